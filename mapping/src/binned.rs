//! The mappers' input stage: a frame's measurements turned into map-frame heights with
//! variances and binned by band of window cells, in parallel over fixed slices (so results
//! never depend on the thread count). Depth images go through the f32 passes of the
//! `depth_pass` module, vectorised over rows of pixels; [`filtered_map_points`] and
//! [`to_map_points`] give the same points in f64, one at a time.

pub use crate::cell_point::{CellPoint, FACE};
use crate::depth_pass::SliceScratch;
use crate::input::{
    Cloud, DepthPixel, EdgeFilter, HeightModel, HeightSample, Placement, RayCache, Rays, Reason,
    Rejections, SensorFrame,
};
use crate::neighbourhood::Neighbourhood;
use crate::window::CellBinner;
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

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
    /// Per slice: the depth pass's buffers, kept from frame to frame.
    scratch: Vec<SliceScratch>,
}

impl Binned {
    /// Bytes held by the lists and the buffers.
    pub fn memory_bytes(&self) -> usize {
        self.lists
            .iter()
            .flatten()
            .map(|l| l.capacity() * std::mem::size_of::<CellPoint>())
            .sum::<usize>()
            + self
                .scratch
                .iter()
                .map(SliceScratch::memory_bytes)
                .sum::<usize>()
    }

    /// The measurements of band `b`, in measurement order (pixel order for depth images).
    pub fn band(&self, b: usize) -> impl Iterator<Item = &CellPoint> + '_ {
        self.lists
            .iter()
            .flat_map(move |slice| slice.get(b).into_iter().flatten())
    }
}

/// How [`prepare_binned`] assigns a frame's measurements to cells and what each records.
#[derive(Debug, Clone, Copy)]
pub struct Binning<'a> {
    /// Gives the storage index of the cell containing map-frame `(x, y)` (m) and its band,
    /// or none outside the window (see [`crate::window::Window::binner`]).
    pub binner: &'a CellBinner,
    /// Each point records where in its cell it lies ([`CellPoint::centrality`], else 0:
    /// it costs about 0.3 ms per VGA frame).
    pub centrality: bool,
    /// Each point of a depth image records whether its pixel is smooth (with an edge
    /// filter; [`CellPoint::smooth`], else false).
    pub smooth: bool,
    /// Per pixel of a depth image (row-major), non-zero where the point is a steep face's,
    /// moved behind it ([`crate::steep`]; [`CellPoint::face`]). Ignored for point clouds.
    pub faces: Option<&'a [u8]>,
}

/// Transforms a frame's measurements into map-frame heights with height variances and
/// assigns each to its cell as `binning` says, its band below `bands`. Runs in parallel
/// over [`SLICES`] slices of the input; within a band the measurements keep their input
/// order. Invalid measurements are dropped and counted by reason (including
/// `outside_window`).
pub fn prepare_binned<M: HeightModel>(
    frame: &SensorFrame<'_>,
    model: &M,
    rays: &mut RayCache,
    binning: Binning<'_>,
    bands: usize,
    edge: Option<&EdgeFilter>,
    out: &mut Binned,
) -> Rejections {
    let t = frame.map_from_sensor;
    out.lists.resize_with(SLICES, Vec::new);
    out.rejections.clear();
    out.rejections.resize(SLICES, Rejections::default());
    out.scratch.resize_with(SLICES, SliceScratch::default);
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
    let Binning {
        binner, centrality, ..
    } = binning;
    let push = |res: Result<HeightSample, Reason>,
                lists: &mut Vec<Vec<CellPoint>>,
                rej: &mut Rejections| match res {
        Ok(p) => match binner.locate(p.x, p.y) {
            Some((cell, band)) => bin(
                lists,
                rej,
                (cell as u32, band),
                p.z,
                p.var,
                if centrality {
                    binner.centrality(p.x, p.y)
                } else {
                    0.0
                },
            ),
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
                .zip(out.scratch.par_iter_mut())
                .enumerate()
                .for_each(|(s, ((lists, rej), scratch))| {
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
                    let out = (&mut lists[..], rej);
                    if centrality {
                        crate::depth_pass::bin_depth_slice::<M, true>(slice, binning, out, scratch);
                    } else {
                        crate::depth_pass::bin_depth_slice::<M, false>(
                            slice, binning, out, scratch,
                        );
                    }
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

impl<'a, M: ?Sized> DepthSlice<'a, M> {
    /// Row `v`'s depths (m; `None` past the image), with its rays in `rays` and its
    /// [`Neighbourhood`] in `nb` (the span when `span` asks for it and there is an edge
    /// filter: smoothness needs the filter's notion of a jump).
    pub(crate) fn row_inputs(
        &self,
        v: usize,
        rays: &mut Vec<(f64, f64)>,
        nb: &mut Neighbourhood,
        span: bool,
    ) -> Option<&'a [f32]> {
        let w = (self.depth.width() as usize).max(1);
        let drow = self.depth.as_slice().get(v * w..(v + 1) * w)?;
        self.rays.row(v, w, rays);
        if self.edge.is_some() {
            nb.fill(self.depth, v, span);
        } else {
            nb.none(drow.len());
        }
        Some(drow)
    }

    /// The edge filter's test: true when depth `d` (m) lies farther than
    /// [`EdgeFilter::threshold_m`] beyond `near1`, the nearest depth within one pixel, or
    /// than [`EdgeFilter::threshold_apart_m`] for two pixels beyond `near2`, the nearest
    /// within two (never without a filter).
    #[inline]
    pub(crate) fn is_edge(&self, d: f64, near1: f32, near2: f32) -> bool
    where
        M: HeightModel,
    {
        let f_px = self.camera.fx();
        self.edge.is_some_and(|e| {
            // The cheap bounds first: the noise term is only needed near a jump.
            let (gap1, gap2) = (d - f64::from(near1), d - f64::from(near2));
            let jump = gap1 > e.threshold_apart_m(1.0, d, f_px, 0.0)
                || gap2 > e.threshold_apart_m(2.0, d, f_px, 0.0);
            jump && {
                let sigma = self.model.depth_sigma_m(d);
                gap1 > e.threshold_apart_m(1.0, d, f_px, sigma)
                    || gap2 > e.threshold_apart_m(2.0, d, f_px, sigma)
            }
        })
    }

    /// The edge filter's sliver test: true when pixel `(u, v)`, of depth `d` (m), has a
    /// neighbour along its row or its column farther than it by more than
    /// [`EdgeFilter::threshold_m`] and a missing return one or two pixels away on the
    /// opposite side. Such a pixel sits between a hole and a farther surface: a flying
    /// pixel beside the hole a foreground edge leaves (docs/mapping-faces.md,
    /// "Slivers beside holes"). Never without a filter.
    pub(crate) fn is_sliver(&self, u: usize, v: usize, d: f64) -> bool
    where
        M: HeightModel,
    {
        let Some(e) = self.edge else {
            return false;
        };
        let tau = e.threshold_m(d, self.camera.fx(), self.model.depth_sigma_m(d));
        let (w, h) = (self.depth.width() as i64, self.depth.height() as i64);
        let px = self.depth.as_slice();
        let at = |du: i64, dv: i64| {
            let (x, y) = (u as i64 + du, v as i64 + dv);
            (x >= 0 && y >= 0 && x < w && y < h)
                .then(|| px.get((y * w + x) as usize).copied())
                .flatten()
        };
        let returned = crate::neighbourhood::returned;
        let hole = |q: Option<f32>| q.is_some_and(|q| !returned(q));
        let farther = |q: Option<f32>| q.is_some_and(|q| returned(q) && f64::from(q) - d > tau);
        [(1, 0), (0, 1)].into_iter().any(|(du, dv)| {
            [1, -1].into_iter().any(|s: i64| {
                farther(at(s * du, s * dv))
                    && (hole(at(-s * du, -s * dv)) || hole(at(-2 * s * du, -2 * s * dv)))
            })
        })
    }
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
    (cell, band): (u32, usize),
    z: f64,
    var: f64,
    centrality: f32,
) {
    match lists.get_mut(band) {
        Some(list) => list.push(CellPoint::new(
            cell,
            centrality,
            false,
            z as f32,
            // Kept where f32 arithmetic stays finite (1e-5 mm to 100 km).
            (var as f32).clamp(VAR_MIN_M2, VAR_MAX_M2),
        )),
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
    let (mut nearest, mut pts) = (Neighbourhood::default(), Vec::<RowPoint>::new());
    let pl = s.place;
    let (lo, hi) = pl.range;
    let rot = pl.rot;
    let t = pl.trans;
    let is_edge = |d: f64, (near1, near2): (f32, f32)| s.is_edge(d, near1, near2);
    let mut rrow = Vec::new();
    for v in s.rows.clone() {
        let Some(drow) = s.row_inputs(v, &mut rrow, &mut nearest, false) else {
            continue;
        };
        let near = || {
            nearest
                .near1
                .iter()
                .copied()
                .zip(nearest.near2.iter().copied())
        };
        pts.clear();
        pts.extend(drow.iter().zip(&rrow).zip(near()).enumerate().map(
            |(u, ((&d, &(xn, yn)), near))| {
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
                    && !is_edge(d, near)
                    // The test reads the image only beside a hole, as the f32 stage does.
                    && !(nearest.hole2.get(u).is_some_and(|&h| h > 0.0) && s.is_sliver(u, v, d));
                RowPoint {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    var,
                    ok,
                }
            },
        ));
        for (u, ((p, &d), near)) in pts.iter().zip(drow).zip(near()).enumerate() {
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
                debug_assert!(is_edge(d, near) || s.is_sliver(u, v, d));
                Reason::DepthEdge
            }));
        }
    }
}
