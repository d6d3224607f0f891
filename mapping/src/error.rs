//! Errors of the mapping crate: inputs and parameters that cannot make a valid map.

/// Why a mapper or a sensor frame could not be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MappingError {
    /// A depth image whose size differs from its camera's: its pixels would be
    /// back-projected along the wrong rays.
    #[error("the depth image is {width}x{height} pixels but its camera is {camera_width}x{camera_height}")]
    DepthSize {
        /// Depth image width (pixels).
        width: u32,
        /// Depth image height (pixels).
        height: u32,
        /// Camera width (pixels).
        camera_width: u32,
        /// Camera height (pixels).
        camera_height: u32,
    },
    /// A point cloud whose number of covariances differs from its number of points.
    #[error("{points} points but {covariances} covariances: one covariance per point is needed")]
    CovarianceCount {
        /// Number of points.
        points: usize,
        /// Number of covariances.
        covariances: usize,
    },
    /// A mapper parameter outside its valid range.
    #[error("mapper parameter {name} = {value}: {reason}")]
    Parameter {
        /// The configuration field (as named in the config struct).
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is expected of it.
        reason: &'static str,
    },
}
