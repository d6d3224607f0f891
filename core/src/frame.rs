//! The RGB-D frame: a colour image and a registered depth image taken at (nearly) the same
//! time.

use crate::image::{DepthImage, RgbImage};

/// One RGB-D frame. The depth image is registered to the colour camera: pixel `(u, v)` of
/// both images sees the same ray.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdFrame {
    /// Zero-based index of the frame in its sequence.
    pub index: usize,
    /// Capture time of the colour image (seconds; the sequence's epoch).
    pub t_s: f64,
    /// Capture time of the depth image (seconds); differs from `t_s` by at most the
    /// association window of the dataset reader.
    pub t_depth_s: f64,
    /// Colour image.
    pub rgb: RgbImage,
    /// Depth along the optical axis in metres; 0.0 where the sensor gave no return.
    pub depth_m: DepthImage,
}
