//! Pairing ground-truth and estimated poses in time, as each preset's tool does.

use crate::error::EvalError;
use crate::options::Preset;
use stride_core::time::{associate_greedy, associate_nearest};
use stride_core::trajectory::Trajectory;

/// Checks the association options: a window `t_max_diff_s` of zero or more seconds and a
/// finite `offset_s`.
pub fn check_association(t_max_diff_s: f64, offset_s: f64) -> Result<(), EvalError> {
    if !(t_max_diff_s.is_finite() && t_max_diff_s >= 0.0) {
        return Err(EvalError::InvalidOption {
            option: "t_max_diff_s",
            message: format!("must be a non-negative number of seconds, got {t_max_diff_s}"),
        });
    }
    if !offset_s.is_finite() {
        return Err(EvalError::InvalidOption {
            option: "offset_s",
            message: format!("must be finite, got {offset_s}"),
        });
    }
    Ok(())
}

/// Index pairs `(i_gt, i_est)` of associated poses, in the order the tool produces them:
/// evo walks the shorter trajectory in time order, TUM sorts by ground-truth time.
pub fn associate(
    gt: &Trajectory,
    est: &Trajectory,
    preset: Preset,
    t_max_diff_s: f64,
    offset_s: f64,
) -> Vec<(usize, usize)> {
    match preset {
        Preset::Evo => {
            // evo_ape/evo_rpe: associate_trajectories(ref, est): the shorter one drives; the
            // offset shifts the estimate's stamps (est + offset ~ ref).
            if est.len() > gt.len() {
                associate_nearest(gt.stamps_s(), est.stamps_s(), offset_s, t_max_diff_s)
            } else {
                associate_nearest(est.stamps_s(), gt.stamps_s(), -offset_s, t_max_diff_s)
                    .into_iter()
                    .map(|(i_est, i_gt)| (i_gt, i_est))
                    .collect()
            }
        }
        // evaluate_ate.py: associate(first=gt, second=est, offset, max_difference), on
        // dictionaries keyed by stamp: of lines with the same stamp, the last one counts.
        Preset::Tum => {
            let (gt_last, est_last) = (last_of_each_stamp(gt), last_of_each_stamp(est));
            let stamps = |t: &Trajectory, keep: &[usize]| -> Vec<f64> {
                keep.iter()
                    .filter_map(|&i| t.stamps_s().get(i).copied())
                    .collect()
            };
            associate_greedy(
                &stamps(gt, &gt_last),
                &stamps(est, &est_last),
                offset_s,
                t_max_diff_s,
            )
            .into_iter()
            .filter_map(|(a, b)| Some((*gt_last.get(a)?, *est_last.get(b)?)))
            .collect()
        }
    }
}

/// Indices of the poses that are the last of their timestamp (all of them when no stamp is
/// duplicated).
fn last_of_each_stamp(t: &Trajectory) -> Vec<usize> {
    let s = t.stamps_s();
    (0..s.len()).filter(|&i| s.get(i + 1) != s.get(i)).collect()
}

fn span(t: &Trajectory) -> String {
    match t.time_span_s() {
        Some((a, b)) => format!("{a:.3}..{b:.3} s"),
        None => "nothing".to_owned(),
    }
}

/// The error for too few associated pairs, with both time spans to help the user.
pub fn too_few_pairs(
    gt: &Trajectory,
    est: &Trajectory,
    found: usize,
    needed: usize,
    t_max_diff_s: f64,
    offset_s: f64,
) -> EvalError {
    EvalError::TooFewPairs {
        found,
        needed,
        t_max_diff_s,
        gt_span: span(gt),
        est_span: span(est),
        offset_note: if offset_s != 0.0 {
            format!(", offset {offset_s} s added to the estimate")
        } else {
            String::new()
        },
    }
}
