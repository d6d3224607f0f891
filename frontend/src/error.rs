//! Errors of the front end.

/// Why a frame could not be processed.
#[derive(Debug, thiserror::Error)]
pub enum FrontendError {
    /// OpenCV reported an error.
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    /// The frame does not fit the camera.
    #[error(
        "frame {index}: image is {width}x{height} but the camera is {camera_width}x{camera_height}"
    )]
    SizeMismatch {
        /// Frame index.
        index: usize,
        /// Image width (px).
        width: u32,
        /// Image height (px).
        height: u32,
        /// Camera width (px).
        camera_width: u32,
        /// Camera height (px).
        camera_height: u32,
    },
    /// A parameter is out of range.
    #[error("invalid visual odometry parameter {name} = {value}: {allowed}")]
    Parameter {
        /// The parameter (a field of `VoConfig`).
        name: &'static str,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: &'static str,
    },
}
