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
    huber_cost, huber_weight, linearize_point, linearize_pose, point_error, pose_error, Mat63,
    Problem,
};
use super::reduced::{BlockPattern, ReducedSystem};
use crate::error::BackendError;
use crate::se3::skew;
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

/// `J^T M` for the pose Jacobian `J = [-I, [q]x]` of a pose-point edge (6x3): `[-M;
/// -[q]x M]` (since `[q]x^T = -[q]x`).
fn pose_jacobian_t_times(q: &Vector3<f64>, m: &Matrix3<f64>) -> Mat63 {
    let qm = Matrix3::from_columns(&[
        q.cross(&m.column(0)),
        q.cross(&m.column(1)),
        q.cross(&m.column(2)),
    ]);
    let mut out = Mat63::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-m));
    out.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-qm));
    out
}

/// `J^T W J` for the pose Jacobian `J = [-I, [q]x]` and a symmetric `W`:
/// `[[W, -B], [-B^T, -[q]x B]]` with `B = W [q]x`.
fn pose_information(q: &Vector3<f64>, w: &Matrix3<f64>) -> Matrix6<f64> {
    let b = w * skew(q);
    let qb = Matrix3::from_columns(&[
        q.cross(&b.column(0)),
        q.cross(&b.column(1)),
        q.cross(&b.column(2)),
    ]);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(w);
    out.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-b));
    out.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-b.transpose()));
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-qb));
    out
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
    let mut lin: Option<Linearization> = None;
    report.termination = Termination::MaxIterations;
    while report.iterations < opts.max_iterations {
        report.iterations += 1;
        let l = match lin.take() {
            Some(l) => l,
            None => Linearization::new(problem, &x, &layout, opts),
        };
        let outcome =
            l.step(problem, &layout, &mut system, lambda)
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
                if relative < opts.function_tolerance {
                    report.termination = Termination::Converged;
                    break;
                }
            }
            _ => {
                report.rejected += 1;
                lambda *= nu;
                nu *= 2.0;
                lin = Some(l);
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

/// One pose-pose edge, linearized: error, Jacobians of its two ends, weighted information.
#[derive(Debug, Clone, Copy, Default)]
struct PoseEdgeLin {
    e: Vector6<f64>,
    j_from: Matrix6<f64>,
    j_to: Matrix6<f64>,
    wom: Matrix6<f64>,
}

/// The points' part at one damping: per point `V^-1` and `V^-1 g_p`, per observation
/// `Y = W V^-1`.
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
    fn new(p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) -> Self {
        let obs: Vec<ObsLin> = layout
            .edge_order
            .par_iter()
            .with_min_len(64)
            .map(|&i| {
                let e = p.point_edges.get(i);
                let (Some(e), Some(pose), Some(pt)) = (
                    e,
                    e.and_then(|e| x.poses.get(e.pose)),
                    e.and_then(|e| x.points.get(e.point)),
                ) else {
                    return ObsLin::default();
                };
                let l = linearize_point(pose, pt, &e.p_camera);
                let chi2 = l.e.dot(&(e.information * l.e));
                let wom = e.information * huber_weight(chi2, opts.point_huber_chi2);
                let q = l.e + e.p_camera.coords;
                ObsLin {
                    cam: layout.cam(e.pose),
                    e: l.e,
                    q,
                    jp: l.j_point,
                    wom,
                    w: pose_jacobian_t_times(&q, &(wom * l.j_point)),
                }
            })
            .collect();
        let (v, gp): (Vec<Matrix3<f64>>, Vec<Vector3<f64>>) = layout
            .point_ranges
            .par_iter()
            .with_min_len(32)
            .map(|r| {
                let mut v = Matrix3::zeros();
                let mut g = Vector3::zeros();
                for o in obs.get(r.clone()).unwrap_or(&[]) {
                    let jtw = o.jp.transpose() * o.wom;
                    v += jtw * o.jp;
                    g += jtw * o.e;
                }
                (v, g)
            })
            .unzip();
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
        let (u, gc): (Vec<_>, Vec<_>) = (0..layout.obs_of_cam.len())
            .into_par_iter()
            .map(|c| {
                let mut u = Matrix6::zeros();
                let mut g = Vector6::zeros();
                for &(pos, _) in &layout.obs_of_cam[c] {
                    if let Some(o) = obs.get(pos) {
                        u += pose_information(&o.q, &o.wom);
                        g += pose_jacobian_t_times(&o.q, &o.wom) * o.e;
                    }
                }
                for &k in &layout.pose_edges_of_cam[c] {
                    let (Some(e), Some(l)) = (p.pose_edges.get(k), pose.get(k)) else {
                        continue;
                    };
                    for (end, j) in [(e.from, &l.j_from), (e.to, &l.j_to)] {
                        if layout.cam(end) == Some(c as u32) {
                            u += j.transpose() * l.wom * j;
                            g += j.transpose() * l.wom * l.e;
                        }
                    }
                }
                (u, g)
            })
            .unzip();
        Self {
            obs,
            v,
            gp,
            u,
            gc,
            pose,
        }
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
        lambda: f64,
    ) -> Option<(Vec<Vector6<f64>>, Vec<Vector3<f64>>, f64)> {
        // Points: damped inverse; then Y = W V^-1 per observation.
        let per_point: Vec<(Matrix3<f64>, Vector3<f64>)> = self
            .v
            .par_iter()
            .zip(&self.gp)
            .with_min_len(32)
            .map(|(v, g)| {
                let mut v = *v;
                for d in 0..3 {
                    v[(d, d)] += lambda * damp(v[(d, d)]);
                }
                let vinv = v.try_inverse().unwrap_or_else(Matrix3::zeros);
                (vinv, vinv * g)
            })
            .collect();
        let ys: Vec<Mat63> = self
            .obs
            .par_iter()
            .zip(&layout.point_of_pos)
            .with_min_len(64)
            .map(|(o, &j)| {
                per_point
                    .get(j)
                    .map_or_else(Mat63::zeros, |(vinv, _)| o.w * vinv)
            })
            .collect();
        let damped = Damped { per_point, ys };
        // Reduced system, column by column.
        let columns: Vec<(Vec<Matrix6<f64>>, Vector6<f64>)> = (0..layout.obs_of_cam.len())
            .into_par_iter()
            .map(|b| self.column(p, layout, system.pattern(), &damped, b, lambda))
            .collect();
        let per_point = damped.per_point;
        let mut blocks = Vec::with_capacity(system.pattern().blocks());
        let mut rhs = Vec::with_capacity(columns.len());
        for (c, r) in columns {
            blocks.extend(c);
            rhs.push(r);
        }
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

    /// Block column `b` of the reduced system (blocks in pattern order) and its right-hand
    /// side.
    fn column(
        &self,
        p: &Problem,
        layout: &Layout,
        pattern: &BlockPattern,
        damped: &Damped,
        b: usize,
        lambda: f64,
    ) -> (Vec<Matrix6<f64>>, Vector6<f64>) {
        let (rows, first_slot) = pattern.column(b);
        let mut blocks = vec![Matrix6::zeros(); rows.len()];
        let mut u = self.u.get(b).copied().unwrap_or_else(Matrix6::zeros);
        for d in 0..6 {
            u[(d, d)] += lambda * damp(u[(d, d)]);
        }
        if let Some(first) = blocks.first_mut() {
            *first = u;
        }
        let mut rhs = -self.gc.get(b).copied().unwrap_or_else(Vector6::zeros);
        let slot_of = |a: usize| pattern.slot(a, b).and_then(|s| s.checked_sub(first_slot));
        for &(pos, j) in &layout.obs_of_cam[b] {
            let (Some(o_b), Some((_, om)), Some(r)) = (
                self.obs.get(pos),
                damped.per_point.get(j),
                layout.point_ranges.get(j),
            ) else {
                continue;
            };
            rhs += o_b.w * om;
            let ys_j = damped.ys.get(r.clone()).unwrap_or(&[]);
            for (o_a, y) in self.obs_of(r).iter().zip(ys_j) {
                let Some(a) = o_a.cam.map(|c| c as usize).filter(|&a| a >= b) else {
                    continue;
                };
                let Some(s) = slot_of(a) else {
                    continue;
                };
                if let Some(blk) = blocks.get_mut(s) {
                    *blk -= y * o_b.w.transpose();
                }
            }
        }
        for &k in &layout.pose_edges_of_cam[b] {
            let (Some(e), Some(l)) = (p.pose_edges.get(k), self.pose.get(k)) else {
                continue;
            };
            let (ca, cb) = (layout.cam(e.from), layout.cam(e.to));
            // The cross block between the edge's two free ends, stored under the lower one.
            if let (Some(ca), Some(cb)) = (ca, cb) {
                let (ca, cb) = (ca as usize, cb as usize);
                if ca > cb && cb == b {
                    if let Some(blk) = slot_of(ca).and_then(|s| blocks.get_mut(s)) {
                        *blk += l.j_from.transpose() * l.wom * l.j_to;
                    }
                } else if cb > ca && ca == b {
                    if let Some(blk) = slot_of(cb).and_then(|s| blocks.get_mut(s)) {
                        *blk += l.j_to.transpose() * l.wom * l.j_from;
                    }
                }
            }
        }
        (blocks, rhs)
    }
}

#[cfg(test)]
#[path = "solver_tests.rs"]
mod tests;
