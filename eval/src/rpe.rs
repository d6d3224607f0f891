//! Relative pose error (RPE): the error of the motion between two poses `delta` apart
//! (paper 004, eq. 2; Sturm et al. 2012). It measures drift, independent of alignment.
//!
//! The two presets differ in more than defaults (see `docs/evaluation.md`):
//!
//! * evo: poses are first associated (nearest within `t_max_diff`), then pairs `(i, j)` are
//!   chosen among the associated poses; the error is `E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)` with `Q`
//!   ground truth and `P` the estimate; rotation error is the angle of `log(E_R)`.
//! * TUM (`evaluate_rpe.py --fixed_delta`): pairs are chosen among *all* estimate poses by
//!   nearest index value (`find_closest_index`, dropping pairs that end on the last pose),
//!   each end is matched to the nearest ground-truth stamp within twice the median
//!   ground-truth interval, and `E = (P_j⁻¹ P_i)⁻¹ (Q_j⁻¹ Q_i)`; rotation error is
//!   `acos((tr E_R - 1) / 2)`.

use crate::align::{compute_alignment, Alignment};
use crate::ate::gather;
use crate::error::EvalError;
use crate::options::{Align, DeltaUnit, Preset};
use crate::stats::Statistics;
use crate::sync::{associate, check_association, too_few_pairs};
use stride_core::pose::{chordal_distance, rotation_angle_acos_rad, rotation_angle_rad, Pose};
use stride_core::trajectory::Trajectory;

/// How to compute the RPE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RpeOptions {
    /// Whose semantics to reproduce.
    pub preset: Preset,
    /// Alignment applied before (matters only for Sim(3), whose scale changes distances).
    pub align: Align,
    /// Association window (s); the TUM preset uses its own rule instead (see module docs).
    pub t_max_diff_s: f64,
    /// Added to the estimate's stamps before associating (s).
    pub offset_s: f64,
    /// Distance between the two poses of a pair, in `unit`.
    pub delta: f64,
    /// Unit of `delta`.
    pub unit: DeltaUnit,
    /// Every pair `delta` apart (within `rel_delta_tol`) instead of consecutive
    /// non-overlapping pairs. evo preset only.
    pub all_pairs: bool,
    /// Relative tolerance on `delta` for all-pairs mode in metres or seconds (evo: 0.1).
    pub rel_delta_tol: f64,
}

impl RpeOptions {
    /// The preset's defaults (evo: 1 frame, consecutive pairs; TUM: 1 s; no alignment).
    pub fn for_preset(preset: Preset) -> Self {
        let (delta, unit) = preset.default_rpe_delta();
        Self {
            preset,
            align: Align::None,
            t_max_diff_s: preset.default_t_max_diff_s(),
            offset_s: 0.0,
            delta,
            unit,
            all_pairs: false,
            rel_delta_tol: 0.1,
        }
    }
}

/// One compared pair of poses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RpePair {
    /// Estimate stamp of the first pose (s).
    pub t_s: f64,
    /// Estimate stamp of the second pose (s).
    pub t_end_s: f64,
    /// Translation error (metres).
    pub trans_m: f64,
    /// Rotation error (degrees).
    pub rot_deg: f64,
    /// Chordal rotation error `||E_R - I||_F` (dimensionless).
    pub rot_chordal: f64,
}

/// The RPE of an estimate against ground truth.
#[derive(Debug, Clone)]
pub struct RpeResult {
    /// The options used.
    pub options: RpeOptions,
    /// Statistics of the translation error (metres per delta).
    pub trans_m: Statistics,
    /// Statistics of the rotation angle error (degrees per delta).
    pub rot_deg: Statistics,
    /// Statistics of the chordal rotation error (dimensionless).
    pub rot_chordal: Statistics,
    /// The compared pairs.
    pub pairs: Vec<RpePair>,
    /// The alignment applied to the estimate.
    pub alignment: Alignment,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

fn validate(o: &RpeOptions) -> Result<(), EvalError> {
    if !(o.delta.is_finite() && o.delta > 0.0) {
        return Err(EvalError::InvalidOption {
            option: "delta",
            message: format!("must be a positive number, got {}", o.delta),
        });
    }
    if o.unit == DeltaUnit::Frames && o.delta.fract() != 0.0 {
        return Err(EvalError::InvalidOption {
            option: "delta",
            message: format!("must be a whole number of frames, got {}", o.delta),
        });
    }
    check_association(o.t_max_diff_s, o.offset_s)?;
    if !(o.rel_delta_tol.is_finite() && o.rel_delta_tol >= 0.0) {
        return Err(EvalError::InvalidOption {
            option: "rel_delta_tol",
            message: format!("must be a non-negative fraction, got {}", o.rel_delta_tol),
        });
    }
    if o.preset == Preset::Tum && o.all_pairs {
        return Err(EvalError::InvalidOption {
            option: "all_pairs",
            message: "cannot reproduce the TUM tool, whose all-pairs mode draws 10 000 random \
                      pairs regardless of delta; use the evo preset for all pairs"
                .into(),
        });
    }
    Ok(())
}

/// Computes the RPE of `est` against `gt`.
pub fn rpe(
    gt: &Trajectory,
    est: &Trajectory,
    options: &RpeOptions,
) -> Result<RpeResult, EvalError> {
    validate(options)?;
    match options.preset {
        Preset::Evo => rpe_evo(gt, est, options),
        Preset::Tum => rpe_tum(gt, est, options),
    }
}

fn finish(
    options: &RpeOptions,
    pairs: Vec<RpePair>,
    alignment: Alignment,
    warnings: Vec<String>,
    poses: usize,
) -> Result<RpeResult, EvalError> {
    let col = |f: fn(&RpePair) -> f64| pairs.iter().map(f).collect::<Vec<_>>();
    let stats = (
        Statistics::from_errors(&col(|p| p.trans_m)),
        Statistics::from_errors(&col(|p| p.rot_deg)),
        Statistics::from_errors(&col(|p| p.rot_chordal)),
    );
    let (Some(trans_m), Some(rot_deg), Some(rot_chordal)) = stats else {
        return Err(EvalError::NoRelativePairs {
            delta: options.delta,
            unit: options.unit,
            poses,
            tolerance_hint: if options.all_pairs {
                format!(
                    " or a larger relative tolerance (now {})",
                    options.rel_delta_tol
                )
            } else {
                String::new()
            },
        });
    };
    Ok(RpeResult {
        options: *options,
        trans_m,
        rot_deg,
        rot_chordal,
        pairs,
        alignment,
        warnings,
    })
}

// ---------------------------------------------------------------------------------------
// evo
// ---------------------------------------------------------------------------------------

fn rpe_evo(gt: &Trajectory, est: &Trajectory, o: &RpeOptions) -> Result<RpeResult, EvalError> {
    let pairs = associate(gt, est, o.preset, o.t_max_diff_s, o.offset_s);
    let needed = if matches!(o.align, Align::Se3 | Align::Sim3) {
        3
    } else {
        2
    };
    if pairs.len() < needed {
        return Err(too_few_pairs(
            gt,
            est,
            pairs.len(),
            needed,
            o.t_max_diff_s,
            o.offset_s,
        ));
    }
    let (q, p_raw, _) = gather(gt, est, &pairs);
    let est_stamps: Vec<f64> = pairs
        .iter()
        .filter_map(|&(_, j)| est.stamps_s().get(j).copied())
        .collect();
    let (alignment, warnings) = compute_alignment(&q, &p_raw, o.align, o.preset)?;
    let p: Vec<Pose> = p_raw.iter().map(|x| alignment.apply(x)).collect();
    let ids = evo_id_pairs(&p, &est_stamps, o);
    let mut out = Vec::with_capacity(ids.len());
    for (i, j) in ids {
        let (Some(qi), Some(qj), Some(pi), Some(pj)) = (q.get(i), q.get(j), p.get(i), p.get(j))
        else {
            continue;
        };
        let e = (qi.inverse() * qj).inverse() * (pi.inverse() * pj);
        out.push(RpePair {
            t_s: est_stamps.get(i).copied().unwrap_or(f64::NAN),
            t_end_s: est_stamps.get(j).copied().unwrap_or(f64::NAN),
            trans_m: e.translation.vector.norm(),
            rot_deg: rotation_angle_rad(&e.rotation).to_degrees(),
            rot_chordal: chordal_distance(e.rotation.to_rotation_matrix().matrix()),
        });
    }
    finish(o, out, alignment, warnings, p.len())
}

/// evo's `id_pairs_from_delta` on the associated (and aligned) estimate poses. Seconds are a
/// stride extension that follows evo's metres rule with elapsed time in place of path length.
fn evo_id_pairs(poses: &[Pose], stamps_s: &[f64], o: &RpeOptions) -> Vec<(usize, usize)> {
    let n = poses.len();
    match o.unit {
        DeltaUnit::Frames => {
            let d = o.delta as usize;
            if o.all_pairs {
                (0..n.saturating_sub(d)).map(|i| (i, i + d)).collect()
            } else {
                let ids: Vec<usize> = (0..n).step_by(d.max(1)).collect();
                ids.windows(2).map(|w| (w[0], w[1])).collect()
            }
        }
        DeltaUnit::Metres => {
            let steps: Vec<f64> = poses
                .windows(2)
                .map(|w| (w[1].translation.vector - w[0].translation.vector).norm())
                .collect();
            pairs_along(&steps, o)
        }
        DeltaUnit::Seconds => {
            let steps: Vec<f64> = stamps_s.windows(2).map(|w| w[1] - w[0]).collect();
            pairs_along(&steps, o)
        }
    }
}

/// Pairs along a path whose consecutive poses are `steps[k]` apart (metres or seconds), as
/// evo's `filter_pairs_by_path`: consecutive mode starts a new pair whenever the distance
/// accumulated since the last one reaches `delta`; all-pairs mode takes, for every `i`, the
/// first `j > i` whose accumulated distance from `i` is nearest `delta`, if within
/// `delta * rel_delta_tol`.
fn pairs_along(steps: &[f64], o: &RpeOptions) -> Vec<(usize, usize)> {
    let delta = o.delta;
    if o.all_pairs {
        let mut acc = Vec::with_capacity(steps.len() + 1);
        acc.push(0.0);
        let mut total = 0.0;
        for s in steps {
            total += s;
            acc.push(total);
        }
        let tol = delta * o.rel_delta_tol;
        let mut out = Vec::new();
        for (i, &si) in acc.iter().enumerate() {
            let rest = acc.get(i + 1..).unwrap_or(&[]);
            // `rest - si` is non-decreasing: the value nearest delta sits at the insertion
            // point or just before it.
            let k = rest.partition_point(|&x| x - si < delta);
            let best = [k.checked_sub(1), Some(k)]
                .into_iter()
                .flatten()
                .filter_map(|k| rest.get(k).map(|&x| (k, ((x - si) - delta).abs())))
                .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            if let Some((mut k, err)) = best {
                // numpy's argmin returns the first of equal values.
                while k > 0 && rest.get(k - 1) == rest.get(k) {
                    k -= 1;
                }
                if err <= tol {
                    out.push((i, i + 1 + k));
                }
            }
        }
        out
    } else {
        let mut ids = vec![0usize];
        let mut covered = 0.0;
        for (k, s) in steps.iter().enumerate() {
            covered += s;
            if covered >= delta {
                ids.push(k + 1);
                covered = 0.0;
            }
        }
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

// ---------------------------------------------------------------------------------------
// TUM
// ---------------------------------------------------------------------------------------

/// `find_closest_index` of the TUM tools: a binary search that remembers the closest value
/// it visited (strictly closer wins) and returns at once on an exact hit.
fn find_closest_index(l: &[f64], t: f64) -> usize {
    let Some(&first) = l.first() else { return 0 };
    let (mut beginning, mut end) = (0usize, l.len());
    let mut difference = (first - t).abs();
    let mut best = 0usize;
    while beginning < end {
        let middle = (end + beginning) / 2;
        let Some(&v) = l.get(middle) else { break };
        if (v - t).abs() < difference {
            difference = (v - t).abs();
            best = middle;
        }
        if t == v {
            return middle;
        } else if v > t {
            end = middle;
        } else {
            beginning = middle + 1;
        }
    }
    best
}

fn median_interval(stamps: &[f64]) -> f64 {
    let diffs: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    Statistics::from_errors(&diffs).map_or(0.0, |s| s.median)
}

fn rpe_tum(gt: &Trajectory, est: &Trajectory, o: &RpeOptions) -> Result<RpeResult, EvalError> {
    let mut warnings = Vec::new();
    let (ts_gt, ts_est) = (gt.stamps_s(), est.stamps_s());
    let n = ts_est.len();
    // The tool's overlap check: at least two distinct estimate stamps survive a round trip
    // through the nearest ground-truth stamp.
    let mut returned = std::collections::BTreeSet::new();
    for &t in ts_est {
        let g = ts_gt
            .get(find_closest_index(ts_gt, t + o.offset_s))
            .copied()
            .unwrap_or(f64::NAN);
        returned.insert(find_closest_index(ts_est, g - o.offset_s));
    }
    if returned.len() < 2 {
        return Err(too_few_pairs(
            gt,
            est,
            returned.len(),
            2,
            2.0 * median_interval(ts_gt),
            o.offset_s,
        ));
    }
    // Alignment is not part of the TUM tool; apply it if asked (scale matters for Sim(3)).
    let alignment = if o.align == Align::None {
        Alignment::identity()
    } else {
        warnings.push(format!(
            "the TUM RPE tool does not align; alignment {} departs from it",
            o.align
        ));
        let pairs = associate(gt, est, Preset::Tum, o.t_max_diff_s, o.offset_s);
        let (q, p, _) = gather(gt, est, &pairs);
        let (a, mut w) = compute_alignment(&q, &p, o.align, o.preset)?;
        warnings.append(&mut w);
        a
    };
    let p: Vec<Pose> = est.poses().iter().map(|x| alignment.apply(x)).collect();
    let index_est: Vec<f64> = match o.unit {
        DeltaUnit::Seconds => ts_est.to_vec(),
        DeltaUnit::Frames => (0..n).map(|i| i as f64).collect(),
        DeltaUnit::Metres => {
            let mut acc = vec![0.0];
            let mut sum = 0.0;
            for w in p.windows(2) {
                sum += (w[1].inverse() * w[0]).translation.vector.norm();
                acc.push(sum);
            }
            acc
        }
    };
    let mut ids = Vec::new();
    for (i, &v) in index_est.iter().enumerate() {
        let j = find_closest_index(&index_est, v + o.delta);
        if j != n - 1 {
            ids.push((i, j));
        }
    }
    let gt_max_time_difference = 2.0 * median_interval(ts_gt);
    let mut out = Vec::with_capacity(ids.len());
    for (i, j) in ids {
        let (Some(&te0), Some(&te1)) = (ts_est.get(i), ts_est.get(j)) else {
            continue;
        };
        let g0 = find_closest_index(ts_gt, te0 + o.offset_s);
        let g1 = find_closest_index(ts_gt, te1 + o.offset_s);
        let (Some(&tg0), Some(&tg1)) = (ts_gt.get(g0), ts_gt.get(g1)) else {
            continue;
        };
        if (tg0 - (te0 + o.offset_s)).abs() > gt_max_time_difference
            || (tg1 - (te1 + o.offset_s)).abs() > gt_max_time_difference
        {
            continue;
        }
        let (Some(p0), Some(p1), Some(q0), Some(q1)) =
            (p.get(i), p.get(j), gt.poses().get(g0), gt.poses().get(g1))
        else {
            continue;
        };
        let e = (p1.inverse() * p0).inverse() * (q1.inverse() * q0);
        let r = e.rotation.to_rotation_matrix();
        out.push(RpePair {
            t_s: te0,
            t_end_s: te1,
            trans_m: e.translation.vector.norm(),
            rot_deg: rotation_angle_acos_rad(r.matrix()).to_degrees(),
            rot_chordal: chordal_distance(r.matrix()),
        });
    }
    if out.len() < 2 {
        // evaluate_rpe.py: "Couldn't find matching timestamp pairs".
        out.clear();
    }
    finish(o, out, alignment, warnings, n)
}

#[cfg(test)]
#[path = "rpe_tests.rs"]
mod tests;
