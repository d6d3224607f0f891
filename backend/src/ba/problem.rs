//! The optimization problem of paper 004's eq. 1: keyframe poses and 3-D points, tied by
//! pose-point edges (a point measured in a camera, 3-D Euclidean error weighted by the
//! measurement's information matrix) and pose-pose edges (a measured relative motion, SE(3)
//! error weighted by a 6x6 information matrix).
//!
//! Variables are stepped with [`crate::se3::retract`] (poses, camera-frame right
//! perturbation `(v [m], w [rad])`) and by addition (points, world frame, m). The Jacobians
//! below are the exact derivatives of the errors with respect to those steps at zero; the
//! tests check every one against central finite differences.

use crate::se3::{log_so3, right_jacobian_inv_so3, skew};
use nalgebra::{Isometry3, Matrix3, Matrix3x6, Matrix6, Point3, SMatrix, Vector3, Vector6};

/// A keyframe pose to estimate (or to hold fixed).
#[derive(Debug, Clone, PartialEq)]
pub struct PoseVar {
    /// `world_from_camera` (m).
    pub world_from_camera: Isometry3<f64>,
    /// Held constant (the gauge, and keyframes outside a local window).
    pub fixed: bool,
}

/// A 3-D point to estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct PointVar {
    /// Position in the world frame (m).
    pub p_world: Point3<f64>,
}

/// A pose-point edge: point `point` measured at `p_camera` in the camera of pose `pose`.
/// Error `e = world_from_camera^-1 p_world - p_camera` (m, camera frame).
#[derive(Debug, Clone, PartialEq)]
pub struct PointEdge {
    /// Index into [`Problem::poses`].
    pub pose: usize,
    /// Index into [`Problem::points`].
    pub point: usize,
    /// The measured point in the camera frame (m).
    pub p_camera: Point3<f64>,
    /// Information matrix of the measurement (1/m^2, camera frame): the inverse of its
    /// covariance.
    pub information: Matrix3<f64>,
}

/// A pose-pose edge: the relative motion `from_from_to` measured between poses `from` and
/// `to`. Error `e = (t(E), Log(R(E)))` with `E = from_from_to^-1 world_from_from^-1
/// world_from_to` (translation in m, rotation vector in rad).
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEdge {
    /// Index into [`Problem::poses`] of the reference pose.
    pub from: usize,
    /// Index into [`Problem::poses`] of the other pose.
    pub to: usize,
    /// The measured `from_from_to` (m).
    pub from_from_to: Isometry3<f64>,
    /// Information matrix of the error (translation first, then rotation).
    pub information: Matrix6<f64>,
}

/// Poses, points and the edges between them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Problem {
    /// Keyframe poses.
    pub poses: Vec<PoseVar>,
    /// 3-D points.
    pub points: Vec<PointVar>,
    /// Pose-point edges.
    pub point_edges: Vec<PointEdge>,
    /// Pose-pose edges.
    pub pose_edges: Vec<PoseEdge>,
}

/// Error and Jacobians of a pose-point edge.
#[derive(Debug, Clone, Copy)]
pub struct PointEdgeLin {
    /// Error (m, camera frame).
    pub e: Vector3<f64>,
    /// Derivative with respect to the pose's step `(v, w)`.
    pub j_pose: Matrix3x6<f64>,
    /// Derivative with respect to the point's step.
    pub j_point: Matrix3<f64>,
}

/// The error of a pose-point edge (m, camera frame).
pub fn point_error(
    world_from_camera: &Isometry3<f64>,
    p_world: &Point3<f64>,
    p_camera: &Point3<f64>,
) -> Vector3<f64> {
    world_from_camera.inverse_transform_point(p_world) - p_camera
}

/// Error and Jacobians of a pose-point edge: with `q = R^T (p - t)`, `e = q - z`,
/// `de/dv = -I`, `de/dw = [q]x`, `de/dp = R^T`.
pub fn linearize_point(
    world_from_camera: &Isometry3<f64>,
    p_world: &Point3<f64>,
    p_camera: &Point3<f64>,
) -> PointEdgeLin {
    let q = world_from_camera.inverse_transform_point(p_world);
    let rt = world_from_camera
        .rotation
        .to_rotation_matrix()
        .into_inner()
        .transpose();
    let mut j_pose = Matrix3x6::zeros();
    j_pose
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-Matrix3::identity()));
    j_pose
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&skew(&q.coords));
    PointEdgeLin {
        e: q - p_camera,
        j_pose,
        j_point: rt,
    }
}

/// The error of a pose-pose edge: translation (m) then rotation vector (rad) of
/// `from_from_to^-1 world_from_from^-1 world_from_to`.
pub fn pose_error(
    world_from_from: &Isometry3<f64>,
    world_from_to: &Isometry3<f64>,
    from_from_to: &Isometry3<f64>,
) -> Vector6<f64> {
    let e = from_from_to.inverse() * world_from_from.inverse() * world_from_to;
    let phi = log_so3(&e.rotation);
    Vector6::new(
        e.translation.x,
        e.translation.y,
        e.translation.z,
        phi.x,
        phi.y,
        phi.z,
    )
}

/// Error and Jacobians (with respect to the `from` and the `to` pose's steps) of a
/// pose-pose edge. With `E = M^-1 Ti^-1 Tk`, `a = Ri^T (tk - ti)` and `phi = Log(R(E))`:
/// `dt/dvi = -RM^T`, `dt/dwi = RM^T [a]x`, `dphi/dwi = -Jr^-1(phi) Rk^T Ri`,
/// `dt/dvk = R(E)`, `dphi/dwk = Jr^-1(phi)`; the other blocks are zero.
pub fn linearize_pose(
    world_from_from: &Isometry3<f64>,
    world_from_to: &Isometry3<f64>,
    from_from_to: &Isometry3<f64>,
) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
    let e = pose_error(world_from_from, world_from_to, from_from_to);
    let phi = Vector3::new(e[3], e[4], e[5]);
    let jr_inv = right_jacobian_inv_so3(&phi);
    let rot = |t: &Isometry3<f64>| t.rotation.to_rotation_matrix().into_inner();
    let (ri, rk, rm) = (rot(world_from_from), rot(world_from_to), rot(from_from_to));
    let re = rm.transpose() * ri.transpose() * rk;
    let a =
        ri.transpose() * (world_from_to.translation.vector - world_from_from.translation.vector);
    let mut ji = Matrix6::zeros();
    ji.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-rm.transpose()));
    ji.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(rm.transpose() * skew(&a)));
    ji.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(-jr_inv * rk.transpose() * ri));
    let mut jk = Matrix6::zeros();
    jk.fixed_view_mut::<3, 3>(0, 0).copy_from(&re);
    jk.fixed_view_mut::<3, 3>(3, 3).copy_from(&jr_inv);
    (e, ji, jk)
}

pub use stride_core::robust::{huber_cost, huber_weight};

/// A 6x3 block (a camera's rows times a point's columns).
pub type Mat63 = SMatrix<f64, 6, 3>;

/// `J^T M` for the pose Jacobian `J = [-I, [q]x]` of a pose-point edge (6x3): `[-M;
/// -[q]x M]` (since `[q]x^T = -[q]x`).
pub fn pose_jacobian_t_times(q: &Vector3<f64>, m: &Matrix3<f64>) -> Mat63 {
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
pub fn pose_information(q: &Vector3<f64>, w: &Matrix3<f64>) -> Matrix6<f64> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se3::retract;
    use nalgebra::{Translation3, UnitQuaternion};

    fn pose(t: [f64; 3], r: [f64; 3]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_euler_angles(r[0], r[1], r[2]),
        )
    }

    #[test]
    fn point_jacobians_match_finite_differences() {
        let t = pose([0.3, -1.2, 0.8], [0.4, -0.3, 2.0]);
        let p = Point3::new(1.0, 0.5, 2.5);
        let z = Point3::new(0.1, 0.2, 1.9);
        let lin = linearize_point(&t, &p, &z);
        let h = 1e-6;
        for c in 0..6 {
            let mut d = Vector6::zeros();
            d[c] = h;
            let col = (point_error(&retract(&t, &d), &p, &z)
                - point_error(&retract(&t, &(-d)), &p, &z))
                / (2.0 * h);
            assert!(
                (col - lin.j_pose.column(c)).norm() < 1e-7,
                "pose column {c}"
            );
        }
        for c in 0..3 {
            let mut d = Vector3::zeros();
            d[c] = h;
            let col = (point_error(&t, &(p + d), &z) - point_error(&t, &(p - d), &z)) / (2.0 * h);
            assert!(
                (col - lin.j_point.column(c)).norm() < 1e-7,
                "point column {c}"
            );
        }
    }

    #[test]
    fn pose_jacobians_match_finite_differences() {
        let ti = pose([0.3, -1.2, 0.8], [0.4, -0.3, 2.0]);
        let tk = pose([0.9, -0.7, 1.1], [0.1, 0.2, 2.6]);
        // A measurement far from the current relative pose, so that the error (and the
        // inverse right Jacobian) is not trivial.
        let m = pose([0.5, 0.2, -0.1], [0.3, 0.4, 0.2]);
        let (e, ji, jk) = linearize_pose(&ti, &tk, &m);
        assert!(e.norm() > 0.3, "a non-trivial error: {e:?}");
        let h = 1e-6;
        for c in 0..6 {
            let mut d = Vector6::zeros();
            d[c] = h;
            let col_i = (pose_error(&retract(&ti, &d), &tk, &m)
                - pose_error(&retract(&ti, &(-d)), &tk, &m))
                / (2.0 * h);
            assert!(
                (col_i - ji.column(c)).norm() < 1e-6,
                "from column {c}: {col_i:?} vs {:?}",
                ji.column(c)
            );
            let col_k = (pose_error(&ti, &retract(&tk, &d), &m)
                - pose_error(&ti, &retract(&tk, &(-d)), &m))
                / (2.0 * h);
            assert!(
                (col_k - jk.column(c)).norm() < 1e-6,
                "to column {c}: {col_k:?} vs {:?}",
                jk.column(c)
            );
        }
    }

    #[test]
    fn structured_products_match_the_plain_ones() {
        let t = pose([0.3, -1.2, 0.8], [0.4, -0.3, 2.0]);
        let l = linearize_point(&t, &Point3::new(1.0, 0.5, 2.5), &Point3::new(0.0, 0.0, 2.0));
        let q = l.e + Vector3::new(0.0, 0.0, 2.0);
        let w = Matrix3::new(4.0, 1.0, 0.5, 1.0, 3.0, -0.2, 0.5, -0.2, 2.0);
        let plain = l.j_pose.transpose() * w * l.j_pose;
        assert!((pose_information(&q, &w) - plain).norm() < 1e-12);
        let m = Matrix3::new(1.0, 2.0, 3.0, -1.0, 0.5, 0.0, 2.0, 1.0, -3.0);
        assert!((pose_jacobian_t_times(&q, &m) - l.j_pose.transpose() * m).norm() < 1e-12);
    }
}
