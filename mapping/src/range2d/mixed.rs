//! Removal of mixed measurements ("mixed pixels": a beam whose footprint straddles a depth
//! edge returns a range between the two surfaces, or beyond the far one), paper 003
//! section 5.3, before the map sees them:
//!
//! * [`drop_small_clusters`]: the scan is cut into clusters of consecutive returns wherever
//!   two neighbours are farther apart than a breakpoint distance that grows with range (the
//!   adaptive breakpoint of Borges and Aldon, plus the range noise), and clusters of fewer
//!   than `min_cluster_beams` returns are dropped: isolated mixed returns beside thin
//!   objects and vertical edges (the paper's first case). Paper 003 uses its authors' own
//!   range clustering, of which it gives no formula; this rule does the same job.
//! * [`three_scan_filter`]: eq. 12 over three consecutive scans (the second case, an edge
//!   across the scanning direction): a run of collinear returns roughly along the scan line
//!   in scan `k-1` marks an angular sector; if the returns of scan `k` in that sector
//!   scatter along the beam (the standard deviation of eq. 12, of the coordinate along the
//!   sensor's central beam) much more than those of scan `k+1`, they are mixed and removed.
//!   The test runs over windows of `scatter_window_beams` beams sliding along the sector
//!   (by half a window): over a whole floor line, the few mixed returns behind one edge
//!   would not move the sector's deviation.

use stride_core::scan::Scan;

/// The filters' parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MixedConfig {
    /// Smallest angle between the beam and a surface treated as a surface (rad), lambda of
    /// the adaptive breakpoint.
    pub breakpoint_lambda_rad: f64,
    /// Range noise allowance added to the breakpoint (m).
    pub breakpoint_noise_m: f64,
    /// Clusters with fewer returns are dropped.
    pub min_cluster_beams: usize,
    /// Fewest returns of a collinear run that marks an edge (eq. 12's sector).
    pub edge_min_beams: usize,
    /// Largest distance of a run's returns from its line (m).
    pub edge_line_tolerance_m: f64,
    /// Largest angle between the run's line and the sensor's y axis (rad).
    pub edge_max_angle_rad: f64,
    /// Scan `k`'s returns are removed when their eq. 12 deviation exceeds this many times
    /// scan `k+1`'s ...
    pub scatter_ratio: f64,
    /// ... plus this (m).
    pub scatter_floor_m: f64,
    /// Beams of the windows eq. 12 is evaluated over within a sector.
    pub scatter_window_beams: usize,
}

impl Default for MixedConfig {
    fn default() -> Self {
        Self {
            breakpoint_lambda_rad: 10f64.to_radians(),
            breakpoint_noise_m: 0.03,
            min_cluster_beams: 4,
            edge_min_beams: 8,
            edge_line_tolerance_m: 0.03,
            edge_max_angle_rad: 30f64.to_radians(),
            scatter_ratio: 3.0,
            scatter_floor_m: 0.01,
            scatter_window_beams: 12,
        }
    }
}

/// The clusters of a scan: half-open beam ranges of consecutive returns.
pub fn clusters(scan: &Scan, config: &MixedConfig) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start: Option<usize> = None;
    let mut last: Option<(usize, (f64, f64), f64)> = None;
    let dphi = scan.angle_increment_rad.abs();
    let k = dphi.sin() / (config.breakpoint_lambda_rad - dphi).sin().max(1e-6);
    for i in 0..scan.ranges.len() {
        let Some(p) = scan.point_2d(i) else { continue };
        let r = scan.ranges.get(i).copied().unwrap_or(0.0);
        match (start, last) {
            (Some(s), Some((j, q, rq))) => {
                let gap = i - j;
                let d_max = rq.min(r) * k * gap as f64 + config.breakpoint_noise_m;
                if (p.0 - q.0).hypot(p.1 - q.1) > d_max {
                    out.push(s..j + 1);
                    start = Some(i);
                }
            }
            _ => start = Some(i),
        }
        last = Some((i, p, r));
    }
    if let (Some(s), Some((j, _, _))) = (start, last) {
        out.push(s..j + 1);
    }
    out
}

/// Drops the returns of clusters with fewer than `min_cluster_beams` returns; returns how
/// many were dropped.
pub fn drop_small_clusters(scan: &mut Scan, config: &MixedConfig) -> usize {
    let mut dropped = 0;
    for c in clusters(scan, config) {
        let n = c.clone().filter(|&i| scan.valid(i)).count();
        if n < config.min_cluster_beams {
            for i in c {
                if scan.valid(i) {
                    scan.drop_return(i);
                    dropped += 1;
                }
            }
        }
    }
    dropped
}

/// Collinear runs of returns in `scan` whose line lies within `edge_max_angle_rad` of the
/// sensor's y axis (across the scanning direction): their beam sectors `[first, last]`.
pub fn edge_sectors(scan: &Scan, config: &MixedConfig) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    for c in clusters(scan, config) {
        let idx: Vec<usize> = c.filter(|&i| scan.valid(i)).collect();
        split_runs(scan, &idx, config, &mut out);
    }
    out
}

/// Iterative end-point fit: splits `idx` at the return farthest from the chord until every
/// piece is within the tolerance; keeps long, lateral pieces.
fn split_runs(scan: &Scan, idx: &[usize], config: &MixedConfig, out: &mut Vec<(usize, usize)>) {
    if idx.len() < config.edge_min_beams.max(2) {
        return;
    }
    let (Some(&first), Some(&last)) = (idx.first(), idx.last()) else {
        return;
    };
    let (Some(a), Some(b)) = (scan.point_2d(first), scan.point_2d(last)) else {
        return;
    };
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len = dx.hypot(dy);
    if len < 1e-9 {
        return;
    }
    let mut worst = (0usize, 0.0f64);
    for (k, &i) in idx.iter().enumerate() {
        if let Some(p) = scan.point_2d(i) {
            let d = ((p.0 - a.0) * dy - (p.1 - a.1) * dx).abs() / len;
            if d > worst.1 {
                worst = (k, d);
            }
        }
    }
    if worst.1 > config.edge_line_tolerance_m {
        let (left, right) = idx.split_at(worst.0.max(1));
        split_runs(scan, left, config, out);
        split_runs(scan, right, config, out);
        return;
    }
    // Angle between the run and the sensor's y axis.
    let angle = (dx.abs()).atan2(dy.abs());
    if angle <= config.edge_max_angle_rad {
        out.push((first, last));
    }
}

/// Eq. 12: the standard deviation of the coordinate along the central beam (x) of the
/// returns of beams `first..=last`, and how many there are.
pub fn sector_scatter(scan: &Scan, first: usize, last: usize) -> (f64, usize) {
    let xs: Vec<f64> = (first..=last)
        .filter_map(|i| scan.point_2d(i).map(|p| p.0))
        .collect();
    let p = xs.len();
    if p == 0 {
        return (0.0, 0);
    }
    let mean = xs.iter().sum::<f64>() / p as f64;
    let var = xs.iter().map(|x| (mean - x).powi(2)).sum::<f64>() / p as f64;
    (var.sqrt(), p)
}

/// The three-scan analysis of eq. 12 on `current`, between `previous` and `next`; returns
/// how many returns of `current` were removed.
pub fn three_scan_filter(
    previous: &Scan,
    current: &mut Scan,
    next: &Scan,
    config: &MixedConfig,
) -> usize {
    let w = config.scatter_window_beams.max(2);
    let mut flagged: Vec<(usize, usize)> = Vec::new();
    for (first, last) in edge_sectors(previous, config) {
        let mut start = first;
        loop {
            let end = (start + w - 1).min(last);
            let (s_cur, n_cur) = sector_scatter(current, start, end);
            let (s_next, n_next) = sector_scatter(next, start, end);
            if n_cur >= 2
                && n_next >= 2
                && s_cur > config.scatter_ratio * s_next + config.scatter_floor_m
            {
                flagged.push((start, end));
            }
            if end >= last {
                break;
            }
            start += w / 2;
        }
    }
    let mut removed = 0;
    for (first, last) in flagged {
        for i in first..=last {
            if current.valid(i) {
                current.drop_return(i);
                removed += 1;
            }
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Isometry3;

    fn scan(ranges: Vec<f64>) -> Scan {
        Scan {
            t_s: 0.0,
            world_from_sensor: Isometry3::identity(),
            angle_min_rad: -0.5,
            angle_increment_rad: 0.01,
            ranges,
        }
    }

    /// Ranges of a straight line x = `x` across the scan (an edge along the sensor's y axis).
    fn line(x: f64, n: usize) -> Vec<f64> {
        (0..n).map(|i| x / (-0.5 + i as f64 * 0.01).cos()).collect()
    }

    #[test]
    fn isolated_returns_are_dropped_and_runs_kept() {
        let mut r = line(0.5, 60);
        // Two stray returns 10 cm behind the line, and a gap of no return.
        r[20] = 0.62;
        r[21] = 0.63;
        r[40] = f64::NAN;
        let mut s = scan(r);
        let c = clusters(&s, &MixedConfig::default());
        assert_eq!(c, vec![0..20, 20..22, 22..60], "{c:?}");
        assert_eq!(drop_small_clusters(&mut s, &MixedConfig::default()), 2);
        assert!(!s.valid(20) && !s.valid(21) && s.valid(19) && s.valid(22));
    }

    #[test]
    fn eq12_by_hand() {
        // x = 0.5, 0.5, 0.6, 0.6 for beams at angle 0: mean 0.55, std 0.05.
        let s = Scan {
            angle_min_rad: 0.0,
            angle_increment_rad: 0.0,
            ..scan(vec![0.5, 0.5, 0.6, 0.6])
        };
        let (sigma, p) = sector_scatter(&s, 0, 3);
        assert_eq!(p, 4);
        assert!((sigma - 0.05).abs() < 1e-12);
    }

    #[test]
    fn a_scan_scattered_across_an_edge_is_removed_and_a_clean_one_kept() {
        let cfg = MixedConfig::default();
        let previous = scan(line(0.5, 60));
        let next = scan(line(0.7, 60));
        assert_eq!(edge_sectors(&previous, &cfg), vec![(0, 59)]);
        // Scan k straddles the edge: ranges alternate between the two lines and beyond.
        let mixed: Vec<f64> = (0..60)
            .map(|i| {
                let a = (-0.5 + i as f64 * 0.01f64).cos();
                [0.5, 0.6, 0.7, 0.78][i % 4] / a
            })
            .collect();
        let mut current = scan(mixed);
        assert_eq!(three_scan_filter(&previous, &mut current, &next, &cfg), 60);
        // A clean scan between the two is kept.
        let mut clean = scan(line(0.6, 60));
        assert_eq!(three_scan_filter(&previous, &mut clean, &next, &cfg), 0);
        // A run along the beam (x varies, y constant) is no edge across the scan.
        let along = Scan {
            angle_min_rad: 0.0,
            angle_increment_rad: 0.0,
            ..scan((0..20).map(|i| 0.3 + 0.01 * i as f64).collect())
        };
        assert!(edge_sectors(&along, &cfg).is_empty());
    }
}
