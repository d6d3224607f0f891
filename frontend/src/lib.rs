//! # stride-frontend
//!
//! RGB-D visual odometry after PUT SLAM's front end (paper 004, section 3.1): keypoints spread
//! evenly over the image ([`features`], FAST with grid bucketing, ORB descriptors on
//! keyframes), pyramidal Lucas-Kanade tracking with a forward-backward check seeded by the
//! predicted motion ([`klt`]), 3-D points with per-point covariances from the depth image
//! ([`points`], paper 000 eqs. 10-12), and the camera motion from Umeyama + RANSAC refined
//! with the covariance-weighted 3-D error ([`motion`]). [`VisualOdometry`] ties them together;
//! [`recovery`] finds frames that tracking loses by matching ORB features against recent
//! keyframes; [`relocalize`] finds those that recovery cannot among every keyframe the run
//! may come back to, by appearance ([`place`]), and places a run's first frame in a saved
//! map ([`VisualOdometry::start_in_map`]).
//!
//! Deterministic: RANSAC is seeded, OpenCV's tracking and detection do not depend on thread
//! scheduling, and nothing else is random.

mod accel;
pub mod config;
pub mod depth_align;
mod depth_link;
pub mod depth_search;
pub mod error;
pub mod features;
mod guided;
mod gyro;
pub mod keyframe;
pub mod klt;
pub mod motion;
mod motion_model;
pub mod orb;
pub mod place;
pub mod points;
pub mod recovery;
pub mod relocalize;
pub mod result;
mod series;
pub mod vo;

pub use accel::AccelerometerFrames;
pub use config::{InlierTest, VoConfig};
pub use error::FrontendError;
pub use gyro::GyroscopeFrames;
pub use result::{
    DepthLink, FrameResult, KeyframeFeature, KeyframeInfo, OdometryLink, PackedFeature,
    PlaceFeature, StageTimes, TrackingStatus,
};
pub use vo::VisualOdometry;

/// Sets the number of threads OpenCV's own pool uses (its parallel Lucas-Kanade and FAST).
/// OpenCV runs beside rayon, so choose it on purpose; results do not depend on it.
pub fn set_opencv_threads(n: usize) -> Result<(), FrontendError> {
    opencv::core::set_num_threads(i32::try_from(n).unwrap_or(1))?;
    Ok(())
}
