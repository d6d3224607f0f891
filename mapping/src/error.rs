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

/// Largest window accepted, in cells per side (16.8 million cells: 1 mm cells over 4 m).
pub const MAX_CELLS_PER_SIDE: usize = 4096;

/// Checks a parameter that must be finite and positive.
pub(crate) fn positive(name: &'static str, value: f64) -> Result<(), MappingError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(MappingError::Parameter {
            name,
            value,
            reason: "must be positive and finite",
        })
    }
}

/// Checks a parameter that must be finite and not negative.
pub(crate) fn non_negative(name: &'static str, value: f64) -> Result<(), MappingError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(MappingError::Parameter {
            name,
            value,
            reason: "must be finite and not negative",
        })
    }
}

/// Checks a sensor model's depth range `[min_m, max_m]` (m): finite, not negative, min
/// below max. Errors name the keys as a configuration file spells them
/// (`sensor.min_depth_m`, `sensor.max_depth_m`).
pub(crate) fn depth_range(min_m: f64, max_m: f64) -> Result<(), MappingError> {
    non_negative("sensor.min_depth_m", min_m)?;
    positive("sensor.max_depth_m", max_m)?;
    if min_m < max_m {
        Ok(())
    } else {
        Err(MappingError::Parameter {
            name: "sensor.max_depth_m",
            value: max_m,
            reason: "must exceed sensor.min_depth_m",
        })
    }
}

/// Checks a moving window's parameters (m) and returns its number of cells per side:
/// positive sizes, between 8 and [`MAX_CELLS_PER_SIDE`] cells per side.
pub(crate) fn window_cells(
    resolution_m: f64,
    size_m: f64,
    lookahead_m: f64,
    recenter_threshold_m: f64,
) -> Result<usize, MappingError> {
    positive("resolution_m", resolution_m)?;
    positive("size_m", size_m)?;
    non_negative("lookahead_m", lookahead_m)?;
    non_negative("recenter_threshold_m", recenter_threshold_m)?;
    let cells = (size_m / resolution_m).round();
    if !(8.0..=MAX_CELLS_PER_SIDE as f64).contains(&cells) {
        return Err(MappingError::Parameter {
            name: "size_m",
            value: size_m,
            reason: "must hold between 8 and 4096 cells of resolution_m per side",
        });
    }
    Ok(cells as usize)
}
