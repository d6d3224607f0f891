//! One frame's fusion into the stack mapper's columns, band by band: accumulate the binned
//! measurements per voxel, apply them to the columns' Kalman filters (eq. 1) and cell filter
//! (eq. 2), collect the visibility check's targets, and decay the vitality of columns not
//! yet established (section 3.1).

use crate::binned::Binned;
use crate::checks::Target;
use crate::column::{Accs, Cell, Spilled, Stack};
use crate::polar::Polar;
use crate::stack::StackConfig;

/// What one band's fusion did: measurements fused, and measurements dropped because their
/// column had too many distinct voxels this frame.
pub(crate) type BandUpdate = (usize, usize);

/// What a band of the window keeps from frame to frame: the columns whose vitality may
/// still decay, and buffers whose capacity is kept so that a frame allocates nothing.
#[derive(Debug, Default)]
pub(crate) struct BandState {
    /// Columns of this band not yet established, whose vitality may decay.
    pub(crate) pending: Vec<u32>,
    /// The pool of spilled accumulators (emptied at each frame).
    spill: Vec<Spilled>,
    /// Columns touched this frame (storage indices).
    touched: Vec<u32>,
    /// Updated, established cells for the visibility check (this frame's).
    pub(crate) targets: Vec<Target>,
}

impl BandState {
    /// Bytes held by its pool and buffers (the pending list is not counted, as before).
    pub(crate) fn memory_bytes(&self) -> usize {
        self.touched.capacity() * std::mem::size_of::<u32>()
            + self.spill.capacity() * std::mem::size_of::<Spilled>()
            + self.targets.capacity() * std::mem::size_of::<Target>()
    }
}

/// The frame's constants of the fusion.
pub(crate) struct Fusion<'a, L> {
    pub(crate) binned: &'a Binned,
    pub(crate) cfg: &'a StackConfig,
    pub(crate) frame_no: u32,
    /// Storage index to map-frame cell centre (m).
    pub(crate) locate: L,
    pub(crate) polar: Polar,
    /// Sensor height in the map frame (m).
    pub(crate) sensor_z_m: f64,
}

/// One band of the window's storage: its first storage index and its slices.
pub(crate) struct Band<'b> {
    pub(crate) index: usize,
    pub(crate) first: usize,
    pub(crate) cells: &'b mut [Cell],
    pub(crate) stacks: &'b mut [Stack],
    pub(crate) accs: &'b mut [Accs],
    pub(crate) state: &'b mut BandState,
}

impl<L: Fn(usize) -> (f64, f64)> Fusion<'_, L> {
    /// Fuses this frame's measurements into one band; its visibility targets are left in
    /// `band.state.targets`.
    pub(crate) fn band(&self, band: Band<'_>) -> BandUpdate {
        let Band {
            index,
            first,
            cells,
            stacks,
            accs,
            state,
        } = band;
        let BandState {
            pending,
            spill,
            touched,
            targets,
        } = state;
        spill.clear();
        touched.clear();
        targets.clear();
        let counts = self.accumulate(index, first, cells, accs, spill, touched);
        self.apply(
            first,
            touched,
            cells,
            stacks,
            (accs, spill),
            pending,
            targets,
        );
        self.decay(first, cells, pending);
        counts
    }

    /// Accumulates the band's measurements per (column, voxel), appending the columns
    /// touched to `touched`; returns the counts of used and overflowing measurements.
    fn accumulate(
        &self,
        index: usize,
        first: usize,
        cells: &mut [Cell],
        accs: &mut [Accs],
        spill: &mut Vec<Spilled>,
        touched: &mut Vec<u32>,
    ) -> (usize, usize) {
        let voxel_h = self.cfg.voxel_height_m as f32;
        let inv_voxel_h = 1.0 / voxel_h;
        let (mut used, mut overflow) = (0, 0);
        for p in self.binned.band(index) {
            let k = (p.cell() as usize).wrapping_sub(first);
            let (Some(cell), Some(acc)) = (cells.get_mut(k), accs.get_mut(k)) else {
                continue;
            };
            if cell.n_acc == 0 {
                touched.push(p.cell());
            }
            let idx_f = (p.z_m * inv_voxel_h).floor();
            let z_rel = p.z_m - idx_f * voxel_h;
            if cell.accumulate(
                acc,
                spill,
                idx_f as i32,
                z_rel,
                1.0 / p.var_m2,
                (p.centrality(), p.smooth(), p.face()),
            ) {
                used += 1;
            } else {
                overflow += 1;
            }
        }
        (used, overflow)
    }

    /// Applies the accumulated voxels to the touched columns; new columns join `pending`.
    /// Appends the visibility targets to `targets`: established cells updated now, at least
    /// two cells from the sensor.
    #[allow(clippy::too_many_arguments)]
    fn apply(
        &self,
        first: usize,
        touched: &[u32],
        cells: &mut [Cell],
        stacks: &mut [Stack],
        (accs, spill): (&[Accs], &[Spilled]),
        pending: &mut Vec<u32>,
        targets: &mut Vec<Target>,
    ) {
        let cfg = self.cfg;
        let min_d = 2.0 * cfg.resolution_m;
        for &ci in touched {
            let k = (ci as usize).wrapping_sub(first);
            let (Some(c), Some(st), Some(acc)) = (cells.get_mut(k), stacks.get_mut(k), accs.get(k))
            else {
                continue;
            };
            let held = acc.in_use(usize::from(c.n_acc), spill);
            c.apply(st, held, self.frame_no, cfg.voxel_height_m as f32, cfg);
            if !c.established && !c.pending {
                c.pending = true;
                pending.push(ci);
            }
            if !(cfg.visibility_check && c.mapped() && c.last_frame == self.frame_no) {
                continue;
            }
            let (x, y) = (self.locate)(ci as usize);
            let (bin, radial, d) = self.polar.of(x, y);
            if d >= min_d {
                let top = f64::from(c.h) + 3.0 * f64::from(c.var).max(0.0).sqrt();
                targets.push(Target {
                    x,
                    y,
                    bin,
                    radial,
                    slope: (top - self.sensor_z_m) / d,
                });
            }
        }
    }

    /// Vitality decays in pending columns not updated now, until they are established; a
    /// column whose vitality reaches 0 is forgotten.
    fn decay(&self, first: usize, cells: &mut [Cell], pending: &mut Vec<u32>) {
        pending.retain(|&ci| {
            let Some(c) = cells.get_mut((ci as usize).wrapping_sub(first)) else {
                return false;
            };
            if !c.pending || c.established {
                c.pending = false;
                return false;
            }
            if c.last_frame != self.frame_no {
                c.vitality = c.vitality.saturating_sub(self.cfg.vitality_decrease);
                if c.vitality == 0 {
                    *c = Cell::default();
                    return false;
                }
            }
            true
        });
    }
}
