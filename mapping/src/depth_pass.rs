//! The vectorised pass of the mappers' input stage over a depth image: rows of pixels turned
//! into map-frame cells, heights and variances in f32 by short loops without branches, then
//! scattered into the band lists of [`crate::binned::Binned`].

use crate::binned::{Binning, CellPoint, DepthSlice, FACE, VAR_MAX_M2, VAR_MIN_M2};
use crate::input::{HeightModel, Reason, Rejections, VarianceConsts};
use crate::neighbourhood::Neighbourhood;
use crate::window::centrality;

/// A steep face's point ([`CellPoint::face`]) says little about the top of the cell it
/// lands in: its height variance is this many times its sensor variance, so that in a voxel
/// shared with a surface's points the surface decides the voxel's height.
const FACE_VARIANCE_SCALE: f32 = 100.0;

/// Per-pixel flags of [`FlatRow`].
const VALID: u32 = 1;
const INSIDE: u32 = 2;
const MAYBE_EDGE: u32 = 4;
/// No depth jump in the pixel's neighbourhood ([`CellPoint::smooth`]).
const SMOOTH: u32 = 8;
/// A return is missing within two pixels and a depth within one lies beyond the pixel's
/// by more than the edge filter's slope term: the sliver test applies
/// (`DepthSlice::is_sliver`, whose farther neighbour lies beyond by more than that).
const MAYBE_SLIVER: u32 = 16;
/// The smoothness test allows the depths of the neighbourhood to span this many times the
/// edge filter's one-pixel jump (`d / (f tan min_grazing)`), plus its noise allowance: over
/// the 4 px across the neighbourhood, a surface seen at about 21 deg or more from the
/// default 8 deg grazing limit (tan 21 deg = tan 8 deg x 4 / 1.5).
const SMOOTH_SPAN: f32 = 1.5;

/// One row of a depth image after the vectorised passes of [`bin_depth_slice`]: per pixel
/// the ray, the height (m), its variance (m²), the cell, and flags.
#[derive(Debug, Clone, Default)]
struct FlatRow {
    xn: Vec<f32>,
    yn: Vec<f32>,
    z: Vec<f32>,
    var: Vec<f32>,
    /// Window-relative cell row and column (fractional) of the point.
    row: Vec<f32>,
    col: Vec<f32>,
    /// Storage index and band of the cell, as floats holding integers (converted in the
    /// scalar pass: a saturating float-to-int cast stops the vectorisation).
    cell: Vec<f32>,
    band: Vec<f32>,
    /// [`CellPoint::centrality`].
    centrality: Vec<f32>,
    flags: Vec<u32>,
}

/// One slice's buffers for [`bin_depth_slice`], kept from frame to frame (in
/// [`crate::binned::Binned`]) so that a frame allocates nothing: the row's rays, its pixels'
/// neighbourhoods, its passes' values and the kept pixels' indices.
#[derive(Debug, Clone, Default)]
pub(crate) struct SliceScratch {
    rays: Vec<(f64, f64)>,
    nb: Neighbourhood,
    row: FlatRow,
    kept: Vec<u32>,
}

impl SliceScratch {
    /// Bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        let f = std::mem::size_of::<f32>();
        let r = &self.row;
        self.rays.capacity() * std::mem::size_of::<(f64, f64)>()
            + self.nb.memory_bytes()
            + [
                &r.xn,
                &r.yn,
                &r.z,
                &r.var,
                &r.row,
                &r.col,
                &r.cell,
                &r.band,
                &r.centrality,
            ]
            .iter()
            .map(|v| v.capacity() * f)
            .sum::<usize>()
            + (r.flags.capacity() + self.kept.capacity()) * std::mem::size_of::<u32>()
    }
}

/// `binned::depth_slice` straight into band lists, in f32: the window's corner is subtracted
/// from the sensor position once per frame, so map coordinates within the window keep
/// sub-micrometre precision. Each row goes through short passes without branches
/// (back-projection and transform; variance; range and edge bounds and the cell; the place
/// in the cell), which the compiler vectorises with 4-wide f32 lanes (one long pass it
/// vectorised only 2 wide), then a scalar pass scatters the valid points into their bands.
/// The few pixels near a depth jump get the edge filter's exact test in f64, and dropped
/// pixels are classified by the f64 path, so reasons and counts stay those of
/// `binned::depth_slice`.
///
/// `CENTRALITY` (a constant, so that a mapper that does not use it pays nothing): whether
/// each point records where in its cell it lies.
///
/// Runs the copy for this CPU's instruction set ([`crate::simd`]; the same results).
pub(crate) fn bin_depth_slice<M: HeightModel + ?Sized, const CENTRALITY: bool>(
    s: DepthSlice<'_, M>,
    binning: Binning<'_>,
    (lists, rej): (&mut [Vec<CellPoint>], &mut Rejections),
    scratch: &mut SliceScratch,
) {
    crate::simd::dispatch(BinSlice::<M, CENTRALITY> {
        s,
        binning,
        lists,
        rej,
        scratch,
    });
}

/// The arguments of [`bin_depth_slice`], for [`crate::simd::dispatch`].
struct BinSlice<'a, 'b, M: ?Sized, const CENTRALITY: bool> {
    s: DepthSlice<'a, M>,
    binning: Binning<'b>,
    lists: &'b mut [Vec<CellPoint>],
    rej: &'b mut Rejections,
    scratch: &'b mut SliceScratch,
}

impl<M: HeightModel + ?Sized, const CENTRALITY: bool> pulp::WithSimd
    for BinSlice<'_, '_, M, CENTRALITY>
{
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        bin_depth_slice_body::<M, CENTRALITY>(
            self.s,
            self.binning,
            (self.lists, self.rej),
            self.scratch,
        );
    }
}

/// The body of [`bin_depth_slice`], inlined into each instruction set's copy.
#[inline(always)]
fn bin_depth_slice_body<M: HeightModel + ?Sized, const CENTRALITY: bool>(
    s: DepthSlice<'_, M>,
    binning: Binning<'_>,
    (lists, rej): (&mut [Vec<CellPoint>], &mut Rejections),
    scratch: &mut SliceScratch,
) {
    let pl = s.place;
    let (binner, smooth) = (binning.binner, binning.smooth);
    let (x0, y0) = binner.corner_m();
    // Row-major entries of the map-from-sensor rotation.
    let m = pl.rot.cast::<f32>();
    let [r00, r01, r02, r10, r11, r12, r20, r21, r22] = [
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
    ];
    let (tx, ty, tz) = (
        (pl.trans.x - x0) as f32,
        (pl.trans.y - y0) as f32,
        pl.trans.z as f32,
    );
    let (lo, hi) = (pl.range.0 as f32, pl.range.1 as f32);
    let inv_cell = binner.cells_per_m() as f32;
    let nf = binner.side() as f32;
    let consts = VarianceConsts {
        r3: [pl.r3.x as f32, pl.r3.y as f32, pl.r3.z as f32],
        inv_fx: (1.0 / s.camera.fx()) as f32,
        inv_fy: (1.0 / s.camera.fy()) as f32,
        model: s.model.f32_consts(),
    };
    let f_px = s.camera.fx();
    let edge_slope = s
        .edge
        .map_or(f32::INFINITY, |e| e.threshold_m(1.0, f_px, 0.0) as f32);
    // The edge filter's noise allowance per metre of depth standard deviation.
    let edge_noise = s.edge.map_or(0.0, |e| e.threshold_m(0.0, f_px, 1.0) as f32);
    let SliceScratch {
        rays,
        nb,
        row: r,
        kept,
    } = scratch;
    for v in s.rows.clone() {
        let Some(drow) = s.row_inputs(v, rays, nb, smooth) else {
            continue;
        };
        // Buffers sized once per slice; every entry up to `n` is written below.
        let len = drow.len();
        for buf in [
            &mut r.xn,
            &mut r.yn,
            &mut r.z,
            &mut r.var,
            &mut r.row,
            &mut r.col,
            &mut r.cell,
            &mut r.band,
            &mut r.centrality,
        ] {
            buf.resize(len, 0.0);
        }
        r.flags.resize(len, 0);
        let n = len
            .min(rays.len())
            .min(nb.near1.len())
            .min(nb.near2.len())
            .min(nb.span2.len())
            .min(nb.hole2.len())
            .min(nb.far1.len());
        for ((x, y), &(rx, ry)) in r.xn.iter_mut().zip(r.yn.iter_mut()).zip(rays.iter()) {
            (*x, *y) = (rx as f32, ry as f32);
        }
        // The vectorised pass: every slice has length `n`, so the bounds checks go.
        let (xs, ys) = (&r.xn[..n], &r.yn[..n]);
        let (near1, near2, spans) = (&nb.near1[..n], &nb.near2[..n], &nb.span2[..n]);
        let (holes, far1) = (&nb.hole2[..n], &nb.far1[..n]);
        let (zs, vars, rows, cols, flags) = (
            &mut r.z[..n],
            &mut r.var[..n],
            &mut r.row[..n],
            &mut r.col[..n],
            &mut r.flags[..n],
        );
        let (cells, bands, cens) = (&mut r.cell[..n], &mut r.band[..n], &mut r.centrality[..n]);
        let d_row = &drow[..n];
        // Short loops rather than one: with fewer live values each, the compiler
        // vectorises them 4 wide instead of 2.
        for i in 0..n {
            let (d, xn, yn) = (d_row[i], xs[i], ys[i]);
            let (px, py) = (xn * d, yn * d);
            zs[i] = r20 * px + r21 * py + r22 * d + tz;
            cols[i] = (r00 * px + r01 * py + r02 * d + tx) * inv_cell;
            rows[i] = (r10 * px + r11 * py + r12 * d + ty) * inv_cell;
        }
        for i in 0..n {
            vars[i] = M::pixel_variance_f32(&consts, xs[i], ys[i], d_row[i]);
        }
        for i in 0..n {
            let (d, var) = (d_row[i], vars[i]);
            let (cf, rf) = (cols[i], rows[i]);
            let valid = (d >= lo) & (d <= hi) & (var > 0.0) & (var < f32::INFINITY);
            let inside = (cf >= 0.0) & (cf < nf) & (rf >= 0.0) & (rf < nf);
            let maybe_edge =
                (d - near1[i] > edge_slope * d) | (d - near2[i] > 2.0 * edge_slope * d);
            (cells[i], bands[i]) = binner.storage_f32(rf, cf);
            flags[i] = u32::from(valid) * VALID
                + u32::from(inside) * INSIDE
                + u32::from(maybe_edge) * MAYBE_EDGE;
        }
        for i in 0..n {
            let d = d_row[i];
            let maybe_sliver = (holes[i] > 0.0) & (far1[i] - d > edge_slope * d);
            flags[i] |= u32::from(maybe_sliver) * MAYBE_SLIVER;
        }
        // Without an edge filter there is no bound (and the allowance would be infinite).
        if smooth && s.edge.is_some() {
            for i in 0..n {
                // The span allowed across the neighbourhood: from the edge filter's bound.
                let d = d_row[i];
                let ok = spans[i]
                    <= SMOOTH_SPAN * edge_slope * d
                        + edge_noise * M::depth_sigma_f32(&consts.model, d);
                flags[i] |= u32::from(ok) * SMOOTH;
            }
        }
        if CENTRALITY {
            for i in 0..n {
                cens[i] = centrality(cols[i], rows[i]);
            }
        }
        let w = s.depth.width() as usize;
        let faces = binning.faces.and_then(|m| m.get(v * w..(v + 1) * w));
        // The scalar pass: the rare invalid, outside and edge pixels are classified and
        // counted, and the indices of the kept pixels collected (a loop with few live
        // values; the scatter below then reads the kept pixels' values by index).
        kept.clear();
        for (u, (&f, (&d, (&n1, &n2)))) in r.flags[..n]
            .iter()
            .zip(drow.iter().zip(near1.iter().zip(near2)))
            .enumerate()
        {
            let f = f & !SMOOTH;
            let keep = if f == VALID | INSIDE {
                // The common case: valid, in the window, away from depth jumps and holes.
                true
            } else if f & VALID == 0 {
                let ray = rays.get(u).copied().unwrap_or((f64::NAN, f64::NAN));
                rej.count(
                    pl.pixel(s.model, s.camera, u, v, ray, d)
                        .err()
                        .unwrap_or(Reason::BadVariance),
                );
                false
            } else if (f & MAYBE_EDGE != 0 && s.is_edge(f64::from(d), n1, n2))
                || (f & MAYBE_SLIVER != 0 && s.is_sliver(u, v, f64::from(d)))
            {
                rej.depth_edge += 1;
                false
            } else if f & INSIDE == 0 {
                rej.outside_window += 1;
                false
            } else {
                true
            };
            if keep {
                kept.push(u as u32);
            }
        }
        // The band being filled is moved out of `lists` while consecutive pixels land in
        // it: pushed to through a local, its length and capacity stay in registers instead
        // of being reloaded from `lists` at every point.
        let mut current: (Option<usize>, Vec<CellPoint>) = (None, Vec::new());
        for &u in kept.iter() {
            let u = u as usize;
            let (Some(&band), Some(&cell), Some(&z), Some(&var)) =
                (bands.get(u), cells.get(u), zs.get(u), vars.get(u))
            else {
                continue;
            };
            let face = faces.and_then(|f| f.get(u)).is_some_and(|&f| f != 0);
            let (centrality, var) = if face {
                (FACE, var * FACE_VARIANCE_SCALE)
            } else if CENTRALITY {
                (cens.get(u).copied().unwrap_or(0.0), var)
            } else {
                (0.0, var)
            };
            let smooth_px = r.flags.get(u).is_some_and(|&f| f & SMOOTH != 0);
            let band = band as usize;
            if current.0 != Some(band) {
                swap_band(lists, &mut current);
                current.0 = Some(band).filter(|&b| b < lists.len());
                if current.0.is_none() {
                    rej.outside_window += 1;
                    continue;
                }
                swap_band(lists, &mut current);
            }
            current.1.push(CellPoint::new(
                cell as u32,
                centrality,
                smooth_px,
                z,
                var.clamp(VAR_MIN_M2, VAR_MAX_M2),
            ));
        }
        swap_band(lists, &mut current);
    }
}

/// Swaps the list held in `current` with band `current.0`'s slot in `lists` (nothing when
/// there is no such band): moves a band's list out to be filled, or back once filled.
#[inline]
fn swap_band(lists: &mut [Vec<CellPoint>], current: &mut (Option<usize>, Vec<CellPoint>)) {
    if let Some(list) = current.0.and_then(|b| lists.get_mut(b)) {
        std::mem::swap(list, &mut current.1);
    }
}
