//! Paper 003's map (section 5): an elevation grid and a certainty grid of the same size,
//! updated point by point (eqs. 9-10), with unknown cells filled by a weighted median of
//! their neighbours (eq. 11) and, optionally, a certainty-assisted spatial (CAS) filter
//! after Ye and Borenstein.
//!
//! Per measured point `p_world` in cell `[i, j]` with height `h_m = p_world.z`:
//! * eq. 9: the cell's certainty grows by `a` when the cell is new (`c = 0`) or when
//!   `|h_m - h| <= Delta z_max` (the plausibility bound of eqs. 6/8 for this point and the
//!   motion since the previous scan); otherwise it stays;
//! * eq. 10: the cell's elevation becomes `h_m` when that is higher.
//!
//! The grid is fixed in the world (z up, metres; cell `[0, 0]`'s centre at the geometry's
//! origin, rows along +y, columns along +x).

use crate::MappingError;
use stride_core::grid::{Grid, GridGeometry};

/// How a cell's elevation takes a new measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElevationRule {
    /// Eq. 10: the highest measurement.
    Highest,
    /// A measurement consistent with the cell (eq. 9's test) is averaged into it, weighted
    /// by the cell's certainty. An inconsistent one feeds a second hypothesis of the cell
    /// (averaged the same way, restarted by a measurement consistent with neither), which
    /// takes over when its certainty exceeds the first's. Range noise then averages out
    /// instead of lifting every cell by the noise's upper tail, a lone mixed return never
    /// moves a cell, and a surface that changes (or was first seen through mixed returns)
    /// takes over once measured more often.
    ConsistentMean,
}

/// The map's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CertaintyConfig {
    /// How a cell's elevation takes a measurement.
    pub rule: ElevationRule,
    /// Certainty gained by a consistent measurement, `a` of eq. 9.
    pub increment: f32,
    /// Eq. 11: an unknown cell (`c = 0`) with at least this many known cells among its 8
    /// neighbours takes their certainty-weighted median; 0 turns filling off.
    pub fill_min_known: usize,
    /// The CAS filter (off by default, as paper 003 runs the URG scanner): a cell whose
    /// certainty is below this fraction of its neighbours' median certainty and whose
    /// height is more than `cas_height_m` from their median height is cleared.
    pub cas_fraction: Option<f32>,
    /// The CAS filter's height tolerance (m).
    pub cas_height_m: f32,
}

impl Default for CertaintyConfig {
    fn default() -> Self {
        Self {
            rule: ElevationRule::ConsistentMean,
            increment: 1.0,
            fill_min_known: 5,
            cas_fraction: None,
            cas_height_m: 0.02,
        }
    }
}

/// The elevation and certainty grids.
#[derive(Debug, Clone)]
pub struct CertaintyMap {
    config: CertaintyConfig,
    geometry: GridGeometry,
    /// Height (m), NaN where unknown.
    elevation: Grid<f32>,
    /// Certainty (0 where unknown).
    certainty: Grid<f32>,
    /// The second hypothesis of [`ElevationRule::ConsistentMean`]: height and certainty.
    alternative: Vec<(f32, f32)>,
    /// Measurements that raised a cell's certainty, and those that did not (eq. 9).
    consistent: usize,
    inconsistent: usize,
}

/// What [`CertaintyMap::finish`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct FinishStats {
    /// Cells cleared by the CAS filter.
    pub cas_cleared: usize,
    /// Unknown cells filled by eq. 11.
    pub filled: usize,
}

impl CertaintyMap {
    /// An empty map over `geometry`.
    pub fn new(geometry: GridGeometry, config: CertaintyConfig) -> Result<Self, MappingError> {
        if !(geometry.resolution.is_finite() && geometry.resolution > 0.0) {
            return Err(MappingError::Parameter {
                name: "resolution_m",
                value: geometry.resolution,
                reason: "must be positive",
            });
        }
        if geometry.rows.max(geometry.cols) > crate::error::MAX_CELLS_PER_SIDE {
            return Err(MappingError::Parameter {
                name: "cells per side",
                value: geometry.rows.max(geometry.cols) as f64,
                reason: "at most 4096",
            });
        }
        if !(config.increment.is_finite() && config.increment > 0.0) {
            return Err(MappingError::Parameter {
                name: "increment",
                value: f64::from(config.increment),
                reason: "must be positive",
            });
        }
        Ok(Self {
            config,
            geometry,
            elevation: Grid::filled(geometry, f32::NAN),
            certainty: Grid::filled(geometry, 0.0),
            alternative: if config.rule == ElevationRule::ConsistentMean {
                vec![(f32::NAN, 0.0); geometry.len()]
            } else {
                Vec::new()
            },
            consistent: 0,
            inconsistent: 0,
        })
    }

    /// The grid's geometry.
    pub fn geometry(&self) -> GridGeometry {
        self.geometry
    }

    /// Eqs. 9-10 for one measured point at world `(x, y)` with height `h_m` (m), whose
    /// plausibility bound is `delta_z_max` (m). Returns false for a point outside the grid.
    pub fn update(&mut self, x: f64, y: f64, h_m: f64, delta_z_max: f64) -> bool {
        let Some(i) = self
            .geometry
            .cell_of(x, y)
            .and_then(|(r, c)| self.geometry.index(r, c))
        else {
            return false;
        };
        let (Some(h), Some(c)) = (
            self.elevation.as_mut_slice().get_mut(i),
            self.certainty.as_mut_slice().get_mut(i),
        ) else {
            return false;
        };
        let h_m = h_m as f32;
        let (a, dz) = (self.config.increment, delta_z_max as f32);
        let consistent = *c == 0.0 || (h_m - *h).abs() <= dz;
        if consistent {
            self.consistent += 1;
        } else {
            self.inconsistent += 1;
        }
        match self.config.rule {
            ElevationRule::Highest => {
                if consistent {
                    *c += a;
                }
                if h.is_nan() || h_m > *h {
                    *h = h_m;
                }
            }
            ElevationRule::ConsistentMean => {
                if *c == 0.0 {
                    *h = h_m;
                    *c = a;
                } else if consistent {
                    *h = (*h * *c + h_m * a) / (*c + a);
                    *c += a;
                } else if let Some((ah, ac)) = self.alternative.get_mut(i) {
                    if *ac > 0.0 && (h_m - *ah).abs() <= dz {
                        *ah = (*ah * *ac + h_m * a) / (*ac + a);
                        *ac += a;
                    } else {
                        (*ah, *ac) = (h_m, a);
                    }
                    if *ac > *c {
                        std::mem::swap(h, ah);
                        std::mem::swap(c, ac);
                    }
                }
            }
        }
        true
    }

    /// Measurements so far that raised a certainty, and those that did not.
    pub fn consistency(&self) -> (usize, usize) {
        (self.consistent, self.inconsistent)
    }

    /// The CAS filter (when configured), then eq. 11's weighted-median fill; returns the
    /// elevation (NaN unknown) and certainty grids.
    pub fn finish(mut self) -> (Grid<f32>, Grid<f32>, FinishStats) {
        let mut stats = FinishStats::default();
        if let Some(fraction) = self.config.cas_fraction {
            stats.cas_cleared = self.cas(fraction);
        }
        if self.config.fill_min_known > 0 {
            stats.filled = self.fill();
        }
        (self.elevation, self.certainty, stats)
    }

    /// Height and certainty of the cell at storage index `i`.
    fn cell(&self, i: usize) -> Option<(f32, f32)> {
        Some((
            *self.elevation.as_slice().get(i)?,
            *self.certainty.as_slice().get(i)?,
        ))
    }

    /// The known 8-neighbours of cell `(r, c)`: (height, certainty).
    fn neighbours(&self, r: usize, c: usize) -> Vec<(f32, f32)> {
        let mut out = Vec::with_capacity(8);
        for dr in -1i64..=1 {
            for dc in -1i64..=1 {
                if dr == 0 && dc == 0 {
                    continue;
                }
                let (rr, cc) = (r as i64 + dr, c as i64 + dc);
                if rr < 0 || cc < 0 {
                    continue;
                }
                let Some(i) = self.geometry.index(rr as usize, cc as usize) else {
                    continue;
                };
                if let Some((h, w)) = self.cell(i) {
                    if w > 0.0 && !h.is_nan() {
                        out.push((h, w));
                    }
                }
            }
        }
        out
    }

    fn cas(&mut self, fraction: f32) -> usize {
        let g = self.geometry;
        let mut clear = Vec::new();
        for r in 0..g.rows {
            for c in 0..g.cols {
                let Some((i, (h, w))) = g.index(r, c).and_then(|i| Some((i, self.cell(i)?))) else {
                    continue;
                };
                if w == 0.0 {
                    continue;
                }
                let mut n = self.neighbours(r, c);
                if n.len() < 3 {
                    continue;
                }
                let median_h =
                    weighted_median(&mut n.iter().map(|&(h, _)| (h, 1.0)).collect::<Vec<_>>());
                let mut ws: Vec<f32> = n.iter().map(|&(_, w)| w).collect();
                ws.sort_by(f32::total_cmp);
                let median_w = ws.get(ws.len() / 2).copied().unwrap_or(0.0);
                n.clear();
                if w < fraction * median_w && (h - median_h).abs() > self.config.cas_height_m {
                    clear.push(i);
                }
            }
        }
        for &i in &clear {
            if let Some(h) = self.elevation.as_mut_slice().get_mut(i) {
                *h = f32::NAN;
            }
            if let Some(w) = self.certainty.as_mut_slice().get_mut(i) {
                *w = 0.0;
            }
        }
        clear.len()
    }

    fn fill(&mut self) -> usize {
        let g = self.geometry;
        let mut fills = Vec::new();
        for r in 0..g.rows {
            for c in 0..g.cols {
                let Some((i, (_, w))) = g.index(r, c).and_then(|i| Some((i, self.cell(i)?))) else {
                    continue;
                };
                if w > 0.0 {
                    continue;
                }
                let mut n = self.neighbours(r, c);
                if n.len() >= self.config.fill_min_known {
                    fills.push((i, weighted_median(&mut n)));
                }
            }
        }
        // The certainty stays 0: eq. 11 fills the elevation of cells never measured.
        for &(i, h) in &fills {
            if let Some(e) = self.elevation.as_mut_slice().get_mut(i) {
                *e = h;
            }
        }
        fills.len()
    }
}

/// The weighted median of `(value, weight)` pairs: the smallest value at which the
/// cumulative weight reaches half the total. Sorts `values`.
pub fn weighted_median(values: &mut [(f32, f32)]) -> f32 {
    values.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f32 = values.iter().map(|v| v.1).sum();
    let mut acc = 0.0;
    for &(v, w) in values.iter() {
        acc += w;
        if acc >= 0.5 * total {
            return v;
        }
    }
    values.last().map_or(f32::NAN, |v| v.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(config: CertaintyConfig) -> CertaintyMap {
        let g = GridGeometry {
            origin_x: 0.005,
            origin_y: 0.005,
            resolution: 0.01,
            rows: 5,
            cols: 5,
        };
        CertaintyMap::new(g, config).unwrap()
    }

    #[test]
    fn eq9_and_eq10_by_hand() {
        let mut m = map(CertaintyConfig {
            rule: ElevationRule::Highest,
            fill_min_known: 0,
            ..CertaintyConfig::default()
        });
        let (x, y) = (0.021, 0.013); // cell [1, 2]
                                     // A new cell: c = 0 -> 1, h = 0.10.
        assert!(m.update(x, y, 0.10, 0.005));
        // Within the bound: c = 2, h stays (lower).
        m.update(x, y, 0.097, 0.005);
        // Beyond the bound: c stays 2, but eq. 10 still raises h to 0.13.
        m.update(x, y, 0.13, 0.005);
        // Within the bound of the new height: c = 3.
        m.update(x, y, 0.128, 0.005);
        assert!(!m.update(0.2, 0.0, 0.0, 0.1), "outside the grid");
        assert_eq!(m.consistency(), (3, 1));
        let (h, c, _) = m.finish();
        assert_eq!(h.get(1, 2), Some(0.13));
        assert_eq!(c.get(1, 2), Some(3.0));
        assert!(h.get(0, 0).unwrap().is_nan());
        assert_eq!(c.get(0, 0), Some(0.0));
    }

    #[test]
    fn the_consistent_mean_averages_noise_and_keeps_steps() {
        let mut m = map(CertaintyConfig {
            fill_min_known: 0,
            ..CertaintyConfig::default()
        });
        let (x, y) = (0.021, 0.013);
        m.update(x, y, 0.10, 0.005);
        m.update(x, y, 0.104, 0.005); // consistent: (0.10 + 0.104) / 2
        m.update(x, y, 0.098, 0.005); // consistent: (0.102 * 2 + 0.098) / 3
        m.update(x, y, 0.30, 0.005); // inconsistent (a mixed return): the alternative
        m.update(x, y, 0.20, 0.005); // inconsistent with both: the alternative restarts
        m.update(x, y, 0.201, 0.005); // the alternative grows to 2 of 3
        assert!((m.cell(m.geometry.index(1, 2).unwrap()).unwrap().0 - 0.1007).abs() < 1e-4);
        m.update(x, y, 0.199, 0.005); // 3 of 3: not yet more certain
        m.update(x, y, 0.2, 0.005); // 4 > 3: the surface moved up (an object put there)
        assert_eq!(m.consistency(), (3, 5));
        let (h, c, _) = m.finish();
        assert!(
            (h.get(1, 2).unwrap() - 0.2).abs() < 1e-3,
            "{:?}",
            h.get(1, 2)
        );
        assert_eq!(c.get(1, 2), Some(4.0));
    }

    #[test]
    fn eq11_fills_unknown_cells_with_the_certainty_weighted_median() {
        let mut m = map(CertaintyConfig::default());
        // The 8 neighbours of cell [2, 2]: heights 1..8 cm, certainty 1 except 8 cm (5).
        let mut k = 0;
        for dr in -1i64..=1 {
            for dc in -1i64..=1 {
                if dr == 0 && dc == 0 {
                    continue;
                }
                k += 1;
                let (x, y) = (0.025 + dc as f64 * 0.01, 0.025 + dr as f64 * 0.01);
                for _ in 0..if k == 8 { 5 } else { 1 } {
                    m.update(x, y, f64::from(k) * 0.01, 1.0);
                }
            }
        }
        let (h, c, stats) = m.finish();
        // Weights 1,1,1,1,1,1,1,5 over 1..8 cm: total 12, half 6 reached at 6 cm.
        assert_eq!(h.get(2, 2), Some(0.06));
        assert_eq!(c.get(2, 2), Some(0.0), "a filled cell keeps certainty 0");
        assert!(stats.filled >= 1);
        assert_eq!(
            weighted_median(&mut [(3.0, 1.0), (1.0, 1.0), (2.0, 1.0)]),
            2.0
        );
    }

    #[test]
    fn cas_clears_a_low_certainty_outlier() {
        let config = CertaintyConfig {
            fill_min_known: 0,
            cas_fraction: Some(0.5),
            ..CertaintyConfig::default()
        };
        let mut m = map(config);
        for r in 0..5 {
            for c in 0..5 {
                let (x, y) = (0.005 + c as f64 * 0.01, 0.005 + r as f64 * 0.01);
                let (h, n) = if (r, c) == (2, 2) { (0.2, 1) } else { (0.0, 4) };
                for _ in 0..n {
                    m.update(x, y, h, 0.001);
                }
            }
        }
        let (h, _, stats) = m.finish();
        assert_eq!(stats.cas_cleared, 1);
        assert!(h.get(2, 2).unwrap().is_nan());
        assert_eq!(h.get(2, 3), Some(0.0));
    }

    #[test]
    fn invalid_parameters_are_refused() {
        let g = GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 0.0,
            rows: 2,
            cols: 2,
        };
        assert!(CertaintyMap::new(g, CertaintyConfig::default()).is_err());
    }
}
