//! The final alignment of the map's views against each other.
//!
//! While the run goes, each view is laid onto the map of the views before it
//! ([`super::TerrainConfig::align`]); only part of the correction found is applied, since
//! corrections that build on corrected views compound. At the end every kept view is
//! aligned again, now against the map of all views (the consensus, including the views
//! after it), and the live map is rebuilt from the views at their new poses. A pass moves
//! each view `final_alignment_gain` of the way from the SLAM's pose to where the consensus
//! puts it (height and the two tilts only, as [`stride_mapping::align`]); a few passes
//! let the consensus itself settle. The SLAM's pose keeps the rest: what the views cannot
//! tell apart (the whole map bending slowly from one end to the other) stays where the SLAM
//! put it.
//!
//! On teddy_200 the SLAM's orientation errors (about 0.3 degree from view to view) made the
//! map's floor rougher than the same views' at ground-truth poses; see
//! docs/mapping-studies.md ("All views against each other") for what the passes measured.

use super::{PipelineError, Terrain};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::time::Instant;
use stride_mapping::align::{AlignConfig, AlignOutcome};
use stride_mapping::input::SensorFrame;
use stride_mapping::ElevationMapper;

/// What one pass of the final alignment did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct RealignPass {
    /// Views aligned against the map of all views.
    pub aligned: usize,
    /// Views left where they were (too few points on known cells, or a correction beyond
    /// the alignment's limits).
    pub kept: usize,
    /// Root mean square of the views' change of orientation in this pass (rad).
    pub rotation_rms_rad: f64,
    /// Root mean square of the views' change of height in this pass (m).
    pub height_rms_m: f64,
    /// Wall time of the pass, the rebuild included (s).
    pub time_s: f64,
}

/// `fraction` of the world-frame correction `world_from_world` (m, rad): the rotation
/// interpolated from the identity, the translation scaled.
fn part_of(world_from_world: &Isometry3<f64>, fraction: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(world_from_world.translation.vector * fraction),
        UnitQuaternion::identity().slerp(&world_from_world.rotation, fraction),
    )
}

impl Terrain {
    /// One pass of the final alignment (see the module documentation); nothing without
    /// [`super::TerrainConfig::align`].
    pub(super) fn realign(&mut self) -> Result<(), PipelineError> {
        let Some(align) = self.config.align.as_ref() else {
            return Ok(());
        };
        let start = Instant::now();
        // The whole offset from the consensus is measured; the gain is applied below,
        // relative to the SLAM's pose rather than to the pose of the previous pass.
        let cfg = AlignConfig {
            gain: 1.0,
            ..align.clone()
        };
        let gain = self.config.final_alignment_gain;
        let mut pass = RealignPass::default();
        // The views with a pose, aligned against the map of all of them at once.
        let mut placed = Vec::with_capacity(self.stored.len());
        let mut frames = Vec::with_capacity(self.stored.len());
        for (i, s) in self.stored.iter().enumerate() {
            if let (Some(at), Some(slam)) = (s.integrated_at, s.mapped_at) {
                frames.push(SensorFrame::depth(&s.depth_m, &self.camera, at, s.t_s)?);
                placed.push((i, at, slam));
            }
        }
        let outcomes = self.live.align_each(&frames, &cfg);
        drop(frames);
        let mut new_poses = vec![None; self.stored.len()];
        for ((i, at, slam), outcome) in placed.into_iter().zip(outcomes) {
            let now = match outcome {
                AlignOutcome::Aligned(a) => {
                    pass.aligned += 1;
                    let whole = a.correction * at * slam.inverse();
                    part_of(&whole, gain) * slam
                }
                _ => {
                    pass.kept += 1;
                    at
                }
            };
            let change = at.inverse() * now;
            pass.rotation_rms_rad += change.rotation.angle().powi(2);
            pass.height_rms_m += (now.translation.z - at.translation.z).powi(2);
            if let Some(slot) = new_poses.get_mut(i) {
                *slot = Some(now);
            }
        }
        let n = (pass.aligned + pass.kept).max(1) as f64;
        pass.rotation_rms_rad = (pass.rotation_rms_rad / n).sqrt();
        pass.height_rms_m = (pass.height_rms_m / n).sqrt();
        // The live map anew from every view at its new pose.
        self.clear_live()?;
        for (s, pose) in self.stored.iter_mut().zip(new_poses) {
            let Some(pose) = pose else { continue };
            let frame = SensorFrame::depth(&s.depth_m, &self.camera, pose, s.t_s)?;
            self.live.integrate(&frame);
            s.integrated_at = Some(pose);
        }
        pass.time_s = start.elapsed().as_secs_f64();
        tracing::debug!(
            "final alignment pass: {} views aligned, {} kept; change rms {:.3} deg, {:.2} mm; {:.0} ms",
            pass.aligned,
            pass.kept,
            pass.rotation_rms_rad.to_degrees(),
            pass.height_rms_m * 1e3,
            pass.time_s * 1e3
        );
        self.stats.final_alignment.push(pass);
        Ok(())
    }
}
