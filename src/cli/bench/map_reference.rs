//! The yardstick of `stride bench map`: the practical limit of a map update.

use nalgebra::Isometry3;
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// One plain pass over a frame's depth pixels on one thread: each pixel with depth is
/// back-projected (pinhole, no distortion), moved into the map frame and kept as its
/// cell's highest point, in a window of `n x n` cells of `resolution_m` (m) around the
/// sensor. No variance, filter, check or binning: what any map update must at least do.
pub struct ReferencePass {
    /// Highest height (m) per cell, row-major.
    top_m: Vec<f32>,
    n: usize,
    resolution_m: f64,
}

impl ReferencePass {
    /// A window of `n x n` cells of `resolution_m` (m).
    pub fn new(n: usize, resolution_m: f64) -> Self {
        Self {
            top_m: vec![f32::NEG_INFINITY; n * n],
            n,
            resolution_m,
        }
    }

    /// Maps one frame seen by `camera` from `map_from_sensor`; returns the time (s) and the
    /// points that landed in the window.
    pub fn run(
        &mut self,
        depth_m: &DepthImage,
        camera: &PinholeCamera,
        map_from_sensor: &Isometry3<f64>,
    ) -> (f64, usize) {
        let start = Instant::now();
        let w = depth_m.width() as usize;
        let half = self.n as f64 * self.resolution_m / 2.0;
        let t = map_from_sensor.translation.vector;
        let rot = map_from_sensor
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .cast::<f32>();
        // Coordinates relative to the window's corner, so that f32 keeps its precision.
        let (tx, ty, tz) = (half as f32, half as f32, t.z as f32);
        let (ifx, ify) = ((1.0 / camera.fx()) as f32, (1.0 / camera.fy()) as f32);
        let (cx, cy) = (camera.cx() as f32, camera.cy() as f32);
        let inv = (1.0 / self.resolution_m) as f32;
        let nf = self.n as f32;
        let mut used = 0;
        for (v, row) in depth_m.as_slice().chunks_exact(w.max(1)).enumerate() {
            let yn = (v as f32 - cy) * ify;
            for (u, &d) in row.iter().enumerate() {
                if d <= 0.0 {
                    continue;
                }
                let (x, y) = ((u as f32 - cx) * ifx * d, yn * d);
                let qx = rot[(0, 0)] * x + rot[(0, 1)] * y + rot[(0, 2)] * d + tx;
                let qy = rot[(1, 0)] * x + rot[(1, 1)] * y + rot[(1, 2)] * d + ty;
                let qz = rot[(2, 0)] * x + rot[(2, 1)] * y + rot[(2, 2)] * d + tz;
                let (c, r) = (qx * inv, qy * inv);
                if c >= 0.0 && r >= 0.0 && c < nf && r < nf {
                    if let Some(top) = self.top_m.get_mut(r as usize * self.n + c as usize) {
                        *top = top.max(qz);
                        used += 1;
                    }
                }
            }
        }
        std::hint::black_box(&self.top_m);
        (start.elapsed().as_secs_f64(), used)
    }
}
