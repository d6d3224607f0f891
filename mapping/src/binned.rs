//! The mappers' input stage: a frame's measurements turned into map-frame heights with
//! variances and binned by band of window cells, in parallel over fixed slices (so results
//! never depend on the thread count). Depth images go through [`depth_slice`], a
//! vectorisable pass over rows of pixels.

use crate::input::{
    Cloud, DepthPixel, EdgeFilter, HeightModel, HeightSample, Placement, RayCache, Rays, Reason,
    Rejections, SensorFrame, VarianceConsts,
};
use crate::window::CellBinner;
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// A measurement assigned to a cell of a map window: the cell's storage index, the height
/// (m, map frame) and its variance (m²).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CellPoint {
    /// Storage index of the cell in the window.
    pub cell: u32,
    /// Height (m, map frame, up).
    pub z_m: f32,
    /// Height variance (m²).
    pub var_m2: f32,
}

/// Smallest height variance handed to a mapper (m²); smaller ones are raised to it.
pub const VAR_MIN_M2: f32 = 1e-10;
/// Largest height variance handed to a mapper (m²); larger ones are lowered to it.
pub const VAR_MAX_M2: f32 = 1e10;

/// Measurements are prepared in this many slices of the input (rows of a depth image), a
/// number that does not depend on the thread count so that results never do.
pub const SLICES: usize = 16;

/// One frame's measurements, grouped by band of storage cells (see [`prepare_binned`]).
#[derive(Debug, Clone, Default)]
pub struct Binned {
    /// `[slice][band]`, each list in measurement order.
    lists: Vec<Vec<Vec<CellPoint>>>,
    rejections: Vec<Rejections>,
}

impl Binned {
    /// Bytes held by the lists.
    pub fn memory_bytes(&self) -> usize {
        self.lists
            .iter()
            .flatten()
            .map(|l| l.capacity() * std::mem::size_of::<CellPoint>())
            .sum()
    }

    /// The measurements of band `b`, in measurement order (pixel order for depth images).
    pub fn band(&self, b: usize) -> impl Iterator<Item = &CellPoint> + '_ {
        self.lists
            .iter()
            .flat_map(move |slice| slice.get(b).into_iter().flatten())
    }
}

/// Transforms a frame's measurements into map-frame heights with height variances and
/// assigns each to its cell: `binner` gives the storage index of the cell containing
/// map-frame `(x, y)` (m) and its band (below `bands`), or none outside the window (see
/// [`crate::window::Window::binner`]). Runs in parallel over [`SLICES`] slices of the input;
/// within a band the measurements keep their input order. Invalid measurements are
/// dropped and counted by reason (including `outside_window`).
pub fn prepare_binned<M: HeightModel>(
    frame: &SensorFrame<'_>,
    model: &M,
    rays: &mut RayCache,
    binner: &CellBinner,
    bands: usize,
    edge: Option<&EdgeFilter>,
    out: &mut Binned,
) -> Rejections {
    let t = frame.map_from_sensor;
    out.lists.resize_with(SLICES, Vec::new);
    out.rejections.clear();
    out.rejections.resize(SLICES, Rejections::default());
    for slice in &mut out.lists {
        slice.resize_with(bands, Vec::new);
        slice.iter_mut().for_each(Vec::clear);
    }
    if !frame.pose_is_finite() {
        return Rejections {
            bad_pose: frame.len(),
            ..Default::default()
        };
    }
    let place = Placement::new(&t, model.range_m());
    let push = |res: Result<HeightSample, Reason>,
                lists: &mut Vec<Vec<CellPoint>>,
                rej: &mut Rejections| match res {
        Ok(p) => match binner.locate(p.x, p.y) {
            Some((cell, band)) => bin(lists, rej, cell as u32, band, p.z, p.var),
            None => rej.outside_window += 1,
        },
        Err(r) => rej.count(r),
    };
    match frame.cloud() {
        Cloud::Depth { depth_m, camera } => {
            let h = depth_m.height() as usize;
            let rays = rays.rays(camera);
            let rows_per_slice = h.div_ceil(SLICES).max(1);
            out.lists
                .par_iter_mut()
                .zip(out.rejections.par_iter_mut())
                .enumerate()
                .for_each(|(s, (lists, rej))| {
                    let rows = (s * rows_per_slice)..((s + 1) * rows_per_slice).min(h);
                    let slice = DepthSlice {
                        depth: depth_m,
                        camera,
                        rays,
                        rows,
                        edge,
                        place: &place,
                        model,
                    };
                    bin_depth_slice(slice, binner, lists, rej);
                });
        }
        Cloud::Points {
            points,
            covariances,
        } => {
            let per_slice = points.len().div_ceil(SLICES).max(1);
            out.lists
                .par_iter_mut()
                .zip(out.rejections.par_iter_mut())
                .enumerate()
                .for_each(|(s, (lists, rej))| {
                    for i in (s * per_slice)..((s + 1) * per_slice).min(points.len()) {
                        let res = match points.get(i) {
                            Some(p) => place.point(model, p, covariances.get(i)),
                            None => Err(Reason::NonFinite),
                        };
                        push(res, lists, rej);
                    }
                });
        }
    }
    let mut rej = Rejections::default();
    for r in &out.rejections {
        rej.add(r);
    }
    rej
}

/// A frame's measurements as map-frame points (`None` where dropped), in input order, with
/// the counts of what was dropped (`outside_window` stays 0: there is no window here).
/// For exporting clouds and for tests; the mappers use [`prepare_binned`].
pub fn to_map_points<M: HeightModel + ?Sized>(
    frame: &SensorFrame<'_>,
    model: &M,
) -> (Vec<Option<HeightSample>>, Rejections) {
    let mut rej = Rejections::default();
    let t = frame.map_from_sensor;
    if !frame.pose_is_finite() {
        rej.bad_pose = frame.len();
        return (vec![None; frame.len()], rej);
    }
    let place = Placement::new(&t, model.range_m());
    let results: Vec<Result<HeightSample, Reason>> = match frame.cloud() {
        Cloud::Depth { depth_m, camera } => {
            let w = (depth_m.width() as usize).max(1);
            let mut cache = RayCache::default();
            let rays = cache.rays(camera);
            let mut row = Vec::new();
            depth_m
                .as_slice()
                .iter()
                .enumerate()
                .map(|(i, &d)| {
                    let (u, v) = (i % w, i / w);
                    if u == 0 {
                        rays.row(v, w, &mut row);
                    }
                    place.pixel(
                        model,
                        camera,
                        u,
                        v,
                        row.get(u).copied().unwrap_or((f64::NAN, f64::NAN)),
                        d,
                    )
                })
                .collect()
        }
        Cloud::Points {
            points,
            covariances,
        } => points
            .iter()
            .enumerate()
            .map(|(i, p)| place.point(model, p, covariances.get(i)))
            .collect(),
    };
    let pts = results
        .into_iter()
        .map(|r| match r {
            Ok(p) => Some(p),
            Err(e) => {
                rej.count(e);
                None
            }
        })
        .collect();
    (pts, rej)
}

/// A frame's measurements as map-frame points after the mappers' own input filters (depth
/// range, and the depth-edge filter when given): the points a mapper bins, before its
/// window, in input order, with the counts of what was dropped. For giving another map
/// representation exactly the same clouds.
pub fn filtered_map_points<M: HeightModel + ?Sized>(
    frame: &SensorFrame<'_>,
    model: &M,
    edge: Option<&EdgeFilter>,
) -> (Vec<HeightSample>, Rejections) {
    let mut rej = Rejections::default();
    if !frame.pose_is_finite() {
        rej.bad_pose = frame.len();
        return (Vec::new(), rej);
    }
    let place = Placement::new(&frame.map_from_sensor, model.range_m());
    let mut out = Vec::new();
    let mut sink = |r: Result<HeightSample, Reason>| match r {
        Ok(p) => out.push(p),
        Err(e) => rej.count(e),
    };
    match frame.cloud() {
        Cloud::Depth { depth_m, camera } => {
            let mut cache = RayCache::default();
            depth_slice(
                DepthSlice {
                    depth: depth_m,
                    camera,
                    rays: cache.rays(camera),
                    rows: 0..depth_m.height() as usize,
                    edge,
                    place: &place,
                    model,
                },
                &mut sink,
            );
        }
        Cloud::Points {
            points,
            covariances,
        } => {
            for (i, p) in points.iter().enumerate() {
                sink(place.point(model, p, covariances.get(i)));
            }
        }
    }
    (out, rej)
}

/// Fills `out` with, for each pixel of row `v`, the smallest non-zero depth (m) of its
/// 3 x 3 neighbourhood (infinity when there is none), using `col` as scratch.
fn nearest_neighbour_row(depth: &DepthImage, v: usize, col: &mut Vec<f32>, out: &mut Vec<f32>) {
    let (w, h) = (depth.width() as usize, depth.height() as usize);
    let px = depth.as_slice();
    let row = |r: usize| px.get(r * w..(r + 1) * w).unwrap_or(&[]);
    let nz = |x: f32| if x > 0.0 { x } else { f32::INFINITY };
    let (up, mid, down) = (
        row(v.saturating_sub(1)),
        row(v),
        row((v + 1).min(h.saturating_sub(1))),
    );
    col.clear();
    col.push(f32::INFINITY);
    col.extend(
        up.iter()
            .zip(mid)
            .zip(down)
            .map(|((&a, &b), &c)| nz(a).min(nz(b)).min(nz(c))),
    );
    col.push(f32::INFINITY);
    out.clear();
    out.extend(col.windows(3).map(|t| match t {
        [a, b, c] => a.min(*b).min(*c),
        _ => f32::INFINITY,
    }));
}

/// One slice of rows of a depth image and what is needed to turn its pixels into map
/// points.
pub(crate) struct DepthSlice<'a, M: ?Sized> {
    pub(crate) depth: &'a DepthImage,
    pub(crate) camera: &'a PinholeCamera,
    pub(crate) rays: Rays<'a>,
    pub(crate) rows: std::ops::Range<usize>,
    pub(crate) edge: Option<&'a EdgeFilter>,
    pub(crate) place: &'a Placement,
    pub(crate) model: &'a M,
}

/// A pixel after the arithmetic pass of [`depth_slice`]: map-frame position (m), height
/// variance (m²) and whether it is a valid measurement.
#[derive(Debug, Clone, Copy, Default)]
struct RowPoint {
    x: f64,
    y: f64,
    z: f64,
    var: f64,
    ok: bool,
}

/// Puts a valid measurement into its band's list, or counts it as outside the window when
/// the band does not exist.
#[inline]
fn bin(
    lists: &mut [Vec<CellPoint>],
    rej: &mut Rejections,
    cell: u32,
    band: usize,
    z: f64,
    var: f64,
) {
    match lists.get_mut(band) {
        Some(list) => list.push(CellPoint {
            cell,
            z_m: z as f32,
            // Kept where f32 arithmetic stays finite (1e-5 mm to 100 km).
            var_m2: (var as f32).clamp(VAR_MIN_M2, VAR_MAX_M2),
        }),
        None => rej.outside_window += 1,
    }
}

/// Turns the pixels of a slice of rows into map points (or reasons to drop them), in
/// pixel order. Each row goes through a branch-free arithmetic pass the compiler can
/// vectorise, then a pass that hands valid points (or the reason for an invalid one) to
/// `sink`.
#[inline]
pub(crate) fn depth_slice<M: HeightModel + ?Sized, S: FnMut(Result<HeightSample, Reason>)>(
    s: DepthSlice<'_, M>,
    mut sink: S,
) {
    let w = (s.depth.width() as usize).max(1);
    let (mut scratch, mut nearest, mut pts) = (Vec::new(), Vec::new(), Vec::<RowPoint>::new());
    let f_px = s.camera.fx();
    let pl = s.place;
    let (lo, hi) = pl.range;
    let rot = pl.rot;
    let t = pl.trans;
    // The edge threshold of `EdgeFilter::threshold_m`, written out so that it vectorises
    // (no filter: an infinite threshold).
    let edge_slope = s
        .edge
        .map_or(f64::INFINITY, |e| e.threshold_m(1.0, f_px, 0.0));
    let edge_k = s.edge.map_or(0.0, |e| e.sigmas * std::f64::consts::SQRT_2);
    let is_edge = |d: f64, near: f32| {
        let gap = d - f64::from(near);
        // The cheap bound first: the noise term is only needed near a jump.
        gap > edge_slope * d && gap > edge_slope * d + edge_k * s.model.depth_sigma_m(d)
    };
    let mut rrow = Vec::new();
    for v in s.rows {
        let Some(drow) = s.depth.as_slice().get(v * w..(v + 1) * w) else {
            continue;
        };
        s.rays.row(v, w, &mut rrow);
        if s.edge.is_some() {
            nearest_neighbour_row(s.depth, v, &mut scratch, &mut nearest);
        } else {
            nearest.clear();
        }
        nearest.resize(drow.len(), f32::INFINITY);
        pts.clear();
        pts.extend(drow.iter().zip(&rrow).zip(&nearest).enumerate().map(
            |(u, ((&d, &(xn, yn)), &near))| {
                let d = f64::from(d);
                let p = nalgebra::Vector3::new(xn * d, yn * d, d);
                let q = rot * p + t;
                let var = s.model.pixel_variance(
                    s.camera,
                    &DepthPixel {
                        u: u as f64,
                        v: v as f64,
                        xn,
                        yn,
                        d_m: d,
                    },
                    &pl.r3,
                );
                let ok = d >= lo
                    && d <= hi
                    && var > 0.0
                    && var < f64::INFINITY
                    && q.x.is_finite()
                    && q.y.is_finite()
                    && !is_edge(d, near);
                RowPoint {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    var,
                    ok,
                }
            },
        ));
        for ((p, &d), &near) in pts.iter().zip(drow).zip(&nearest) {
            if p.ok {
                sink(Ok(HeightSample {
                    x: p.x,
                    y: p.y,
                    z: p.z,
                    var: p.var,
                }));
                continue;
            }
            let d = f64::from(d);
            sink(Err(if d == 0.0 {
                Reason::NoReturn
            } else if !d.is_finite() {
                Reason::NonFinite
            } else if d < lo || d > hi {
                Reason::OutOfRange
            } else if !(p.var.is_finite() && p.var > 0.0) {
                Reason::BadVariance
            } else if !(p.x.is_finite() && p.y.is_finite()) {
                Reason::NonFinite
            } else {
                debug_assert!(is_edge(d, near));
                Reason::DepthEdge
            }));
        }
    }
}

/// Per-pixel flags of [`FlatRow`].
const VALID: u32 = 1;
const INSIDE: u32 = 2;
const MAYBE_EDGE: u32 = 4;

/// One row of a depth image after the vectorised passes of [`bin_depth_slice`]: per pixel
/// the ray, the height (m), its variance (m²), the cell, and flags.
#[derive(Default)]
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
    flags: Vec<u32>,
}

/// [`depth_slice`] straight into band lists, in f32: the window's corner is subtracted
/// from the sensor position once per frame, so map coordinates within the window keep
/// sub-micrometre precision. Each row goes through three short passes without branches
/// (back-projection and transform; variance; range and edge bounds and the cell), which the
/// compiler vectorises with 4-wide f32 lanes (one long pass it vectorised only 2 wide), then
/// a scalar pass scatters the valid points into their bands. The few pixels near a depth jump get the edge filter's exact test in f64,
/// and dropped pixels are classified by the f64 path, so reasons and counts stay those of
/// [`depth_slice`].
fn bin_depth_slice<M: HeightModel + ?Sized>(
    s: DepthSlice<'_, M>,
    binner: &CellBinner,
    lists: &mut [Vec<CellPoint>],
    rej: &mut Rejections,
) {
    let w = (s.depth.width() as usize).max(1);
    let pl = s.place;
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
    };
    let f_px = s.camera.fx();
    let edge_slope = s
        .edge
        .map_or(f32::INFINITY, |e| e.threshold_m(1.0, f_px, 0.0) as f32);
    let exact_edge = |d: f64, near: f32| {
        s.edge
            .is_some_and(|e| d - f64::from(near) > e.threshold_m(d, f_px, s.model.depth_sigma_m(d)))
    };
    let (mut rays, mut scratch, mut nearest) = (Vec::new(), Vec::new(), Vec::new());
    let mut r = FlatRow::default();
    for v in s.rows.clone() {
        let Some(drow) = s.depth.as_slice().get(v * w..(v + 1) * w) else {
            continue;
        };
        s.rays.row(v, w, &mut rays);
        if s.edge.is_some() {
            nearest_neighbour_row(s.depth, v, &mut scratch, &mut nearest);
        } else {
            nearest.clear();
        }
        nearest.resize(drow.len(), f32::INFINITY);
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
        ] {
            buf.resize(len, 0.0);
        }
        r.flags.resize(len, 0);
        let n = len.min(rays.len()).min(nearest.len());
        for ((x, y), &(rx, ry)) in r.xn.iter_mut().zip(r.yn.iter_mut()).zip(&rays) {
            (*x, *y) = (rx as f32, ry as f32);
        }
        // The vectorised pass: every slice has length `n`, so the bounds checks go.
        let (xs, ys, near) = (&r.xn[..n], &r.yn[..n], &nearest[..n]);
        let (zs, vars, rows, cols, flags) = (
            &mut r.z[..n],
            &mut r.var[..n],
            &mut r.row[..n],
            &mut r.col[..n],
            &mut r.flags[..n],
        );
        let (cells, bands) = (&mut r.cell[..n], &mut r.band[..n]);
        let d_row = &drow[..n];
        // Three loops rather than one: with fewer live values each, the compiler
        // vectorises them 4 wide instead of 2.
        for i in 0..n {
            let (d, xn, yn) = (d_row[i], xs[i], ys[i]);
            let (px, py) = (xn * d, yn * d);
            zs[i] = r20 * px + r21 * py + r22 * d + tz;
            cols[i] = (r00 * px + r01 * py + r02 * d + tx) * inv_cell;
            rows[i] = (r10 * px + r11 * py + r12 * d + ty) * inv_cell;
        }
        for i in 0..n {
            vars[i] = s.model.pixel_variance_f32(&consts, xs[i], ys[i], d_row[i]);
        }
        for i in 0..n {
            let (d, var) = (d_row[i], vars[i]);
            let (cf, rf) = (cols[i], rows[i]);
            let valid = (d >= lo) & (d <= hi) & (var > 0.0) & (var < f32::INFINITY);
            let inside = (cf >= 0.0) & (cf < nf) & (rf >= 0.0) & (rf < nf);
            let maybe_edge = d - near[i] > edge_slope * d;
            (cells[i], bands[i]) = binner.storage_f32(rf, cf);
            flags[i] = u32::from(valid) * VALID
                + u32::from(inside) * INSIDE
                + u32::from(maybe_edge) * MAYBE_EDGE;
        }
        let pixels = r
            .flags
            .iter()
            .zip(drow)
            .zip(r.z.iter().zip(&r.var))
            .zip(r.cell.iter().zip(&r.band))
            .zip(&nearest)
            .take(n);
        for (u, ((((&f, &d), (&z, &var)), (&cell, &band)), &near)) in pixels.enumerate() {
            let kept = if f == VALID | INSIDE {
                // The common case: valid, in the window, away from depth jumps.
                true
            } else if f & VALID == 0 {
                let ray = rays.get(u).copied().unwrap_or((f64::NAN, f64::NAN));
                rej.count(
                    pl.pixel(s.model, s.camera, u, v, ray, d)
                        .err()
                        .unwrap_or(Reason::BadVariance),
                );
                false
            } else if f & MAYBE_EDGE != 0 && exact_edge(f64::from(d), near) {
                rej.depth_edge += 1;
                false
            } else if f & INSIDE == 0 {
                rej.outside_window += 1;
                false
            } else {
                true
            };
            if !kept {
                continue;
            }
            match lists.get_mut(band as usize) {
                Some(list) => list.push(CellPoint {
                    cell: cell as u32,
                    z_m: z,
                    var_m2: var.clamp(VAR_MIN_M2, VAR_MAX_M2),
                }),
                None => rej.outside_window += 1,
            }
        }
    }
}
