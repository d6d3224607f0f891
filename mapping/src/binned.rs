//! The mappers' input stage: a frame's measurements turned into map-frame heights with
//! variances and binned by band of window cells, in parallel over fixed slices (so results
//! never depend on the thread count).

use crate::input::{
    depth_slice, Cloud, DepthSlice, EdgeFilter, HeightModel, HeightSample, Placement, RayCache,
    Reason, Rejections, SensorFrame,
};
use rayon::prelude::*;

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
    /// The measurements of band `b`, in measurement order (pixel order for depth images).
    pub fn band(&self, b: usize) -> impl Iterator<Item = &CellPoint> + '_ {
        self.lists
            .iter()
            .flat_map(move |slice| slice.get(b).into_iter().flatten())
    }
}

/// Transforms a frame's measurements into map-frame heights with height variances and
/// assigns each to its cell: `locate(x, y)` gives the storage index of the cell containing
/// map-frame `(x, y)` (m) and its band (below `bands`), or `None` outside the window (see
/// [`crate::window::Window::band_indexer`]). Runs in parallel over [`SLICES`] slices of the input;
/// within a band the measurements keep their input order. Invalid measurements are
/// dropped and counted by reason (including `outside_window`).
pub fn prepare_binned<M: HeightModel, L: Fn(f64, f64) -> Option<(usize, usize)> + Sync>(
    frame: &SensorFrame<'_>,
    model: &M,
    rays: &mut RayCache,
    locate: L,
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
        Ok(p) => match locate(p.x, p.y) {
            Some((cell, band)) => {
                if let Some(list) = lists.get_mut(band) {
                    list.push(CellPoint {
                        cell: cell as u32,
                        z_m: p.z as f32,
                        // Kept where f32 arithmetic stays finite (1e-5 mm to 100 km).
                        var_m2: (p.var as f32).clamp(VAR_MIN_M2, VAR_MAX_M2),
                    });
                } else {
                    rej.outside_window += 1;
                }
            }
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
                    depth_slice(
                        DepthSlice {
                            depth: depth_m,
                            camera,
                            rays,
                            rows,
                            edge,
                            place: &place,
                            model,
                        },
                        |res| push(res, lists, rej),
                    );
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
