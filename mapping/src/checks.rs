//! The two checks the stack mapper runs after each update, as small pieces: paper 000's
//! line-of-sight table (section 3.2) and the see-through test on depth images (an
//! extension; see [`crate::stack::StackConfig::see_through_check`]).

use crate::input::PrimeSenseHeight;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// A line-of-sight target of the visibility check: an updated, established cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Target {
    /// Map-frame position of the cell centre (m).
    pub(crate) x: f64,
    pub(crate) y: f64,
    pub(crate) bin: i64,
    pub(crate) radial: usize,
    /// `(h + 3 sigma - z_sensor) / distance` (rise per metre from the sensor).
    pub(crate) slope: f64,
}

/// The lowest line of sight over every (azimuth bin, radial step) from the sensor: per bin,
/// the running minimum of the targets' slopes from far to near, so that one lookup tells
/// whether anything beyond a column is seen over it.
pub(crate) struct LosTable<'a> {
    table: &'a [f32],
    bmin: i64,
    bmax: i64,
    radial: usize,
}

impl<'a> LosTable<'a> {
    /// Builds the table in `storage` (reused between frames) from this frame's targets.
    pub(crate) fn build(storage: &'a mut Vec<f32>, targets: &[Target]) -> Self {
        let bmin = targets.iter().map(|t| t.bin).min().unwrap_or(0);
        let bmax = targets.iter().map(|t| t.bin).max().unwrap_or(-1);
        let radial = targets.iter().map(|t| t.radial).max().map_or(0, |r| r + 1);
        let nb = (bmax - bmin + 1).max(0) as usize;
        storage.clear();
        storage.resize(nb * radial, f32::INFINITY);
        for t in targets {
            if let Some(v) = storage.get_mut((t.bin - bmin) as usize * radial + t.radial) {
                *v = v.min(t.slope as f32);
            }
        }
        if radial > 0 {
            storage.par_chunks_mut(radial).for_each(|row| {
                let mut run = f32::INFINITY;
                for v in row.iter_mut().rev() {
                    run = run.min(*v);
                    *v = run;
                }
            });
        }
        Self {
            table: storage,
            bmin,
            bmax,
            radial,
        }
    }

    /// True when azimuth bin `bin` is within `margin` bins of this frame's targets.
    pub(crate) fn near_bins(&self, bin: i64, margin: i64) -> bool {
        bin >= self.bmin - margin && bin <= self.bmax + margin
    }

    /// The lowest line-of-sight slope over the targets at least two radial steps beyond
    /// radial step `r` in azimuth bin `bin`, if any target lies there.
    pub(crate) fn slope_beyond(&self, bin: i64, r: usize) -> Option<f32> {
        if !self.near_bins(bin, 0) || r + 2 >= self.radial {
            return None;
        }
        let slope = *self
            .table
            .get((bin - self.bmin) as usize * self.radial + r + 2)?;
        slope.is_finite().then_some(slope)
    }
}

/// The see-through test: the depth image of this frame, to ask whether the sensor sees past
/// a column's top.
pub(crate) struct SeeThrough<'a> {
    pixels: &'a [f32],
    width: i64,
    height: i64,
    camera: &'a PinholeCamera,
    sensor_from_map: Isometry3<f64>,
    model: PrimeSenseHeight,
    /// Extra margin beyond the noise (m): one cell.
    margin_m: f64,
}

impl<'a> SeeThrough<'a> {
    /// The test for a depth image seen by `camera` from `map_from_sensor`; `margin_m` (m)
    /// is added to the noise allowance.
    pub(crate) fn new(
        depth: &'a DepthImage,
        camera: &'a PinholeCamera,
        map_from_sensor: &Isometry3<f64>,
        model: PrimeSenseHeight,
        margin_m: f64,
    ) -> Self {
        Self {
            pixels: depth.as_slice(),
            width: i64::from(depth.width()),
            height: i64::from(depth.height()),
            camera,
            sensor_from_map: map_from_sensor.inverse(),
            model,
            margin_m,
        }
    }

    /// True when every pixel of the 3 x 3 neighbourhood of the projection of map point
    /// `(x, y, top)` (m) measures a surface beyond it by more than `3 sigma_d + margin`
    /// (a missing return counts as not free; points outside the depth range or the image's
    /// inner border are never free).
    pub(crate) fn sees_past(&self, x: f64, y: f64, top: f64) -> bool {
        let q = self.sensor_from_map * Point3::new(x, y, top);
        if q.z < self.model.min_depth_m || q.z > self.model.max_depth_m {
            return false;
        }
        let Some(px) = self.camera.project(&q) else {
            return false;
        };
        let (u, v) = ((px.x + 0.5).floor() as i64, (px.y + 0.5).floor() as i64);
        if u < 1 || v < 1 || u >= self.width - 1 || v >= self.height - 1 {
            return false;
        }
        // `d - 3 sigma_d(d)` grows with d, so the nearest of the nine decides (a missing
        // return counts as 0: never free).
        let mut nearest = f32::INFINITY;
        for dv in -1..=1 {
            let start = ((v + dv) * self.width + u - 1) as usize;
            let Some(&[a, b, c]) = self.pixels.get(start..start + 3) else {
                return false;
            };
            for d in [a, b, c] {
                nearest = crate::neighbourhood::min_of(nearest, if d > 0.0 { d } else { 0.0 });
            }
        }
        let d = f64::from(nearest);
        d.is_finite() && d > q.z + 3.0 * self.model.model.sigma_d(d) + self.margin_m
    }
}
