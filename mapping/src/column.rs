//! One column of the stack map (paper 000, section 3): its voxels with their height
//! filters, this frame's accumulated measurements, and the cell filter fed by the highest
//! voxel. The per-column arithmetic of [`crate::stack::StackMapper`], apart from its passes
//! over the window.

use crate::stack::StackConfig;

pub(crate) const MAX_VOXELS: usize = 6;
/// Distinct voxels whose accumulators a column holds in its own [`Accs`] (one cache line).
pub(crate) const FAST_ACC: usize = 3;
/// Distinct voxels one column can accumulate in one frame (64 cm of 2 cm voxels within one
/// cell): beyond [`FAST_ACC`] its accumulators move to its band's spill pool, so that a
/// column measured over many voxels (a vertical surface) keeps every measurement; beyond
/// this, measurements are dropped and counted (`UpdateStats::points_overflow`).
pub(crate) const MAX_ACC: usize = 32;

/// The accumulators of a column that spilled out of its [`Accs`], in a band's pool.
pub(crate) type Spilled = [Acc; MAX_ACC];

/// One voxel of a column: its index (height band `[idx, idx + 1) * voxel_height`), height
/// filter state (m, m²) and the frame that last updated it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Voxel {
    pub(crate) idx: i32,
    pub(crate) h: f32,
    pub(crate) var: f32,
    pub(crate) last_frame: u32,
}

/// The frame's measurements of one voxel, combined: sum of weights `1/var` (1/m²) and of
/// weighted heights above the voxel's bottom (m/m²).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Acc {
    pub(crate) idx: i32,
    pub(crate) sw: f32,
    pub(crate) swh: f32,
    /// Sum of the measurements' centralities in the cell (see
    /// [`crate::input::CellPoint::centrality`]).
    pub(crate) sc: f32,
    /// How many of the measurements come from smooth pixels (see
    /// [`crate::input::CellPoint::smooth`]; saturating).
    pub(crate) smooth: u16,
    /// How many are measurements of a surface's height, not a steep face's points (see
    /// [`crate::input::CellPoint::face`]; saturating).
    pub(crate) surface: u16,
}

/// The voxel stack of a column (kept apart from [`Cell`] so that the passes over the
/// window touch little memory).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Stack {
    pub(crate) voxels: [Voxel; MAX_VOXELS],
}

/// This frame's accumulators of a column (a compact array of their own, one cache line: the
/// per-point pass touches only these and the cells): the first [`FAST_ACC`] distinct voxels,
/// in the order they were measured, or, once more were measured, the index of the column's
/// [`Spilled`] accumulators in its band's pool (which then hold all of them).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[repr(align(64))]
pub(crate) struct Accs {
    fast: [Acc; FAST_ACC],
    spill: u32,
}

impl Accs {
    /// The first `n` accumulators (`n` = the column's distinct voxels this frame).
    pub(crate) fn in_use<'a>(&'a self, n: usize, pool: &'a [Spilled]) -> &'a [Acc] {
        if n <= FAST_ACC {
            self.fast.get(..n).unwrap_or(&[])
        } else {
            pool.get(self.spill as usize)
                .and_then(|s| s.get(..n))
                .unwrap_or(&[])
        }
    }

    /// As [`Accs::in_use`], to update them.
    fn in_use_mut<'a>(&'a mut self, n: usize, pool: &'a mut [Spilled]) -> &'a mut [Acc] {
        if n <= FAST_ACC {
            self.fast.get_mut(..n).unwrap_or(&mut [])
        } else {
            pool.get_mut(self.spill as usize)
                .and_then(|s| s.get_mut(..n))
                .unwrap_or(&mut [])
        }
    }
}

// Three accumulators and the pool index fill one 64-byte line exactly.
const _: () = assert!(std::mem::size_of::<Accs>() == 64);

/// A column of the map.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Cell {
    /// Cell filter state (valid once `has_estimate`): height (m) and variance (m²).
    pub(crate) h: f32,
    pub(crate) var: f32,
    /// Frames that updated the column.
    pub(crate) updates: u32,
    /// Frame number (1-based) of the last update; 0 = never.
    pub(crate) last_frame: u32,
    pub(crate) vitality: u8,
    pub(crate) n_voxels: u8,
    pub(crate) n_acc: u8,
    pub(crate) has_estimate: bool,
    pub(crate) established: bool,
    /// On its band's list of columns whose vitality still decays.
    pub(crate) pending: bool,
    /// The estimate rests on steep faces' points alone (a bound from below): the first
    /// measurement of a surface replaces it.
    pub(crate) bound_only: bool,
}

impl Cell {
    /// True when the column is part of the map.
    pub(crate) fn mapped(&self) -> bool {
        self.established && self.has_estimate
    }

    /// True when the column's height goes into the exported map: it is mapped and a
    /// surface measured it. A column known from steep faces' points alone holds a lower
    /// bound of its top, not a height, and stays out (unknown) until a surface is seen.
    pub(crate) fn exported(&self) -> bool {
        self.mapped() && !self.bound_only
    }

    /// Adds a measurement (height `z_rel` m above the voxel's bottom, weight `w` =
    /// 1/variance) to this frame's accumulator of voxel `idx`, spilling the column's
    /// accumulators into `pool` when it gets more than [`FAST_ACC`] distinct voxels. False
    /// when it already has [`MAX_ACC`] (the measurement is dropped).
    #[inline]
    pub(crate) fn accumulate(
        &mut self,
        acc: &mut Accs,
        pool: &mut Vec<Spilled>,
        idx: i32,
        z_rel: f32,
        w: f32,
        (centrality, smooth, face): (f32, bool, bool),
    ) -> bool {
        let add = |a: &mut Acc| {
            a.sw += w;
            a.swh += w * z_rel;
            a.sc += centrality;
            a.smooth = a.smooth.saturating_add(u16::from(smooth));
            a.surface = a.surface.saturating_add(u16::from(!face));
        };
        let n = usize::from(self.n_acc);
        if let Some(a) = acc.in_use_mut(n, pool).iter_mut().find(|a| a.idx == idx) {
            add(a);
            return true;
        }
        let slot = if n < FAST_ACC {
            acc.fast.get_mut(n)
        } else if n == FAST_ACC {
            // Spill: the column's accumulators move to the pool, in the same order.
            let mut spilled = [Acc::default(); MAX_ACC];
            for (s, a) in spilled.iter_mut().zip(&acc.fast) {
                *s = *a;
            }
            acc.spill = pool.len() as u32;
            pool.push(spilled);
            pool.last_mut().and_then(|s| s.get_mut(n))
        } else {
            pool.get_mut(acc.spill as usize).and_then(|s| s.get_mut(n))
        };
        match slot {
            Some(a) => {
                *a = Acc {
                    idx,
                    sw: w,
                    swh: w * z_rel,
                    sc: centrality,
                    smooth: u16::from(smooth),
                    surface: u16::from(!face),
                };
                self.n_acc += 1;
                true
            }
            None => false,
        }
    }

    /// Applies the frame's accumulated measurements: voxel filters (eq. 1), vitality, and
    /// the cell filter (eq. 2) fed by the highest voxel updated now.
    pub(crate) fn apply(
        &mut self,
        st: &mut Stack,
        acc: &[Acc],
        frame_no: u32,
        voxel_h: f32,
        cfg: &StackConfig,
    ) {
        let mut highest: Option<(f32, f32, i32, u16, u16)> = None;
        let accs = acc.iter();
        // The voxels that may feed the cell filter: those with enough of the column's
        // central support, or else the best supported one.
        let support: f32 = accs.clone().map(|a| a.sc).sum();
        let best = accs.clone().map(|a| a.sc).fold(0.0, f32::max);
        let need = (cfg.step_support_fraction * support).min(best);
        for a in accs {
            let bottom = a.idx as f32 * voxel_h;
            let (hm, vm) = (bottom + a.swh / a.sw, 1.0 / a.sw);
            let n = usize::from(self.n_voxels);
            let slot = match st.voxels.iter().take(n).position(|v| v.idx == a.idx) {
                Some(s) => s,
                None => {
                    // A new voxel starts from no prior: its first measurement is its
                    // estimate (a prior at the voxel's centre would pull a sparsely seen
                    // surface towards the voxel grid, by 18 % of its offset after four
                    // 5 mm points); a full stack gives up its least recently updated voxel.
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
                            h: hm,
                            var: vm,
                            last_frame: frame_no,
                        };
                    }
                    s
                }
            };
            if let Some(v) = st.voxels.get_mut(slot) {
                if v.last_frame != frame_no {
                    // Eq. 1 (a voxel created now already holds this frame's measurement).
                    let k = v.var / (v.var + vm);
                    v.h -= k * (v.h - hm);
                    v.var *= 1.0 - k;
                    v.last_frame = frame_no;
                }
                if a.sc >= need && highest.is_none_or(|(_, _, i, _, _)| a.idx > i) {
                    highest = Some((v.h, v.var, a.idx, a.smooth, a.surface));
                }
            }
        }
        self.n_acc = 0;
        let Some((hp, vp, _, smooth, surface)) = highest else {
            return;
        };
        self.updates += 1;
        self.last_frame = frame_no;
        if !self.established {
            // A measurement from a smooth depth patch cannot be a flying pixel: the column
            // needs no repeated sightings to be believed.
            self.vitality = if cfg.establish_smooth && smooth > 0 {
                cfg.vitality_threshold.saturating_add(1)
            } else {
                self.vitality.saturating_add(cfg.vitality_increase)
            };
            if self.vitality > cfg.vitality_threshold {
                self.established = true;
            }
        }
        if !self.established {
            return;
        }
        // A voxel of steep faces' points alone bounds the column's top from below: below
        // an estimate of the top it says nothing, and an estimate of such bounds gives way
        // to the first surface measured.
        let bound = surface == 0;
        if !self.has_estimate || (self.bound_only && !bound) {
            // No prior (or only bounds): this measurement is the estimate.
            self.h = hp;
            self.var = vp;
            self.has_estimate = true;
            self.bound_only = bound;
            return;
        }
        if bound && !self.bound_only && hp <= self.h {
            return;
        }
        // Eq. 2.
        let k = self.var / (self.var + vp);
        self.h -= k * (self.h - hp);
        self.var *= 1.0 - k;
    }

    /// Removes the voxels above `z` (m) that were not measured in frame `frame_no` and
    /// lowers the column's height to its highest remaining voxel when that is lower (an
    /// empty column is forgotten). Returns whether the column changed.
    pub(crate) fn cut_above(&mut self, st: &mut Stack, z: f32, frame_no: u32) -> bool {
        if self.h <= z {
            return false;
        }
        let n = usize::from(self.n_voxels);
        let mut kept = [Voxel::default(); MAX_VOXELS];
        let mut m = 0;
        for v in st.voxels.iter().take(n) {
            if v.h <= z || v.last_frame == frame_no {
                if let Some(slot) = kept.get_mut(m) {
                    *slot = *v;
                    m += 1;
                }
            }
        }
        let removed = m < n;
        st.voxels = kept;
        self.n_voxels = m as u8;
        match st.voxels.iter().take(m).max_by_key(|v| v.idx).copied() {
            Some(top) if top.h < self.h => {
                self.h = top.h;
                self.var = top.var;
                true
            }
            Some(_) => removed,
            None => {
                *self = Cell::default();
                true
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A column measured over more voxels than its own accumulators hold keeps every
    /// measurement: the voxel measured last but most (a floor after a wall's face, in pixel
    /// order) still feeds the cell filter. Three single points on a wall's face at voxels
    /// 10-12 come first, then six on the floor at voxel 2.
    #[test]
    fn a_column_measured_over_many_voxels_keeps_every_measurement() {
        let cfg = StackConfig::default();
        let voxel_h = cfg.voxel_height_m as f32;
        let (mut c, mut st, mut acc, mut pool): (Cell, Stack, Accs, Vec<Spilled>) =
            Default::default();
        let mut add = |idx: i32| {
            c.accumulate(
                &mut acc,
                &mut pool,
                idx,
                0.5 * voxel_h,
                1e4,
                (1.0, true, false),
            )
        };
        for idx in [10, 11, 12] {
            assert!(add(idx));
        }
        for _ in 0..6 {
            assert!(add(2));
        }
        assert_eq!((usize::from(c.n_acc), pool.len()), (4, 1));
        let held = acc.in_use(usize::from(c.n_acc), &pool);
        assert_eq!(
            held.iter().map(|a| a.idx).collect::<Vec<_>>(),
            [10, 11, 12, 2]
        );
        c.apply(&mut st, held, 1, voxel_h, &cfg);
        assert!(c.mapped());
        assert!((c.h - 2.5 * voxel_h).abs() < 1e-6, "fed {} m", c.h);
        // Up to MAX_ACC distinct voxels a frame, then measurements are refused.
        let mut c = Cell::default();
        let (mut acc, mut pool) = (Accs::default(), Vec::new());
        for idx in 0..MAX_ACC as i32 {
            assert!(c.accumulate(&mut acc, &mut pool, idx, 0.0, 1.0, (1.0, false, false)));
        }
        assert!(!c.accumulate(&mut acc, &mut pool, -1, 0.0, 1.0, (1.0, false, false)));
        assert!(c.accumulate(&mut acc, &mut pool, 3, 0.0, 1.0, (1.0, false, false)));
    }

    /// A steep face's points bound a column's top from below: alone they make its
    /// estimate (kept out of the exported map), the first surface replaces it, and below a
    /// surface's estimate they change nothing, while above it they count.
    #[test]
    fn a_steep_face_bounds_the_top_from_below() {
        let cfg = StackConfig::default();
        let voxel_h = cfg.voxel_height_m as f32;
        let (mut c, mut st, mut acc, mut pool): (Cell, Stack, Accs, Vec<Spilled>) =
            Default::default();
        // One frame: four points in the middle of voxel `idx`, a face's or not.
        let mut frame = |c: &mut Cell, no: u32, idx: i32, face: bool| {
            for _ in 0..4 {
                let centrality = if face { 0.0 } else { 1.0 };
                c.accumulate(
                    &mut acc,
                    &mut pool,
                    idx,
                    0.5 * voxel_h,
                    1e4,
                    (centrality, true, face),
                );
            }
            let held = acc.in_use(usize::from(c.n_acc), &pool);
            c.apply(&mut st, held, no, voxel_h, &cfg);
        };
        let mid = |idx: i32| (idx as f32 + 0.5) * voxel_h;
        frame(&mut c, 1, 5, true);
        assert!(c.mapped() && c.bound_only);
        assert!((c.h - mid(5)).abs() < 1e-6);
        // A bound alone is no height: the column stays out of the exported map.
        assert!(!c.exported());
        // The top, seen: it replaces the bound.
        frame(&mut c, 2, 8, false);
        assert!(!c.bound_only && c.exported());
        assert!((c.h - mid(8)).abs() < 1e-6, "{}", c.h);
        // A face below it: nothing changes.
        frame(&mut c, 3, 6, true);
        assert!((c.h - mid(8)).abs() < 1e-6, "{}", c.h);
        // A face above it: the top is higher than estimated.
        frame(&mut c, 4, 10, true);
        assert!(c.h > mid(8) + 0.5 * voxel_h && !c.bound_only, "{}", c.h);
    }
}
