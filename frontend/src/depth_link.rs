//! Depth links between keyframes: a weakly tracked keyframe's depth image aligned with the
//! depth of each recent keyframe ([`crate::depth_align`]), started at the odometry's pose.
//! A back end adds each relative pose found as a pose-pose constraint beside the features'
//! points.
//!
//! Why more than the previous keyframe: under blur a keyframe starts every one or two
//! frames, and a chain of links between such neighbours adds up their errors (the depth
//! alone, aligned frame to frame on teddy_200, drifts to 18 mm; with a keyframe every 6-12
//! frames, 8 mm). The recent keyframes kept for recovery stand 0.15 m or 15 degrees apart
//! (`recovery::SPACING_M`), so links to them span the longer baselines. Where keyframes
//! already stand far apart (a low frame rate, a gap) the previous one is linked alone.

use crate::depth_align::DepthAlignParams;
use crate::recovery::align_with_keyframe;
use crate::result::{DepthLink, OdometryLink};
use crate::vo::VisualOdometry;
use nalgebra::Isometry3;
use rayon::prelude::*;
use stride_core::frame::RgbdFrame;
use stride_core::image::DepthImage;

/// Fewest samples paired, as a fraction of those with depth, for a link: lower than for a
/// lost frame ([`crate::depth_align`]'s 0.4), since the alignment starts from a pose the
/// features measured, and a keyframe after dropped frames sees less of the previous one
/// (teddy_200 after a 1 s gap: 35 %).
const LINK_MIN_PAIRED_FRACTION: f64 = 0.3;

/// A weak keyframe is linked to the older recent keyframes, beyond the previous one, only
/// when it stands within this distance (m) and [`SHORT_STEP_DEG`] of the previous one: a
/// chain of such short links is what adds up (teddy_200 blurred to 25 px: keyframes a
/// median 12 mm and 0.9 degree apart). At 2-3 frames per second keyframes stand 10-20 cm
/// and 8-12 degrees apart, a chain is short, and the older keyframes overlap less: linking
/// them there cost every 10th frame of teddy_200 4.4 -> 4.8 mm.
const SHORT_STEP_M: f64 = 0.05;

/// See [`SHORT_STEP_M`] (degrees).
const SHORT_STEP_DEG: f64 = 5.0;

impl VisualOdometry {
    /// The depth links of the keyframe made of `frame`, whose odometry link is `odometry`:
    /// one to each recent keyframe (newest first; only the previous one after a step
    /// longer than [`SHORT_STEP_M`] or [`SHORT_STEP_DEG`]) whose alignment is accepted.
    /// Empty when its pose rests on enough inliers (or the links are off), was not
    /// measured by the features (a lost frame's prediction, or a frame already placed by
    /// its depth: its link would count the same alignment twice), or the previous
    /// keyframe's depth is not kept. A refused alignment is logged and leaves that link
    /// out. The recent keyframes' poses are the odometry's as it recorded them, so the
    /// starts for the older ones can be a few centimetres off (the first level pairs
    /// within 10 cm); the links themselves are relative.
    pub(crate) fn depth_links(&self, frame: &RgbdFrame, odometry: &OdometryLink) -> Vec<DepthLink> {
        let inliers = odometry.inliers;
        if inliers == 0 || inliers >= self.config.keyframe_depth_link_inliers {
            return Vec::new();
        }
        let Some(previous) = self
            .recent
            .keyframes
            .back()
            .filter(|k| k.id == odometry.previous_id)
        else {
            return Vec::new();
        };
        let step = &odometry.previous_from_this;
        let short = step.translation.vector.norm() < SHORT_STEP_M
            && step.rotation.angle().to_degrees() < SHORT_STEP_DEG;
        let world_from_this = previous.world_from_kf * step;
        let params = DepthAlignParams {
            min_paired_fraction: LINK_MIN_PAIRED_FRACTION,
            ..DepthAlignParams::from_config(&self.config)
        };
        // The keyframes' depth and poses only: their pyramids are not shared across
        // threads. Each alignment is computed alone, so the links do not depend on the
        // number of threads.
        let targets: Vec<(u64, &DepthImage, Isometry3<f64>)> = self
            .recent
            .keyframes
            .iter()
            .rev()
            .take(if short { usize::MAX } else { 1 })
            .map(|k| (k.id, &k.depth_m, k.world_from_kf))
            .collect();
        // Collected in order: the links come newest first whatever the thread count.
        let camera = &self.camera;
        targets
            .par_iter()
            .filter_map(|&(id, depth_m, world_from_kf)| {
                // Both in the linked keyframe's frame: the link is relative.
                let keyframe = (id, depth_m, Isometry3::identity());
                let start = world_from_kf.inverse() * world_from_this;
                let a = align_with_keyframe(camera, frame, keyframe, start, &params)?;
                Some(DepthLink {
                    keyframe_id: id,
                    keyframe_from_this: a.world_from_cur,
                    information: a.information,
                })
            })
            .collect()
    }
}
