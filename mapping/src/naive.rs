//! The naive reference: every measurement's height dropped into its cell, the cell's height
//! the median of what landed there. No sensor model, no filter, no window. It is what a
//! map would hold if nothing were ever rejected, so its known cells are the cells whose
//! surface the sensor saw: the yardstick for the other mappers' coverage, and a baseline
//! for their accuracy (flying pixels and all).
//!
//! With a true terrain ([`NaiveMedian::seen`]) only the measurements on the true surface
//! count (within a height tolerance of it, and with their ray meeting it near them): its
//! cells are then the cells whose top the sensor really saw, without those that only flying
//! pixels or the shadow behind an edge reach.
//!
//! Memory: a cell keeps at most [`SAMPLES_PER_CELL`] heights, a uniform sample of those it
//! received (reservoir sampling with a fixed seed, so the map is repeatable): about 300
//! bytes a cell, for every cell ever seen. It is a yardstick for evaluation, not a map to
//! run for hours.

use crate::input::{pose_is_finite, Cloud, SensorFrame};
use crate::window::cell_coord;
use crate::{ElevationMapper, MapLayers, UpdateStats};
use nalgebra::{Point2, Point3};
use std::collections::HashMap;
use std::time::Instant;
use stride_core::grid::Grid;
use stride_core::rng::mix64;
use stride_core::uncertainty::PrimeSenseModel;

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
    /// The truth gate of [`NaiveMedian::seen`].
    truth: Option<Truth>,
}

/// What a measurement must agree with to count as seeing the true surface.
#[derive(Debug, Clone)]
struct Truth {
    /// The true terrain (world frame, z up, NaN where unknown).
    terrain: Grid<f32>,
    /// The largest height difference from it (m).
    tolerance_m: f64,
    /// The sensor's depth noise: the ray must meet the terrain within
    /// [`SEEN_RAY_SIGMAS`] standard deviations of the measurement.
    sensor: PrimeSenseModel,
}

/// How far along its ray from a measurement, in standard deviations of its depth, the ray
/// must meet the true surface for the measurement to count as seeing it
/// ([`NaiveMedian::seen`]). A flying pixel in the shadow behind an edge can lie within the
/// height tolerance of the floor under it, but its ray meets the floor only farther on
/// (20 cm for one 3 cm above a floor seen at 8 degrees; 3 sigma_d is 5.8 cm at 2.5 m).
pub const SEEN_RAY_SIGMAS: f64 = 3.0;

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
    /// `tolerance_m` (m) in height of the true terrain `truth` (world frame, z up) whose ray
    /// from the sensor crosses it, from above to below, within [`SEEN_RAY_SIGMAS`] of
    /// `sensor`'s depth standard deviation of them (a terrain cell without height counts as
    /// solid): a measurement on the far edge of a box's top counts, one hanging above the
    /// floor in the box's shadow does not.
    pub fn seen(
        resolution_m: f64,
        range_m: (f64, f64),
        truth: Grid<f32>,
        tolerance_m: f64,
        sensor: PrimeSenseModel,
    ) -> Self {
        Self {
            truth: Some(Truth {
                terrain: truth,
                tolerance_m,
                sensor,
            }),
            ..Self::new(resolution_m, range_m)
        }
    }

    /// Adds a measurement at `p_map` (m, map frame) of depth `d_m` (m: along the optical
    /// axis for a depth image, the range for a point cloud) seen from `sensor_map`; false
    /// when the truth gate refused it.
    fn add(&mut self, p_map: &Point3<f64>, d_m: f64, sensor_map: &Point3<f64>) -> bool {
        let (x, y, z) = (p_map.x, p_map.y, p_map.z);
        if let Some(t) = &self.truth {
            match t.terrain.sample_bilinear(x, y) {
                Some(h) if (z - f64::from(h)).abs() <= t.tolerance_m => {}
                _ => return false,
            }
            let window_m = SEEN_RAY_SIGMAS * t.sensor.sigma_d(d_m);
            if !ray_meets_truth(&t.terrain, sensor_map, p_map, window_m) {
                return false;
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
        let sensor = Point3::from(pose.translation.vector);
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
                        used += usize::from(self.add(&p_map, d, &sensor));
                    }
                }
            }
            Cloud::Points { points, .. } => {
                for p in points {
                    let p_map = pose * p;
                    if p_map.coords.iter().all(|c| c.is_finite()) {
                        used += usize::from(self.add(&p_map, p.coords.norm(), &sensor));
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

/// Whether the ray from `sensor_map` through `p_map` (m, map frame) passes from above the
/// true terrain to below it (a cell without height counts as solid) within `window_m` (m)
/// of `p_map` along the ray: above the truth where the window starts, and at or below it
/// somewhere on the way to its end (sampled every tenth of the window, the end first).
fn ray_meets_truth(
    truth: &Grid<f32>,
    sensor_map: &Point3<f64>,
    p_map: &Point3<f64>,
    window_m: f64,
) -> bool {
    const STEPS: u32 = 10;
    let ray = p_map - sensor_map;
    let len = ray.norm();
    if len.is_nan() || len <= 0.0 {
        return false;
    }
    let above = |s: f64| {
        let q = p_map + ray * (s / len);
        truth
            .sample_bilinear(q.x, q.y)
            .map_or(f64::NEG_INFINITY, |t| q.z - f64::from(t))
    };
    above(-window_m) >= 0.0
        && (1..=2 * STEPS)
            .rev()
            .any(|i| above(-window_m + window_m * f64::from(i) / f64::from(STEPS)) <= 0.0)
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
        let model = PrimeSenseModel::default();
        let mut m = NaiveMedian::seen(0.1, (0.1, 10.0), Grid::filled(g, 0.0), 0.03, model);
        assert_eq!(m.name(), "seen");
        // Seen from 0.4 m above the floor, 1 m back: on the surface; a flying pixel above
        // it; one 2.8 cm above the floor (within the height tolerance) whose ray meets the
        // floor 11.6 cm farther on (3 sigma_d there: 2.2 cm), as in an edge's shadow; a
        // point outside the truth.
        let sensor = Isometry3::translation(-1.0, 0.0, 0.4);
        let pts: Vec<Point3<f64>> = [
            Point3::new(0.0, 0.0, 0.002),
            Point3::new(0.3, 0.0, 0.2),
            Point3::new(0.5, 0.0, 0.028),
            Point3::new(5.0, 0.0, 0.0),
        ]
        .iter()
        .map(|p_map| sensor.inverse() * p_map)
        .collect();
        let covs = vec![Matrix3::identity(); pts.len()];
        let f = SensorFrame::points(&pts, &covs, sensor, 0.0).unwrap();
        assert_eq!(m.integrate(&f).points_used, 1);
        let known: Vec<_> = m.export().known_cells().map(|k| k.0).collect();
        assert_eq!(known, vec![(0, 0)]);
    }

    /// The ray must go from above the truth to below it within the window; a cell without
    /// height is solid.
    #[test]
    fn a_ray_meets_the_truth_only_where_it_crosses_it() {
        use stride_core::grid::GridGeometry;
        let g = GridGeometry {
            origin_x: -2.0,
            origin_y: -1.0,
            resolution: 0.01,
            rows: 201,
            cols: 401,
        };
        let mut truth = Grid::filled(g, 0.0);
        let sensor = Point3::new(-1.0, 0.0, 0.4);
        let on_floor = Point3::new(0.0, 0.0, 0.0);
        assert!(ray_meets_truth(&truth, &sensor, &on_floor, 0.1));
        // Measured 5 cm short of the floor along its ray (depth noise): still met.
        let short = on_floor + (sensor - on_floor).normalize() * 0.05;
        assert!(ray_meets_truth(&truth, &sensor, &short, 0.1));
        // 3 cm above the floor on a ray that meets it 12.5 cm farther on.
        let hanging = Point3::new(1.0, 0.0, 0.03);
        let sensor_far = Point3::new(-0.5, 0.0, 0.4);
        assert!(!ray_meets_truth(&truth, &sensor_far, &hanging, 0.1));
        // On the top of a box, 3 cm before its far edge: the ray crosses the top there and
        // meets the floor only far behind.
        let mut with_box = truth.clone();
        for c in 150..203 {
            for r in 95..106 {
                *with_box.get_mut(r, c).unwrap() = 0.2;
            }
        }
        let top_edge = Point3::new(-0.01, 0.0, 0.2);
        assert!(ray_meets_truth(&with_box, &sensor, &top_edge, 0.1));
        // A cell without height just before the point is solid: the ray cannot pass it.
        for c in 189..194 {
            for r in 95..106 {
                *truth.get_mut(r, c).unwrap() = f32::NAN;
            }
        }
        assert!(!ray_meets_truth(&truth, &sensor, &on_floor, 0.1));
    }
}
