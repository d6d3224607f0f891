//! The depth alignment from many starts, for the first frame after dropped frames that
//! nothing else places, and the depth's check of a pose from ORB matches for that frame.
//!
//! After a gap of a second or two the motion model's guess can be 0.2-0.5 m and 10-30
//! degrees off, beyond the reach of the depth alignment ([`crate::depth_align`]), while the
//! depth images still overlap enough to fix the pose when the alignment starts near it
//! (teddy_200's 2 s gaps: 23-29 % of the samples paired, within 6-17 mm and 1-2 degrees of
//! the ground truth; docs/slam.md, Known limits). So the alignment, with two coarser levels
//! ([`crate::depth_align::align_coarse`]), starts from a fixed grid around the guess: turned
//! about the camera's vertical axis by up to [`MAX_TURN_DEG`] in steps of [`TURN_STEP_DEG`],
//! moved sideways and along the view by up to [`MAX_MOVE_M`] in steps of [`MOVE_STEP_M`].
//! Every start runs the coarse levels; the [`REFINED_STARTS`] that paired most samples there
//! go on through the fine ones. Of those that converge, pass the alignment's own checks and
//! pair enough samples ([`accepted`]: a fifth of them, or a tenth and 30 % of those that
//! land on the keyframe's surface), the one with the most samples paired wins (the first
//! in the grid's order among equals). The grid is fixed and the starts run in parallel
//! with their results kept in order, so the result is repeatable whatever the thread count.
//!
//! The same depth checks a pose that ORB matches give such a frame
//! (`VisualOdometry::checked_by_depth`): a few dozen matches between views half a metre
//! apart can agree on a wrong pose, and the alignment started there corrects it; the
//! matches that hold at the corrected pose stay as tracks.

use crate::depth_align::{align, align_coarse, DepthAlignParams, DepthAlignment, DepthView};
use crate::keyframe::Track;
use crate::motion::{is_inlier, Correspondence};
use crate::points::Measurement;
use crate::recovery::{orb_motion_params, Recovered};
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use stride_core::frame::RgbdFrame;

/// Largest turn of a start from the guess, either way (degrees).
pub const MAX_TURN_DEG: f64 = 40.0;
/// Step between the starts' turns (degrees).
pub const TURN_STEP_DEG: f64 = 10.0;
/// Largest move of a start from the guess, sideways and along the view, either way (m).
pub const MAX_MOVE_M: f64 = 0.4;
/// Step between the starts' moves (m).
pub const MOVE_STEP_M: f64 = 0.2;
/// Fewest samples paired with the keyframe's surface, as a fraction of the samples with
/// depth, for a result to be taken on its overlap alone (across teddy_200's gaps the poses
/// taken pair 20-32 %, a wrong one from the last frame's pose paired 19 %).
pub const MIN_PAIRED_FRACTION: f64 = 0.2;
/// The least overlap of a result taken for its consistency ([`MIN_PAIRED_ON_SURFACE`]):
/// after a fast stretch the views share less than [`MIN_PAIRED_FRACTION`] of the samples,
/// and a true pose still pairs a good share of those that land on the keyframe's surface.
pub const LOW_OVERLAP_MIN_FRACTION: f64 = 0.1;
/// Fewest samples paired, as a fraction of those that land on the keyframe's surface
/// (`DepthAlignment::on_surface`), for a result of low overlap. On teddy_200's gaps the
/// poses the search and the check took paired 32-54 % of them (20-32 % of all samples),
/// the wrong or unconverged results 11-22 % (7-14 % of all): a wrong pose lands many
/// samples on the surface, far from it.
pub const MIN_PAIRED_ON_SURFACE: f64 = 0.3;
/// How far (m) the depth alignment started at a pose from ORB matches may move it before
/// the depth's pose replaces it (`VisualOdometry::checked_by_depth`). Across teddy_200's
/// 2 s gaps the alignment lands 5-19 mm from the ground truth, so a correct ORB pose moves
/// less; the wrong ones seen moved 58-213 mm.
pub const CHECK_MAX_MOVE_M: f64 = 0.05;
/// The turn (degrees) that [`CHECK_MAX_MOVE_M`] allows: the alignment lands within 0.3-2
/// degrees of the truth there; the wrong ORB poses seen moved 3.5-14 degrees.
pub const CHECK_MAX_TURN_DEG: f64 = 3.0;

/// How many starts go on to the fine levels: those whose coarse levels paired most samples.
/// Most of the grid's starts converge to a few poses, and the best-paired one is among the
/// first few: with 4, 8, 16 or 32 of them kept, teddy_200's searched gaps (21 runs) end
/// within 0.2 mm of ATE of the run that refines all 225, in about a third of its time.
pub const REFINED_STARTS: usize = 8;

/// The alignment's settings for the search and the check: the odometry's, with the least
/// overlap a result may have ([`LOW_OVERLAP_MIN_FRACTION`]; [`accepted`] asks more).
fn search_params(config: &crate::VoConfig) -> DepthAlignParams {
    DepthAlignParams {
        min_paired_fraction: LOW_OVERLAP_MIN_FRACTION,
        ..DepthAlignParams::from_config(config)
    }
}

/// Whether the search (or the check) takes an alignment that passed its own checks: one
/// that pairs [`MIN_PAIRED_FRACTION`] of its samples, or [`LOW_OVERLAP_MIN_FRACTION`] of
/// them and [`MIN_PAIRED_ON_SURFACE`] of those that land on the keyframe's surface.
pub fn accepted(a: &DepthAlignment) -> bool {
    let pairs = a.pairs as f64;
    pairs >= MIN_PAIRED_FRACTION * a.samples as f64
        || (pairs >= LOW_OVERLAP_MIN_FRACTION * a.samples as f64
            && pairs >= MIN_PAIRED_ON_SURFACE * a.on_surface as f64)
}

/// The starts around `guess` (`world_from_camera`): the guess moved in its own camera frame
/// by `(dx, 0, dz)` and turned about its y axis (the camera's vertical).
pub fn starts(guess: &Isometry3<f64>) -> Vec<Isometry3<f64>> {
    let steps = |max: f64, step: f64| -> Vec<f64> {
        let n = (max / step).round() as i64;
        (-n..=n).map(|k| k as f64 * step).collect()
    };
    let turns = steps(MAX_TURN_DEG, TURN_STEP_DEG);
    let moves = steps(MAX_MOVE_M, MOVE_STEP_M);
    let mut out = Vec::with_capacity(turns.len() * moves.len() * moves.len());
    for &turn in &turns {
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), turn.to_radians());
        for &dx in &moves {
            for &dz in &moves {
                out.push(guess * Isometry3::from_parts(Translation3::new(dx, 0.0, dz), rotation));
            }
        }
    }
    out
}

/// The best-paired of the alignments of `current` with `keyframe` from [`starts`] around
/// `current.world_from_camera`, if any passes the alignment's checks with `params` and is
/// [`accepted`]: every start through the coarse levels ([`align_coarse`]), the
/// [`REFINED_STARTS`] that paired most samples there on through the fine ones ([`align`]).
pub fn best_of_starts(
    keyframe: &DepthView<'_>,
    current: &DepthView<'_>,
    camera: &stride_core::camera::PinholeCamera,
    params: &DepthAlignParams,
) -> Option<DepthAlignment> {
    use rayon::prelude::*;
    let view = |world_from_camera| DepthView {
        depth_m: current.depth_m,
        world_from_camera,
    };
    // In parallel, collected in the grid's order, and the grid's order decides among
    // equals: the result is the same whatever the thread count.
    let mut coarse: Vec<(usize, Isometry3<f64>, usize)> = starts(&current.world_from_camera)
        .into_par_iter()
        .enumerate()
        .map(|(i, start)| {
            let (pose, pairs) = align_coarse(keyframe, &view(start), camera, params);
            (i, pose, pairs)
        })
        .collect();
    coarse.sort_by(|a, b| b.2.cmp(&a.2).then(a.0.cmp(&b.0)));
    coarse.truncate(REFINED_STARTS);
    coarse.sort_by_key(|c| c.0);
    let aligned: Vec<Option<DepthAlignment>> = coarse
        .into_par_iter()
        .map(|(_, pose, _)| {
            let a = align(keyframe, &view(pose), camera, params).ok();
            a.filter(accepted)
        })
        .collect();
    aligned
        .into_iter()
        .flatten()
        .fold(None, |best: Option<DepthAlignment>, a| match best {
            Some(b) if b.pairs >= a.pairs => Some(b),
            _ => Some(a),
        })
}

impl VisualOdometry {
    /// Places the first frame after dropped frames by its depth from many starts around
    /// `world_from_pred` (see the module documentation); `None` when the search or depth
    /// alignment is off, no keyframe's depth is kept, or no start converges to an accepted result.
    pub(crate) fn search_depth(
        &self,
        frame: &RgbdFrame,
        world_from_pred: &Isometry3<f64>,
    ) -> Option<Recovered> {
        if !(self.config.depth_alignment && self.config.depth_search) {
            return None;
        }
        let kf = self.recent.keyframes.back()?;
        let params = search_params(&self.config);
        let keyframe = DepthView {
            depth_m: &kf.depth_m,
            world_from_camera: kf.world_from_kf,
        };
        let current = DepthView {
            depth_m: &frame.depth_m,
            world_from_camera: *world_from_pred,
        };
        let Some(a) = best_of_starts(&keyframe, &current, &self.camera, &params) else {
            tracing::debug!(
                "frame {}: no start of the depth search converged to an accepted pose",
                frame.index
            );
            return None;
        };
        tracing::debug!(
            "frame {}: depth search placed it against keyframe {} ({} of {} samples paired, rms {:.2} sigma)",
            frame.index, kf.id, a.pairs, a.samples, a.rms_sigmas
        );
        Some(Recovered::by_depth(&a, kf.id, &kf.world_from_kf))
    }

    /// Checks `found`, a pose of the first frame after dropped frames from ORB matches,
    /// against the frame's depth: the alignment with the newest keyframe, started at it,
    /// taken as the search takes its results ([`accepted`]). When that is accepted and
    /// moves the pose by more than [`CHECK_MAX_MOVE_M`] or [`CHECK_MAX_TURN_DEG`], the
    /// depth's pose is returned ([`Recovered::by_depth`]), with those of `found`'s tracks
    /// whose matches are still inliers there as its tracks; `None` when the depth agrees,
    /// is refused, or the search is off. A few dozen ORB inliers between views
    /// 0.5 m and 30 degrees apart can agree on a pose 0.1-0.2 m and 8-14 degrees off, which
    /// thousands of depth samples correct (teddy_200, 2 s dropped at 2.0 and 2.2 s).
    pub(crate) fn checked_by_depth(
        &self,
        frame: &RgbdFrame,
        found: &Recovered,
    ) -> Option<Recovered> {
        if !(self.config.depth_alignment && self.config.depth_search) {
            return None;
        }
        let kf = self.recent.keyframes.back()?;
        let params = search_params(&self.config);
        let a = self.align_with(frame, kf, kf.world_from_kf, found.world_from_cur, &params)?;
        if !accepted(&a) {
            return None;
        }
        let moved = found.world_from_cur.inverse() * a.world_from_cur;
        let (move_m, turn_deg) = (
            moved.translation.vector.norm(),
            moved.rotation.angle().to_degrees(),
        );
        if move_m <= CHECK_MAX_MOVE_M && turn_deg <= CHECK_MAX_TURN_DEG {
            return None;
        }
        // The matches that still hold at the depth's pose stay as tracks, as recovery's do:
        // the frames after the gap go on tracking the points seen before it.
        let mut placed = Recovered::by_depth(&a, kf.id, &kf.world_from_kf);
        let orb = orb_motion_params(&self.config, 0);
        let holds = |(track, current): &&(Track, Option<Measurement>)| match (&track.point, current)
        {
            (Some(point), Some(current)) => {
                let c = Correspondence {
                    reference: point.world,
                    current: *current,
                };
                is_inlier(&c, &a.world_from_cur, orb.test, orb.model_noise_m)
            }
            _ => false,
        };
        placed.tracks = found.tracks.iter().filter(holds).cloned().collect();
        tracing::debug!(
            "frame {}: the depth moved its pose from ORB matches by {:.0} mm and {:.1} deg ({} of {} samples paired with keyframe {}); the depth's pose is kept, with {} of the {} matches",
            frame.index, move_m * 1e3, turn_deg, a.pairs, a.samples, kf.id, placed.tracks.len(), found.tracks.len()
        );
        Some(placed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_overlap_is_taken_only_where_it_agrees() {
        let result = |pairs, on_surface| DepthAlignment {
            world_from_cur: Isometry3::identity(),
            pairs,
            samples: 10_000,
            on_surface,
            rms_sigmas: 0.3,
            condition: 3e-3,
            information: nalgebra::Matrix6::identity(),
        };
        // A fifth of the samples: taken on its overlap alone.
        assert!(accepted(&result(2_000, 9_000)));
        // Less: taken when most of what lands on the keyframe's surface lies on it.
        assert!(accepted(&result(1_500, 4_000)));
        assert!(!accepted(&result(1_500, 8_000)));
        // Under a tenth: never.
        assert!(!accepted(&result(900, 1_000)));
    }

    #[test]
    fn the_grid_surrounds_the_guess_and_holds_it() {
        let guess = Isometry3::from_parts(
            Translation3::new(1.0, -0.5, 2.0),
            UnitQuaternion::from_euler_angles(0.1, -0.4, 0.2),
        );
        let starts = starts(&guess);
        assert_eq!(starts.len(), 9 * 5 * 5);
        assert!(starts
            .iter()
            .any(|s| (s.to_homogeneous() - guess.to_homogeneous()).norm() < 1e-12));
        let from_guess: Vec<Isometry3<f64>> = starts.iter().map(|s| guess.inverse() * s).collect();
        let largest_turn = from_guess
            .iter()
            .map(|d| d.rotation.angle().to_degrees())
            .fold(0.0, f64::max);
        assert!((largest_turn - MAX_TURN_DEG).abs() < 1e-9, "{largest_turn}");
        // Moves stay in the camera's horizontal plane (no change along its y axis).
        assert!(from_guess.iter().all(|d| d.translation.y.abs() < 1e-12));
        let largest_move = from_guess
            .iter()
            .map(|d| d.translation.x.abs().max(d.translation.z.abs()))
            .fold(0.0, f64::max);
        assert!((largest_move - MAX_MOVE_M).abs() < 1e-12, "{largest_move}");
    }
}
