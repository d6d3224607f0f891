//! SE(3) and SO(3) helpers for the optimizer: the retraction it steps poses with, rotation
//! logarithm, the inverse right Jacobian of SO(3), and the conversion of a frontend
//! information matrix into the retraction's tangent space.
//!
//! Poses are `world_from_camera` isometries `(R, t)`. The optimizer perturbs them on the
//! right, in the camera frame, with the decoupled retraction
//! `retract((R, t), (v, w)) = (R Exp(w), t + R v)`: `v` (m) moves the camera along its own
//! axes, `w` (rad) turns it about them. Tangent vectors are ordered translation first,
//! rotation second, as in the frontend.

use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// The skew-symmetric matrix `[v]x` with `[v]x a = v x a`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Steps a `world_from_camera` pose by a camera-frame tangent vector `(v [m], w [rad])`:
/// `(R Exp(w), t + R v)`.
pub fn retract(pose: &Isometry3<f64>, delta: &Vector6<f64>) -> Isometry3<f64> {
    let v = Vector3::new(delta[0], delta[1], delta[2]);
    let w = Vector3::new(delta[3], delta[4], delta[5]);
    let t = pose.translation.vector + pose.rotation * v;
    Isometry3::from_parts(
        Translation3::from(t),
        pose.rotation * UnitQuaternion::from_scaled_axis(w),
    )
}

/// The rotation vector (axis times angle, rad) of a rotation: SO(3)'s logarithm.
pub fn log_so3(r: &UnitQuaternion<f64>) -> Vector3<f64> {
    r.scaled_axis()
}

/// Inverse of SO(3)'s right Jacobian at `phi` (rad): the derivative of
/// `Log(Exp(phi) Exp(d))` with respect to `d` at `d = 0`.
pub fn right_jacobian_inv_so3(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = skew(phi);
    if theta < 1e-5 {
        return Matrix3::identity() + 0.5 * k + (1.0 / 12.0) * k * k;
    }
    // (1 + cos) / (2 theta sin) written with the half angle, finite up to theta = pi.
    let coef = 1.0 / (theta * theta) - 1.0 / (2.0 * theta * (0.5 * theta).tan());
    Matrix3::identity() + 0.5 * k + coef * k * k
}

/// The relation between the frontend's left, world-frame perturbation
/// (`T <- (Exp(wL), vL) T`) and this module's right one (`retract`): `delta_left = A
/// delta_right`. An information matrix `info_left` of a pose becomes `A^T info_left A` in
/// the retraction's tangent space.
pub fn left_from_right(pose: &Isometry3<f64>) -> Matrix6<f64> {
    let r = pose.rotation.to_rotation_matrix().into_inner();
    let t = pose.translation.vector;
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(skew(&t) * r));
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    a
}

/// True when every number of the pose is finite.
pub fn is_finite(pose: &Isometry3<f64>) -> bool {
    pose.translation.vector.iter().all(|v| v.is_finite())
        && pose.rotation.coords.iter().all(|v| v.is_finite())
}

/// True when every coordinate of the point is finite.
pub fn point_is_finite(p: &Point3<f64>) -> bool {
    p.coords.iter().all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn retract_is_a_right_perturbation() {
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, -2.0, 0.5),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1),
        );
        let d = Vector6::new(0.1, 0.2, -0.3, 0.01, -0.02, 0.03);
        let step = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, -0.3),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.02, 0.03)),
        );
        // The decoupled retraction moves the origin like pose * (v, Exp(w)).
        let a = retract(&pose, &d);
        let b = pose * step;
        assert!((a.translation.vector - b.translation.vector).norm() < 1e-12);
        assert!(a.rotation.angle_to(&b.rotation) < 1e-12);
    }

    #[test]
    fn right_jacobian_inverse_matches_finite_differences() {
        for phi in [
            Vector3::new(0.3, -0.5, 0.9),
            Vector3::new(1e-7, 0.0, 2e-7),
            Vector3::new(0.0, 2.5, 0.1),
        ] {
            let j = right_jacobian_inv_so3(&phi);
            let r = UnitQuaternion::from_scaled_axis(phi);
            let h = 1e-6;
            for c in 0..3 {
                let mut d = Vector3::zeros();
                d[c] = h;
                let plus = log_so3(&(r * UnitQuaternion::from_scaled_axis(d)));
                let minus = log_so3(&(r * UnitQuaternion::from_scaled_axis(-d)));
                let col = (plus - minus) / (2.0 * h);
                assert!(
                    (col - j.column(c)).norm() < 1e-6,
                    "phi {phi:?} column {c}: {col:?} vs {:?}",
                    j.column(c)
                );
            }
        }
    }

    #[test]
    fn left_from_right_maps_perturbations() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.4, 1.0, -0.7),
            UnitQuaternion::from_euler_angles(-0.4, 0.7, 0.2),
        );
        let d = Vector6::new(1e-6, -2e-6, 3e-6, 2e-6, 1e-6, -1e-6);
        let right = retract(&pose, &d);
        let l = left_from_right(&pose) * d;
        let left = Isometry3::from_parts(
            Translation3::new(l[0], l[1], l[2]),
            UnitQuaternion::from_scaled_axis(Vector3::new(l[3], l[4], l[5])),
        ) * pose;
        assert!((right.translation.vector - left.translation.vector).norm() < 1e-10);
        assert!(right.rotation.angle_to(&left.rotation) < 1e-10);
    }
}
