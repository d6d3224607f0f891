//! What the odometry reports per frame: the pose, how it was obtained, timings, and for
//! keyframes the features a back end builds its map from.

use crate::features::OrbDescriptor;
use crate::points::Measurement;
use nalgebra::{Isometry3, Matrix6, Point2};

/// How a frame's pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingStatus {
    /// The first frame: it defines the world frame.
    Initialized,
    /// Estimated from tracked 3-D points.
    Tracked,
    /// Lucas-Kanade could not follow (or kept too few inliers); the pose was found by
    /// matching ORB features against recent keyframes ([`crate::recovery`]).
    Recovered,
    /// Found among the keyframes the run may come back to ([`crate::relocalize`]): the
    /// first frame of a run in a saved map, or a frame that tracking and recovery lost.
    Relocalized,
    /// Lost by the features (tracking, recovery and relocalization), placed by aligning
    /// its depth image with the last keyframe's ([`crate::depth_align`]): the colour image
    /// too blurred to follow, the geometry still sharp. Tracking restarts here.
    DepthAligned,
    /// Not estimable: predicted by the constant-velocity model; tracking restarts here.
    Lost,
}

impl TrackingStatus {
    /// A short lowercase name for reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            TrackingStatus::Initialized => "initialized",
            TrackingStatus::Tracked => "tracked",
            TrackingStatus::Recovered => "recovered",
            TrackingStatus::Relocalized => "relocalized",
            TrackingStatus::DepthAligned => "depth",
            TrackingStatus::Lost => "lost",
        }
    }
}

/// Time spent in each stage of one frame (s).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageTimes {
    /// Corner detection and ORB description (keyframes only).
    pub detect_s: f64,
    /// Grey conversion, pyramid, Lucas-Kanade both ways, 3-D measurement.
    pub track_s: f64,
    /// RANSAC.
    pub ransac_s: f64,
    /// Gauss-Newton refinement.
    pub refine_s: f64,
    /// Wide-baseline recovery (detection, ORB matching, RANSAC), when it ran.
    pub recover_s: f64,
    /// The whole frame.
    pub total_s: f64,
}

/// A keypoint of a keyframe, for a back end's map.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeFeature {
    /// Track identifier: the same keypoint tracked by Lucas-Kanade keeps it from keyframe
    /// to keyframe (a data association a back end can rely on); new keypoints get new ones.
    pub track_id: u64,
    /// Pixel position (distorted image coordinates).
    pub px: Point2<f32>,
    /// The keypoint measured with this keyframe's depth image: 3-D point and covariance in
    /// the keyframe's camera frame (m, m^2). `None` without valid depth there.
    pub measurement: Option<Measurement>,
    /// ORB descriptor, when computed and the point is not too close to the border.
    pub descriptor: Option<OrbDescriptor>,
}

/// An ORB feature detected in a keyframe, with depth ([`KeyframeInfo::place_features`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaceFeature {
    /// Pixel position (distorted image coordinates).
    pub px: Point2<f32>,
    /// ORB descriptor.
    pub descriptor: OrbDescriptor,
    /// The point in the keyframe's camera frame and its covariance (m, m^2).
    pub measurement: Measurement,
}

/// A [`PlaceFeature`] in f32, as the places that hold many keep them (relocalization's
/// remembered keyframes, loop closure, saved maps): 76 bytes instead of 136. The rounding
/// (7 significant digits) is far below the depth's noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PackedFeature {
    /// Pixel position (px, distorted image coordinates).
    pub px: [f32; 2],
    /// ORB descriptor.
    pub descriptor: OrbDescriptor,
    /// The point in the keyframe's camera frame (m).
    pub p_camera_m: [f32; 3],
    /// The upper triangle of its covariance, `[xx, xy, xz, yy, yz, zz]` (m^2).
    pub cov_upper_m2: [f32; 6],
}

impl PackedFeature {
    /// `f` rounded to f32.
    pub fn new(f: &PlaceFeature) -> Self {
        let (p, c) = (&f.measurement.p, &f.measurement.cov);
        Self {
            px: [f.px.x, f.px.y],
            descriptor: f.descriptor,
            p_camera_m: [p.x, p.y, p.z].map(|v| v as f32),
            cov_upper_m2: [c.m11, c.m12, c.m13, c.m22, c.m23, c.m33].map(|v| v as f32),
        }
    }

    /// The measurement back in f64 (the covariance symmetric).
    pub fn measurement(&self) -> Measurement {
        let [x, y, z] = self.p_camera_m.map(f64::from);
        let [a, b, c, d, e, f] = self.cov_upper_m2.map(f64::from);
        Measurement {
            p: nalgebra::Point3::new(x, y, z),
            cov: nalgebra::Matrix3::new(a, b, c, b, d, e, c, e, f),
        }
    }

    /// The feature back in f64.
    pub fn feature(&self) -> PlaceFeature {
        PlaceFeature {
            px: Point2::new(self.px[0], self.px[1]),
            descriptor: self.descriptor,
            measurement: self.measurement(),
        }
    }
}

/// The link of a keyframe to the one before it, as the odometry measured it.
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryLink {
    /// The previous keyframe's identifier.
    pub previous_id: u64,
    /// `previous_from_this`: this keyframe's pose in the previous keyframe's camera frame
    /// (m).
    pub previous_from_this: Isometry3<f64>,
    /// Information matrix of this keyframe's pose estimate (left, world-frame
    /// perturbation, translation then rotation); zero when the pose was predicted rather
    /// than estimated ([`TrackingStatus::Lost`]).
    pub information: Matrix6<f64>,
    /// The feature inliers the pose rests on: 0 when it was predicted
    /// ([`TrackingStatus::Lost`]) or placed by its depth ([`TrackingStatus::DepthAligned`]).
    pub inliers: usize,
}

/// The link of a keyframe to an earlier one (the previous keyframe or an older recent one)
/// measured by aligning their depth images ([`crate::depth_align`]).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthLink {
    /// The earlier keyframe's identifier.
    pub keyframe_id: u64,
    /// `keyframe_from_this`: this keyframe's pose in the earlier keyframe's camera frame
    /// (m).
    pub keyframe_from_this: Isometry3<f64>,
    /// Information matrix of `keyframe_from_this` (left perturbation in the earlier
    /// keyframe's camera frame, translation then rotation; 1/m², 1/rad²).
    pub information: Matrix6<f64>,
}

/// A new keyframe: what a back end needs to add it to its map.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeInfo {
    /// Keyframe identifier (0, 1, 2, ... in the order they are made).
    pub id: u64,
    /// Every tracked keypoint of the keyframe (old tracks and new detections).
    pub features: Vec<KeyframeFeature>,
    /// Multi-scale ORB features detected in the keyframe and measured with its depth
    /// ([`crate::VoConfig::place_features`]; empty when off): unlike the tracked keypoints,
    /// whose positions drift by a pixel or two from the corner, they are found again where
    /// a later pass detects them, so they are what keyframes are matched by when nothing
    /// else ties them (loops, pieces of the map after a lost frame).
    pub place_features: Vec<PlaceFeature>,
    /// The link to the previous keyframe; `None` for the first.
    pub odometry: Option<OdometryLink>,
    /// Links measured by depth alignment to the recent keyframes (newest first), for a
    /// keyframe whose pose rests on few inliers
    /// ([`crate::VoConfig::keyframe_depth_link_inliers`]); empty otherwise, for the first
    /// keyframe, after a lost frame, or where the alignments were refused.
    pub depth_links: Vec<DepthLink>,
}

/// What the odometry says about one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameResult {
    /// Frame index.
    pub index: usize,
    /// Frame time (s).
    pub t_s: f64,
    /// `world_from_camera`; the world frame is the first frame's camera frame, moved by
    /// the back end's corrections when there is one.
    pub world_from_camera: Isometry3<f64>,
    /// The keyframe this frame's pose is relative to (its own identifier for a keyframe).
    pub keyframe_id: u64,
    /// `keyframe_from_camera`: the frame's pose relative to that keyframe (identity for a
    /// keyframe). A back end's later correction of the keyframe moves the frame with it.
    pub keyframe_from_camera: Isometry3<f64>,
    /// How the pose was obtained.
    pub status: TrackingStatus,
    /// The keyframe a recovered or relocalized frame was matched against (this run's, or
    /// a saved map's); `None` otherwise.
    pub matched_keyframe: Option<u64>,
    /// Whether this frame became a keyframe.
    pub keyframe: bool,
    /// Keypoints tracked into this frame.
    pub tracked: usize,
    /// Of them, with a valid 3-D point in this frame and in the keyframe.
    pub correspondences: usize,
    /// RANSAC inliers after refinement.
    pub inliers: usize,
    /// RANSAC iterations.
    pub ransac_iterations: usize,
    /// Information matrix of the pose (left, world-frame perturbation, translation then
    /// rotation; zero when not estimated).
    pub information: Matrix6<f64>,
    /// Stage timings.
    pub timing: StageTimes,
    /// The new keyframe, when this frame became one.
    pub new_keyframe: Option<KeyframeInfo>,
}
