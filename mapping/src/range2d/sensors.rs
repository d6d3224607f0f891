//! The two 2-D range sensors of paper 003, in their own frames.
//!
//! * [`StripeSensor`]: a camera and a laser-stripe emitter tilted down by `beta` (section
//!   3.1). A stripe pixel `(u, v)` gives a 3-D point in the camera frame by eq. 1, whose
//!   axes are the paper's: `x_c` lateral, `y_c` from the camera towards the emitter, `z_c`
//!   along the optical axis. Eq. 2 gives the viewing half-angles from the focal length.
//! * [`UrgSensor`] (in core, shared with the simulator): the Hokuyo URG-04LX.

use nalgebra::{Matrix3, Point3, Vector3};
pub use stride_core::range_sensor::UrgSensor;

/// The structured-light stripe sensor (paper 003, section 3.1), parameters in metres and
/// radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StripeSensor {
    /// Distance between the camera's optical centre and the emitter, `b` (m).
    pub baseline_m: f64,
    /// Tilt of the light plane, `beta` (rad).
    pub beta_rad: f64,
    /// Vertical half viewing angle, `tau_c` (rad).
    pub tau_c_rad: f64,
    /// Horizontal half viewing angle, `gamma_c` (rad).
    pub gamma_c_rad: f64,
    /// Rows of the image region used, `R_ver` (px).
    pub rows_px: f64,
    /// Columns, `R_hor` (px).
    pub cols_px: f64,
}

/// Standard deviations of the stripe sensor's inputs, for propagation into a point's
/// covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StripeNoise {
    /// Of the stripe's column `u` (px).
    pub u_px: f64,
    /// Of the stripe's row `v` (px), `Delta v` of eq. 8.
    pub v_px: f64,
    /// Of the baseline `b` (m).
    pub baseline_m: f64,
    /// Of `beta` (rad).
    pub beta_rad: f64,
    /// Of `tau_c` (rad).
    pub tau_c_rad: f64,
}

impl StripeSensor {
    /// The sensor with viewing angles from the focal length (eq. 2):
    /// `tau_c = atan(R_ver / 2f)`, `gamma_c = atan(R_hor / 2f)`.
    pub fn from_focal(
        baseline_m: f64,
        beta_rad: f64,
        focal_px: f64,
        rows_px: f64,
        cols_px: f64,
    ) -> Self {
        Self {
            baseline_m,
            beta_rad,
            tau_c_rad: (rows_px / (2.0 * focal_px)).atan(),
            gamma_c_rad: (cols_px / (2.0 * focal_px)).atan(),
            rows_px,
            cols_px,
        }
    }

    /// The point seen at stripe pixel `(u, v)` in the camera frame (eq. 1), or `None` where
    /// the row's line of sight does not meet the light plane in front of the camera.
    pub fn point(&self, u: f64, v: f64) -> Option<Point3<f64>> {
        Self::eq1(
            u,
            v,
            self.baseline_m,
            self.beta_rad,
            self.tau_c_rad,
            self.gamma_c_rad,
            self.rows_px,
            self.cols_px,
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn eq1(
        u: f64,
        v: f64,
        b: f64,
        beta: f64,
        tau: f64,
        gamma: f64,
        rows: f64,
        cols: f64,
    ) -> Option<Point3<f64>> {
        let cot_beta = 1.0 / beta.tan();
        let den = (1.0 - 2.0 * v / rows) * tau.tan() + cot_beta;
        if den <= 1e-12 {
            return None;
        }
        let z = b / den;
        let x = z * (1.0 - 2.0 * u / cols) * gamma.tan();
        let y = -b * (1.0 - cot_beta / den);
        Some(Point3::new(x, y, z))
    }

    /// The covariance (m²) of the point at `(u, v)`: the input noises propagated through
    /// eq. 1 by its Jacobian (central differences).
    pub fn covariance(&self, u: f64, v: f64, noise: &StripeNoise) -> Option<Matrix3<f64>> {
        let p = |du: f64, dv: f64, db: f64, dbeta: f64, dtau: f64| {
            Self::eq1(
                u + du,
                v + dv,
                self.baseline_m + db,
                self.beta_rad + dbeta,
                self.tau_c_rad + dtau,
                self.gamma_c_rad,
                self.rows_px,
                self.cols_px,
            )
            .map(|p| p.coords)
        };
        let inputs: [(f64, [f64; 5]); 5] = [
            (noise.u_px, [1e-3, 0.0, 0.0, 0.0, 0.0]),
            (noise.v_px, [0.0, 1e-3, 0.0, 0.0, 0.0]),
            (noise.baseline_m, [0.0, 0.0, 1e-6, 0.0, 0.0]),
            (noise.beta_rad, [0.0, 0.0, 0.0, 1e-7, 0.0]),
            (noise.tau_c_rad, [0.0, 0.0, 0.0, 0.0, 1e-7]),
        ];
        let mut cov = Matrix3::zeros();
        for (sigma, h) in inputs {
            let step: f64 = h.iter().map(|x| x.abs()).sum();
            let plus = p(h[0], h[1], h[2], h[3], h[4])?;
            let minus = p(-h[0], -h[1], -h[2], -h[3], -h[4])?;
            let column: Vector3<f64> = (plus - minus) / (2.0 * step) * sigma;
            cov += column * column.transpose();
        }
        Some(cov)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// The paper's example configuration of Fig. 3: VGA, b = 100 mm, beta = 70 deg,
    /// tau_c = 19.1 deg, gamma_c = 24.8 deg.
    fn fig3() -> StripeSensor {
        StripeSensor {
            baseline_m: 0.1,
            beta_rad: 70f64.to_radians(),
            tau_c_rad: 19.1f64.to_radians(),
            gamma_c_rad: 24.8f64.to_radians(),
            rows_px: 480.0,
            cols_px: 640.0,
        }
    }

    #[test]
    fn eq1_by_hand() {
        let s = fig3();
        // Centre row: (1 - 2v/R) = 0, so z = b / cot(beta) = b tan(beta), y = 0.
        let p = s.point(320.0, 240.0).unwrap();
        assert_relative_eq!(p.z, 0.1 * 70f64.to_radians().tan(), epsilon = 1e-12);
        assert_relative_eq!(p.x, 0.0, epsilon = 1e-12);
        assert_relative_eq!(p.y, 0.0, epsilon = 1e-12);
        // Top row v = 0, left column u = 0: den = tan(19.1) + cot(70) = 0.3462809 + 0.3639702
        // = 0.7102513; z = 0.1 / 0.7102513 = 0.1407952; x = z tan(24.8) = 0.0650565;
        // y = -0.1 (1 - 0.3639702 / 0.7102513) = -0.0487547.
        let p = s.point(0.0, 0.0).unwrap();
        assert_relative_eq!(p.z, 0.1407952, epsilon = 1e-7);
        assert_relative_eq!(p.x, 0.0650565, epsilon = 1e-7);
        assert_relative_eq!(p.y, -0.0487547, epsilon = 1e-7);
        // Bottom row, where the line of sight is parallel to the plane, has no point.
        let steep = StripeSensor {
            tau_c_rad: 45f64.to_radians(),
            beta_rad: 45f64.to_radians(),
            ..s
        };
        assert!(steep.point(0.0, 480.0).is_none());
    }

    #[test]
    fn eq2_and_the_ragno_prototype() {
        // Fig. 3's angles from VGA: tau_c = 19.1 deg is atan(240 / f), f = 691 px.
        let s = StripeSensor::from_focal(0.1, 1.2, 691.0, 480.0, 640.0);
        assert_relative_eq!(s.tau_c_rad.to_degrees(), 19.15, epsilon = 0.01);
        assert_relative_eq!(s.gamma_c_rad.to_degrees(), 24.85, epsilon = 0.01);
    }

    #[test]
    fn stripe_uncertainty_grows_with_range_along_z() {
        let s = fig3();
        let noise = StripeNoise {
            u_px: 0.5,
            v_px: 0.5,
            baseline_m: 0.0,
            beta_rad: 0.0,
            tau_c_rad: 0.0,
        };
        let near = s.covariance(320.0, 0.0, &noise).unwrap();
        let far = s.covariance(320.0, 470.0, &noise).unwrap();
        assert!(s.point(320.0, 470.0).unwrap().z > s.point(320.0, 0.0).unwrap().z);
        // Fig. 3b: the z uncertainty grows (hyperbolically) with range.
        assert!(far[(2, 2)] > 4.0 * near[(2, 2)], "{near} {far}");
        // dz/dv by hand at the centre row: z = b / D, dD/dv = -2 tan(tau) / R, so
        // dz/dv = b * 2 tan(tau) / (R D^2) with D = cot(beta).
        let c = s.covariance(320.0, 240.0, &noise).unwrap();
        let d = 1.0 / 70f64.to_radians().tan();
        let dz_dv = 0.1 * 2.0 * 19.1f64.to_radians().tan() / (480.0 * d * d);
        assert_relative_eq!(c[(2, 2)].sqrt(), dz_dv * 0.5, max_relative = 1e-5);
    }
}
