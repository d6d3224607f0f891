//! Errors of the front end.

/// Why a frame could not be processed.
#[derive(Debug, thiserror::Error)]
pub enum FrontendError {
    /// OpenCV reported an error.
    #[error("OpenCV: {0}")]
    OpenCv(#[from] opencv::Error),
    /// The frame does not fit the camera.
    #[error("image is {width}x{height} but the camera is {camera_width}x{camera_height}")]
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
    /// The first frame of a run in a saved map could not be placed in it. The odometry
    /// then puts it at the newest saved keyframe's pose instead; this error reaches the
    /// caller only when the map holds no keyframe to put it at.
    #[error(
        "not localized in the saved map: its {features} ORB features with depth matched at most {most_matches} of one keyframe's (of {keyframes}), and no keyframe gave {min_inliers} RANSAC inliers"
    )]
    NotLocalized {
        /// Frame index.
        index: usize,
        /// Frame time (s).
        t_s: f64,
        /// Keyframes of the map.
        keyframes: usize,
        /// The frame's ORB features with depth.
        features: usize,
        /// The most descriptor matches with one keyframe.
        most_matches: usize,
        /// Inliers needed (`recovery_min_inliers`).
        min_inliers: usize,
    },
    /// The place-recognition vocabulary could not be read.
    #[error("place recognition: {0}")]
    Place(#[from] crate::place::PlaceError),
}
