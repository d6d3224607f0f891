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

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::grid::GridGeometry;

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
}
