//! The part of a Levenberg-Marquardt iteration that depends on the estimate but not on the
//! damping: every edge linearized, and the blocks of the normal equations that do not
//! involve the Schur complement.
//!
//! One pass over the pose-point edges, in parallel over fixed partitions of the points,
//! computes for each edge only what the later stages read again (`W = J_pose^T w Omega
//! J_point`, a 6x3 block: 152 bytes an edge), and sums in the same pass each point's `V`
//! and `g_p` and each partition's share of the cameras' `U` and `g_c`. The partitions' sums
//! are added in partition order, so results are bit-identical whatever the thread count.
//! Poses' rotation matrices are computed once per pass, not once per edge.

use super::layout::{split_by_ranges, Frames, Layout, Vars, NO_CAM};
use super::problem::{
    huber_weight, linearize_pose, pose_information, pose_jacobian_t_times, Mat63, Problem,
};
use super::solver::SolverOptions;
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;

/// One pose-point edge, linearized, as the Schur complement needs it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ObsLin {
    /// Free camera index, or [`NO_CAM`] when the pose is fixed.
    pub(crate) cam: u32,
    /// `J_pose^T (w Omega) J_point` with the robust weight `w` folded in.
    pub(crate) w: Mat63,
}

impl Default for ObsLin {
    fn default() -> Self {
        Self {
            cam: NO_CAM,
            w: Mat63::zeros(),
        }
    }
}

/// One pose-pose edge, linearized: error, Jacobians of its two ends, weighted information.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PoseEdgeLin {
    pub(crate) e: Vector6<f64>,
    pub(crate) j_from: Matrix6<f64>,
    pub(crate) j_to: Matrix6<f64>,
    pub(crate) wom: Matrix6<f64>,
}

/// Per-camera 6x6 blocks and 6-vectors summed over one partition of the points.
pub(crate) type CameraSums = (Vec<Matrix6<f64>>, Vec<Vector6<f64>>);

/// Everything that depends on the estimate but not on the damping.
pub(crate) struct Linearization {
    /// Per position in the layout's `edge_order`.
    pub(crate) obs: Vec<ObsLin>,
    /// Per point: `V = sum J_point^T w Omega J_point`.
    pub(crate) v: Vec<Matrix3<f64>>,
    /// Per point: `g_p = sum J_point^T w Omega e`.
    pub(crate) gp: Vec<Vector3<f64>>,
    /// Per free camera: `U` (point and pose edges).
    pub(crate) u: Vec<Matrix6<f64>>,
    /// Per free camera: `g_c`.
    pub(crate) gc: Vec<Vector6<f64>>,
    /// Per pose edge.
    pub(crate) pose: Vec<PoseEdgeLin>,
}

impl Linearization {
    /// Buffers sized for `layout`, filled at `x`.
    pub(crate) fn new(p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) -> Self {
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
    pub(crate) fn update(&mut self, p: &Problem, x: &Vars, layout: &Layout, opts: &SolverOptions) {
        let frames = Frames::of(x);
        let n_cams = layout.obs_of_cam.len();
        let obs_parts = split_by_ranges(&mut self.obs, &layout.partition_obs);
        let v_parts = split_by_ranges(&mut self.v, &layout.partitions);
        let g_parts = split_by_ranges(&mut self.gp, &layout.partitions);
        let partial: Vec<CameraSums> = obs_parts
            .into_par_iter()
            .zip(v_parts)
            .zip(g_parts)
            .zip(layout.partitions.par_iter())
            .map(|(((obs, v), g), points)| {
                let mut u = vec![Matrix6::zeros(); n_cams];
                let mut gc = vec![Vector6::zeros(); n_cams];
                let first = layout.point_ranges.get(points.start).map_or(0, |r| r.start);
                for ((j, vj), gj) in points.clone().zip(v.iter_mut()).zip(g.iter_mut()) {
                    *vj = Matrix3::zeros();
                    *gj = Vector3::zeros();
                    let Some(r) = layout.point_ranges.get(j) else {
                        continue;
                    };
                    // Positions within the partition's slice (point ranges only grow).
                    let local = r.start.checked_sub(first).zip(r.end.checked_sub(first));
                    let (Some(pt), Some(out)) =
                        (x.points.get(j), local.and_then(|(a, b)| obs.get_mut(a..b)))
                    else {
                        continue;
                    };
                    for (o, &i) in out.iter_mut().zip(layout.edges(r)) {
                        *o = ObsLin::default();
                        let Some(e) = p.point_edges.get(i) else {
                            continue;
                        };
                        let Some((q, rt)) = frames.to_camera(e.pose, pt) else {
                            continue;
                        };
                        let err = q - e.p_camera.coords;
                        let chi2 = err.dot(&(e.information * err));
                        let wom = e.information * huber_weight(chi2, opts.point_huber_chi2);
                        // J_point = R^T: `a` is w Omega J_point, `we` is w Omega e.
                        let a = wom * rt;
                        let we = wom * err;
                        *vj += rt.tr_mul(&a);
                        *gj += rt.tr_mul(&we);
                        let cam = layout.cam(e.pose).unwrap_or(NO_CAM);
                        *o = ObsLin {
                            cam,
                            w: pose_jacobian_t_times(&q, &a),
                        };
                        if let (Some(uc), Some(g)) =
                            (u.get_mut(cam as usize), gc.get_mut(cam as usize))
                        {
                            // J_pose^T we = [-we; -q x we].
                            *uc += pose_information(&q, &wom);
                            let qw = q.cross(&we);
                            *g -= Vector6::new(we.x, we.y, we.z, qw.x, qw.y, qw.z);
                        }
                    }
                }
                (u, gc)
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
    pub(crate) fn obs_of(&self, r: &std::ops::Range<usize>) -> &[ObsLin] {
        self.obs.get(r.clone()).unwrap_or(&[])
    }
}
