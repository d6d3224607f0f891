//! The Hokuyo URG-04LX laser scanner of paper 003 (section 4.1): 683 beams over 240
//! degrees at 10 Hz, 1 mm resolution, range noise by the maker's specification, and the
//! systematic range error that eq. 4 corrects between 50 and 1000 mm (raw). Its frame is
//! ROS's `LaserScan`'s: beams in the x-y plane, angle from +x towards +y.

use nalgebra::Vector3;

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
