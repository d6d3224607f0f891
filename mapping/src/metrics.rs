//! How good a map is: its error against a ground-truth elevation grid, its coverage, and the
//! performance index of paper 000 (eq. 13) between two maps.

use serde::Serialize;
use stride_core::grid::Grid;

/// A map compared with ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MapScore {
    /// Mean squared height error over the cells both observe (m²).
    pub mse: f64,
    /// Its square root (m).
    pub rmse: f64,
    /// Mean absolute error (m).
    pub mean_abs: f64,
    /// 95th percentile of the absolute error (m).
    pub p95_abs: f64,
    /// Largest absolute error (m).
    pub max_abs: f64,
    /// Cells compared (known in both).
    pub cells_compared: usize,
    /// Cells of the map with a height.
    pub cells_observed: usize,
    /// Fraction of the ground-truth cells inside the map's extent that the map knows.
    pub coverage: f64,
}

/// Compares a map's elevation with ground truth, sampled bilinearly at the map's cell
/// centres (both grids in the same frame, z up). `None` when no cell can be compared.
pub fn compare(map: &Grid<f32>, gt: &Grid<f32>) -> Option<MapScore> {
    let g = map.geometry;
    let mut errs = Vec::new();
    let mut gt_cells = 0usize;
    let mut observed = 0usize;
    for r in 0..g.rows {
        for c in 0..g.cols {
            let (x, y) = g.center(r, c);
            let truth = gt.sample_bilinear(x, y);
            let h = map.get(r, c).filter(|v| !v.is_nan());
            observed += usize::from(h.is_some());
            if let Some(t) = truth {
                gt_cells += 1;
                if let Some(h) = h {
                    errs.push(f64::from(h) - f64::from(t));
                }
            }
        }
    }
    if errs.is_empty() {
        return None;
    }
    let n = errs.len() as f64;
    let mse = errs.iter().map(|e| e * e).sum::<f64>() / n;
    let mut abs: Vec<f64> = errs.iter().map(|e| e.abs()).collect();
    abs.sort_by(f64::total_cmp);
    Some(MapScore {
        mse,
        rmse: mse.sqrt(),
        mean_abs: abs.iter().sum::<f64>() / n,
        p95_abs: abs
            .get(((abs.len() - 1) as f64 * 0.95).round() as usize)
            .copied()
            .unwrap_or(f64::NAN),
        max_abs: abs.last().copied().unwrap_or(f64::NAN),
        cells_compared: errs.len(),
        cells_observed: observed,
        coverage: if gt_cells > 0 {
            errs.len() as f64 / gt_cells as f64
        } else {
            0.0
        },
    })
}

/// Paper 000's performance index (eq. 13) of map `f` against map `m`:
/// `PI = (sum o_f (h_f - h_t)^2 N_om) / (sum o_m (h_m - h_t)^2 N_of)`, the ratio of their
/// mean squared errors against ground truth `t`, each over the cells it observes. Below 1,
/// `f` is the better map. `None` when either map has no comparable cell or `m` is perfect.
pub fn performance_index(f: &Grid<f32>, m: &Grid<f32>, gt: &Grid<f32>) -> Option<f64> {
    let (sf, sm) = (compare(f, gt)?, compare(m, gt)?);
    (sm.mse > 0.0).then(|| sf.mse / sm.mse)
}

/// Phantom obstacles: map cells that stand higher than a flat ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PhantomScore {
    /// Map cells over flat ground truth (every ground-truth cell within `radius_m` known,
    /// their heights within `flat_tol_m` of each other).
    pub flat_cells: usize,
    /// Of those, cells higher than the ground truth by more than `threshold_m`.
    pub phantoms: usize,
    /// And cells lower than it by more than `threshold_m` (false pits).
    pub pits: usize,
    /// Largest height above the ground truth over flat cells (m).
    pub max_excess_m: f64,
    /// The threshold (m).
    pub threshold_m: f64,
}

/// The lowest and highest ground truth within `k` cells of cell `(gr, gc)` of `gt`; `None`
/// when any of those cells is unknown (NaN: an object's or a wall's footprint) or outside
/// the grid.
fn span_around(gt: &Grid<f32>, gr: usize, gc: usize, k: i64) -> Option<(f32, f32)> {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for dr in -k..=k {
        for dc in -k..=k {
            let (rr, cc) = (gr as i64 + dr, gc as i64 + dc);
            let t = (rr >= 0 && cc >= 0)
                .then(|| gt.get(rr as usize, cc as usize))
                .flatten()
                .filter(|v| !v.is_nan())?;
            lo = lo.min(t);
            hi = hi.max(t);
        }
    }
    Some((lo, hi))
}

/// Counts phantom obstacles of `map` against `gt` (same frame, z up): see [`PhantomScore`].
/// The flat test keeps object edges and steps out (a map cell there may honestly hold
/// either height).
pub fn phantoms(
    map: &Grid<f32>,
    gt: &Grid<f32>,
    radius_m: f64,
    flat_tol_m: f64,
    threshold_m: f64,
) -> PhantomScore {
    let g = map.geometry;
    let gg = gt.geometry;
    let k = (radius_m / gg.resolution).round().max(0.0) as i64;
    let mut out = PhantomScore {
        flat_cells: 0,
        phantoms: 0,
        pits: 0,
        max_excess_m: f64::NAN,
        threshold_m,
    };
    for r in 0..g.rows {
        for c in 0..g.cols {
            let Some(h) = map.get(r, c).filter(|v| !v.is_nan()) else {
                continue;
            };
            let (x, y) = g.center(r, c);
            let Some((gr, gc)) = gg.cell_of(x, y) else {
                continue;
            };
            let Some((lo, hi)) = span_around(gt, gr, gc, k) else {
                continue;
            };
            if f64::from(hi - lo) > flat_tol_m {
                continue;
            }
            let Some(t) = gt.get(gr, gc) else { continue };
            let excess = f64::from(h) - f64::from(t);
            out.flat_cells += 1;
            out.phantoms += usize::from(excess > threshold_m);
            out.pits += usize::from(excess < -threshold_m);
            out.max_excess_m = if out.max_excess_m.is_nan() {
                excess
            } else {
                out.max_excess_m.max(excess)
            };
        }
    }
    out
}

/// A plane `z = a x + b y + c` fitted to the floor of a map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FloorFit {
    /// Cells on the floor (within `band_m` of the plane).
    pub cells: usize,
    /// Fraction of the map's cells on the floor.
    pub fraction: f64,
    /// `[a, b, c]` (a, b unitless; c in m).
    pub plane: [f64; 3],
    /// Angle between the plane and the map's x-y plane (degrees).
    pub tilt_deg: f64,
    /// Standard deviation of the floor cells' heights about the plane (m).
    pub residual_std_m: f64,
    /// 95th percentile of their absolute distance to the plane (m).
    pub residual_p95_m: f64,
}

/// How flat a map's floor is, without ground truth: the most common height (1 cm bins)
/// seeds the floor, cells within `band_m` of it are fitted with a plane by least squares,
/// then the cells within `band_m` of that plane are fitted again. `None` with fewer than
/// 100 floor cells.
pub fn floor_fit(map: &Grid<f32>, band_m: f64) -> Option<FloorFit> {
    let g = map.geometry;
    let cells: Vec<(f64, f64, f64)> = (0..g.rows)
        .flat_map(|r| (0..g.cols).map(move |c| (r, c)))
        .filter_map(|(r, c)| {
            let h = map.get(r, c).filter(|v| v.is_finite())?;
            let (x, y) = g.center(r, c);
            Some((x, y, f64::from(h)))
        })
        .collect();
    let lo = cells.iter().map(|p| p.2).fold(f64::INFINITY, f64::min);
    let mut hist: std::collections::BTreeMap<i64, usize> = std::collections::BTreeMap::new();
    for p in &cells {
        *hist.entry(((p.2 - lo) / 0.01) as i64).or_default() += 1;
    }
    let mode = hist
        .iter()
        .max_by_key(|(_, n)| **n)
        .map(|(b, _)| lo + (*b as f64 + 0.5) * 0.01)?;
    let fit = |near: &dyn Fn(&(f64, f64, f64)) -> bool| -> Option<[f64; 3]> {
        let (mut ata, mut atb) = (
            nalgebra::Matrix3::<f64>::zeros(),
            nalgebra::Vector3::<f64>::zeros(),
        );
        for p in cells.iter().filter(|p| near(p)) {
            let a = nalgebra::Vector3::new(p.0, p.1, 1.0);
            ata += a * a.transpose();
            atb += a * p.2;
        }
        let s = ata.cholesky()?.solve(&atb);
        Some([s.x, s.y, s.z])
    };
    let first = fit(&|p| (p.2 - mode).abs() <= band_m)?;
    let dist = |pl: &[f64; 3], p: &(f64, f64, f64)| p.2 - (pl[0] * p.0 + pl[1] * p.1 + pl[2]);
    let plane = fit(&|p| dist(&first, p).abs() <= band_m)?;
    let mut res: Vec<f64> = cells
        .iter()
        .map(|p| dist(&plane, p))
        .filter(|d| d.abs() <= band_m)
        .collect();
    if res.len() < 100 {
        return None;
    }
    let n = res.len() as f64;
    let mean = res.iter().sum::<f64>() / n;
    let std = (res.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt();
    res.iter_mut().for_each(|d| *d = d.abs());
    res.sort_by(f64::total_cmp);
    let p95 = res
        .get(((res.len() - 1) as f64 * 0.95) as usize)
        .copied()
        .unwrap_or(f64::NAN);
    Some(FloorFit {
        cells: res.len(),
        fraction: n / cells.len().max(1) as f64,
        plane,
        tilt_deg: (plane[0].hypot(plane[1])).atan().to_degrees(),
        residual_std_m: std,
        residual_p95_m: p95,
    })
}

/// A map scored over the cells seen: the cells a reference map knows (the measurements on
/// the true surface, [`crate::naive::NaiveMedian::seen`]) where ground truth exists;
/// separately near steps (ground truth within `radius_m` spans more than `step_m`, or has
/// no height there: an object's or a wall's footprint, or the edge of the truth's grid) and
/// away from them, where a cell
/// straddling a step may honestly hold either height.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SeenScore {
    /// Cells seen (with ground truth).
    pub cells_seen: usize,
    /// Fraction of them the map knows.
    pub coverage: f64,
    /// Height RMSE over the seen cells the map knows (m).
    pub rmse_m: f64,
    /// Seen cells near steps.
    pub cells_near_steps: usize,
    /// Fraction of those the map knows.
    pub coverage_near_steps: f64,
    /// RMSE near steps (m).
    pub rmse_near_steps_m: f64,
    /// RMSE away from steps (m).
    pub rmse_away_m: f64,
}

/// Scores `map` over the cells `seen` knows (all grids in the same frame, z up, with cells
/// on the same lattice): see [`SeenScore`]. `None` when no seen cell has ground truth.
pub fn compare_over_seen(
    map: &Grid<f32>,
    seen: &Grid<f32>,
    gt: &Grid<f32>,
    step_m: f64,
    radius_m: f64,
) -> Option<SeenScore> {
    let g = seen.geometry;
    let gg = gt.geometry;
    let k = (radius_m / gg.resolution).round().max(0.0) as i64;
    let near_step = |x: f64, y: f64| -> bool {
        gg.cell_of(x, y).is_some_and(|(gr, gc)| {
            span_around(gt, gr, gc, k).is_none_or(|(lo, hi)| f64::from(hi - lo) > step_m)
        })
    };
    // (cells, known, sum of squared errors) near steps and away.
    let mut near = (0usize, 0usize, 0.0f64);
    let mut away = (0usize, 0usize, 0.0f64);
    for r in 0..g.rows {
        for c in 0..g.cols {
            if seen.get(r, c).is_none_or(f32::is_nan) {
                continue;
            }
            let (x, y) = g.center(r, c);
            let Some(truth) = gt.sample_bilinear(x, y) else {
                continue;
            };
            let acc = if near_step(x, y) {
                &mut near
            } else {
                &mut away
            };
            acc.0 += 1;
            if let Some(h) = map.at(x, y).filter(|v| !v.is_nan()) {
                acc.1 += 1;
                acc.2 += f64::from(h - truth).powi(2);
            }
        }
    }
    let cells = near.0 + away.0;
    if cells == 0 {
        return None;
    }
    let rmse = |sse: f64, n: usize| {
        if n > 0 {
            (sse / n as f64).sqrt()
        } else {
            f64::NAN
        }
    };
    let frac = |k: usize, n: usize| if n > 0 { k as f64 / n as f64 } else { f64::NAN };
    Some(SeenScore {
        cells_seen: cells,
        coverage: frac(near.1 + away.1, cells),
        rmse_m: rmse(near.2 + away.2, near.1 + away.1),
        cells_near_steps: near.0,
        coverage_near_steps: frac(near.1, near.0),
        rmse_near_steps_m: rmse(near.2, near.1),
        rmse_away_m: rmse(away.2, away.1),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::grid::GridGeometry;

    #[test]
    fn scores_over_the_cells_seen_near_and_away_from_steps() {
        let g = GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 0.1,
            rows: 6,
            cols: 10,
        };
        let cells = |f: &dyn Fn(usize, usize) -> f32| {
            Grid::from_vec(g, (0..60).map(|i| f(i / 10, i % 10)).collect()).unwrap()
        };
        // A 10 cm step between columns 4 and 5.
        let truth = |c: usize| if c >= 5 { 0.1f32 } else { 0.0 };
        let gt = cells(&|_, c| truth(c));
        // Seen: rows 1-4, columns 1-8 (off the truth's border). The map knows columns 2.. with
        // a 1 cm error away from the step and 5 cm next to it (columns 4 and 5).
        let seen = cells(&|r, c| {
            if (1..=4).contains(&r) && (1..=8).contains(&c) {
                0.0
            } else {
                f32::NAN
            }
        });
        let map = cells(&|_, c| match c {
            0 | 1 => f32::NAN,
            4 | 5 => truth(c) + 0.05,
            _ => truth(c) + 0.01,
        });
        let s = compare_over_seen(&map, &seen, &gt, 0.02, 0.1).unwrap();
        assert_eq!(s.cells_seen, 32);
        assert_eq!(s.cells_near_steps, 8);
        assert!((s.coverage - 28.0 / 32.0).abs() < 1e-12, "{s:?}");
        assert!((s.coverage_near_steps - 1.0).abs() < 1e-12);
        assert!((s.rmse_near_steps_m - 0.05).abs() < 1e-6, "{s:?}");
        assert!((s.rmse_away_m - 0.01).abs() < 1e-6, "{s:?}");
        // A map that knows nothing seen covers nothing and has no error to state.
        let empty = Grid::filled(g, f32::NAN);
        let e = compare_over_seen(&empty, &seen, &gt, 0.02, 0.1).unwrap();
        assert_eq!(e.coverage, 0.0);
        assert!(e.rmse_m.is_nan());
    }

    #[test]
    fn mse_coverage_and_performance_index() {
        let g = GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 0.1,
            rows: 10,
            cols: 10,
        };
        let gt = Grid::filled(g, 0.0f32);
        let mut a = Grid::filled(g, f32::NAN);
        let mut b = Grid::filled(g, f32::NAN);
        for r in 0..5 {
            for c in 0..10 {
                *a.get_mut(r, c).unwrap() = 0.01; // error 1 cm on half the cells
                *b.get_mut(r, c).unwrap() = if c % 2 == 0 { 0.02 } else { -0.02 };
            }
        }
        let s = compare(&a, &gt).unwrap();
        assert!(
            (s.mse - 1e-4).abs() < 1e-9
                && s.cells_compared == 50
                && (s.coverage - 0.5).abs() < 1e-12
        );
        assert!((s.max_abs - 0.01).abs() < 1e-6);
        let pi = performance_index(&a, &b, &gt).unwrap();
        assert!((pi - 0.25).abs() < 1e-4, "{pi}");
        assert!(compare(&Grid::filled(g, f32::NAN), &gt).is_none());
    }

    #[test]
    fn phantoms_count_only_over_flat_ground_truth() {
        let g = GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 0.01,
            rows: 40,
            cols: 40,
        };
        let mut gt = Grid::filled(g, 0.0f32);
        // A 10 cm box in one corner: not flat ground.
        for r in 0..8 {
            for c in 0..8 {
                *gt.get_mut(r, c).unwrap() = 0.10;
            }
        }
        let mut map = gt.clone();
        *map.get_mut(20, 20).unwrap() = 0.05; // a phantom on flat ground
        *map.get_mut(30, 30).unwrap() = 0.015; // within the 2 cm threshold
        *map.get_mut(8, 8).unwrap() = 0.10; // beside the box: not judged
        let p = phantoms(&map, &gt, 0.05, 0.01, 0.02);
        assert_eq!(p.phantoms, 1);
        assert!((p.max_excess_m - 0.05).abs() < 1e-6);
        assert!(p.flat_cells < 40 * 40 - 64 && p.flat_cells > 500, "{p:?}");
    }

    #[test]
    fn floor_fit_recovers_a_tilted_floor_beside_an_object() {
        let g = GridGeometry {
            origin_x: -1.0,
            origin_y: -1.0,
            resolution: 0.02,
            rows: 100,
            cols: 100,
        };
        let mut map = Grid::filled(g, f32::NAN);
        let mut rng = stride_core::rng::SplitMix64::new(3);
        for r in 0..100 {
            for c in 0..100 {
                let (x, y) = g.center(r, c);
                let object = x > 0.5 && y > 0.5;
                let h = if object {
                    0.4
                } else {
                    0.02 * x - 0.01 * y + 0.3 + 0.005 * rng.normal()
                };
                *map.get_mut(r, c).unwrap() = h as f32;
            }
        }
        let f = floor_fit(&map, 0.05).unwrap();
        assert!(
            (f.plane[0] - 0.02).abs() < 1e-3
                && (f.plane[1] + 0.01).abs() < 1e-3
                && (f.plane[2] - 0.3).abs() < 1e-3,
            "{f:?}"
        );
        assert!((f.residual_std_m - 0.005).abs() < 5e-4, "{f:?}");
        assert!((f.tilt_deg - (0.02f64.hypot(0.01)).atan().to_degrees()).abs() < 0.05);
        assert!(
            (f.fraction - (1.0 - 576.0 / 10_000.0)).abs() < 1e-9,
            "the object (24 x 24 cells) is not floor: {f:?}"
        );
    }
}
