//! # stride-mapping
//!
//! Elevation maps for walking robots, in a map frame whose z axis points up:
//!
//! * [`stack::StackMapper`]: paper 000's map (voxel stacks with Kalman filters, vitality
//!   counter, visibility check, see-through check, depth-edge filter; median filter on
//!   export).
//! * [`fankhauser::FankhauserMapper`]: the Fankhauser et al. (2014) update (ANYbotics'
//!   elevation_mapping: per-cell Kalman fusion with Mahalanobis gating and its Kinect noise
//!   model), the baseline, behind the same [`ElevationMapper`] trait.
//! * [`input`]: sensor frames (depth images or point clouds with covariances) and the
//!   sensor models that give each point a height variance.
//! * [`stereo`]: paper 000's stereo uncertainty model (eqs. 5-9) and stereo artifact filter
//!   (section 4.1).
//! * [`metrics`]: MSE against ground truth, coverage, and the performance index (eq. 13).
//! * [`align`]: a frame laid onto the map before it is integrated (height and tilt), for
//!   poses whose orientation is less exact than the map.
//! * [`post`]: the median filter that fills small holes and removes isolated cells.
//! * [`simd`]: the input stage's loops run compiled for AVX2 where the CPU has it.
//! * [`error`]: what a mapper refuses to be built from (invalid parameters, inconsistent
//!   frames); a mapper that exists has valid parameters.
//!
//! Mapping never depends on the SLAM crates: it takes poses and measurements, so it serves
//! any SLAM. File formats are the caller's business (stride-datasets writes the grids).
//!
//! An update runs its stages in parallel (rayon) on the pool of the thread that calls it.
//! Call it from a thread that belongs to a pool, such as one that has called
//! `stride_core::parallel::join_own_pool`: from a thread outside any pool, the update goes
//! to rayon's global pool while the thread waits, and on two cores one update in ten to
//! twenty then ran at one worker's speed (p95 8.7 against 4.5 ms per VGA frame). The maps
//! are the same either way.

pub mod align;
mod archive;
mod binned;
mod cell_point;
mod checks;
mod column;
pub mod denoise;
mod depth_pass;
pub mod error;
pub mod fankhauser;
mod fuse;
pub mod input;
pub mod metrics;
pub mod naive;
mod neighbourhood;
mod polar;
pub mod post;
pub mod range2d;
pub mod simd;
pub mod stack;
pub mod steep;
pub mod stereo;
pub mod window;

pub use error::MappingError;
use input::{Rejections, SensorFrame};
use stride_core::grid::{Grid, GridGeometry};

/// What one [`ElevationMapper::integrate`] call did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct UpdateStats {
    /// Measurements that updated the map.
    pub points_used: usize,
    /// Measurements dropped because a cell already had too many distinct voxels this frame.
    pub points_overflow: usize,
    /// Measurements dropped, by reason.
    pub rejected: Rejections,
    /// Columns that lost voxels in the visibility check.
    pub cells_cleared: usize,
    /// Depth pixels on steep faces moved behind them before binning
    /// ([`stack::StackConfig::steep_push_sigmas`]; 0 for the other mappers).
    pub steep_pushed: usize,
    /// Wall time of the update (s).
    pub update_s: f64,
    /// Of which: turning the measurements into map-frame heights and binning them (s).
    pub prepare_s: f64,
    /// Of which: the checks after the fusion (visibility, see-through) (s).
    pub checks_s: f64,
}

impl UpdateStats {
    /// The stats of a frame dropped whole because its pose is not finite (nothing in the
    /// map changes), `start` being when its update began.
    pub fn bad_pose(frame: &SensorFrame<'_>, start: std::time::Instant) -> Self {
        Self {
            rejected: Rejections {
                bad_pose: frame.len(),
                ..Default::default()
            },
            update_s: start.elapsed().as_secs_f64(),
            ..Default::default()
        }
    }
}

/// An elevation mapper: integrates sensor frames, exports its layers.
pub trait ElevationMapper {
    /// A short name for reports (`stack`, `fankhauser`).
    fn name(&self) -> &'static str;
    /// Integrates one frame (measurements and the sensor's pose in the map frame).
    fn integrate(&mut self, frame: &SensorFrame<'_>) -> UpdateStats;
    /// Every cell mapped so far (the moving window and the cells it left behind), as the
    /// filters left them.
    fn export(&self) -> MapLayers;
    /// Bytes the map holds (cells, voxel stacks, archive and per-frame buffers; hash-map
    /// overhead not counted), for memory comparisons with other map representations.
    fn memory_bytes(&self) -> usize;
    /// Columns dropped so far from the archive of cells the moving window left behind, to
    /// keep the archive within its cap: mapped cells the exported map no longer holds (0
    /// for mappers that keep every cell).
    fn archive_dropped_cells(&self) -> usize {
        0
    }
    /// The map as its method delivers it: [`Self::export`] followed by the mapper's own
    /// post-processing (the stack mapper's median filter, paper 000), with what it changed.
    /// Mappers without post-processing return `export()` unchanged.
    fn finished(&self) -> (MapLayers, post::MedianStats) {
        (self.export(), post::MedianStats::default())
    }
}

/// A mapper's layers over the bounding box of its cells, in the map frame (z up), NaN where
/// unknown.
#[derive(Debug, Clone, PartialEq)]
pub struct MapLayers {
    /// Height (m).
    pub elevation: Grid<f32>,
    /// Height variance (m²).
    pub variance: Grid<f32>,
    /// Vitality counter (paper 000; NaN for mappers without one).
    pub vitality: Grid<f32>,
    /// Number of frames that updated the cell.
    pub updates: Grid<f32>,
}

impl MapLayers {
    /// Layers from `(world cell (row, col), height, variance, vitality, updates)` tuples
    /// with cells of `resolution` metres, over their bounding box.
    pub fn from_cells(
        resolution: f64,
        cells: impl Iterator<Item = ((i64, i64), f32, f32, f32, f32)> + Clone,
    ) -> Self {
        let (mut r0, mut c0, mut r1, mut c1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
        for ((r, c), ..) in cells.clone() {
            r0 = r0.min(r);
            c0 = c0.min(c);
            r1 = r1.max(r);
            c1 = c1.max(c);
        }
        if r0 > r1 {
            (r0, c0, r1, c1) = (0, 0, 0, 0);
        }
        let g = GridGeometry {
            origin_x: c0 as f64 * resolution,
            origin_y: r0 as f64 * resolution,
            resolution,
            rows: (r1 - r0 + 1) as usize,
            cols: (c1 - c0 + 1) as usize,
        };
        let mut layers = Self {
            elevation: Grid::filled(g, f32::NAN),
            variance: Grid::filled(g, f32::NAN),
            vitality: Grid::filled(g, f32::NAN),
            updates: Grid::filled(g, f32::NAN),
        };
        for ((r, c), h, var, vit, upd) in cells {
            let (rr, cc) = ((r - r0) as usize, (c - c0) as usize);
            for (layer, v) in [
                (&mut layers.elevation, h),
                (&mut layers.variance, var),
                (&mut layers.vitality, vit),
                (&mut layers.updates, upd),
            ] {
                if let Some(slot) = layer.get_mut(rr, cc) {
                    *slot = v;
                }
            }
        }
        layers
    }

    /// Every cell with a height: `(world cell (row, col), height, variance, vitality,
    /// updates)`, the world cell being the cell's centre over the resolution.
    pub fn known_cells(&self) -> impl Iterator<Item = ((i64, i64), f32, f32, f32, f32)> + '_ {
        let g = self.elevation.geometry;
        let (r0, c0) = (
            (g.origin_y / g.resolution).round() as i64,
            (g.origin_x / g.resolution).round() as i64,
        );
        let layers = [&self.variance, &self.vitality, &self.updates];
        self.elevation
            .as_slice()
            .iter()
            .enumerate()
            .filter(|(_, h)| !h.is_nan())
            .map(move |(i, &h)| {
                let [var, vit, upd] =
                    layers.map(|l| l.as_slice().get(i).copied().unwrap_or(f32::NAN));
                let (row, col) = ((i / g.cols.max(1)) as i64, (i % g.cols.max(1)) as i64);
                ((r0 + row, c0 + col), h, var, vit, upd)
            })
    }

    /// These layers with `top` laid over them: a cell has `top`'s values where `top` knows
    /// its height and these elsewhere, over the bounding box of both. Errors when the
    /// resolutions differ.
    pub fn overlaid(&self, top: &MapLayers) -> Result<MapLayers, MappingError> {
        let res = self.elevation.geometry.resolution;
        let top_res = top.elevation.geometry.resolution;
        if (res - top_res).abs() > 1e-9 * res.abs() {
            return Err(MappingError::Parameter {
                name: "resolution_m",
                value: top_res,
                reason: "layers laid over each other must have the same resolution",
            });
        }
        let mut cells: std::collections::BTreeMap<(i64, i64), (f32, f32, f32, f32)> = self
            .known_cells()
            .map(|(k, h, v, vi, u)| (k, (h, v, vi, u)))
            .collect();
        for (k, h, v, vi, u) in top.known_cells() {
            cells.insert(k, (h, v, vi, u));
        }
        Ok(MapLayers::from_cells(
            res,
            cells.iter().map(|(&k, &(h, v, vi, u))| (k, h, v, vi, u)),
        ))
    }

    /// Number of cells with a height.
    pub fn cells_observed(&self) -> usize {
        self.elevation
            .as_slice()
            .iter()
            .filter(|v| !v.is_nan())
            .count()
    }
}
