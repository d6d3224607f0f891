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
use super::sensors::UrgSensor;
use crate::MappingError;
use std::time::Instant;
use stride_core::grid::{Grid, GridGeometry};
use stride_core::scan::Scan;

/// The range error that eqs. 6/8 allow for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RangeError {
    /// The URG-04LX's specification (10 mm to 1 m, then 1 %), times this many standard
    /// deviations; with `raw`, ranges are raw readings that eq. 4 corrects first.
    Urg {
        /// Standard deviations that make the maximum error of eq. 6.
        sigmas: f64,
        /// The log holds raw readings (eq. 4 applies).
        raw: bool,
    },
    /// A triangulating stripe sensor: the range error grows with the square of the range,
    /// `Delta r = r^2 Delta v / (b f)` (eq. 1 differentiated by the stripe's row, at the
    /// image centre), with the baseline `b` (m), the focal length `f` (px) and the stripe's
    /// row error `Delta v` (px).
    Stripe {
        /// Baseline (m).
        baseline_m: f64,
        /// Focal length (px).
        focal_px: f64,
        /// Row error (px).
        row_px: f64,
    },
}

impl RangeError {
    /// The maximum range error (m) at range `r_m`.
    pub fn max_error_m(&self, r_m: f64) -> f64 {
        match *self {
            RangeError::Urg { sigmas, .. } => sigmas * UrgSensor::range_sigma_m(r_m),
            RangeError::Stripe {
                baseline_m,
                focal_px,
                row_px,
            } => r_m * r_m * row_px / (baseline_m * focal_px),
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
    let mut map = CertaintyMap::new(geometry, config.certainty)?;
    let mut stats = ScanMapStats::default();
    let mut times = Vec::with_capacity(scans.len());
    let filtered = filter_scans(&mut scans, config);
    stats.uncalibrated = filtered.uncalibrated;
    stats.dropped_clusters = filtered.dropped_clusters;
    stats.dropped_three_scan = filtered.dropped_three_scan;
    times.extend(filtered.scan_s);
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
            let r = p_s.norm();
            if r > config.max_range_m {
                stats.beyond_range += 1;
                continue;
            }
            let err = p_s / r * config.range_error.max_error_m(r);
            let dz = config
                .bound
                .delta_z_max(&scan.world_from_sensor, &p_s, &[err], motion);
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
    fn range_errors_by_hand() {
        let urg = RangeError::Urg {
            sigmas: 2.0,
            raw: false,
        };
        assert_eq!(urg.max_error_m(0.5), 0.02);
        let stripe = RangeError::Stripe {
            baseline_m: 0.12,
            focal_px: 600.0,
            row_px: 0.5,
        };
        // 0.3^2 * 0.5 / (0.12 * 600) = 0.000625.
        assert!((stripe.max_error_m(0.3) - 0.000625).abs() < 1e-12);
    }
}
