//! Depth links between keyframes: a new keyframe's depth image aligned with the previous
//! keyframe's ([`crate::depth_align`]), started at the odometry's relative pose, when the
//! keyframe's pose rests on few inliers. A back end adds the relative pose found as a
//! pose-pose constraint beside the features' points.

use crate::depth_align::DepthAlignParams;
use crate::result::{DepthLink, OdometryLink};
use crate::vo::VisualOdometry;
use nalgebra::Isometry3;
use stride_core::frame::RgbdFrame;

/// Fewest samples paired, as a fraction of those with depth, for a link: lower than for a
/// lost frame ([`crate::depth_align`]'s 0.4), since the alignment starts from a pose the
/// features measured, and a keyframe after dropped frames sees less of the previous one
/// (teddy_200 after a 1 s gap: 35 %).
const LINK_MIN_PAIRED_FRACTION: f64 = 0.3;

impl VisualOdometry {
    /// The depth link of the keyframe made of `frame`, whose odometry link is `odometry`.
    /// `None` when its pose rests on enough inliers (or the links are off), was not
    /// measured by the features (a lost frame's prediction, or a frame already placed by
    /// its depth: its link would count the same alignment twice), the previous keyframe's
    /// depth is not kept, or the alignment is refused (logged).
    pub(crate) fn depth_link(
        &self,
        frame: &RgbdFrame,
        odometry: &OdometryLink,
    ) -> Option<DepthLink> {
        let inliers = odometry.inliers;
        if inliers == 0 || inliers >= self.config.keyframe_depth_link_inliers {
            return None;
        }
        let previous = self
            .recent
            .keyframes
            .back()
            .filter(|k| k.id == odometry.previous_id)?;
        let params = DepthAlignParams {
            min_paired_fraction: LINK_MIN_PAIRED_FRACTION,
            ..DepthAlignParams::from_config(&self.config)
        };
        // Both in the previous keyframe's frame: the link is relative.
        let a = self.align_with(
            frame,
            previous,
            Isometry3::identity(),
            odometry.previous_from_this,
            &params,
        )?;
        Some(DepthLink {
            previous_id: odometry.previous_id,
            previous_from_this: a.world_from_cur,
            information: a.information,
        })
    }
}
