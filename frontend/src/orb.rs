//! ORB features with depth, and their matching: what wide-baseline recovery
//! ([`crate::recovery`]), relocalization and the keyframes' place features are made of.
//!
//! Multi-scale ORB (OpenCV's) on a grey image, each feature measured in 3-D by the depth
//! image (camera frame, m, with its covariance); matches by Hamming distance, kept when close
//! enough, clearly better than the second nearest, and the only claim on their reference.

use crate::error::FrontendError;
use crate::features::{match_descriptors, OrbDescriptor};
use crate::points::{measure, Measurement, ShutterMotion};
use crate::PlaceFeature;
use crate::VoConfig;
use nalgebra::Point2;
use opencv::core::{KeyPoint, Mat, Point2f, Ptr, Vector};
use opencv::features2d::{Feature2DTrait, ORB_ScoreType, ORB};
use opencv::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// Largest Hamming distance (of 256 bits) of an accepted match: ORB-SLAM's stricter bound.
pub const MAX_HAMMING: u32 = 50;
/// A match is kept only when its distance is below this fraction of the second best's.
pub const RATIO: f64 = 0.8;
/// ORB features per image: as ORB-SLAM extracts from a VGA frame.
const ORB_FEATURES: i32 = 1000;
/// Pyramid levels of the keyframes' place features ([`crate::VoConfig::place_features`]):
/// four (a 1.7x range of scales) matched loops as well as eight on teddy's pingpong
/// sequences (1,000 frames, seeds 1-3: ATE 6.65 against 6.84 mm) for less time.
pub(crate) const PLACE_LEVELS: i32 = 4;
/// ORB's FAST threshold: lower than the tracking's, for the weakly textured, blurred frames
/// that recovery most often faces.
const ORB_FAST_THRESHOLD: i32 = 12;

/// An ORB feature with a depth measurement: its pixel, descriptor and 3-D point in its
/// camera's frame (m, covariance m^2).
#[derive(Debug, Clone, Copy)]
pub(crate) struct OrbPoint {
    pub(crate) px: Point2f,
    pub(crate) descriptor: OrbDescriptor,
    pub(crate) p_camera: Measurement,
}

impl From<PlaceFeature> for OrbPoint {
    fn from(f: PlaceFeature) -> Self {
        Self {
            px: Point2f::new(f.px.x, f.px.y),
            descriptor: f.descriptor,
            p_camera: f.measurement,
        }
    }
}

impl From<&OrbPoint> for PlaceFeature {
    fn from(o: &OrbPoint) -> Self {
        Self {
            px: Point2::new(o.px.x, o.px.y),
            descriptor: o.descriptor,
            measurement: o.p_camera,
        }
    }
}

/// OpenCV's ORB as recovery (`levels` 8) and the place features ([`PLACE_LEVELS`]) use
/// it: the same extractor but for its pyramid's depth.
pub(crate) fn orb_extractor(levels: i32) -> Result<Ptr<ORB>, FrontendError> {
    Ok(ORB::create(
        ORB_FEATURES,
        1.2,
        levels,
        31,
        0,
        2,
        ORB_ScoreType::HARRIS_SCORE,
        31,
        ORB_FAST_THRESHOLD,
    )?)
}

/// Place features as a keyframe gets them ([`crate::KeyframeInfo::place_features`]), for
/// tools that describe images the way relocalization and loop closure see keyframes
/// (`stride bench place`).
pub struct PlaceExtractor {
    orb: Ptr<ORB>,
}

impl PlaceExtractor {
    /// The extractor the odometry uses for keyframes.
    pub fn new() -> Result<Self, FrontendError> {
        Ok(Self {
            orb: orb_extractor(PLACE_LEVELS)?,
        })
    }

    /// The ORB descriptors of `gray`'s place features: those with a depth in `depth_m`
    /// that `config`'s range and edge test accept (a still camera, `camera` the image's).
    pub fn descriptors(
        &mut self,
        gray: &Mat,
        depth_m: &DepthImage,
        camera: &PinholeCamera,
        config: &VoConfig,
    ) -> Result<Vec<OrbDescriptor>, FrontendError> {
        let still = ShutterMotion::default();
        let points = orb_points(&mut self.orb, gray, depth_m, camera, &still, config)?;
        Ok(points.iter().map(|p| p.descriptor).collect())
    }
}

/// ORB points of a grey image with depth.
pub(crate) fn orb_points(
    orb: &mut Ptr<ORB>,
    gray: &Mat,
    depth_m: &DepthImage,
    camera: &PinholeCamera,
    shutter: &ShutterMotion,
    config: &VoConfig,
) -> Result<Vec<OrbPoint>, FrontendError> {
    {
        let mut kps = Vector::<KeyPoint>::new();
        let mut desc = Mat::default();
        orb.detect_and_compute(gray, &opencv::core::no_array(), &mut kps, &mut desc, false)?;
        let mut out = Vec::with_capacity(kps.len());
        for (row, k) in kps.iter().enumerate() {
            let px = k.pt();
            let (Ok(bytes), Some(p_camera)) = (
                desc.at_row::<u8>(row as i32),
                measure(depth_m, camera, (px.x, px.y), shutter, config),
            ) else {
                continue;
            };
            if let Ok(descriptor) = <OrbDescriptor>::try_from(bytes) {
                out.push(OrbPoint {
                    px,
                    descriptor,
                    p_camera,
                });
            }
        }
        Ok(out)
    }
}

/// Accepted matches `(query, reference)` between two sets of ORB points
/// ([`match_descriptors`] with [`MAX_HAMMING`] and [`RATIO`]).
pub(crate) fn match_points(query: &[OrbPoint], reference: &[OrbPoint]) -> Vec<(usize, usize)> {
    match_points_within(query, reference, (MAX_HAMMING, RATIO))
}

/// [`match_points`] with the bounds `(max_hamming, ratio)` given.
pub(crate) fn match_points_within(
    q: &[OrbPoint],
    r: &[OrbPoint],
    bounds: (u32, f64),
) -> Vec<(usize, usize)> {
    let descriptors = |p: &[OrbPoint]| p.iter().map(|o| o.descriptor).collect::<Vec<_>>();
    match_descriptors(&descriptors(q), &descriptors(r), bounds.0, bounds.1)
}
