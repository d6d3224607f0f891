//! The elevation map of paper 000 (Belter et al.), section 3: every cell holds a stack of
//! voxels, each with its own height Kalman filter, and a cell Kalman filter fed by the
//! highest voxel updated in a frame; a vitality counter keeps isolated measurements out of
//! the map; a visibility check removes cells that would have hidden what the sensor now sees.
//!
//! Per frame:
//!
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
//! 5. visibility: the sensor saw each updated cell, so the line of sight to it is free. For
//!    rays from the sensor through the updated cells (far to near, one per azimuth bin: the
//!    farthest and the lowest), every established cell that rises above the line of sight to
//!    the updated cell's `h + 3 sigma` loses its voxels above that line (paper 000, section 3.2).
//!
//! The median fill of small holes is applied when the map is exported ([`crate::post`]).

use crate::input::{prepare_binned, Binned, PrimeSenseHeight, RayCache, SensorFrame};
use crate::window::Window;
use crate::{ElevationMapper, MapLayers, UpdateStats};
use rayon::prelude::*;
use std::collections::HashMap;
use std::time::Instant;

/// Parameters of [`StackMapper`].
#[derive(Debug, Clone, PartialEq)]
pub struct StackConfig {
    /// Cell size (m).
    pub resolution_m: f64,
    /// Side of the moving window (m).
    pub size_m: f64,
    /// Height of a voxel of the stack (m).
    pub voxel_height_m: f64,
    /// Vitality increase for an updated column (`V_i`).
    pub vitality_increase: u8,
    /// Vitality decrease for a column not updated (`V_d`).
    pub vitality_decrease: u8,
    /// Vitality threshold above which a column is established (`V_t`).
    pub vitality_threshold: u8,
    /// Run the visibility check.
    pub visibility_check: bool,
    /// Azimuth bins of the visibility check (rays per frame: up to two per bin).
    pub visibility_bins: usize,
    /// The window is centred this far ahead of the sensor along its horizontal viewing
    /// direction (m).
    pub lookahead_m: f64,
    /// The window moves when its desired centre is farther than this from its centre (m).
    pub recenter_threshold_m: f64,
    /// The sensor model.
    pub sensor: PrimeSenseHeight,
}

impl Default for StackConfig {
    /// Paper 000's values: `V_i = 3`, `V_d = 2`, `V_t = 7`; 1 cm cells in a 4 x 4 m window;
    /// 2 cm voxels.
    fn default() -> Self {
        Self {
            resolution_m: 0.01,
            size_m: 4.0,
            voxel_height_m: 0.02,
            vitality_increase: 3,
            vitality_decrease: 2,
            vitality_threshold: 7,
            visibility_check: true,
            visibility_bins: 720,
            lookahead_m: 1.2,
            recenter_threshold_m: 0.3,
            sensor: PrimeSenseHeight::default(),
        }
    }
}

const MAX_VOXELS: usize = 6;
const MAX_ACC: usize = 3;

/// One voxel of a column: its index (height band `[idx, idx + 1) * voxel_height`), height
/// filter state (m, m²) and the frame that last updated it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Voxel {
    idx: i32,
    h: f32,
    var: f32,
    last_frame: u32,
}

/// The frame's measurements of one voxel, combined: sum of weights `1/var` (1/m²) and of
/// weighted heights above the voxel's bottom (m/m²).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Acc {
    idx: i32,
    sw: f32,
    swh: f32,
}

/// The voxel stack of a column and this frame's accumulators (kept apart from [`Cell`] so
/// that the per-point pass and the visibility walk touch little memory).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Stack {
    voxels: [Voxel; MAX_VOXELS],
    acc: [Acc; MAX_ACC],
}

/// A column of the map.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Cell {
    /// Cell filter state (valid once `has_estimate`): height (m) and variance (m²).
    h: f32,
    var: f32,
    /// Frames that updated the column.
    updates: u32,
    /// Frame number (1-based) of the last update; 0 = never.
    last_frame: u32,
    vitality: u8,
    n_voxels: u8,
    n_acc: u8,
    has_estimate: bool,
    established: bool,
    /// On its band's list of columns whose vitality still decays.
    pending: bool,
}

impl Cell {
    /// True when the column is part of the map.
    fn mapped(&self) -> bool {
        self.established && self.has_estimate
    }

    /// Adds a measurement (height `z` m, weight `w` = 1/variance) to this frame's
    /// accumulator of voxel `idx`. False when the column already has `MAX_ACC` distinct
    /// voxels this frame (the measurement is dropped).
    #[inline]
    fn accumulate(&mut self, st: &mut Stack, idx: i32, z_rel: f32, w: f32) -> bool {
        let n = usize::from(self.n_acc);
        for a in st.acc.iter_mut().take(n) {
            if a.idx == idx {
                a.sw += w;
                a.swh += w * z_rel;
                return true;
            }
        }
        match st.acc.get_mut(n) {
            Some(a) => {
                *a = Acc {
                    idx,
                    sw: w,
                    swh: w * z_rel,
                };
                self.n_acc += 1;
                true
            }
            None => false,
        }
    }

    /// Applies the frame's accumulated measurements: voxel filters (eq. 1), vitality, and
    /// the cell filter (eq. 2) fed by the highest voxel updated now.
    fn apply(&mut self, st: &mut Stack, frame_no: u32, voxel_h: f32, cfg: &StackConfig) {
        let mut highest: Option<(f32, f32, i32)> = None;
        for a in st.acc.iter().take(usize::from(self.n_acc)) {
            let bottom = a.idx as f32 * voxel_h;
            let (hm, vm) = (bottom + a.swh / a.sw, 1.0 / a.sw);
            let n = usize::from(self.n_voxels);
            let slot = match st.voxels.iter().take(n).position(|v| v.idx == a.idx) {
                Some(s) => s,
                None => {
                    // A new voxel starts at its centre with the spread of a uniform value
                    // within it; a full stack gives up its least recently updated voxel.
                    let s = if n < MAX_VOXELS {
                        self.n_voxels += 1;
                        n
                    } else {
                        st.voxels
                            .iter()
                            .enumerate()
                            .min_by_key(|(_, v)| v.last_frame)
                            .map_or(0, |(i, _)| i)
                    };
                    if let Some(v) = st.voxels.get_mut(s) {
                        *v = Voxel {
                            idx: a.idx,
                            h: bottom + 0.5 * voxel_h,
                            var: voxel_h * voxel_h / 12.0,
                            last_frame: 0,
                        };
                    }
                    s
                }
            };
            if let Some(v) = st.voxels.get_mut(slot) {
                // Eq. 1.
                let k = v.var / (v.var + vm);
                v.h -= k * (v.h - hm);
                v.var *= 1.0 - k;
                v.last_frame = frame_no;
                if highest.is_none_or(|(_, _, i)| a.idx > i) {
                    highest = Some((v.h, v.var, a.idx));
                }
            }
        }
        self.n_acc = 0;
        let Some((hp, vp, _)) = highest else { return };
        self.updates += 1;
        self.last_frame = frame_no;
        if !self.established {
            self.vitality = self.vitality.saturating_add(cfg.vitality_increase);
            if self.vitality > cfg.vitality_threshold {
                self.established = true;
            }
        }
        if self.established {
            if self.has_estimate {
                // Eq. 2.
                let k = self.var / (self.var + vp);
                self.h -= k * (self.h - hp);
                self.var *= 1.0 - k;
            } else {
                // No prior: the first established measurement is the estimate.
                self.h = hp;
                self.var = vp;
                self.has_estimate = true;
            }
        }
    }

    /// Removes the voxels above `z` (m) and re-derives the column's height from the highest
    /// remaining voxel (an empty column is forgotten). Returns whether the column changed.
    fn cut_above(&mut self, st: &mut Stack, z: f32) -> bool {
        if self.h <= z {
            return false;
        }
        let n = usize::from(self.n_voxels);
        let mut kept = [Voxel::default(); MAX_VOXELS];
        let mut m = 0;
        for v in st.voxels.iter().take(n) {
            if v.h <= z {
                if let Some(slot) = kept.get_mut(m) {
                    *slot = *v;
                    m += 1;
                }
            }
        }
        st.voxels = kept;
        self.n_voxels = m as u8;
        match st.voxels.iter().take(m).max_by_key(|v| v.idx).copied() {
            Some(top) => {
                self.h = top.h;
                self.var = top.var;
            }
            None => *self = Cell::default(),
        }
        true
    }
}

/// A ray of the visibility check: from the sensor to an updated cell.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ray {
    /// Horizontal distance from the sensor (m).
    d: f64,
    /// Map-frame (x, y) of the updated cell's centre (m).
    x: f64,
    y: f64,
    /// Height the line of sight ends at (m): the cell's `h + 3 sigma`.
    target: f64,
}

/// Per azimuth bin: the farthest and the lowest (in elevation angle) ray.
#[derive(Debug, Clone, Default)]
struct RayBins {
    far: Vec<Option<Ray>>,
    low: Vec<Option<Ray>>,
}

impl RayBins {
    fn new(bins: usize) -> Self {
        Self {
            far: vec![None; bins],
            low: vec![None; bins],
        }
    }

    /// Offers a ray to bin `b`; `sz` is the sensor height (m). Ties keep the ray offered
    /// first, so merging per-band bins in band order is deterministic.
    fn offer(&mut self, b: usize, r: Ray, sz: f64) {
        if let Some(slot) = self.far.get_mut(b) {
            if slot.is_none_or(|f| r.d > f.d) {
                *slot = Some(r);
            }
        }
        if let Some(slot) = self.low.get_mut(b) {
            if slot.is_none_or(|l| (r.target - sz) / r.d < (l.target - sz) / l.d) {
                *slot = Some(r);
            }
        }
    }

    fn merge(&mut self, o: &RayBins, sz: f64) {
        for (b, r) in o.far.iter().enumerate().chain(o.low.iter().enumerate()) {
            if let Some(r) = r {
                self.offer(b, *r, sz);
            }
        }
    }
}

/// A monotonic stand-in for the azimuth of `(dx, dy)` in `[0, 4)` (the "diamond angle"),
/// cheaper than `atan2`; bins of equal width in it are at most ~1.4x wider in angle than
/// others.
fn pseudo_azimuth(dx: f64, dy: f64) -> f64 {
    let s = dx.abs() + dy.abs();
    if s == 0.0 {
        return 0.0;
    }
    let p = dy / s; // in [-1, 1]
    if dx >= 0.0 {
        if dy >= 0.0 {
            p
        } else {
            4.0 + p
        }
    } else {
        2.0 - p
    }
}

/// An archived (evicted) column: its exported values.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Archived {
    h: f32,
    var: f32,
    vitality: u8,
    updates: u32,
}

/// Paper 000's voxel-stack elevation mapper. See the module documentation.
pub struct StackMapper {
    cfg: StackConfig,
    window: Window<Cell>,
    /// Voxel stacks, by the same storage index as the window's cells.
    stacks: Vec<Stack>,
    archive: HashMap<(i64, i64), Archived>,
    rays: RayCache,
    binned: Binned,
    /// Per band: columns not yet established whose vitality may decay.
    pending: Vec<Vec<u32>>,
    band_cells: usize,
    frame_no: u32,
    centered: bool,
}

/// Bands of storage rows that the update runs over in parallel: a fixed number, so that
/// results never depend on the thread count.
const BANDS: usize = 8;

impl StackMapper {
    /// A mapper with these parameters.
    pub fn new(cfg: StackConfig) -> Self {
        let size = ((cfg.size_m / cfg.resolution_m).round() as usize).max(8);
        let window = Window::new(size, cfg.resolution_m, (0, 0));
        let band_cells = size.div_ceil(BANDS) * size;
        Self {
            cfg,
            stacks: vec![Stack::default(); size * size],
            window,
            archive: HashMap::new(),
            rays: RayCache::default(),
            binned: Binned::default(),
            pending: vec![Vec::new(); BANDS],
            band_cells,
            frame_no: 0,
            centered: false,
        }
    }

    /// The parameters.
    pub fn config(&self) -> &StackConfig {
        &self.cfg
    }

    fn recenter(&mut self, frame: &SensorFrame<'_>) {
        let t = &frame.map_from_sensor;
        let fwd = t.rotation * nalgebra::Vector3::z();
        let horiz = nalgebra::Vector2::new(fwd.x, fwd.y);
        let dir = if horiz.norm() > 1e-6 {
            horiz.normalize()
        } else {
            nalgebra::Vector2::zeros()
        };
        let want =
            nalgebra::Vector2::new(t.translation.x, t.translation.y) + dir * self.cfg.lookahead_m;
        let n = self.window.size() as i64;
        let (r0, c0) = self.window.origin();
        let centre = self.window.cell_center((r0 + n / 2, c0 + n / 2));
        if self.centered
            && (nalgebra::Vector2::new(centre.0, centre.1) - want).norm()
                <= self.cfg.recenter_threshold_m
        {
            return;
        }
        let (wr, wc) = self.window.world_cell(want.x, want.y);
        let archive = &mut self.archive;
        self.window.move_to((wr - n / 2, wc - n / 2), |cell, c| {
            if c.mapped() {
                archive.insert(
                    cell,
                    Archived {
                        h: c.h,
                        var: c.var,
                        vitality: c.vitality,
                        updates: c.updates,
                    },
                );
            }
        });
        // Evicted columns were reset: drop them from the decay lists before their storage is
        // reused (otherwise a new column there would decay twice per frame).
        let cells = self.window.cells();
        for list in &mut self.pending {
            list.retain(|&ci| cells.get(ci as usize).is_some_and(|c| c.pending));
        }
        self.centered = true;
    }

    /// The visibility check of section 3.2 (see the module documentation) along the rays
    /// collected in `bins`. The rays are walked in parallel, reading the map; the cuts are
    /// then applied in a fixed order. Returns the number of columns that changed.
    fn visibility(&mut self, bins: &RayBins, sensor: (f64, f64, f64)) -> usize {
        let (sx, sy, sz) = sensor;
        let res = self.window.resolution();
        let frame_no = self.frame_no;
        let rays: Vec<Ray> = bins
            .far
            .iter()
            .chain(bins.low.iter())
            .flatten()
            .copied()
            .collect();
        let cells = self.window.cells();
        let indexer = self.window.indexer();
        let mut cuts: Vec<(u32, f32)> = rays
            .par_iter()
            .flat_map_iter(|ray| {
                let mut out = Vec::new();
                // Walk the cells the segment from the updated cell to the sensor crosses
                // (a 2-D DDA in cell units), skipping the cell itself and the sensor's
                // surroundings; cut every mapped column not seen now that rises above the
                // line of sight. The line of sight within a cell is taken at its highest,
                // so nothing the ray passes above is cut.
                let (x0, y0) = (ray.x / res + 0.5, ray.y / res + 0.5);
                let (x1, y1) = (sx / res + 0.5, sy / res + 0.5);
                let (dx, dy) = (x1 - x0, y1 - y0);
                let (mut cx, mut cy) = (x0.floor() as i64, y0.floor() as i64);
                let (ex, ey) = (x1.floor() as i64, y1.floor() as i64);
                let (stx, sty) = (if dx > 0.0 { 1 } else { -1 }, if dy > 0.0 { 1 } else { -1 });
                let (tdx, tdy) = (
                    if dx != 0.0 {
                        (1.0 / dx).abs()
                    } else {
                        f64::INFINITY
                    },
                    if dy != 0.0 {
                        (1.0 / dy).abs()
                    } else {
                        f64::INFINITY
                    },
                );
                let mut tmx = if dx > 0.0 {
                    ((cx + 1) as f64 - x0) / dx
                } else if dx < 0.0 {
                    (cx as f64 - x0) / dx
                } else {
                    f64::INFINITY
                };
                let mut tmy = if dy > 0.0 {
                    ((cy + 1) as f64 - y0) / dy
                } else if dy < 0.0 {
                    (cy as f64 - y0) / dy
                } else {
                    f64::INFINITY
                };
                // Line of sight at ray parameter t (0 at the updated cell, 1 at the sensor).
                let los = |t: f64| ray.target + (sz - ray.target) * t;
                let stop = 2.0 * res / ray.d.max(res); // parameter span of the last 2 cells
                let mut t_enter;
                loop {
                    t_enter = tmx.min(tmy);
                    if tmx < tmy {
                        cx += stx;
                        tmx += tdx;
                    } else {
                        cy += sty;
                        tmy += tdy;
                    }
                    if t_enter >= 1.0 - stop || (cx == ex && cy == ey) {
                        break;
                    }
                    let t_exit = tmx.min(tmy).min(1.0);
                    let top = los(t_enter).max(los(t_exit));
                    let (px, py) = ((cx as f64) * res, (cy as f64) * res);
                    let Some(i) = indexer(px, py) else { continue };
                    if let Some(c) = cells.get(i) {
                        if c.mapped() && c.last_frame != frame_no && f64::from(c.h) > top {
                            out.push((i as u32, top as f32));
                        }
                    }
                }
                out
            })
            .collect();
        // The same column may be cut by several rays: keep the lowest cut (cutting at each
        // in turn gives the same result).
        cuts.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        cuts.dedup_by_key(|c| c.0);
        let mut removed = 0;
        let cells = self.window.cells_mut();
        for (i, z) in cuts {
            if let (Some(c), Some(st)) =
                (cells.get_mut(i as usize), self.stacks.get_mut(i as usize))
            {
                if c.cut_above(st, z) {
                    removed += 1;
                }
            }
        }
        removed
    }
}

impl ElevationMapper for StackMapper {
    fn name(&self) -> &'static str {
        "stack"
    }

    fn integrate(&mut self, frame: &SensorFrame<'_>) -> UpdateStats {
        let start = Instant::now();
        self.frame_no += 1;
        let cfg = self.cfg.clone();
        if !crate::input::pose_is_finite(&frame.map_from_sensor) {
            let rej = prepare_binned(
                frame,
                &cfg.sensor,
                &mut self.rays,
                |_, _| None,
                1,
                &mut self.binned,
            );
            return UpdateStats {
                rejected: rej,
                update_s: start.elapsed().as_secs_f64(),
                ..Default::default()
            };
        }
        self.recenter(frame);
        let band_cells = self.band_cells;
        let size = self.window.size();
        let rej = prepare_binned(
            frame,
            &cfg.sensor,
            &mut self.rays,
            self.window.band_indexer(size.div_ceil(BANDS)),
            BANDS,
            &mut self.binned,
        );
        let voxel_h = cfg.voxel_height_m as f32;
        let inv_voxel_h = 1.0 / voxel_h;
        let frame_no = self.frame_no;
        let binned = &self.binned;
        let locate = self.window.locator();
        let s = frame.map_from_sensor.translation.vector;
        let (sx, sy, sz) = (s.x, s.y, s.z);
        let bins_n = cfg.visibility_bins.max(8);
        let min_d = 2.0 * cfg.resolution_m;
        let results: Vec<(usize, usize, RayBins)> = self
            .window
            .cells_mut()
            .par_chunks_mut(band_cells)
            .zip(self.stacks.par_chunks_mut(band_cells))
            .zip(self.pending.par_iter_mut())
            .enumerate()
            .map(|(b, ((cells, stacks), pending))| {
                let lo = b * band_cells;
                let (mut used, mut overflow) = (0usize, 0usize);
                let mut touched: Vec<u32> = Vec::new();
                for p in binned.band(b) {
                    let k = p.cell as usize - lo;
                    let (Some(cell), Some(st)) = (cells.get_mut(k), stacks.get_mut(k)) else {
                        continue;
                    };
                    if cell.n_acc == 0 {
                        touched.push(p.cell);
                    }
                    let idx_f = (p.z_m * inv_voxel_h).floor();
                    let idx = idx_f as i32;
                    if cell.accumulate(st, idx, p.z_m - idx_f * voxel_h, 1.0 / p.var_m2) {
                        used += 1;
                    } else {
                        overflow += 1;
                    }
                }
                let mut bins = RayBins::new(if cfg.visibility_check { bins_n } else { 0 });
                for &ci in &touched {
                    let k = ci as usize - lo;
                    let (Some(c), Some(st)) = (cells.get_mut(k), stacks.get_mut(k)) else {
                        continue;
                    };
                    c.apply(st, frame_no, voxel_h, &cfg);
                    if !c.established && !c.pending {
                        c.pending = true;
                        pending.push(ci);
                    }
                    if cfg.visibility_check && c.mapped() && c.last_frame == frame_no {
                        let (x, y) = locate(ci as usize);
                        let (dx, dy) = (x - sx, y - sy);
                        let d = dx.hypot(dy);
                        if d >= min_d {
                            let bin = ((pseudo_azimuth(dx, dy) * 0.25 * bins_n as f64) as usize)
                                .min(bins_n - 1);
                            let target = f64::from(c.h) + 3.0 * f64::from(c.var).max(0.0).sqrt();
                            bins.offer(bin, Ray { d, x, y, target }, sz);
                        }
                    }
                }
                // Vitality decays in columns not updated now, until they are established.
                pending.retain(|&ci| {
                    let Some(c) = cells.get_mut(ci as usize - lo) else {
                        return false;
                    };
                    if !c.pending || c.established {
                        c.pending = false;
                        return false;
                    }
                    if c.last_frame != frame_no {
                        c.vitality = c.vitality.saturating_sub(cfg.vitality_decrease);
                        if c.vitality == 0 {
                            *c = Cell::default();
                            return false;
                        }
                    }
                    true
                });
                (used, overflow, bins)
            })
            .collect();
        let (mut used, mut overflow) = (0, 0);
        let mut bins = RayBins::new(if cfg.visibility_check { bins_n } else { 0 });
        for (u, o, b) in &results {
            used += u;
            overflow += o;
            bins.merge(b, sz);
        }
        let cleared = if cfg.visibility_check {
            self.visibility(&bins, (sx, sy, sz))
        } else {
            0
        };
        UpdateStats {
            points_used: used,
            points_overflow: overflow,
            rejected: rej,
            cells_cleared: cleared,
            update_s: start.elapsed().as_secs_f64(),
        }
    }

    fn export(&self) -> MapLayers {
        let mut cells: HashMap<(i64, i64), Archived> = self.archive.clone();
        for (i, c) in self.window.cells().iter().enumerate() {
            if c.mapped() {
                cells.insert(
                    self.window.cell_of_index(i),
                    Archived {
                        h: c.h,
                        var: c.var,
                        vitality: c.vitality,
                        updates: c.updates,
                    },
                );
            }
        }
        MapLayers::from_cells(
            self.cfg.resolution_m,
            cells
                .iter()
                .map(|(&k, a)| (k, a.h, a.var, f32::from(a.vitality), a.updates as f32)),
        )
    }
}
