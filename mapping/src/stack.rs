//! The elevation map of paper 000 (Belter et al.), section 3: every cell holds a stack of
//! voxels, each with its own height Kalman filter, and a cell Kalman filter fed by the
//! highest voxel updated in a frame; a vitality counter keeps isolated measurements out of
//! the map; a visibility check removes cells that would have hidden what the sensor now sees.
//!
//! Per frame:
//!
//! 0. depth images are first smoothed on their own surfaces ([`crate::denoise`], an
//!    extension: [`StackConfig::depth_smoothing`]), then pass the depth-edge filter
//!    ([`crate::input::EdgeFilter`]), the sensor front end paper 000 assumes: flying pixels
//!    behind foreground edges are dropped;
//! 1. every point's height and height variance come from its covariance in the map frame
//!    ([`crate::input`]);
//! 2. the points of a voxel are fused into its filter (eq. 1). All measurements of one voxel
//!    in one frame are combined first (information-weighted mean); for a static state with an
//!    identity model this equals updating once per point, in any order;
//! 3. for each updated column, the highest voxel updated in this frame feeds the cell filter
//!    (eq. 2), once the column is established;
//! 4. the vitality counter rises by `V_i` for an updated column and falls by `V_d` for a
//!    column not updated; above `V_t` it locks and the column is established (only
//!    established columns are part of the map);
//! 5. visibility (section 3.2): the sensor saw each updated, established cell, so the line
//!    of sight to its `h + 3 sigma` is free. Every mapped column at least two cells nearer
//!    along the same azimuth (bins of [`StackConfig::visibility_bin_m`]) that rises above
//!    the lowest such line loses its voxels above it. This visits the updated cells from far
//!    to near as the paper does, as a running minimum over distance per azimuth bin;
//! 6. see-through (an extension, [`StackConfig::see_through_check`]): a column whose top the
//!    depth image now sees through loses its top voxel. Flying pixels that hang in an
//!    obstacle's shadow lie on lines of sight, so step 5 cannot remove them; this can once
//!    the robot has moved.
//!
//! Columns measured in the current frame never lose the voxels measured now.
//!
//! The median fill of small holes ([`crate::post`]) is applied by
//! [`ElevationMapper::finished`], when [`StackConfig::median_filter`] asks for it.

use crate::archive::{Archive, Archived};
use crate::checks::{LosTable, SeeThrough, Target};
use crate::column::{Accs, Cell, Stack, Voxel};
use crate::denoise::Smoother;
use crate::error::MappingError;
use crate::fuse::{Band, BandState, BandUpdate, Fusion};
use crate::input::{
    prepare_binned, Binned, Binning, Cloud, PrimeSenseHeight, RayCache, SensorFrame,
};
use crate::polar::Polar;
use crate::post::{median_filter, MedianStats};
use crate::steep::{PushFrame, SteepPush};
use crate::window::Window;
use crate::{ElevationMapper, MapLayers, UpdateStats};
use rayon::prelude::*;
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// Paper 000's voxel-stack elevation mapper. See the module documentation.
pub struct StackMapper {
    cfg: StackConfig,
    window: Window<Cell>,
    /// Voxel stacks, by the same storage index as the window's cells.
    stacks: Vec<Stack>,
    /// Per-frame accumulators, by the same storage index.
    accs: Vec<Accs>,
    archive: Archive,
    rays: RayCache,
    binned: Binned,
    /// Per band: columns whose vitality may decay, and the fusion's buffers (among them the
    /// accumulators of columns measured over more voxels than [`Accs`] holds).
    bands: Vec<BandState>,
    /// The visibility check's targets of all bands (a buffer kept from frame to frame).
    targets: Vec<Target>,
    band_cells: usize,
    /// Scratch table of the visibility check (lowest line-of-sight slope per azimuth bin
    /// and distance).
    los_table: Vec<f32>,
    /// The depth smoothing's buffers.
    smoother: Smoother,
    /// The buffer of the steep faces' push ([`crate::steep`]).
    pusher: SteepPush,
    frame_no: u32,
}

/// Bands of storage rows that the update runs over in parallel: a fixed number, so that
/// results never depend on the thread count.
const BANDS: usize = 32;

impl StackMapper {
    /// A mapper with these parameters, once [`StackConfig::validate`] accepts them.
    pub fn new(cfg: StackConfig) -> Result<Self, MappingError> {
        let size = cfg.validate()?;
        let window = Window::new(size, cfg.resolution_m, (0, 0));
        let band_cells = size.div_ceil(BANDS) * size;
        Ok(Self {
            cfg,
            stacks: vec![Stack::default(); size * size],
            accs: vec![Accs::default(); size * size],
            window,
            archive: Archive::default(),
            rays: RayCache::default(),
            binned: Binned::default(),
            bands: (0..BANDS).map(|_| BandState::default()).collect(),
            targets: Vec::new(),
            band_cells,
            los_table: Vec::new(),
            smoother: Smoother::default(),
            pusher: SteepPush::default(),
            frame_no: 0,
        })
    }

    /// The parameters.
    pub fn config(&self) -> &StackConfig {
        &self.cfg
    }

    /// The archive of columns the window left behind: columns in it now, columns dropped
    /// from it so far to keep [`StackConfig::archive_max_cells`], and columns resumed from
    /// it so far when the window came back over them.
    pub fn archive_cells(&self) -> (usize, usize, usize) {
        (
            self.archive.len(),
            self.archive.dropped(),
            self.archive.taken(),
        )
    }

    /// Builds the ray table of `camera` if it is not the one held (shared with the
    /// update's input stage), for passes over depth images beside the update
    /// ([`StackMapper::align`]).
    pub(crate) fn prepare_rays(&mut self, camera: &PinholeCamera) {
        self.rays.rays(camera);
    }

    /// The ray table of `camera` when [`StackMapper::prepare_rays`] built it (or none is
    /// needed), and the sensor model.
    pub(crate) fn prepared_rays(
        &self,
        camera: &PinholeCamera,
    ) -> (Option<crate::input::Rays<'_>>, &PrimeSenseHeight) {
        (self.rays.cached(camera), &self.cfg.sensor)
    }

    /// The height (m) and variance (m²) of the established cell under map point `(x, y)`
    /// (m), as the cell filter holds it now (before the median filter); `None` outside the
    /// window or where the map knows nothing.
    pub fn established_height(&self, x: f64, y: f64) -> Option<(f32, f32)> {
        let i = self.window.index(self.window.world_cell(x, y))?;
        let c = self.window.cells().get(i)?;
        c.mapped().then_some((c.h, c.var))
    }

    /// Keeps the window ahead of the sensor; evicted established columns go to the archive.
    fn recenter(&mut self, frame: &SensorFrame<'_>) {
        let archive = &mut self.archive;
        let moved = self.window.follow(
            &frame.map_from_sensor,
            self.cfg.lookahead_m,
            self.cfg.recenter_threshold_m,
            |cell, c| {
                if c.mapped() {
                    archive.insert(
                        cell,
                        Archived {
                            h: c.h,
                            var: c.var,
                            vitality: c.vitality,
                            updates: c.updates,
                            bound_only: c.bound_only,
                        },
                    );
                }
            },
        );
        if moved {
            // Evicted columns were reset: drop them from the decay lists before their storage
            // is reused (otherwise a new column there would decay twice per frame).
            let cells = self.window.cells();
            for list in self.bands.iter_mut().map(|b| &mut b.pending) {
                list.retain(|&ci| cells.get(ci as usize).is_some_and(|c| c.pending));
            }
            self.reload_archived();
            let n = self.window.size() as i64;
            let (r0, c0) = self.window.origin();
            self.archive
                .cap(self.cfg.archive_max_cells, (r0 + n / 2, c0 + n / 2));
        }
    }

    /// Columns that come back into the window resume from the archive (an established
    /// column with one voxel at its height) instead of starting afresh; they leave the
    /// archive, which holds only columns outside the window.
    fn reload_archived(&mut self) {
        let voxel_h = self.cfg.voxel_height_m as f32;
        if self.archive.is_empty() {
            return;
        }
        let entered = self.window.entered().to_vec();
        for i in entered {
            let key = self.window.cell_of_index(i);
            let Some(a) = self.archive.remove(key) else {
                continue;
            };
            let (Some(c), Some(st)) = (self.window.cells_mut().get_mut(i), self.stacks.get_mut(i))
            else {
                continue;
            };
            *c = Cell {
                h: a.h,
                var: a.var,
                updates: a.updates,
                vitality: a.vitality,
                n_voxels: 1,
                has_estimate: true,
                established: true,
                bound_only: a.bound_only,
                ..Cell::default()
            };
            if let Some(v) = st.voxels.first_mut() {
                *v = Voxel {
                    idx: (a.h / voxel_h).floor() as i32,
                    h: a.h,
                    var: a.var,
                    last_frame: 0,
                };
            }
        }
    }

    /// The visibility check's polar frame for this sensor pose: azimuth bins of
    /// `visibility_bin_m` at the far range (a pseudo-angle unit is about a radian ahead of
    /// the sensor) and radial steps of two cells.
    fn polar_frame(&self, frame: &SensorFrame<'_>) -> Polar {
        let cfg = &self.cfg;
        let s = frame.map_from_sensor.translation.vector;
        let fwd = frame.map_from_sensor.rotation * nalgebra::Vector3::z();
        let heading = nalgebra::Vector2::new(fwd.x, fwd.y);
        let heading = if heading.norm() > 1e-9 {
            heading.normalize()
        } else {
            nalgebra::Vector2::x()
        };
        let far_m = cfg.sensor.max_depth_m.max(cfg.resolution_m);
        Polar {
            sx: s.x,
            sy: s.y,
            hx: heading.x,
            hy: heading.y,
            bins_per_unit: far_m / cfg.visibility_bin_m.max(1e-4),
            inv_step: 0.5 / cfg.resolution_m,
        }
    }

    /// The checks after the update, in one pass over the window's mapped columns:
    ///
    /// * the visibility check of section 3.2 (when `targets` is given; see the module
    ///   documentation). Every updated, established cell is a target: the line of sight
    ///   from the sensor to its `h + 3 sigma` must be free. Targets are grouped by azimuth
    ///   bin and distance; from far to near, the lowest line of sight over each distance is
    ///   the running minimum of the targets' slopes beyond it (two cells of margin). A
    ///   column that rises above the lowest line of sight of its bin loses the voxels above
    ///   it (voxels measured in this frame stay);
    /// * the see-through check (when `image` is given; [`StackConfig::see_through_check`]).
    ///
    /// Returns the number of columns changed.
    fn post_checks(
        &mut self,
        targets: Option<&[Target]>,
        polar: &Polar,
        sz: f64,
        image: Option<(&DepthImage, &PinholeCamera, &nalgebra::Isometry3<f64>)>,
    ) -> usize {
        let targets = targets.unwrap_or(&[]);
        let los = LosTable::build(&mut self.los_table, targets);
        if targets.is_empty() && image.is_none() {
            return 0;
        }
        // Only columns around the targets and the sensor can be cut: those beyond every
        // target have no line of sight over them, and the see-through check needs a surface
        // beyond the column (the whole window when there are no targets).
        let inf = f64::INFINITY;
        let bbox = if targets.is_empty() {
            (-inf, inf, -inf, inf)
        } else {
            targets
                .iter()
                .fold((polar.sx, polar.sx, polar.sy, polar.sy), |b, t| {
                    (b.0.min(t.x), b.1.max(t.x), b.2.min(t.y), b.3.max(t.y))
                })
        };
        let (frame_no, band_cells, polar) = (self.frame_no, self.band_cells, *polar);
        let locate = self.window.locator();
        let (voxel_h, res) = (self.cfg.voxel_height_m as f32, self.cfg.resolution_m);
        let see = image.map(|(depth, camera, map_from_sensor)| {
            SeeThrough::new(depth, camera, map_from_sensor, self.cfg.sensor, res)
        });
        let check = |c: &mut Cell, st: &mut Stack, x: f64, y: f64| -> bool {
            let (bin, r, d) = polar.of(x, y);
            let mut hit = false;
            // Line of sight to the targets two radial steps on (at least two cells farther
            // than this column).
            if let Some(slope) = los.slope_beyond(bin, r).filter(|_| d >= 2.0 * res) {
                let line_m = sz + f64::from(slope) * d;
                if f64::from(c.h) > line_m {
                    hit |= c.cut_above(st, line_m as f32, frame_no);
                }
            }
            // See-through: only columns in the azimuth range of this frame's targets can be
            // in view (all of them when there are no targets).
            let in_view = targets.is_empty() || los.near_bins(bin, 8);
            if let (Some(see), true) = (&see, in_view && c.mapped()) {
                if see.sees_past(x, y, f64::from(c.h)) {
                    hit |= c.cut_above(st, c.h - voxel_h, frame_no);
                }
            }
            hit
        };
        self.window
            .cells_mut()
            .par_chunks_mut(band_cells)
            .zip(self.stacks.par_chunks_mut(band_cells))
            .enumerate()
            .map(|(band, (cells, stacks))| {
                let mut changed = 0;
                for (k, (c, st)) in cells.iter_mut().zip(stacks.iter_mut()).enumerate() {
                    if !c.mapped() {
                        continue;
                    }
                    let (x, y) = locate(band * band_cells + k);
                    if x >= bbox.0 && x <= bbox.1 && y >= bbox.2 && y <= bbox.3 {
                        changed += usize::from(check(c, st, x, y));
                    }
                }
                changed
            })
            .sum()
    }
}

impl ElevationMapper for StackMapper {
    fn name(&self) -> &'static str {
        "stack"
    }

    fn archive_dropped_cells(&self) -> usize {
        self.archive.dropped()
    }

    fn memory_bytes(&self) -> usize {
        self.window.memory_bytes()
            + self.stacks.capacity() * std::mem::size_of::<Stack>()
            + self.accs.capacity() * std::mem::size_of::<Accs>()
            + self
                .bands
                .iter()
                .map(BandState::memory_bytes)
                .sum::<usize>()
            + self.archive.memory_bytes()
            + self.binned.memory_bytes()
            + self.los_table.capacity() * std::mem::size_of::<f32>()
            + self.smoother.memory_bytes()
            + self.pusher.memory_bytes()
            + self.targets.capacity() * std::mem::size_of::<Target>()
    }

    fn integrate(&mut self, frame: &SensorFrame<'_>) -> UpdateStats {
        let start = Instant::now();
        self.frame_no += 1;
        let cfg = self.cfg.clone();
        if !frame.pose_is_finite() {
            return UpdateStats::bad_pose(frame, start);
        }
        self.recenter(frame);
        let smoothed = match (&cfg.depth_smoothing, frame.cloud()) {
            (Some(d), Cloud::Depth { depth_m, .. }) => {
                Some(self.smoother.smooth(depth_m, &cfg.sensor, d))
            }
            _ => None,
        };
        let frame = &match &smoothed {
            Some(image) => frame.with_depth(image),
            None => *frame,
        };
        let pushed = match frame.cloud() {
            Cloud::Depth { depth_m, camera } if cfg.steep_push_sigmas > 0.0 => {
                let up_camera = frame
                    .map_from_sensor
                    .rotation
                    .inverse_transform_vector(&nalgebra::Vector3::z());
                let f = PushFrame {
                    camera,
                    up_camera,
                    model: &cfg.sensor,
                    sigmas: cfg.steep_push_sigmas,
                };
                Some(self.pusher.push(depth_m, &f))
            }
            _ => None,
        };
        let frame = &match &pushed {
            Some((image, _)) => frame.with_depth(image),
            None => *frame,
        };
        let band_cells = self.band_cells;
        let size = self.window.size();
        let rej = prepare_binned(
            frame,
            &cfg.sensor,
            &mut self.rays,
            Binning {
                binner: &self.window.binner(size.div_ceil(BANDS)),
                centrality: cfg.step_support_fraction > 0.0,
                smooth: cfg.establish_smooth,
                faces: pushed.as_ref().map(|_| self.pusher.moved()),
            },
            BANDS,
            cfg.edge_filter.as_ref(),
            &mut self.binned,
        );
        let prepare_s = start.elapsed().as_secs_f64();
        let polar = self.polar_frame(frame);
        let sz = frame.map_from_sensor.translation.z;
        let fusion = Fusion {
            binned: &self.binned,
            cfg: &cfg,
            frame_no: self.frame_no,
            locate: self.window.locator(),
            polar,
            sensor_z_m: sz,
        };
        let (used, overflow): BandUpdate = self
            .window
            .cells_mut()
            .par_chunks_mut(band_cells)
            .zip(self.stacks.par_chunks_mut(band_cells))
            .zip(self.accs.par_chunks_mut(band_cells))
            .zip(self.bands.par_iter_mut())
            .enumerate()
            .map(|(index, (((cells, stacks), accs), state))| {
                fusion.band(Band {
                    index,
                    first: index * band_cells,
                    cells,
                    stacks,
                    accs,
                    state,
                })
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        // In band order, as before the buffers were kept.
        let mut targets = std::mem::take(&mut self.targets);
        targets.clear();
        for b in &self.bands {
            targets.extend_from_slice(&b.targets);
        }
        let image = match (cfg.see_through_check, frame.cloud()) {
            (true, Cloud::Depth { depth_m, camera }) => {
                Some((depth_m, camera, &frame.map_from_sensor))
            }
            _ => None,
        };
        let checks_start = Instant::now();
        let cleared = self.post_checks(
            cfg.visibility_check.then_some(&targets[..]),
            &polar,
            sz,
            image,
        );
        self.targets = targets;
        if let Some(image) = smoothed {
            self.smoother.restore(image);
        }
        let steep_pushed = pushed.map_or(0, |(image, n)| {
            self.pusher.restore(image);
            n
        });
        UpdateStats {
            points_used: used,
            points_overflow: overflow,
            rejected: rej,
            cells_cleared: cleared,
            steep_pushed,
            update_s: start.elapsed().as_secs_f64(),
            prepare_s,
            checks_s: checks_start.elapsed().as_secs_f64(),
        }
    }

    fn finished(&self) -> (MapLayers, MedianStats) {
        let mut layers = self.export();
        let stats = match &self.cfg.median_filter {
            Some(f) => median_filter(&mut layers.elevation, &mut layers.variance, f),
            None => MedianStats::default(),
        };
        (layers, stats)
    }

    fn export(&self) -> MapLayers {
        // The archive holds only columns outside the window: the two never overlap. A
        // column known from steep faces alone is a lower bound of its top, not a height:
        // left out of both (`Cell::exported`).
        let window = self
            .window
            .cells()
            .iter()
            .enumerate()
            .filter(|(_, c)| c.exported())
            .map(|(i, c)| {
                let v = (c.h, c.var, f32::from(c.vitality), c.updates as f32);
                (self.window.cell_of_index(i), v.0, v.1, v.2, v.3)
            });
        let archived = self
            .archive
            .iter()
            .filter(|(_, a)| !a.bound_only)
            .map(|(k, a)| (k, a.h, a.var, f32::from(a.vitality), a.updates as f32));
        MapLayers::from_cells(self.cfg.resolution_m, archived.chain(window))
    }
}

#[path = "stack_config.rs"]
mod config;
pub use config::StackConfig;

#[cfg(test)]
#[path = "stack_tests.rs"]
mod tests;
