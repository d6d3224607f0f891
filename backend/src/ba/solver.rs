//! Levenberg-Marquardt over a [`Problem`], with the points eliminated by the Schur
//! complement (each point a 3x3 block) and the reduced camera system solved by sparse
//! Cholesky ([`ReducedSystem`]).
//!
//! Per iteration: linearize every edge (in parallel over points); for the current damping,
//! invert each point's 3x3 block and form the reduced system column by column (in parallel
//! over cameras: each column is written by one task, summing its points in a fixed order, so
//! results are bit-identical whatever the thread count); solve; back-substitute the points;
//! accept the step if the cost drops (Nielsen's damping update), else raise the damping.
//! A step that makes any number non-finite is rejected like one that raises the cost, so the
//! estimate never becomes NaN.

use super::layout::{Layout, Vars};
use super::problem::{
    huber_cost, huber_weight, linearize_point, linearize_pose, point_error, pose_error,
    pose_information, pose_jacobian_t_times, Mat63, Problem,
};
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

/// One pose-point edge, linearized, with its robust weight folded into `wom`.
#[derive(Debug, Clone, Copy, Default)]
struct ObsLin {
    /// Free camera index, if the pose is free.
    cam: Option<u32>,
    e: Vector3<f64>,
    /// The point in the camera frame: the pose Jacobian is `[-I, [q]x]`.
    q: Vector3<f64>,
    /// The point Jacobian `R^T`.
    jp: Matrix3<f64>,
    /// Weighted information `w * Omega`.
    wom: Matrix3<f64>,
    /// `J_pose^T wom J_point`.
    w: Mat63,
}

/// Robust cost of the whole problem (sum of per-point costs in point order, then pose
/// edges), or `None` when a number is not finite.
fn total_cost(p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) -> Option<f64> {
    let per_point: Vec<f64> = layout
        .point_ranges
        .par_iter()
        .map(|r| {
            layout
                .edges(r)
                .iter()
                .filter_map(|&i| p.point_edges.get(i))
                .map(|e| {
                    let (Some(pose), Some(pt)) = (x.poses.get(e.pose), x.points.get(e.point))
                    else {
                        return 0.0;
                    };
                    let r = point_error(pose, pt, &e.p_camera);
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
        let outcome = lin
            .step(problem, &layout, &mut system, &mut damped, lambda)
            .and_then(|(dc, dp, predicted)| {
                let candidate = x.stepped(&layout, &dc, &dp)?;
                let new_cost = total_cost(problem, &candidate, &layout, opts)?;
                Some((candidate, new_cost, predicted))
            });
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

/// Per-camera 6x6 blocks and 6-vectors summed over one partition of the points.
type CameraSums = (Vec<Matrix6<f64>>, Vec<Vector6<f64>>);

/// One pose-pose edge, linearized: error, Jacobians of its two ends, weighted information.
#[derive(Debug, Clone, Copy, Default)]
struct PoseEdgeLin {
    e: Vector6<f64>,
    j_from: Matrix6<f64>,
    j_to: Matrix6<f64>,
    wom: Matrix6<f64>,
}

/// The points' part at one damping: per point `V^-1` and `V^-1 g_p`, per observation
/// `Y = W V^-1`. Kept between iterations to reuse its buffers.
#[derive(Default)]
struct Damped {
    per_point: Vec<(Matrix3<f64>, Vector3<f64>)>,
    ys: Vec<Mat63>,
}

/// Everything that depends on the estimate but not on the damping.
struct Linearization {
    /// Per position in `edge_order`.
    obs: Vec<ObsLin>,
    /// Per point: `V = sum jp^T wom jp` and `g_p = sum jp^T wom e`.
    v: Vec<Matrix3<f64>>,
    gp: Vec<Vector3<f64>>,
    /// Per free camera: `U` (point and pose edges) and `g_c`.
    u: Vec<Matrix6<f64>>,
    gc: Vec<Vector6<f64>>,
    /// Per pose edge: error, Jacobians, weighted information.
    pose: Vec<PoseEdgeLin>,
}

impl Linearization {
    /// Buffers sized for `layout`, filled at `x`.
    fn new(p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) -> Self {
        let mut l = Self {
            obs: vec![ObsLin::default(); layout.edge_order.len()],
            v: vec![Matrix3::zeros(); layout.point_ranges.len()],
            gp: vec![Vector3::zeros(); layout.point_ranges.len()],
            u: Vec::new(),
            gc: Vec::new(),
            pose: Vec::new(),
        };
        l.update(p, x, layout, opts);
        l
    }

    /// Linearizes every edge at `x`, reusing the buffers (fresh megabytes per iteration
    /// cost more in page faults than the arithmetic, and do not parallelize).
    fn update(&mut self, p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) {
        self.obs
            .par_iter_mut()
            .zip(layout.edge_order.par_iter())
            .with_min_len(64)
            .for_each(|(out, &i)| {
                *out = ObsLin::default();
                let e = p.point_edges.get(i);
                let (Some(e), Some(pose), Some(pt)) = (
                    e,
                    e.and_then(|e| x.poses.get(e.pose)),
                    e.and_then(|e| x.points.get(e.point)),
                ) else {
                    return;
                };
                let l = linearize_point(pose, pt, &e.p_camera);
                let chi2 = l.e.dot(&(e.information * l.e));
                let wom = e.information * huber_weight(chi2, opts.point_huber_chi2);
                let q = l.e + e.p_camera.coords;
                *out = ObsLin {
                    cam: layout.cam(e.pose),
                    e: l.e,
                    q,
                    jp: l.j_point,
                    wom,
                    w: pose_jacobian_t_times(&q, &(wom * l.j_point)),
                };
            });
        let obs = &self.obs;
        self.v
            .par_iter_mut()
            .zip(self.gp.par_iter_mut())
            .zip(layout.point_ranges.par_iter())
            .with_min_len(32)
            .for_each(|((v, g), r)| {
                *v = Matrix3::zeros();
                *g = Vector3::zeros();
                for o in obs.get(r.clone()).unwrap_or(&[]) {
                    let jtw = o.jp.transpose() * o.wom;
                    *v += jtw * o.jp;
                    *g += jtw * o.e;
                }
            });
        let pose: Vec<PoseEdgeLin> = p
            .pose_edges
            .iter()
            .map(|e| {
                let (Some(a), Some(b)) = (x.poses.get(e.from), x.poses.get(e.to)) else {
                    return PoseEdgeLin::default();
                };
                let (r, j_from, j_to) = linearize_pose(a, b, &e.from_from_to);
                let chi2 = r.dot(&(e.information * r));
                PoseEdgeLin {
                    e: r,
                    j_from,
                    j_to,
                    wom: e.information * huber_weight(chi2, opts.pose_huber_chi2),
                }
            })
            .collect();
        // U and g_c: each partition of the points sums its observations' terms per camera,
        // then the partitions are added in order (a fixed order: bit-identical results).
        let n_cams = layout.obs_of_cam.len();
        let partial: Vec<CameraSums> = layout
            .partitions
            .par_iter()
            .map(|range| {
                let mut u = vec![Matrix6::zeros(); n_cams];
                let mut g = vec![Vector6::zeros(); n_cams];
                let edges = layout.point_ranges.get(range.clone()).unwrap_or(&[]);
                let (Some(first), Some(last)) = (edges.first(), edges.last()) else {
                    return (u, g);
                };
                for o in obs.get(first.start..last.end).unwrap_or(&[]) {
                    let Some(c) = o.cam.map(|c| c as usize) else {
                        continue;
                    };
                    if let (Some(uc), Some(gc)) = (u.get_mut(c), g.get_mut(c)) {
                        *uc += pose_information(&o.q, &o.wom);
                        *gc += pose_jacobian_t_times(&o.q, &o.wom) * o.e;
                    }
                }
                (u, g)
            })
            .collect();
        let mut u = vec![Matrix6::zeros(); n_cams];
        let mut gc = vec![Vector6::zeros(); n_cams];
        for (pu, pg) in &partial {
            for (a, b) in u.iter_mut().zip(pu) {
                *a += b;
            }
            for (a, b) in gc.iter_mut().zip(pg) {
                *a += b;
            }
        }
        for (e, l) in p.pose_edges.iter().zip(&pose) {
            for (end, j) in [(e.from, &l.j_from), (e.to, &l.j_to)] {
                if let Some(c) = layout.cam(end).map(|c| c as usize) {
                    if let (Some(uc), Some(g)) = (u.get_mut(c), gc.get_mut(c)) {
                        *uc += j.transpose() * l.wom * j;
                        *g += j.transpose() * l.wom * l.e;
                    }
                }
            }
        }
        self.u = u;
        self.gc = gc;
        self.pose = pose;
    }

    /// The linearized edges of a point's range.
    fn obs_of(&self, r: &std::ops::Range<usize>) -> &[ObsLin] {
        self.obs.get(r.clone()).unwrap_or(&[])
    }

    /// The damped Gauss-Newton step `(cameras, points, predicted cost decrease)`, or `None`
    /// when the reduced system is not positive definite.
    #[allow(clippy::type_complexity)]
    fn step(
        &self,
        p: &Problem,
        layout: &Layout,
        system: &mut ReducedSystem,
        damped: &mut Damped,
        lambda: f64,
    ) -> Option<(Vec<Vector6<f64>>, Vec<Vector3<f64>>, f64)> {
        // Points: damped inverse; then Y = W V^-1 per observation.
        damped
            .per_point
            .resize(self.v.len(), (Matrix3::zeros(), Vector3::zeros()));
        damped
            .per_point
            .par_iter_mut()
            .zip(self.v.par_iter().zip(&self.gp))
            .with_min_len(32)
            .for_each(|(out, (v, g))| {
                let mut v = *v;
                for d in 0..3 {
                    v[(d, d)] += lambda * damp(v[(d, d)]);
                }
                let vinv = v.try_inverse().unwrap_or_else(Matrix3::zeros);
                *out = (vinv, vinv * g);
            });
        damped.ys.resize(self.obs.len(), Mat63::zeros());
        let per_point = &damped.per_point;
        damped
            .ys
            .par_iter_mut()
            .zip(self.obs.par_iter().zip(&layout.point_of_pos))
            .with_min_len(64)
            .for_each(|(y, (o, &j))| {
                *y = per_point
                    .get(j)
                    .map_or_else(Mat63::zeros, |(vinv, _)| o.w * vinv);
            });
        let (blocks, rhs) = self.reduced(p, layout, system.pattern(), damped, lambda);
        let per_point = &damped.per_point;
        let dc = system.solve(&blocks, &rhs)?;
        // Back-substitution and the predicted decrease -g.d + lambda d^T D d.
        let dp_pred: Vec<(Vector3<f64>, f64)> = layout
            .point_ranges
            .par_iter()
            .enumerate()
            .map(|(j, r)| {
                let (Some((vinv, _)), Some(gp), Some(v)) =
                    (per_point.get(j), self.gp.get(j), self.v.get(j))
                else {
                    return (Vector3::zeros(), 0.0);
                };
                let mut rhs = -gp;
                for o in self.obs_of(r) {
                    if let Some(d) = o.cam.and_then(|c| dc.get(c as usize)) {
                        rhs -= o.w.transpose() * d;
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
            let (Some(g), Some(u)) = (self.gc.get(c), self.u.get(c)) else {
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
    /// `lambda`. The points' part is summed per partition of the points in parallel, then
    /// the partitions are added in order; the cameras' own terms and the pose edges after.
    fn reduced(
        &self,
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
            for j in range.clone() {
                let (Some(r), Some((_, om))) =
                    (layout.point_ranges.get(j), damped.per_point.get(j))
                else {
                    continue;
                };
                let obs = self.obs_of(r);
                let ys = damped.ys.get(r.clone()).unwrap_or(&[]);
                for o_b in obs {
                    let Some(b) = o_b.cam.map(|c| c as usize) else {
                        continue;
                    };
                    if let Some(rb) = rhs.get_mut(b) {
                        *rb += o_b.w * om;
                    }
                    let wt = o_b.w.transpose();
                    for (o_a, y) in obs.iter().zip(ys) {
                        let Some(a) = o_a.cam.map(|c| c as usize).filter(|&a| a >= b) else {
                            continue;
                        };
                        if let Some(blk) = pattern.slot(a, b).and_then(|s| blocks.get_mut(s)) {
                            *blk -= y * wt;
                        }
                    }
                }
            }
            (blocks, rhs)
        };
        let mut blocks = vec![Matrix6::zeros(); pattern.blocks()];
        let mut rhs: Vec<Vector6<f64>> = self.gc.iter().map(|g| -g).collect();
        rhs.resize(n_cams, Vector6::zeros());
        // As many partitions at a time as there are threads, each added in order as its
        // wave ends: the sum (and so the result) is the same as with every partition at
        // once, but a large problem holds a few copies of its blocks instead of one per
        // partition (300 keyframes that all see each other: 13 MB a copy).
        let wave = rayon::current_num_threads().max(1);
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
        for (b, u) in self.u.iter().enumerate() {
            let mut u = *u;
            for d in 0..6 {
                u[(d, d)] += lambda * damp(u[(d, d)]);
            }
            if let Some(blk) = pattern.slot(b, b).and_then(|s| blocks.get_mut(s)) {
                *blk += u;
            }
        }
        // The cross block between a pose edge's two free ends, stored under the lower one.
        for (e, l) in p.pose_edges.iter().zip(&self.pose) {
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
}

#[cfg(test)]
#[path = "solver_tests.rs"]
mod tests;
