//! Ray-cast rendering of the scene (CPU, rayon over image rows) and the RGB-D sensor models.
//!
//! Depth follows a Kinect/PrimeSense-class sensor: Gaussian noise with
//! `sigma_z = k z^2` (Khoshelham & Elberink 2012, `k` about 1.4e-3 /m), disparity quantised to
//! 1/8 pixel, no return outside the working range or at grazing incidence, and dropouts and
//! "flying pixels" (values between foreground and background) along depth edges. Colour is
//! Lambertian shading of procedural albedo, averaged over sub-frames spanning the exposure
//! (physical motion blur), with read and shot noise and vignetting.

use super::raster::{intersect_near_patch, PatchBuffer, TerrainRaster, NO_PATCH};
use super::scene::Scene;
use super::texture::albedo;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::{Image, RgbImage};
use stride_core::rng::{hash_normal_fast, hash_uniform, key, mix64};

/// Depth sensor model parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct DepthNoise {
    /// `k` in `sigma_z = k z^2` (1/m).
    pub sigma_coeff_per_m: f64,
    /// Baseline times focal length of the disparity (px * m): 0.075 m * 580 px for a Kinect.
    pub disparity_bf_px_m: f64,
    /// Disparity steps per pixel (8 for a Kinect).
    pub disparity_subpixel: f64,
    /// Nearest return (m).
    pub min_range_m: f64,
    /// Farthest return (m).
    pub max_range_m: f64,
    /// Below this cosine of incidence there is no return; up to twice it, returns thin out.
    pub grazing_cos: f64,
    /// A pixel is on a depth edge when a neighbour differs by more than this fraction of z.
    pub edge_rel: f64,
    /// Probability that an edge pixel has no return.
    pub edge_dropout: f64,
    /// Probability that an edge pixel is a flying pixel (between foreground and background).
    pub flying_pixels: f64,
    /// Offset (px) between where the depth is measured and the colour pixel it is
    /// registered to: the residual of the sensor's depth-to-colour registration.
    pub registration_offset_px: [f64; 2],
    /// Relative depth bias growing with the squared distance from the image centre
    /// (normalised to 1 at the corners), as the Kinect's depth distortion.
    pub bias_radial: f64,
    /// Amplitude of a smooth, static relative depth bias field across the image.
    pub bias_field: f64,
    /// Fraction of the noise variance shared by blocks of `correlated_block_px` pixels
    /// (structured-light depth noise is spatially correlated).
    pub correlated_fraction: f64,
    /// Side of the blocks sharing noise (px).
    pub correlated_block_px: usize,
}

impl Default for DepthNoise {
    fn default() -> Self {
        Self {
            sigma_coeff_per_m: 1.4e-3,
            disparity_bf_px_m: 0.075 * 580.0,
            disparity_subpixel: 8.0,
            min_range_m: 0.45,
            max_range_m: 4.5,
            grazing_cos: 0.12,
            edge_rel: 0.04,
            edge_dropout: 0.5,
            flying_pixels: 0.1,
            registration_offset_px: [0.6, 0.3],
            bias_radial: 0.004,
            bias_field: 0.003,
            correlated_fraction: 0.5,
            correlated_block_px: 4,
        }
    }
}

/// Per-pixel result of tracing one pose.
pub struct Geometry {
    /// z-depth in the camera frame (m); 0 where nothing was hit.
    pub depth_z: Vec<f32>,
    /// |cos| of the angle between the ray and the surface normal.
    pub cos_inc: Vec<f32>,
    /// Shaded colour (linear, 0..255 scale).
    pub color: Vec<[f32; 3]>,
    /// Rays whose terrain hit was found by marching the height field: every ray of a
    /// marched render; in a rasterised one, the rays that missed their pixel's patch and
    /// its eight neighbours (pixels that no patch covers, such as the sky, are not marched:
    /// no terrain there).
    pub marched_rays: usize,
}

/// Renders the scene through an ideal pinhole camera.
pub struct Renderer<'a> {
    scene: &'a Scene,
    camera: PinholeCamera,
    rays: Vec<[f64; 3]>,
    max_t: f64,
    raster: TerrainRaster,
}

/// How a render finds the terrain under each pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visibility {
    /// Rasterise the terrain's patches, then intersect each ray with its pixel's patch
    /// exactly (marching only where that fails). The default: 1.6-1.7x faster per frame
    /// (`stride bench synth`), the same images within the sensor's noise.
    Rasterized,
    /// March every ray through the height field's maximum mipmap (the reference).
    Marched,
}

const LIGHT: [f64; 3] = [0.3294, 0.2353, 0.9143]; // normalised (0.35, 0.25, 0.97)

impl<'a> Renderer<'a> {
    /// A renderer for `camera` (distortion ignored: images are rendered undistorted).
    pub fn new(scene: &'a Scene, camera: PinholeCamera) -> Self {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        let mut rays = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let x = (u as f64 - camera.cx()) / camera.fx();
                let y = (v as f64 - camera.cy()) / camera.fy();
                let n = (x * x + y * y + 1.0).sqrt();
                rays.push([x / n, y / n, 1.0 / n]);
            }
        }
        Self {
            scene,
            camera,
            rays,
            max_t: 12.0,
            raster: TerrainRaster::new(&scene.terrain),
        }
    }

    /// The camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// Traces pixel `idx`. `patches` holds the rasterised patch per pixel (or `None` to
    /// march every ray); `marched` counts the rays marched.
    #[allow(clippy::too_many_arguments)]
    fn trace_pixel(
        &self,
        pose: &Isometry3<f64>,
        o: [f64; 3],
        idx: usize,
        cand: &[super::scene::ScreenBox],
        want_color: bool,
        patches: Option<&PatchBuffer>,
        marched: &mut usize,
    ) -> (f32, f32, [f32; 3]) {
        let w = self.camera.width() as usize;
        let Some(rc) = self.rays.get(idx) else {
            return (0.0, 0.0, [0.0; 3]);
        };
        let dw = pose.rotation * Vector3::new(rc[0], rc[1], rc[2]);
        let d = [dw.x, dw.y, dw.z];
        let (u, v) = ((idx % w) as f64, (idx / w) as f64);
        let terrain = &self.scene.terrain;
        let hint = patches.map(|p| p.patch.get(idx).copied().unwrap_or(NO_PATCH));
        let hit = self
            .scene
            .trace_with(o, d, self.max_t, cand, u, v, |limit| {
                match hint {
                    // No triangle of the terrain covers this pixel centre: no terrain here.
                    Some(NO_PATCH) => return None,
                    Some(patch) => {
                        let pc = self.raster.patch_cols();
                        if let Some((t, n)) =
                            intersect_near_patch(terrain, pc, patch, o, d, self.max_t)
                        {
                            return (t <= limit).then_some((t, Some(n)));
                        }
                    }
                    None => {}
                }
                *marched += 1;
                terrain.intersect(o, d, limit).map(|h| (h.t, None))
            });
        match hit {
            None => (
                0.0,
                0.0,
                if want_color {
                    [120.0, 130.0, 140.0]
                } else {
                    [0.0; 3]
                },
            ),
            Some(hit) => {
                let n = hit.normal;
                let cos = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]).abs();
                let z = (hit.t * rc[2]) as f32;
                if !want_color {
                    return (z, cos as f32, [0.0; 3]);
                }
                let footprint = hit.t / self.camera.fx() / cos.max(0.25);
                let a = albedo(
                    hit.material,
                    hit.uv.0,
                    hit.uv.1,
                    footprint,
                    self.scene.texture_seed,
                );
                let lambert = (n[0] * LIGHT[0] + n[1] * LIGHT[1] + n[2] * LIGHT[2]).max(0.0);
                let s = 0.42 + 0.62 * lambert;
                (
                    z,
                    cos as f32,
                    [(a[0] * s) as f32, (a[1] * s) as f32, (a[2] * s) as f32],
                )
            }
        }
    }

    /// Traces every pixel from `world_from_camera`: depth, incidence and (when `with_color`)
    /// colour; without colour the colour buffer is left black and shading is skipped.
    pub fn render(&self, world_from_camera: &Isometry3<f64>, with_color: bool) -> Geometry {
        self.render_with(world_from_camera, with_color, Visibility::Rasterized)
    }

    /// [`Self::render`] with a choice of how the terrain is found.
    pub fn render_with(
        &self,
        world_from_camera: &Isometry3<f64>,
        with_color: bool,
        visibility: Visibility,
    ) -> Geometry {
        let n = self.rays.len();
        let w = self.camera.width() as usize;
        let cand = self.scene.screen_boxes(&self.camera, world_from_camera);
        let patches = self.patches(std::slice::from_ref(world_from_camera), 1.0, visibility);
        let o = world_from_camera.translation.vector;
        let o = [o.x, o.y, o.z];
        let mut depth_z = vec![0.0f32; n];
        let mut cos_inc = vec![0.0f32; n];
        let mut color = vec![[0.0f32; 3]; n];
        let marched_rays = depth_z
            .par_chunks_mut(w)
            .zip(cos_inc.par_chunks_mut(w))
            .zip(color.par_chunks_mut(w))
            .enumerate()
            .map(|(row, ((dz, ci), col))| {
                let mut marched = 0usize;
                for k in 0..w {
                    let (z, c, rgb) = self.trace_pixel(
                        world_from_camera,
                        o,
                        row * w + k,
                        &cand,
                        with_color,
                        patches.as_ref(),
                        &mut marched,
                    );
                    dz[k] = z;
                    ci[k] = c;
                    col[k] = rgb;
                }
                marched
            })
            .sum();
        Geometry {
            depth_z,
            cos_inc,
            color,
            marched_rays,
        }
    }

    /// The rasterised patches seen from `row_poses` (see [`TerrainRaster::rasterize`]), or
    /// `None` when marching.
    fn patches(
        &self,
        row_poses: &[Isometry3<f64>],
        pad_px: f64,
        visibility: Visibility,
    ) -> Option<PatchBuffer> {
        (visibility == Visibility::Rasterized).then(|| {
            let mut buffer = PatchBuffer::default();
            self.raster.rasterize(
                &self.scene.terrain,
                &self.camera,
                row_poses,
                pad_px,
                self.max_t,
                &mut buffer,
            );
            buffer
        })
    }

    /// Colour only, added into `acc` (for averaging sub-frames). `row_poses` holds one
    /// `world_from_camera` per image row (a rolling shutter exposes rows at different times)
    /// or a single pose for all rows; `pad_px` widens the objects' screen boxes to cover the
    /// rows' motion.
    pub fn accumulate_color(
        &self,
        row_poses: &[Isometry3<f64>],
        pad_px: f64,
        acc: &mut [[f32; 3]],
        visibility: Visibility,
    ) {
        let w = self.camera.width() as usize;
        let Some(mid) = row_poses.get(row_poses.len() / 2) else {
            return;
        };
        let cand = self.scene.screen_boxes_padded(&self.camera, mid, pad_px);
        let patches = self.patches(row_poses, pad_px, visibility);
        acc.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
            let pose = row_poses.get(row).or(row_poses.first()).unwrap_or(mid);
            let o = pose.translation.vector;
            let o = [o.x, o.y, o.z];
            let mut marched = 0usize;
            for (k, px) in out.iter_mut().enumerate() {
                let (_, _, rgb) = self.trace_pixel(
                    pose,
                    o,
                    row * w + k,
                    &cand,
                    true,
                    patches.as_ref(),
                    &mut marched,
                );
                px[0] += rgb[0];
                px[1] += rgb[1];
                px[2] += rgb[2];
            }
        });
    }

    /// World points seen at a few pixels (a 5 x 5 lattice), for estimating image motion.
    pub fn probe_points(&self, world_from_camera: &Isometry3<f64>) -> Vec<Point3<f64>> {
        let (w, h) = (self.camera.width() as usize, self.camera.height() as usize);
        let cand = self.scene.screen_boxes(&self.camera, world_from_camera);
        let o = world_from_camera.translation.vector;
        let mut out = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                let (u, v) = ((w - 1) * (2 * i + 1) / 10, (h - 1) * (2 * j + 1) / 10);
                let idx = v * w + u;
                let Some(rc) = self.rays.get(idx) else {
                    continue;
                };
                let d = world_from_camera.rotation * Vector3::new(rc[0], rc[1], rc[2]);
                if let Some(hit) = self.scene.trace(
                    [o.x, o.y, o.z],
                    [d.x, d.y, d.z],
                    self.max_t,
                    &cand,
                    u as f64,
                    v as f64,
                ) {
                    out.push(Point3::from(o + d * hit.t));
                }
            }
        }
        out
    }

    /// Largest displacement (px) of the probe points between two camera poses.
    pub fn image_motion_px(
        &self,
        points: &[Point3<f64>],
        a: &Isometry3<f64>,
        b: &Isometry3<f64>,
    ) -> f64 {
        let (ia, ib) = (a.inverse(), b.inverse());
        points
            .iter()
            .filter_map(|p| {
                let pa = self.camera.project(&(ia * p))?;
                let pb = self.camera.project(&(ib * p))?;
                Some((pa - pb).norm())
            })
            .fold(0.0, f64::max)
    }
}

/// Applies the depth sensor model to clean z-depth; returns raw 16-bit units
/// (`round(z * depth_scale)`, 0 = no return). Randomness is a pure function of
/// `(seed, frame, pixel)`, so results do not depend on thread scheduling.
pub fn depth_sensor(
    geom: &Geometry,
    width: usize,
    model: &DepthNoise,
    depth_scale: f64,
    seed: u64,
    frame: u64,
) -> Image<u16> {
    let n = geom.depth_z.len();
    let h = n / width.max(1);
    let mut out = vec![0u16; n];
    let frame_key = key(&[seed, frame, 0xDE97]);
    let bias_seed = (seed as u32) ^ 0xB1A5;
    out.par_chunks_mut(width)
        .enumerate()
        .for_each(|(row, dst)| {
            for (col, px) in dst.iter_mut().enumerate() {
                // Misregistration: the depth comes from a slightly offset point of the image.
                let sc = (col as f64 + model.registration_offset_px[0])
                    .round()
                    .clamp(0.0, width as f64 - 1.0) as usize;
                let sr = (row as f64 + model.registration_offset_px[1])
                    .round()
                    .clamp(0.0, h as f64 - 1.0) as usize;
                let i = sr * width + sc;
                let pixel = row * width + col;
                let z = f64::from(geom.depth_z.get(i).copied().unwrap_or(0.0));
                if z <= 0.0 {
                    continue;
                }
                let k = mix64(frame_key ^ (pixel as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                let cos = f64::from(geom.cos_inc.get(i).copied().unwrap_or(0.0));
                if cos < model.grazing_cos {
                    continue;
                }
                if cos < 2.0 * model.grazing_cos
                    && hash_uniform(k ^ 1) > (cos - model.grazing_cos) / model.grazing_cos
                {
                    continue;
                }
                // Depth edge: the neighbour that differs most.
                let mut far = z;
                let mut edge = false;
                for (dr, dc) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                    let (r2, c2) = (sr as i64 + dr, sc as i64 + dc);
                    if r2 < 0 || c2 < 0 || r2 >= h as i64 || c2 >= width as i64 {
                        continue;
                    }
                    let zn = f64::from(
                        geom.depth_z
                            .get(r2 as usize * width + c2 as usize)
                            .copied()
                            .unwrap_or(0.0),
                    );
                    let zn = if zn <= 0.0 {
                        model.max_range_m * 2.0
                    } else {
                        zn
                    };
                    if (zn - z).abs() > model.edge_rel * z {
                        edge = true;
                        if (zn - z).abs() > (far - z).abs() {
                            far = zn;
                        }
                    }
                }
                let mut zm = z;
                if edge {
                    let r = hash_uniform(k ^ 2);
                    if r < model.edge_dropout {
                        continue;
                    }
                    if r < model.edge_dropout + model.flying_pixels {
                        let f = 0.15 + 0.7 * hash_uniform(k ^ 3);
                        zm = z + (far.min(model.max_range_m) - z) * f;
                    }
                }
                // Static bias: radial distortion plus a smooth field.
                let (nx, ny) = (
                    (col as f64 - width as f64 / 2.0) / (width as f64 / 2.0),
                    (row as f64 - h as f64 / 2.0) / (h as f64 / 2.0),
                );
                let bias = model.bias_radial * (nx * nx + ny * ny) / 2.0
                    + model.bias_field
                        * super::texture::value_noise(
                            bias_seed,
                            col as f64 / 160.0,
                            row as f64 / 120.0,
                        );
                zm *= 1.0 + bias;
                // Axial noise, part of it shared by a block of pixels, then disparity
                // quantisation.
                let block = model.correlated_block_px.max(1);
                let kb = mix64(
                    frame_key
                        ^ 0xB10C
                        ^ ((((row / block) as u64) << 20) | (col / block) as u64)
                            .wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                let f = model.correlated_fraction.clamp(0.0, 1.0);
                let noise =
                    (1.0 - f).sqrt() * hash_normal_fast(k ^ 4) + f.sqrt() * hash_normal_fast(kb);
                zm += model.sigma_coeff_per_m * zm * zm * noise;
                if model.disparity_subpixel > 0.0 && zm > 0.0 {
                    let d = (model.disparity_bf_px_m / zm * model.disparity_subpixel).round()
                        / model.disparity_subpixel;
                    if d <= 0.0 {
                        continue;
                    }
                    zm = model.disparity_bf_px_m / d;
                }
                if zm < model.min_range_m || zm > model.max_range_m {
                    continue;
                }
                *px = (zm * depth_scale).round().clamp(0.0, 65535.0) as u16;
            }
        });
    Image::from_vec(width as u32, h as u32, out)
        .unwrap_or_else(|_| Image::filled(width as u32, h as u32, 0))
}

/// Turns accumulated radiance into an 8-bit image with vignetting (`1 - 0.22 r^2`, r = 1 at
/// the corners), shot noise and read noise (`read_noise_dn` standard deviation).
pub fn rgb_sensor(
    color: &[[f32; 3]],
    camera: &PinholeCamera,
    read_noise_dn: f64,
    seed: u64,
    frame: u64,
) -> RgbImage {
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let r_max2 = (camera.cx().max(w as f64 - camera.cx())).powi(2)
        + (camera.cy().max(h as f64 - camera.cy())).powi(2);
    let mut out = vec![[0u8; 3]; w * h];
    let frame_key = key(&[seed, frame, 0xC010]);
    out.par_chunks_mut(w).enumerate().for_each(|(row, dst)| {
        for (col, px) in dst.iter_mut().enumerate() {
            let i = row * w + col;
            let c = color.get(i).copied().unwrap_or([0.0; 3]);
            let r2 =
                ((col as f64 - camera.cx()).powi(2) + (row as f64 - camera.cy()).powi(2)) / r_max2;
            let vig = 1.0 - 0.22 * r2;
            for (ch, out_ch) in px.iter_mut().enumerate() {
                let v = f64::from(c[ch]) * vig;
                let sigma = (read_noise_dn * read_noise_dn + 0.015 * v.max(0.0)).sqrt();
                let noisy = v + sigma
                    * hash_normal_fast(
                        frame_key ^ ((i * 3 + ch) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                    );
                *out_ch = noisy.round().clamp(0.0, 255.0) as u8;
            }
        }
    });
    Image::from_vec(w as u32, h as u32, out)
        .unwrap_or_else(|_| Image::filled(w as u32, h as u32, [0; 3]))
}
