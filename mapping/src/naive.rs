//! The naive reference: every measurement's height dropped into its cell, the cell's height
//! the median of what landed there. No sensor model, no filter, no window. It is what a
//! map would hold if nothing were ever rejected, so its known cells are the cells whose
//! surface the sensor saw: the yardstick for the other mappers' coverage, and a baseline
//! for their accuracy (flying pixels and all).
//!
//! With a true terrain ([`NaiveMedian::seen`]) only the measurements within a tolerance of
//! the true surface count: its cells are then the cells whose top the sensor really saw,
//! without those that only flying pixels or the shadow behind an edge reach.
//!
//! Memory: a cell keeps at most [`SAMPLES_PER_CELL`] heights, a uniform sample of those it
//! received (reservoir sampling with a fixed seed, so the map is repeatable): about 300
//! bytes a cell, for every cell ever seen. It is a yardstick for evaluation, not a map to
//! run for hours.

use crate::input::{pose_is_finite, Cloud, SensorFrame};
use crate::window::cell_coord;
use crate::{ElevationMapper, MapLayers, UpdateStats};
use nalgebra::Point2;
use std::collections::HashMap;
use std::time::Instant;
use stride_core::grid::Grid;
use stride_core::rng::mix64;

/// Most heights a cell keeps for its median.
pub const SAMPLES_PER_CELL: usize = 64;

/// One cell: a sample of the heights that landed in it, and how many did.
#[derive(Debug, Clone, Default)]
struct Cell {
    heights: Vec<f32>,
    seen: u64,
    frames: u32,
    last_frame: u64,
}

/// The per-cell median of every measurement (world frame, z up).
#[derive(Debug, Clone)]
pub struct NaiveMedian {
    resolution_m: f64,
    /// Depth range accepted (m, along the optical axis).
    range_m: (f64, f64),
    cells: HashMap<(i64, i64), Cell>,
    frames: u64,
    /// The true terrain (world frame, z up, NaN where unknown) and the largest height
    /// difference from it (m) of a measurement that counts.
    truth: Option<(Grid<f32>, f64)>,
}

impl NaiveMedian {
    /// A map of cells of `resolution_m` (m) taking depths within `range_m` (m).
    pub fn new(resolution_m: f64, range_m: (f64, f64)) -> Self {
        Self {
            resolution_m,
            range_m,
            cells: HashMap::new(),
            frames: 0,
            truth: None,
        }
    }

    /// The cells seen: as [`NaiveMedian::new`], counting only measurements within
    /// `tolerance_m` (m) of the true terrain `truth` (world frame, z up).
    pub fn seen(
        resolution_m: f64,
        range_m: (f64, f64),
        truth: Grid<f32>,
        tolerance_m: f64,
    ) -> Self {
        Self {
            truth: Some((truth, tolerance_m)),
            ..Self::new(resolution_m, range_m)
        }
    }

    /// Adds a measurement at `(x, y, z)` (m, world); false when the truth gate refused it.
    fn add(&mut self, x: f64, y: f64, z: f64) -> bool {
        if let Some((truth, tol)) = &self.truth {
            match truth.sample_bilinear(x, y) {
                Some(t) if (z - f64::from(t)).abs() <= *tol => {}
                _ => return false,
            }
        }
        let inv = 1.0 / self.resolution_m;
        let key = (cell_coord(y, inv), cell_coord(x, inv));
        let frame = self.frames;
        let cell = self.cells.entry(key).or_default();
        if cell.last_frame != frame || cell.frames == 0 {
            cell.frames += 1;
            cell.last_frame = frame;
        }
        cell.seen += 1;
        if cell.heights.len() < SAMPLES_PER_CELL {
            cell.heights.push(z as f32);
        } else {
            // Keep each of the `seen` heights with probability SAMPLES / seen.
            let r = mix64(cell.seen ^ (key.0 as u64).rotate_left(21) ^ (key.1 as u64)) % cell.seen;
            if let Some(slot) = cell.heights.get_mut(r as usize) {
                *slot = z as f32;
            }
        }
        true
    }
}

impl ElevationMapper for NaiveMedian {
    fn name(&self) -> &'static str {
        if self.truth.is_some() {
            "seen"
        } else {
            "naive"
        }
    }

    fn integrate(&mut self, frame: &SensorFrame<'_>) -> UpdateStats {
        let start = Instant::now();
        if !pose_is_finite(&frame.map_from_sensor) {
            return UpdateStats::bad_pose(frame, start);
        }
        self.frames += 1;
        let mut used = 0;
        let pose = frame.map_from_sensor;
        match frame.cloud() {
            Cloud::Depth { depth_m, camera } => {
                let (w, h) = (depth_m.width(), depth_m.height());
                for v in 0..h {
                    for u in 0..w {
                        let Some(d) = depth_m.get(u, v).map(f64::from) else {
                            continue;
                        };
                        if !(d >= self.range_m.0 && d <= self.range_m.1) {
                            continue;
                        }
                        let p = camera.unproject(&Point2::new(f64::from(u), f64::from(v)), d);
                        let p_map = pose * p;
                        used += usize::from(self.add(p_map.x, p_map.y, p_map.z));
                    }
                }
            }
            Cloud::Points { points, .. } => {
                for p in points {
                    let p_map = pose * p;
                    if p_map.coords.iter().all(|c| c.is_finite()) {
                        used += usize::from(self.add(p_map.x, p_map.y, p_map.z));
                    }
                }
            }
        }
        UpdateStats {
            points_used: used,
            update_s: start.elapsed().as_secs_f64(),
            ..Default::default()
        }
    }

    fn export(&self) -> MapLayers {
        MapLayers::from_cells(
            self.resolution_m,
            self.cells.iter().filter_map(|(&key, c)| {
                let mut h = c.heights.clone();
                h.sort_by(f32::total_cmp);
                let median = *h.get(h.len() / 2)?;
                let n = h.len() as f32;
                let mean = h.iter().sum::<f32>() / n;
                let var = h.iter().map(|x| (x - mean) * (x - mean)).sum::<f32>() / n;
                Some((key, median, var, f32::NAN, c.frames as f32))
            }),
        )
    }

    fn memory_bytes(&self) -> usize {
        self.cells
            .values()
            .map(|c| std::mem::size_of::<Cell>() + 16 + 4 * c.heights.capacity())
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Matrix3, Point3};

    #[test]
    fn a_cell_holds_the_median_of_its_points_and_keeps_a_bounded_sample() {
        let mut m = NaiveMedian::new(0.1, (0.1, 10.0));
        let mut pts: Vec<Point3<f64>> = [0.3, 0.1, 0.2, 5.0, 0.25]
            .iter()
            .map(|&z| Point3::new(0.01, 0.02, z))
            .collect();
        pts.push(Point3::new(1.0, 1.0, -0.5));
        let covs = vec![Matrix3::identity(); pts.len()];
        let f = SensorFrame::points(&pts, &covs, Isometry3::identity(), 0.0).unwrap();
        assert_eq!(m.integrate(&f).points_used, 6);
        let l = m.export();
        let known: Vec<_> = l.known_cells().collect();
        assert_eq!(known.len(), 2);
        let at = |key| known.iter().find(|k| k.0 == key).map(|k| k.1);
        assert_eq!(at((0, 0)), Some(0.25));
        assert_eq!(at((10, 10)), Some(-0.5));
        // Many more points than the sample holds: memory stays bounded, the median stays put.
        let many: Vec<Point3<f64>> = (0..10_000)
            .map(|i| Point3::new(0.0, 0.0, f64::from(i % 101) * 0.01))
            .collect();
        let covs = vec![Matrix3::identity(); many.len()];
        let f = SensorFrame::points(&many, &covs, Isometry3::identity(), 1.0).unwrap();
        m.integrate(&f);
        assert!(m.cells.get(&(0, 0)).unwrap().heights.len() <= SAMPLES_PER_CELL);
        let h = m.export().known_cells().find(|k| k.0 == (0, 0)).unwrap().1;
        assert!((h - 0.5).abs() < 0.15, "{h}");
    }

    #[test]
    fn the_seen_map_counts_only_measurements_on_the_true_surface() {
        use stride_core::grid::GridGeometry;
        let g = GridGeometry {
            origin_x: -1.0,
            origin_y: -1.0,
            resolution: 0.1,
            rows: 21,
            cols: 21,
        };
        let mut m = NaiveMedian::seen(0.1, (0.1, 10.0), Grid::filled(g, 0.0), 0.03);
        assert_eq!(m.name(), "seen");
        // On the surface, a flying pixel above it, and a point outside the truth's extent.
        let pts = vec![
            Point3::new(0.0, 0.0, 0.01),
            Point3::new(0.3, 0.0, 0.2),
            Point3::new(5.0, 0.0, 0.0),
        ];
        let covs = vec![Matrix3::identity(); pts.len()];
        let f = SensorFrame::points(&pts, &covs, Isometry3::identity(), 0.0).unwrap();
        assert_eq!(m.integrate(&f).points_used, 1);
        let known: Vec<_> = m.export().known_cells().map(|k| k.0).collect();
        assert_eq!(known, vec![(0, 0)]);
    }
}
