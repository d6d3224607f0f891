//! Levenberg-Marquardt over a [`Problem`], with the points eliminated by the Schur
//! complement (each point a 3x3 block) and the reduced camera system solved by sparse
//! Cholesky ([`ReducedSystem`]).
//!
//! Per iteration: linearize every edge after an accepted step (the private `linearize`
//! module, in parallel over fixed partitions of the points); for the current damping,
//! invert each point's 3x3 block and sum the reduced system per partition (each point's
//! `Y = W V^-1` formed on the spot), the partitions' sums added in partition order, so
//! results are bit-identical whatever the thread count; solve; back-substitute the points;
//! accept the step if the cost drops (Nielsen's damping update), else raise the damping.
//! A step that makes any number non-finite is rejected like one that raises the cost, so the
//! estimate never becomes NaN.

use super::layout::{Frames, Layout, Vars};
use super::linearize::{CameraSums, Linearization};
use super::problem::{huber_cost, pose_error, Mat63, Problem};
use super::reduced::{BlockPattern, ReducedSystem};
use crate::error::BackendError;
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;
use std::time::Instant;

/// Settings of [`solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct SolverOptions {
    /// Most iterations (accepted and rejected steps).
    pub max_iterations: usize,
    /// Huber threshold on the squared Mahalanobis distance of pose-point edges (3 degrees of
    /// freedom; 7.815 is the 95 % quantile); `None` for plain least squares.
    pub point_huber_chi2: Option<f64>,
    /// Huber threshold on pose-pose edges (6 degrees of freedom; 12.59 is the 95 % quantile).
    pub pose_huber_chi2: Option<f64>,
    /// Initial damping, relative to the diagonal of the normal equations.
    pub initial_lambda: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction of it.
    pub function_tolerance: f64,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            max_iterations: 10,
            point_huber_chi2: Some(7.815),
            pose_huber_chi2: Some(12.59),
            initial_lambda: 1e-4,
            function_tolerance: 1e-6,
        }
    }
}

/// Why [`solve`] stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// The cost stopped decreasing (relative decrease below the tolerance).
    Converged,
    /// The iteration budget ran out.
    MaxIterations,
    /// No step lowered the cost even with very large damping.
    NoProgress,
    /// Nothing to optimize (no free pose and no point).
    Empty,
}

/// What [`solve`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveReport {
    /// Iterations run (accepted and rejected).
    pub iterations: usize,
    /// Accepted steps.
    pub accepted: usize,
    /// Rejected steps (cost not lowered, not positive definite, or non-finite).
    pub rejected: usize,
    /// Robust cost before (sum of Huber costs of squared Mahalanobis distances).
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
    /// Why it stopped.
    pub termination: Termination,
    /// Wall time (s).
    pub time_s: f64,
}

/// Robust cost of the whole problem (sum of per-point costs in point order, then pose
/// edges), or `None` when a number is not finite.
fn total_cost(p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) -> Option<f64> {
    let frames = Frames::of(x);
    let per_point: Vec<f64> = layout
        .point_ranges
        .par_iter()
        .map(|r| {
            layout
                .edges(r)
                .iter()
                .filter_map(|&i| p.point_edges.get(i))
                .map(|e| {
                    let Some((q, _)) = x
                        .points
                        .get(e.point)
                        .and_then(|pt| frames.to_camera(e.pose, pt))
                    else {
                        return 0.0;
                    };
                    let r = q - e.p_camera.coords;
                    huber_cost(r.dot(&(e.information * r)), opts.point_huber_chi2)
                })
                .sum()
        })
        .collect();
    let mut cost: f64 = per_point.iter().sum();
    for e in &p.pose_edges {
        let (Some(a), Some(b)) = (x.poses.get(e.from), x.poses.get(e.to)) else {
            continue;
        };
        let r = pose_error(a, b, &e.from_from_to);
        cost += huber_cost(r.dot(&(e.information * r)), opts.pose_huber_chi2);
    }
    cost.is_finite().then_some(cost)
}

/// Largest memory (bytes) for the copies of the reduced system's blocks when every partition
/// is summed at once.
const WAVE_ALL_BYTES: usize = 4 << 20;

/// Marquardt's scaling of a diagonal entry, kept within a sane range.
fn damp(d: f64) -> f64 {
    d.clamp(1e-6, 1e32)
}

/// Optimizes the free poses and the points of `problem` in place. The problem's values are
/// only replaced by accepted steps; a rejected or failed step leaves them as they were.
pub fn solve(problem: &mut Problem, opts: &SolverOptions) -> Result<SolveReport, BackendError> {
    let start = Instant::now();
    let layout = Layout::new(problem);
    let mut x = Vars::of(problem);
    let mut report = SolveReport {
        iterations: 0,
        accepted: 0,
        rejected: 0,
        initial_cost: 0.0,
        final_cost: 0.0,
        termination: Termination::Empty,
        time_s: 0.0,
    };
    let Some(mut cost) = total_cost(problem, &x, &layout, opts) else {
        return Err(BackendError::Solver(
            "the initial estimate has a non-finite cost".into(),
        ));
    };
    report.initial_cost = cost;
    report.final_cost = cost;
    if layout.obs_of_cam.is_empty() && problem.points.is_empty() {
        report.time_s = start.elapsed().as_secs_f64();
        return Ok(report);
    }
    let mut system = ReducedSystem::new(layout.pattern(problem))?;
    let mut lambda = opts.initial_lambda;
    let mut nu = 2.0;
    let mut lin = Linearization::new(problem, &x, &layout, opts);
    let mut damped = Damped::default();
    let mut stale = false;
    report.termination = Termination::MaxIterations;
    while report.iterations < opts.max_iterations {
        report.iterations += 1;
        if stale {
            lin.update(problem, &x, &layout, opts);
            stale = false;
        }
        let outcome = step(&lin, problem, &layout, &mut system, &mut damped, lambda).and_then(
            |(dc, dp, predicted)| {
                let candidate = x.stepped(&layout, &dc, &dp)?;
                let new_cost = total_cost(problem, &candidate, &layout, opts)?;
                Some((candidate, new_cost, predicted))
            },
        );
        match outcome {
            Some((candidate, new_cost, predicted)) if new_cost < cost => {
                let rho = (cost - new_cost) / predicted.max(f64::MIN_POSITIVE);
                let relative = (cost - new_cost) / cost.max(f64::MIN_POSITIVE);
                x = candidate;
                cost = new_cost;
                report.accepted += 1;
                lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                nu = 2.0;
                stale = true;
                if relative < opts.function_tolerance {
                    report.termination = Termination::Converged;
                    break;
                }
            }
            _ => {
                report.rejected += 1;
                lambda *= nu;
                nu *= 2.0;
                if lambda > 1e16 {
                    report.termination = Termination::NoProgress;
                    break;
                }
            }
        }
    }
    for (v, pose) in problem.poses.iter_mut().zip(x.poses) {
        v.world_from_camera = pose;
    }
    for (v, p) in problem.points.iter_mut().zip(x.points) {
        v.p_world = p;
    }
    report.final_cost = cost;
    report.time_s = start.elapsed().as_secs_f64();
    Ok(report)
}

/// The points' part at one damping: per point `V^-1` and `V^-1 g_p`. Kept between
/// iterations to reuse its buffer.
#[derive(Default)]
struct Damped {
    per_point: Vec<(Matrix3<f64>, Vector3<f64>)>,
}

/// The damped Gauss-Newton step `(cameras, points, predicted cost decrease)`, or `None`
/// when the reduced system is not positive definite.
#[allow(clippy::type_complexity)]
fn step(
    lin: &Linearization,
    p: &Problem,
    layout: &Layout,
    system: &mut ReducedSystem,
    damped: &mut Damped,
    lambda: f64,
) -> Option<(Vec<Vector6<f64>>, Vec<Vector3<f64>>, f64)> {
    // Points: the damped inverse of V, and V^-1 g_p.
    damped
        .per_point
        .resize(lin.v.len(), (Matrix3::zeros(), Vector3::zeros()));
    damped
        .per_point
        .par_iter_mut()
        .zip(lin.v.par_iter().zip(&lin.gp))
        .with_min_len(64)
        .for_each(|(out, (v, g))| {
            let mut v = *v;
            for d in 0..3 {
                v[(d, d)] += lambda * damp(v[(d, d)]);
            }
            let vinv = v.try_inverse().unwrap_or_else(Matrix3::zeros);
            *out = (vinv, vinv * g);
        });
    let (blocks, rhs) = reduced(lin, p, layout, system.pattern(), damped, lambda);
    let per_point = &damped.per_point;
    let dc = system.solve(&blocks, &rhs)?;
    // Back-substitution and the predicted decrease -g.d + lambda d^T D d.
    let dp_pred: Vec<(Vector3<f64>, f64)> = layout
        .point_ranges
        .par_iter()
        .with_min_len(64)
        .enumerate()
        .map(|(j, r)| {
            let (Some((vinv, _)), Some(gp), Some(v)) =
                (per_point.get(j), lin.gp.get(j), lin.v.get(j))
            else {
                return (Vector3::zeros(), 0.0);
            };
            let mut rhs = -gp;
            for o in lin.obs_of(r) {
                if let Some(d) = dc.get(o.cam as usize) {
                    rhs -= o.w.tr_mul(d);
                }
            }
            let d = vinv * rhs;
            let mut pred = -gp.dot(&d);
            for k in 0..3 {
                pred += lambda * damp(v[(k, k)]) * d[k] * d[k];
            }
            (d, pred)
        })
        .collect();
    let mut predicted: f64 = dp_pred.iter().map(|(_, x)| x).sum();
    for (c, d) in dc.iter().enumerate() {
        let (Some(g), Some(u)) = (lin.gc.get(c), lin.u.get(c)) else {
            continue;
        };
        predicted -= g.dot(d);
        for k in 0..6 {
            predicted += lambda * damp(u[(k, k)]) * d[k] * d[k];
        }
    }
    let dp = dp_pred.into_iter().map(|(d, _)| d).collect();
    Some((dc, dp, predicted))
}

/// The reduced system's blocks (in pattern order) and right-hand side at damping
/// `lambda`. The points' part is summed per partition of the points in parallel, then the
/// partitions are added in order; the cameras' own terms and the pose edges after.
fn reduced(
    lin: &Linearization,
    p: &Problem,
    layout: &Layout,
    pattern: &BlockPattern,
    damped: &Damped,
    lambda: f64,
) -> (Vec<Matrix6<f64>>, Vec<Vector6<f64>>) {
    let n_cams = layout.obs_of_cam.len();
    let partition_sums = |range: &std::ops::Range<usize>| -> CameraSums {
        let mut blocks = vec![Matrix6::zeros(); pattern.blocks()];
        let mut rhs = vec![Vector6::zeros(); n_cams];
        // `Y = W V^-1` of the current point's observations (reused from point to point).
        let mut ys: Vec<Mat63> = Vec::new();
        for j in range.clone() {
            let (Some(r), Some((vinv, om))) = (layout.point_ranges.get(j), damped.per_point.get(j))
            else {
                continue;
            };
            let obs = lin.obs_of(r);
            ys.clear();
            ys.extend(obs.iter().map(|o| o.w * vinv));
            for o_b in obs {
                let b = o_b.cam as usize;
                let Some(rb) = rhs.get_mut(b) else {
                    continue;
                };
                *rb += o_b.w * om;
                let wt = o_b.w.transpose();
                for (o_a, y) in obs.iter().zip(&ys) {
                    let a = o_a.cam as usize;
                    if a < b || a >= n_cams {
                        continue;
                    }
                    if let Some(blk) = pattern.slot(a, b).and_then(|s| blocks.get_mut(s)) {
                        *blk -= y * wt;
                    }
                }
            }
        }
        (blocks, rhs)
    };
    let mut blocks = vec![Matrix6::zeros(); pattern.blocks()];
    let mut rhs: Vec<Vector6<f64>> = lin.gc.iter().map(|g| -g).collect();
    rhs.resize(n_cams, Vector6::zeros());
    // Partitions are summed in waves, each added in order as its wave ends: the sum (and
    // so the result) is the same whatever the wave's size. A small problem sums every
    // partition at once, so that a thread the machine descheduled does not hold the others
    // up at the end of each wave; a large one as many at a time as there are threads, to
    // hold a few copies of its blocks instead of one per partition (300 keyframes that all
    // see each other: 13 MB a copy).
    let copy_bytes = pattern.blocks() * std::mem::size_of::<Matrix6<f64>>();
    let wave = if copy_bytes * layout.partitions.len() <= WAVE_ALL_BYTES {
        layout.partitions.len().max(1)
    } else {
        rayon::current_num_threads().max(1)
    };
    for chunk in layout.partitions.chunks(wave) {
        let partial: Vec<CameraSums> = chunk.par_iter().map(partition_sums).collect();
        for (pb, pr) in &partial {
            for (a, b) in blocks.iter_mut().zip(pb) {
                *a += b;
            }
            for (a, b) in rhs.iter_mut().zip(pr) {
                *a += b;
            }
        }
    }
    for (b, u) in lin.u.iter().enumerate() {
        let mut u = *u;
        for d in 0..6 {
            u[(d, d)] += lambda * damp(u[(d, d)]);
        }
        if let Some(blk) = pattern.slot(b, b).and_then(|s| blocks.get_mut(s)) {
            *blk += u;
        }
    }
    // The cross block between a pose edge's two free ends, stored under the lower one.
    for (e, l) in p.pose_edges.iter().zip(&lin.pose) {
        let (Some(ca), Some(cb)) = (layout.cam(e.from), layout.cam(e.to)) else {
            continue;
        };
        let (ca, cb) = (ca as usize, cb as usize);
        let (slot, blk) = if ca > cb {
            (pattern.slot(ca, cb), l.j_from.transpose() * l.wom * l.j_to)
        } else if cb > ca {
            (pattern.slot(cb, ca), l.j_to.transpose() * l.wom * l.j_from)
        } else {
            continue;
        };
        if let Some(b) = slot.and_then(|s| blocks.get_mut(s)) {
            *b += blk;
        }
    }
    (blocks, rhs)
}

#[cfg(test)]
#[path = "solver_tests.rs"]
mod tests;
