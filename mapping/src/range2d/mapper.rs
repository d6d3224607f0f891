//! Scans in, map out: paper 003's whole update for a sequence of scans with their poses.
//!
//! Per scan, in order: raw URG ranges corrected by eq. 4 (when asked; a raw range outside
//! eq. 4's interval is dropped and counted), small isolated clusters dropped, eq. 12's
//! three-scan analysis (scan `k` against `k-1` and `k+1`, so a scan is mapped once its
//! successor has arrived), then every remaining return updates the map by eqs. 9-10 with
//! the plausibility bound of eqs. 6/8 for the motion since the previous scan. At the end,
//! the CAS filter (when configured) and eq. 11's fill.

use super::certainty::{CertaintyConfig, CertaintyMap, FinishStats};
use super::mixed::{drop_small_clusters, three_scan_filter, MixedConfig};
use super::plausibility::{Bound, Motion};
use super::sensors::{StripeNoise, StripeSensor, UrgSensor};
use crate::MappingError;
use nalgebra::{Point3, Vector3};
use std::time::Instant;
use stride_core::grid::{Grid, GridGeometry};
use stride_core::scan::Scan;

/// The sensor errors that eqs. 6/8 allow for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RangeError {
    /// Eq. 6's range term for the URG-04LX: its specification (10 mm to 1 m, then 1 %),
    /// times this many standard deviations; with `raw`, ranges are raw readings that eq. 4
    /// corrects first.
    Urg {
        /// Standard deviations that make the maximum error of eq. 6.
        sigmas: f64,
        /// The log holds raw readings (eq. 4 applies).
        raw: bool,
    },
    /// Eq. 8's four sensor terms for the stripe sensor: the point's displacement under the
    /// maximum errors of the stripe row `v`, the baseline `b`, `beta` and `tau_c` (eq. 1's
    /// Jacobian). The scans are in the light plane's frame
    /// ([`StripeSensor::camera_from_plane`]).
    Stripe {
        /// The sensor.
        sensor: StripeSensor,
        /// The maximum errors (the column's is not used: eq. 8 has no term for it).
        errors: StripeNoise,
    },
}

impl RangeError {
    /// Eq. 8's errors of the Ragno prototype: the stripe row to 1 px (twice the detector's
    /// 0.5 px), the baseline to 1 mm, beta to 0.2 degrees and tau_c to 0.1 degrees (from a
    /// calibration as in paper 003's reference 14).
    pub fn ragno_stripe() -> Self {
        RangeError::Stripe {
            sensor: StripeSensor::ragno(),
            errors: StripeNoise {
                u_px: 0.0,
                v_px: 1.0,
                baseline_m: 0.001,
                beta_rad: 0.2f64.to_radians(),
                tau_c_rad: 0.1f64.to_radians(),
            },
        }
    }

    /// The point's displacements (sensor frame, m) under each sensor error, for eqs. 6/8:
    /// along the beam by the range error for the scanner; eq. 1's Jacobian columns for the
    /// stripe sensor (none when the point cannot be put back into the image).
    pub fn sensor_errors(&self, p_sensor: &Vector3<f64>) -> Vec<Vector3<f64>> {
        match self {
            RangeError::Urg { sigmas, .. } => {
                let r = p_sensor.norm();
                vec![p_sensor / r.max(1e-12) * (*sigmas * UrgSensor::range_sigma_m(r))]
            }
            RangeError::Stripe { sensor, errors } => {
                let camera_from_plane = sensor.camera_from_plane();
                let p_camera = camera_from_plane * Point3::from(*p_sensor);
                let Some((u, v)) = sensor.pixel_of(&p_camera) else {
                    return Vec::new();
                };
                let plane_from_camera = camera_from_plane.rotation.inverse();
                sensor
                    .error_vectors(u, v, errors)
                    .map(|e| e.iter().skip(1).map(|d| plane_from_camera * d).collect())
                    .unwrap_or_default()
            }
        }
    }
}

/// The scan mapper's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanMapConfig {
    /// The grids (eqs. 9-11, CAS).
    pub certainty: CertaintyConfig,
    /// The attitude and mounting errors of eqs. 6/8.
    pub bound: Bound,
    /// The sensor's range error.
    pub range_error: RangeError,
    /// Mixed-measurement removal; `None` maps every return.
    pub mixed: Option<MixedConfig>,
    /// Returns farther than this (m) are not mapped: paper 003 maps a local area ahead of
    /// the robot, where the scanner is accurate (its favourable interval is 0.2-0.9 m).
    pub max_range_m: f64,
}

impl Default for ScanMapConfig {
    fn default() -> Self {
        Self {
            certainty: CertaintyConfig::default(),
            bound: Bound::default(),
            range_error: RangeError::Urg {
                sigmas: 2.0,
                raw: false,
            },
            mixed: Some(MixedConfig::default()),
            max_range_m: 1.5,
        }
    }
}

/// What mapping the scans did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ScanMapStats {
    /// Scans mapped.
    pub scans: usize,
    /// Returns in them (after eq. 4).
    pub returns: usize,
    /// Raw ranges outside eq. 4's interval, dropped.
    pub uncalibrated: usize,
    /// Returns dropped as small isolated clusters.
    pub dropped_clusters: usize,
    /// Returns dropped by the three-scan analysis.
    pub dropped_three_scan: usize,
    /// Returns outside the grid.
    pub outside: usize,
    /// Returns beyond `max_range_m`, not mapped.
    pub beyond_range: usize,
    /// Returns that raised a cell's certainty (eq. 9), and those that did not.
    pub consistent: usize,
    /// See `consistent`.
    pub inconsistent: usize,
    /// The end's filters.
    pub finish: FinishStats,
    /// Median wall time of one scan's update (filters and map) (s).
    pub scan_median_s: f64,
}

/// What [`filter_scans`] removed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FilterStats {
    /// Raw ranges outside eq. 4's interval.
    pub uncalibrated: usize,
    /// Returns in small isolated clusters.
    pub dropped_clusters: usize,
    /// Returns removed by the three-scan analysis.
    pub dropped_three_scan: usize,
    /// Wall time per scan (s).
    pub scan_s: Vec<f64>,
}

/// Raw URG-04LX readings to ranges by eq. 4, in place; a raw range outside eq. 4's interval
/// is dropped. Returns how many were.
pub fn calibrate_raw(scans: &mut [Scan]) -> usize {
    let mut dropped = 0;
    for s in scans.iter_mut() {
        for r in &mut s.ranges {
            if r.is_finite() && *r > 0.0 {
                match UrgSensor::calibrate_mm(*r * 1000.0) {
                    Ok(mm) => *r = mm / 1000.0,
                    Err(_) => {
                        *r = f64::NAN;
                        dropped += 1;
                    }
                }
            }
        }
    }
    dropped
}

/// The preprocessing of [`map_scans`], in place: eq. 4 for raw URG readings, then the
/// mixed-measurement filters (when configured).
pub fn filter_scans(scans: &mut [Scan], config: &ScanMapConfig) -> FilterStats {
    let mut stats = FilterStats {
        scan_s: vec![0.0; scans.len()],
        ..FilterStats::default()
    };
    if let RangeError::Urg { raw: true, .. } = config.range_error {
        stats.uncalibrated = calibrate_raw(scans);
    }
    let Some(mixed) = &config.mixed else {
        return stats;
    };
    for (s, t) in scans.iter_mut().zip(&mut stats.scan_s) {
        let start = Instant::now();
        stats.dropped_clusters += drop_small_clusters(s, mixed);
        *t += start.elapsed().as_secs_f64();
    }
    for k in 1..scans.len().saturating_sub(1) {
        let start = Instant::now();
        let (before, rest) = scans.split_at_mut(k);
        let (current, after) = rest.split_at_mut(1);
        if let (Some(prev), Some(cur), Some(next)) =
            (before.last(), current.first_mut(), after.first())
        {
            stats.dropped_three_scan += three_scan_filter(prev, cur, next, mixed);
        }
        if let Some(t) = stats.scan_s.get_mut(k) {
            *t += start.elapsed().as_secs_f64();
        }
    }
    stats
}

/// Maps `scans` (in time order) into a grid over `geometry`; returns the elevation (m, NaN
/// unknown), the certainty and what was done.
pub fn map_scans(
    mut scans: Vec<Scan>,
    geometry: GridGeometry,
    config: &ScanMapConfig,
) -> Result<(Grid<f32>, Grid<f32>, ScanMapStats), MappingError> {
    let filtered = filter_scans(&mut scans, config);
    map_filtered(&scans, geometry, config, filtered)
}

/// The map update of [`map_scans`] on scans that [`filter_scans`] has already filtered
/// (`filtered` is what it reported).
pub fn map_filtered(
    scans: &[Scan],
    geometry: GridGeometry,
    config: &ScanMapConfig,
    filtered: FilterStats,
) -> Result<(Grid<f32>, Grid<f32>, ScanMapStats), MappingError> {
    let mut map = CertaintyMap::new(geometry, config.certainty)?;
    let mut stats = ScanMapStats {
        uncalibrated: filtered.uncalibrated,
        dropped_clusters: filtered.dropped_clusters,
        dropped_three_scan: filtered.dropped_three_scan,
        ..ScanMapStats::default()
    };
    let mut times = filtered.scan_s;
    times.resize(scans.len(), 0.0);
    for (k, scan) in scans.iter().enumerate() {
        let t = Instant::now();
        let motion = match k.checked_sub(1).and_then(|j| scans.get(j)) {
            Some(prev) => Motion::between(&prev.world_from_sensor, &scan.world_from_sensor),
            None => Motion::default(),
        };
        for i in 0..scan.ranges.len() {
            let (Some(p_s), Some(p_w)) = (scan.p_sensor(i), scan.p_world(i)) else {
                continue;
            };
            stats.returns += 1;
            if p_s.norm() > config.max_range_m {
                stats.beyond_range += 1;
                continue;
            }
            let errors = config.range_error.sensor_errors(&p_s);
            let dz = config
                .bound
                .delta_z_max(&scan.world_from_sensor, &p_s, &errors, motion);
            if !map.update(p_w.x, p_w.y, p_w.z, dz) {
                stats.outside += 1;
            }
        }
        if let Some(x) = times.get_mut(k) {
            *x += t.elapsed().as_secs_f64();
        }
        stats.scans += 1;
    }
    (stats.consistent, stats.inconsistent) = map.consistency();
    let (elevation, certainty, finish) = map.finish();
    stats.finish = finish;
    times.sort_by(f64::total_cmp);
    stats.scan_median_s = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
    Ok((elevation, certainty, stats))
}

/// The grid covering every return of `scans` within `max_range_m` of its sensor, with
/// `margin_m` to spare, cells of `resolution_m`.
pub fn covering_geometry(
    scans: &[Scan],
    resolution_m: f64,
    margin_m: f64,
    max_range_m: f64,
) -> Option<GridGeometry> {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for s in scans {
        for i in 0..s.ranges.len() {
            if s.ranges.get(i).is_some_and(|&r| r > max_range_m) {
                continue;
            }
            if let Some(p) = s.p_world(i) {
                x0 = x0.min(p.x);
                y0 = y0.min(p.y);
                x1 = x1.max(p.x);
                y1 = y1.max(p.y);
            }
        }
    }
    (x0 <= x1).then(|| {
        GridGeometry::covering(
            x0 - margin_m,
            y0 - margin_m,
            x1 + margin_m,
            y1 + margin_m,
            resolution_m,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, UnitQuaternion, Vector3};

    /// A scanner 0.26 m above a flat floor at z = 0, tilted down 35 degrees, moving along x.
    fn sweep(n: usize) -> Vec<Scan> {
        let urg = UrgSensor::default();
        let tilt = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 35f64.to_radians());
        (0..n)
            .map(|k| {
                let pose =
                    Isometry3::from_parts(Vector3::new(0.01 * k as f64, 0.0, 0.26).into(), tilt);
                // Each beam's range to the floor (no return beyond 1.5 m or above the horizon).
                let ranges = (0..urg.beams)
                    .map(|i| {
                        let d = pose.rotation * urg.beam_direction(i);
                        let r = if d.z < -1e-6 { 0.26 / -d.z } else { f64::NAN };
                        if r <= 1.5 {
                            r
                        } else {
                            f64::NAN
                        }
                    })
                    .collect();
                Scan {
                    t_s: 0.1 * k as f64,
                    world_from_sensor: pose,
                    angle_min_rad: urg.angle_min_rad,
                    angle_increment_rad: urg.angle_increment_rad,
                    ranges,
                }
            })
            .collect()
    }

    #[test]
    fn a_flat_floor_maps_flat_and_certain() {
        let scans = sweep(60);
        let g = covering_geometry(&scans, 0.01, 0.0, 1.5).unwrap();
        let (h, c, stats) = map_scans(scans, g, &ScanMapConfig::default()).unwrap();
        assert_eq!(stats.scans, 60);
        assert_eq!(stats.dropped_clusters + stats.dropped_three_scan, 0);
        let known: Vec<f32> = h
            .as_slice()
            .iter()
            .copied()
            .filter(|v| !v.is_nan())
            .collect();
        assert!(known.len() > 2000, "{} cells", known.len());
        assert!(
            known.iter().all(|v| v.abs() < 1e-6),
            "a noise-free floor is at 0"
        );
        assert!(c.as_slice().iter().copied().fold(0.0, f32::max) >= 2.0);
        assert_eq!(stats.inconsistent, 0);
    }

    #[test]
    fn raw_readings_are_corrected_and_out_of_range_ones_counted() {
        let mut scans = sweep(3);
        for s in &mut scans {
            for r in &mut s.ranges {
                if r.is_finite() {
                    *r = UrgSensor::raw_for_mm(*r * 1000.0).map_or(f64::NAN, |mm| mm / 1000.0);
                }
            }
        }
        // A raw 1.2 m is beyond eq. 4's 1000 mm.
        scans[0].ranges[341] = 1.2;
        let g = covering_geometry(&sweep(3), 0.01, 0.1, 1.5).unwrap();
        let config = ScanMapConfig {
            range_error: RangeError::Urg {
                sigmas: 2.0,
                raw: true,
            },
            mixed: None,
            ..ScanMapConfig::default()
        };
        let (h, _, stats) = map_scans(scans, g, &config).unwrap();
        assert_eq!(stats.uncalibrated, 1);
        let known: Vec<f32> = h
            .as_slice()
            .iter()
            .copied()
            .filter(|v| !v.is_nan())
            .collect();
        assert!(
            known.iter().all(|v| v.abs() < 1e-6),
            "corrected back onto the floor"
        );
    }

    #[test]
    fn sensor_errors_by_hand() {
        let urg = RangeError::Urg {
            sigmas: 2.0,
            raw: false,
        };
        // 2 sigma of 10 mm along the beam at 0.5 m.
        let e = urg.sensor_errors(&Vector3::new(0.3, 0.4, 0.0));
        assert!((e[0] - Vector3::new(0.012, 0.016, 0.0)).norm() < 1e-12);
        // Eq. 8, the stripe row's term alone, for the sheet's central point: in the camera
        // frame dz/dv = b 2 tan(tau) / (R D^2) with D = cot(beta) at the centre row; the
        // point moves along the light plane (its z in the plane's frame stays 0).
        let sensor = StripeSensor::ragno();
        let only_v = RangeError::Stripe {
            sensor,
            errors: StripeNoise {
                u_px: 0.0,
                v_px: 1.0,
                baseline_m: 0.0,
                beta_rad: 0.0,
                tau_c_rad: 0.0,
            },
        };
        let centre = sensor.point(320.0, 240.0).unwrap();
        let p_plane = sensor.camera_from_plane().inverse() * centre;
        let e = only_v.sensor_errors(&p_plane.coords);
        assert_eq!(e.len(), 4);
        let d = 1.0 / sensor.beta_rad.tan();
        let dz_dv = 0.12 * 2.0 * sensor.tau_c_rad.tan() / (480.0 * d * d);
        let in_camera = sensor.camera_from_plane().rotation * e[0];
        assert!(
            (in_camera.z - dz_dv).abs() < 1e-6 * dz_dv.max(1.0),
            "{in_camera} vs {dz_dv}"
        );
        assert!(e[0].z.abs() < 1e-9, "stays in the plane");
        assert!(e[1..].iter().all(|x| x.norm() == 0.0));
    }
}
