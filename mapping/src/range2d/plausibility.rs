//! Paper 003's kinematics and plausibility bound (section 5.2).
//!
//! * Eq. 5: the sensor-to-map rotation `Rot(X, phi_r) Rot(Y', psi_r) Rot(X'', alpha)` from
//!   the trunk's pitch `phi_r`, its roll `psi_r` and the sensor's fixed tilt `alpha` (the
//!   paper's frame: x lateral, y forward, z up; rotations right-handed, successive ones
//!   about the new axes).
//! * Eq. 7: the trunk's total rotation about the lateral axis, `gamma`.
//! * Eqs. 6 and 8: `Delta z_max`, the largest change of a cell's elevation between two
//!   consecutive scans that is still consistent with the robot's motion and the errors of
//!   the measurement, the attitude and the mounting.
//! * The turning extension: the horizontal translation that a turn by `theta` is worth.
//!
//! The map ([`super::certainty`]) takes full 6-DoF poses (`world_from_sensor`), so it
//! evaluates eqs. 6/8 in that form ([`Bound::delta_z_max`]): `gamma` is the tilt of the
//! scan's central beam below the horizon (eq. 7 for a sensor mounted as in eq. 5), and each
//! partial derivative of the point's height is taken about the matching axis (the trunk's
//! lateral axis for pitch, its heading for roll, the sensor's own lateral axis for
//! `alpha`), `dz/d(angle) = (axis x (p_world - sensor))_z`.

use nalgebra::{Isometry3, Rotation3, Unit, Vector3};

/// Eq. 5: the rotation from the sensor frame to the map frame (paper's axes).
pub fn sensor_to_map(pitch_rad: f64, roll_rad: f64, alpha_rad: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), pitch_rad)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), roll_rad)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), alpha_rad)
}

/// Eq. 7: the total rotation of the trunk about the map's x axis (rad).
pub fn gamma(pitch_rad: f64, roll_rad: f64, alpha_rad: f64) -> f64 {
    let (sp, cp) = pitch_rad.sin_cos();
    let (sa, ca) = alpha_rad.sin_cos();
    let cr = roll_rad.cos();
    (cp * sa + sp * ca * cr).atan2(-sp * sa + cp * ca * cr)
}

/// The turning extension of section 5.2: the horizontal translation (m) that turning by
/// `theta_rad` is worth for a point at range `range_m` from a sensor `sensor_offset_m` (d_s)
/// ahead of the turning axis: `Delta x = (r + d_s) tan(theta / 2)`, `d = Delta x tan(theta)`.
pub fn turning_translation(range_m: f64, sensor_offset_m: f64, theta_rad: f64) -> f64 {
    let t = theta_rad.abs().min(1.5);
    (range_m + sensor_offset_m) * (t / 2.0).tan() * t.tan()
}

/// The error bounds of eqs. 6 and 8 (maximum errors, not standard deviations).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bound {
    /// `Delta phi_r`: the attitude estimate's pitch error (rad).
    pub pitch_rad: f64,
    /// `Delta psi_r`: its roll error (rad).
    pub roll_rad: f64,
    /// `Delta alpha`: the mounting tilt's error (rad; the paper's 1 degree).
    pub mount_rad: f64,
    /// Distance from the turning axis to the sensor, `d_s` (m), for the turning extension.
    pub sensor_offset_m: f64,
}

impl Default for Bound {
    /// The paper's mounting error (1 degree) and a small IMU's attitude error (1 degree).
    fn default() -> Self {
        Self {
            pitch_rad: 1f64.to_radians(),
            roll_rad: 1f64.to_radians(),
            mount_rad: 1f64.to_radians(),
            sensor_offset_m: 0.15,
        }
    }
}

/// The motion between two consecutive scans that eqs. 6/8 allow for.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion {
    /// Horizontal translation of the sensor, `d_(k,k+1)` (m).
    pub translation_m: f64,
    /// Change of heading (rad), for the turning extension.
    pub turn_rad: f64,
}

impl Motion {
    /// The motion from `a` to `b` (both `world_from_sensor`, world z up).
    pub fn between(a: &Isometry3<f64>, b: &Isometry3<f64>) -> Self {
        let d = b.translation.vector - a.translation.vector;
        let heading = |p: &Isometry3<f64>| {
            let f = p.rotation * Vector3::x();
            f.y.atan2(f.x)
        };
        let mut turn = heading(b) - heading(a);
        while turn > std::f64::consts::PI {
            turn -= std::f64::consts::TAU;
        }
        while turn < -std::f64::consts::PI {
            turn += std::f64::consts::TAU;
        }
        Self {
            translation_m: d.x.hypot(d.y),
            turn_rad: turn,
        }
    }
}

impl Bound {
    /// Eqs. 6/8 for a point measured at `p_sensor` by a sensor at `world_from_sensor`
    /// (ROS scanner axes: x the central beam, y lateral), after `motion`;
    /// `sensor_errors` are the point's displacements (sensor frame, m) under each of the
    /// sensor's maximum errors: the range error along the beam for a scanner (eq. 6), the
    /// errors of `b`, `beta`, `tau_c` and `v` for the stripe sensor (eq. 8).
    pub fn delta_z_max(
        &self,
        world_from_sensor: &Isometry3<f64>,
        p_sensor: &Vector3<f64>,
        sensor_errors: &[Vector3<f64>],
        motion: Motion,
    ) -> f64 {
        let r = world_from_sensor.rotation;
        let v = r * p_sensor; // sensor to point, world axes
        let beam = r * Vector3::x();
        let horizontal = beam.x.hypot(beam.y);
        let gamma = (-beam.z).atan2(horizontal);
        let d = motion.translation_m
            + turning_translation(v.norm(), self.sensor_offset_m, motion.turn_rad);
        let mut bound = d * gamma.tan().abs();
        for e in sensor_errors {
            bound += (r * e).z.abs();
        }
        let heading = if horizontal > 1e-9 {
            Vector3::new(beam.x, beam.y, 0.0) / horizontal
        } else {
            Vector3::x()
        };
        let lateral = Vector3::z().cross(&heading);
        let mount_axis = r * Vector3::y();
        for (axis, err) in [
            (lateral, self.pitch_rad),
            (heading, self.roll_rad),
            (mount_axis, self.mount_rad),
        ] {
            bound += axis.cross(&v).z.abs() * err;
        }
        bound
    }
}

/// The unit direction of a scanner's central beam in the world (for reports).
pub fn central_beam(world_from_sensor: &Isometry3<f64>) -> Unit<Vector3<f64>> {
    Unit::new_normalize(world_from_sensor.rotation * Vector3::x())
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::UnitQuaternion;

    #[test]
    fn eq5_and_eq7_by_hand() {
        // Without roll eq. 7 is the sum of pitch and tilt.
        assert_relative_eq!(gamma(0.1, 0.0, 0.5), 0.6, epsilon = 1e-12);
        // With roll: phi = 10, psi = 20, alpha = 35 deg:
        // num = cos10 sin35 + sin10 cos35 cos20 = 0.5648625 + 0.1336659 = 0.6985284
        // den = -sin10 sin35 + cos10 cos35 cos20 = -0.0996005 + 0.7580569 = 0.6584564
        // gamma = atan2(0.6985284, 0.6584564) = 0.8149198 rad.
        let g = gamma(10f64.to_radians(), 20f64.to_radians(), 35f64.to_radians());
        assert_relative_eq!(g, 0.8149198, epsilon = 1e-7);
        // Eq. 7 reads the rotation of eq. 5: gamma = atan2(-R[1][2], R[2][2]).
        let (p, r, a) = (0.2, -0.3, 0.6);
        let m = sensor_to_map(p, r, a);
        assert_relative_eq!(
            gamma(p, r, a),
            (-m[(1, 2)]).atan2(m[(2, 2)]),
            epsilon = 1e-12
        );
        // A pure tilt turns the forward axis (y) up by alpha.
        let y = sensor_to_map(0.0, 0.0, 0.3) * Vector3::y();
        assert_relative_eq!(
            y,
            Vector3::new(0.0, 0.3f64.cos(), 0.3f64.sin()),
            epsilon = 1e-12
        );
    }

    #[test]
    fn turning_by_hand() {
        // r = 0.5, d_s = 0.1, theta = 10 deg: 0.6 tan 5 tan 10 = 0.6 * 0.0874887 * 0.1763270
        // = 0.0092560.
        let d = turning_translation(0.5, 0.1, 10f64.to_radians());
        assert_relative_eq!(d, 0.0092560, epsilon = 1e-7);
        assert_eq!(
            turning_translation(0.5, 0.1, -0.2),
            turning_translation(0.5, 0.1, 0.2)
        );
    }

    /// A scanner 0.26 m up, tilted down by 35 degrees about its y axis, looking along +x.
    fn messor() -> Isometry3<f64> {
        Isometry3::from_parts(
            Vector3::new(0.0, 0.0, 0.26).into(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 35f64.to_radians()),
        )
    }

    #[test]
    fn eq6_by_hand() {
        let pose = messor();
        // The central beam meets the ground at range 0.26 / sin 35 = 0.453296.
        let range = 0.26 / 35f64.to_radians().sin();
        let p = Vector3::new(range, 0.0, 0.0);
        let dr = 0.01;
        let none = Bound {
            pitch_rad: 0.0,
            roll_rad: 0.0,
            mount_rad: 0.0,
            sensor_offset_m: 0.0,
        };
        // Range only: |dz/dr| dr = sin 35 * 0.01.
        let b = none.delta_z_max(&pose, &p, &[Vector3::new(dr, 0.0, 0.0)], Motion::default());
        assert_relative_eq!(b, 35f64.to_radians().sin() * dr, epsilon = 1e-12);
        // Motion: d tan(gamma), gamma = 35 deg.
        let m = Motion {
            translation_m: 0.02,
            turn_rad: 0.0,
        };
        assert_relative_eq!(
            none.delta_z_max(&pose, &p, &[], m),
            0.02 * 35f64.to_radians().tan(),
            epsilon = 1e-12
        );
        // Pitch error: the point swings about the lateral axis by its horizontal reach:
        // |dz/dphi| = range cos 35; the mounting error (about the sensor's y axis, here
        // horizontal too) alike; roll moves a point straight ahead not at all.
        let pitch = Bound {
            pitch_rad: 0.01,
            ..none
        };
        assert_relative_eq!(
            pitch.delta_z_max(&pose, &p, &[], Motion::default()),
            range * 35f64.to_radians().cos() * 0.01,
            epsilon = 1e-12
        );
        let mount = Bound {
            mount_rad: 0.01,
            ..none
        };
        assert_relative_eq!(
            mount.delta_z_max(&pose, &p, &[], Motion::default()),
            range * 35f64.to_radians().cos() * 0.01,
            epsilon = 1e-12
        );
        let roll = Bound {
            roll_rad: 0.01,
            ..none
        };
        assert_relative_eq!(
            roll.delta_z_max(&pose, &p, &[], Motion::default()),
            0.0,
            epsilon = 1e-12
        );
        // A beam 90 degrees to the side is moved by roll: by its lateral reach.
        let side = Vector3::new(0.0, 0.3, 0.0);
        assert_relative_eq!(
            roll.delta_z_max(&pose, &side, &[], Motion::default()),
            0.3 * 0.01,
            epsilon = 1e-12
        );
    }

    #[test]
    fn motion_between_poses() {
        let a = messor();
        let b = Isometry3::from_parts(
            Vector3::new(0.03, 0.04, 0.27).into(),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.2) * a.rotation,
        );
        let m = Motion::between(&a, &b);
        assert_relative_eq!(m.translation_m, 0.05, epsilon = 1e-12);
        assert_relative_eq!(m.turn_rad, 0.2, epsilon = 1e-9);
    }
}
