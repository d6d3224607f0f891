//! The two 2-D range sensors of paper 003, in their own frames (shared by the simulator and
//! the mapper):
//!
//! * [`StripeSensor`]: a camera and a laser-stripe emitter tilted down by `beta` (section
//!   3.1). A stripe pixel `(u, v)` gives a 3-D point in the camera frame by eq. 1, whose
//!   axes are the paper's: `x_c` lateral, `y_c` from the emitter towards the camera (the
//!   emitter is at `y_c = -b`), `z_c` along the optical axis; the light plane is
//!   `y_c = z_c cot(beta) - b`. Eq. 2 gives the viewing half-angles from the focal length.
//! * [`UrgSensor`]: the Hokuyo URG-04LX (section 4.1): 683 beams over 240 degrees at 10 Hz,
//!   1 mm resolution, range noise by the maker's specification, and the systematic range
//!   error that eq. 4 corrects between 50 and 1000 mm (raw). Its frame is ROS's
//!   `LaserScan`'s: beams in the x-y plane, angle from +x towards +y.

use nalgebra::{Matrix3, Point3, Vector3};

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

    /// The displacements (camera frame, m) of the point at `(u, v)` under each input's
    /// error, in the order u, v, b, beta, tau_c: eq. 1's Jacobian columns (central
    /// differences) times `noise`. Eq. 8's sensor terms are the last four.
    pub fn error_vectors(&self, u: f64, v: f64, noise: &StripeNoise) -> Option<[Vector3<f64>; 5]> {
        let p = |h: [f64; 5]| {
            Self::eq1(
                u + h[0],
                v + h[1],
                self.baseline_m + h[2],
                self.beta_rad + h[3],
                self.tau_c_rad + h[4],
                self.gamma_c_rad,
                self.rows_px,
                self.cols_px,
            )
            .map(|p| p.coords)
        };
        let sigmas = [
            noise.u_px,
            noise.v_px,
            noise.baseline_m,
            noise.beta_rad,
            noise.tau_c_rad,
        ];
        let steps = [1e-3, 1e-3, 1e-6, 1e-7, 1e-7];
        let mut out = [Vector3::zeros(); 5];
        for (k, (col, (sigma, step))) in out.iter_mut().zip(sigmas.iter().zip(steps)).enumerate() {
            let mut h = [0.0; 5];
            if let Some(x) = h.get_mut(k) {
                *x = step;
            }
            let plus = p(h)?;
            let minus = p(h.map(|x| -x))?;
            *col = (plus - minus) / (2.0 * step) * *sigma;
        }
        Some(out)
    }

    /// The covariance (m²) of the point at `(u, v)`: the input noises (standard
    /// deviations) propagated through eq. 1 by its Jacobian.
    pub fn covariance(&self, u: f64, v: f64, noise: &StripeNoise) -> Option<Matrix3<f64>> {
        Some(
            self.error_vectors(u, v, noise)?
                .iter()
                .fold(Matrix3::zeros(), |c, e| c + e * e.transpose()),
        )
    }

    /// The stripe pixel `(u, v)` at which a point of the light plane (camera frame) is seen:
    /// eq. 1 inverted, `u = R_hor/2 (1 - x/(z tan gamma_c))`, `v = R_ver/2 (1 + y/(z tan
    /// tau_c))`; `None` behind the camera.
    pub fn pixel_of(&self, p_camera: &Point3<f64>) -> Option<(f64, f64)> {
        (p_camera.z > 1e-9).then(|| {
            (
                self.cols_px / 2.0 * (1.0 - p_camera.x / (p_camera.z * self.gamma_c_rad.tan())),
                self.rows_px / 2.0 * (1.0 + p_camera.y / (p_camera.z * self.tau_c_rad.tan())),
            )
        })
    }

    /// The light plane's frame in the camera frame (the frame stripe returns are written
    /// in as scans): origin at the emitter (`y_c = -b`), x the sheet's central direction
    /// (`(0, cot beta, 1)` normalised), y the camera's x axis, z their cross product.
    pub fn camera_from_plane(&self) -> nalgebra::Isometry3<f64> {
        let central = Vector3::new(0.0, 1.0 / self.beta_rad.tan(), 1.0).normalize();
        let y = Vector3::x();
        let z = central.cross(&y);
        let r = nalgebra::Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[central, y, z]));
        nalgebra::Isometry3::from_parts(
            Vector3::new(0.0, -self.baseline_m, 0.0).into(),
            nalgebra::UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    /// Paper 003's Ragno prototype: b = 120 mm, beta = 45 degrees, tau_c = 28.14 degrees,
    /// gamma_c = 38.8 degrees, a VGA image.
    pub fn ragno() -> Self {
        Self {
            baseline_m: 0.12,
            beta_rad: 45f64.to_radians(),
            tau_c_rad: 28.14f64.to_radians(),
            gamma_c_rad: 38.8f64.to_radians(),
            rows_px: 480.0,
            cols_px: 640.0,
        }
    }
}

/// A raw URG-04LX range outside the interval where paper 003's calibration (eq. 4) holds.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("raw range {range_mm} mm is outside eq. 4's calibrated interval [50, 1000] mm")]
pub struct UncalibratedRange {
    /// The raw range (mm).
    pub range_mm: f64,
}

/// The Hokuyo URG-04LX scanner (paper 003, section 4.1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UrgSensor {
    /// Beams per scan.
    pub beams: usize,
    /// Angle of the first beam (rad).
    pub angle_min_rad: f64,
    /// Angle between beams (rad).
    pub angle_increment_rad: f64,
    /// Shortest range returned (m).
    pub range_min_m: f64,
    /// Longest range returned (m).
    pub range_max_m: f64,
    /// Scans per second.
    pub rate_hz: f64,
}

/// Lower end of eq. 4's calibrated interval of raw ranges (mm).
pub const URG_CALIBRATION_MIN_MM: f64 = 50.0;
/// Upper end of eq. 4's calibrated interval of raw ranges (mm).
pub const URG_CALIBRATION_MAX_MM: f64 = 1000.0;

impl Default for UrgSensor {
    /// The URG-04LX: 683 beams 360/1024 degrees apart, centred on +x (240 degrees), 0.02 to
    /// 4.095 m, 10 Hz.
    fn default() -> Self {
        let inc = (360.0f64 / 1024.0).to_radians();
        Self {
            beams: 683,
            angle_min_rad: -341.0 * inc,
            angle_increment_rad: inc,
            range_min_m: 0.02,
            range_max_m: 4.095,
            rate_hz: 10.0,
        }
    }
}

impl UrgSensor {
    /// The unit direction of beam `i` in the sensor frame.
    pub fn beam_direction(&self, i: usize) -> Vector3<f64> {
        let a = self.angle_min_rad + i as f64 * self.angle_increment_rad;
        Vector3::new(a.cos(), a.sin(), 0.0)
    }

    /// The range's standard deviation (m) by the maker's specification: 10 mm up to 1 m,
    /// 1 % of the range beyond.
    pub fn range_sigma_m(range_m: f64) -> f64 {
        if range_m <= 1.0 {
            0.01
        } else {
            0.01 * range_m
        }
    }

    /// Eq. 4's systematic error `Delta r_m` (mm) of a raw range `r_m` (mm), without the
    /// validity check (the simulator inverts it).
    pub fn systematic_error_mm(raw_mm: f64) -> f64 {
        38.6 + 0.18 * raw_mm + 0.3e-3 * raw_mm * raw_mm - 0.2e-7 * raw_mm.powi(3)
    }

    /// Eq. 4: the corrected range `r = r_m + Delta r_m` (mm) of a raw range (mm); an error
    /// outside the calibrated interval of raw ranges, 50 to 1000 mm.
    pub fn calibrate_mm(raw_mm: f64) -> Result<f64, UncalibratedRange> {
        if !(URG_CALIBRATION_MIN_MM..=URG_CALIBRATION_MAX_MM).contains(&raw_mm) {
            return Err(UncalibratedRange { range_mm: raw_mm });
        }
        Ok(raw_mm + Self::systematic_error_mm(raw_mm))
    }

    /// The raw range (mm) that eq. 4 turns into `true_mm`, for simulating raw readings:
    /// eq. 4 extended over the sensor's whole scale (0 to 4095 mm raw, where it increases),
    /// so a raw reading outside the calibrated interval is what [`Self::calibrate_mm`]
    /// refuses; `None` beyond the scale.
    pub fn raw_for_mm(true_mm: f64) -> Option<f64> {
        let f = |r: f64| r + Self::systematic_error_mm(r) - true_mm;
        let (mut lo, mut hi) = (0.0, 4095.0);
        if !(f(lo) <= 0.0 && f(hi) >= 0.0) {
            return None;
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if f(mid) > 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Some(0.5 * (lo + hi))
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
    fn pixels_invert_eq1_and_the_light_plane_frame_holds_its_points() {
        let s = fig3();
        let p = s.point(100.0, 300.0).unwrap();
        let (u, v) = s.pixel_of(&p).unwrap();
        assert_relative_eq!((u, v).0, 100.0, epsilon = 1e-9);
        assert_relative_eq!(v, 300.0, epsilon = 1e-9);
        // In the plane's frame a point of the sheet has z = 0.
        let q = s.camera_from_plane().inverse() * p;
        assert_relative_eq!(q.z, 0.0, epsilon = 1e-12);
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

    #[test]
    fn eq4_by_hand_and_its_valid_range() {
        // r_m = 500: 38.6 + 90 + 75 - 2.5 = 201.1 mm of correction.
        assert_relative_eq!(
            UrgSensor::calibrate_mm(500.0).unwrap(),
            701.1,
            epsilon = 1e-9
        );
        // r_m = 50: 38.6 + 9 + 0.75 - 0.0025.
        assert_relative_eq!(
            UrgSensor::calibrate_mm(50.0).unwrap(),
            98.3475,
            epsilon = 1e-9
        );
        for bad in [49.9, 1000.5, f64::NAN] {
            let e = UrgSensor::calibrate_mm(bad).unwrap_err().to_string();
            assert!(
                e.contains("outside eq. 4's calibrated interval [50, 1000] mm"),
                "{e}"
            );
        }
        let raw = UrgSensor::raw_for_mm(701.1).unwrap();
        assert_relative_eq!(raw, 500.0, epsilon = 1e-6);
        // A true 90 mm needs a raw reading below 50 mm, which eq. 4 refuses.
        let raw = UrgSensor::raw_for_mm(90.0).unwrap();
        assert!(raw < 50.0 && UrgSensor::calibrate_mm(raw).is_err());
        assert!(UrgSensor::raw_for_mm(1600.0).unwrap() > 1000.0);
        assert!(UrgSensor::raw_for_mm(1e6).is_none());
    }

    #[test]
    fn urg_geometry() {
        let s = UrgSensor::default();
        let span = (s.beams - 1) as f64 * s.angle_increment_rad;
        assert_relative_eq!(span.to_degrees(), 239.77, epsilon = 0.01);
        assert_relative_eq!(s.beam_direction(341), Vector3::x(), epsilon = 1e-12);
        assert_eq!(UrgSensor::range_sigma_m(0.5), 0.01);
        assert_relative_eq!(UrgSensor::range_sigma_m(3.0), 0.03);
    }
}
