//! Depth links between keyframes: a weakly tracked keyframe's depth image aligned with the
//! depth of each recent keyframe ([`crate::depth_align`]), started at the odometry's pose.
//! A back end adds each relative pose found as a pose-pose constraint beside the features'
//! points.
//!
//! Why more than the previous keyframe: under blur a keyframe starts every one or two
//! frames, and a chain of links between such neighbours adds up their errors (the depth
//! alone, aligned frame to frame on teddy_200, drifts to 18 mm; with a keyframe every 6-12
//! frames, 8 mm). The recent keyframes kept for recovery stand 0.15 m or 15 degrees apart
//! (`recovery::SPACING_M`), so links to them span the longer baselines; in a chain of weak
//! keyframes two nearby ones at 4.5 and 9 cm are linked too ([`NEARBY_BASELINES_M`]).
//! Where keyframes already stand far apart (a low frame rate, a gap) the previous one is
//! linked alone.

use crate::depth_align::DepthAlignParams;
use crate::recovery::{align_with_keyframe, NearbyKeyframe};
use crate::result::{DepthLink, OdometryLink};
use crate::vo::VisualOdometry;
use nalgebra::Isometry3;
use rayon::prelude::*;
use std::collections::VecDeque;
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

/// Baselines (m) at which a weak keyframe after a short step, in a chain of weak keyframes
/// (the previous one was linked too), is also linked to the nearby keyframe
/// (`recovery::NEARBY_KEYFRAMES`) standing nearest to each: the depth alone drifts least
/// with 4-9 cm between a frame and its reference (teddy_200, a keyframe every 6-12 frames:
/// 8 mm; every frame: 18 mm), a range the spaced recent keyframes (0.15 m apart) skip.
/// teddy_200 blurred to 25 px by the peers' injector, seeds 1-8: 9.21 -> 8.47 mm mean
/// (worst 11.22 -> 10.29); by the study's own blur, the same (sum over 0-35 px 63.7 mm
/// both). Without the chain condition a lone weak keyframe on a synthetic walk got them
/// too, each within 2 mm of the truth, and the walk's ATE rose 1.98 -> 3.12 mm; these
/// baselines alone, without the spaced keyframes, 15.8 mm at 25 px (seeds 1-3).
const NEARBY_BASELINES_M: [f64; 2] = [0.045, 0.09];

impl VisualOdometry {
    /// The depth links of the keyframe made of `frame`, whose odometry link is `odometry`:
    /// one to each recent keyframe (newest first; only the previous one after a step
    /// longer than [`SHORT_STEP_M`] or [`SHORT_STEP_DEG`]), then, in a chain of weak
    /// keyframes, to the nearby ones at [`NEARBY_BASELINES_M`], whose alignment is accepted.
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
        let mut targets: Vec<(u64, &DepthImage, Isometry3<f64>)> = self
            .recent
            .keyframes
            .iter()
            .rev()
            .take(if short { usize::MAX } else { 1 })
            .map(|k| (k.id, &*k.depth_m, k.world_from_kf))
            .collect();
        // In a chain of weak keyframes (the previous one was linked too), also the
        // nearby keyframes at the short baselines.
        let chain = self
            .recent
            .nearby
            .back()
            .is_some_and(|k| k.id == previous.id && k.linked);
        if short && chain {
            for k in nearest_at_baselines(&self.recent.nearby, &world_from_this, previous.id) {
                if targets.iter().all(|t| t.0 != k.id) {
                    targets.push((k.id, &*k.depth_m, k.world_from_kf));
                }
            }
        }
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

/// For each of [`NEARBY_BASELINES_M`], the keyframe of `nearby` (other than
/// `previous_id`) whose distance from `world_from_this` is nearest to it (the same one can
/// come twice), in the baselines' order.
fn nearest_at_baselines<'a>(
    nearby: &'a VecDeque<NearbyKeyframe>,
    world_from_this: &Isometry3<f64>,
    previous_id: u64,
) -> Vec<&'a NearbyKeyframe> {
    let distance_m = |k: &NearbyKeyframe| {
        (k.world_from_kf.inverse() * world_from_this)
            .translation
            .vector
            .norm()
    };
    NEARBY_BASELINES_M
        .iter()
        .filter_map(|&baseline_m| {
            let off = |k: &&NearbyKeyframe| (distance_m(k) - baseline_m).abs();
            (nearby.iter())
                .filter(|k| k.id != previous_id)
                .min_by(|a, b| off(a).total_cmp(&off(b)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use std::sync::Arc;

    /// Keyframes 1 cm apart along the optical axis, the newest at 15 cm: from a keyframe
    /// at 16 cm whose previous one is the newest, the links reach the keyframes 4.5 and 9
    /// cm back, and never the previous one.
    #[test]
    fn the_nearby_keyframes_nearest_the_short_baselines_are_linked() {
        let depth_m = Arc::new(DepthImage::filled(4, 4, 1.0));
        let at_z = |z: f64| Isometry3::translation(0.0, 0.0, z);
        let nearby: VecDeque<NearbyKeyframe> = (0..16)
            .map(|i| NearbyKeyframe {
                id: i,
                depth_m: Arc::clone(&depth_m),
                world_from_kf: at_z(0.01 * i as f64),
                linked: true,
            })
            .collect();
        let this = at_z(0.16);
        let ids: Vec<u64> = nearest_at_baselines(&nearby, &this, 15)
            .iter()
            .map(|k| k.id)
            .collect();
        // 16 - 4.5 = 11.5 cm: keyframes 11 and 12 tie, rounding decides; 16 - 9 = 7 cm.
        assert!(ids == vec![11, 7] || ids == vec![12, 7], "{ids:?}");
        let far = at_z(1.0);
        let ids: Vec<u64> = nearest_at_baselines(&nearby, &far, 15)
            .iter()
            .map(|k| k.id)
            .collect();
        assert_eq!(
            ids,
            vec![14, 14],
            "all too near: the farthest but the previous"
        );
    }
}
