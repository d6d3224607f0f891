//! Rigid-body poses in SE(3).
//!
//! A pose is an [`Isometry3<f64>`] named after what it does: `world_from_camera` maps a point
//! expressed in the camera frame (`p_camera`) into the world frame
//! (`p_world = world_from_camera * p_camera`). Its translation is therefore the camera's
//! position in the world, which is what a TUM trajectory file stores on each line
//! (`t tx ty tz qx qy qz qw`). Translations are in metres, angles in radians unless a name
//! says `deg`.

use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion};

/// A rigid transform `b_from_a` (translation in metres). See the module documentation.
pub type Pose = Isometry3<f64>;

/// Why raw numbers could not be turned into a pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseError {
    /// One of the seven numbers is NaN or infinite.
    #[error("{field} is not a finite number ({value})")]
    NonFinite {
        /// Name of the offending field (`tx`, `qw`, ...).
        field: &'static str,
        /// The value that was found.
        value: f64,
    },
    /// The quaternion is (numerically) zero and describes no rotation at all.
    #[error("quaternion (qx qy qz qw) has norm {norm:e}: it is zero and describes no rotation")]
    ZeroQuaternion {
        /// Euclidean norm of the quaternion as given.
        norm: f64,
    },
}

/// Smallest quaternion norm that is still normalised rather than rejected.
///
/// The same threshold as the TUM tools and evo use (`sqrt(4 * f64::EPSILON)` on the norm):
/// below it they silently substitute the identity rotation, which we refuse to do.
pub const MIN_QUATERNION_NORM: f64 = 2.980_232_238_769_531_2e-8;

/// Quaternions whose norm is within this of 1 count as unit quaternions and are not
/// normalised again (a few rounding steps of a unit quaternion's norm).
const UNIT_NORM_TOLERANCE: f64 = 8.0 * f64::EPSILON;

/// Builds a pose from a translation (metres) and a quaternion in TUM order `(qx, qy, qz, qw)`.
///
/// The quaternion is normalised, unless its norm is already 1 within a few rounding steps:
/// then it is kept digit for digit, so that a pose read and written again is unchanged.
/// Returns the pose and the quaternion's norm before normalisation, so that callers can warn
/// about quaternions far from unit length.
pub fn pose_from_translation_quaternion(
    t_m: [f64; 3],
    q_xyzw: [f64; 4],
) -> Result<(Pose, f64), PoseError> {
    const NAMES: [&str; 7] = ["tx", "ty", "tz", "qx", "qy", "qz", "qw"];
    for (i, v) in t_m.iter().chain(q_xyzw.iter()).enumerate() {
        if !v.is_finite() {
            return Err(PoseError::NonFinite {
                field: NAMES[i],
                value: *v,
            });
        }
    }
    let [qx, qy, qz, qw] = q_xyzw;
    let q = Quaternion::new(qw, qx, qy, qz);
    let norm = q.norm();
    if norm < MIN_QUATERNION_NORM {
        return Err(PoseError::ZeroQuaternion { norm });
    }
    // A quaternion already of unit norm is kept as given: normalising it can change its last
    // digit, and a pose read and written again (a saved map saved again) would drift.
    let rotation = if (norm - 1.0).abs() <= UNIT_NORM_TOLERANCE {
        UnitQuaternion::new_unchecked(q)
    } else {
        UnitQuaternion::from_quaternion(q)
    };
    let translation = Translation3::new(t_m[0], t_m[1], t_m[2]);
    Ok((Isometry3::from_parts(translation, rotation), norm))
}

/// Splits a pose into its translation (metres) and its unit quaternion in TUM order
/// `(qx, qy, qz, qw)`, with `qw >= 0` so that the written form is unique.
pub fn pose_to_translation_quaternion(pose: &Pose) -> ([f64; 3], [f64; 4]) {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
    (
        [t.x, t.y, t.z],
        [sign * q.i, sign * q.j, sign * q.k, sign * q.w],
    )
}

/// Rotation angle of a unit quaternion in radians, in `[0, pi]`.
///
/// Computed as `2 atan2(|v|, |w|)`, which is accurate for small and large angles alike
/// (unlike `acos((trace - 1) / 2)`).
pub fn rotation_angle_rad(q: &UnitQuaternion<f64>) -> f64 {
    let v = q.quaternion().vector().norm();
    2.0 * v.atan2(q.quaternion().w.abs())
}

/// Rotation angle in radians of a rotation matrix, as `acos((trace(R) - 1) / 2)` clamped
/// to `[0, pi]`.
///
/// This is the formula of the TUM benchmark's `evaluate_rpe.py`; it loses precision for
/// angles below about 1e-7 rad. Prefer [`rotation_angle_rad`] unless reproducing that tool.
pub fn rotation_angle_acos_rad(r: &Matrix3<f64>) -> f64 {
    ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos()
}

/// Chordal distance of a rotation from the identity: the Frobenius norm `||R - I||_F`
/// (dimensionless, in `[0, 2 sqrt(2)]`), as evo's `rotation_part` pose relation.
pub fn chordal_distance(r: &Matrix3<f64>) -> f64 {
    (r - Matrix3::identity()).norm()
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::Vector3;

    /// A unit quaternion read and written again keeps every digit (this one's last digit
    /// changed when it was normalised again), and one far from unit length is normalised.
    #[test]
    fn a_unit_quaternion_is_written_back_as_it_was_read() {
        let q = [
            -0.566602364126898,
            0.6009677246189715,
            -0.38672213026751995,
            0.4101774602455104,
        ];
        let t = [0.0, 0.0, 1.4347255896186015];
        let normalised = UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]));
        assert_ne!(normalised.coords.x, q[0], "the case this test is about");
        let (pose, norm) = pose_from_translation_quaternion(t, q).unwrap();
        assert!((norm - 1.0).abs() < 1e-15);
        assert_eq!(pose_to_translation_quaternion(&pose), (t, q));
        let (pose, norm) = pose_from_translation_quaternion(t, [0.0, 0.0, 0.0, 2.0]).unwrap();
        assert_eq!(norm, 2.0);
        assert_eq!(
            pose_to_translation_quaternion(&pose).1,
            [0.0, 0.0, 0.0, 1.0]
        );
    }

    #[test]
    fn round_trip_through_tum_fields() {
        let (pose, norm) =
            pose_from_translation_quaternion([1.0, 2.0, 3.0], [0.0, 0.0, 0.6, 0.8]).unwrap();
        assert_relative_eq!(norm, 1.0);
        let (t, q) = pose_to_translation_quaternion(&pose);
        assert_eq!(t, [1.0, 2.0, 3.0]);
        assert_relative_eq!(q[2], 0.6, epsilon = 1e-15);
        assert_relative_eq!(q[3], 0.8, epsilon = 1e-15);
    }

    #[test]
    fn non_unit_quaternion_is_normalised_and_reported() {
        let (pose, norm) =
            pose_from_translation_quaternion([0.0; 3], [0.0, 0.0, 0.0, 2.0]).unwrap();
        assert_relative_eq!(norm, 2.0);
        assert_relative_eq!(pose.rotation.angle(), 0.0);
    }

    #[test]
    fn zero_and_non_finite_are_rejected() {
        assert!(matches!(
            pose_from_translation_quaternion([0.0; 3], [0.0; 4]),
            Err(PoseError::ZeroQuaternion { .. })
        ));
        assert!(matches!(
            pose_from_translation_quaternion([0.0, f64::NAN, 0.0], [0.0, 0.0, 0.0, 1.0]),
            Err(PoseError::NonFinite { field: "ty", .. })
        ));
        assert!(matches!(
            pose_from_translation_quaternion([0.0; 3], [0.0, 0.0, f64::INFINITY, 1.0]),
            Err(PoseError::NonFinite { field: "qz", .. })
        ));
    }

    #[test]
    fn angle_formulas_agree() {
        for angle in [1e-3, 0.1, 1.0, 3.0] {
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), angle);
            assert_relative_eq!(rotation_angle_rad(&q), angle, epsilon = 1e-12);
            let r = q.to_rotation_matrix().into_inner();
            assert_relative_eq!(rotation_angle_acos_rad(&r), angle, epsilon = 1e-7);
            assert_relative_eq!(
                chordal_distance(&r),
                2.0 * 2f64.sqrt() * (angle / 2.0).sin(),
                epsilon = 1e-12
            );
        }
    }
}
