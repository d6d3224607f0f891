//! The RGB-D sensor models applied to rendered images.
//!
//! Depth follows a Kinect/PrimeSense-class sensor: Gaussian noise with
//! `sigma_z = k z^2` (Khoshelham & Elberink 2012, `k` about 1.4e-3 /m), disparity quantised to
//! 1/8 pixel, no return outside the working range or at grazing incidence, dropouts and
//! "flying pixels" (values between foreground and background) along depth edges, and a
//! static bias (radial plus a smooth field). Colour gets vignetting, shot and read noise.
//! The parts that do not change from frame to frame (the depth bias, the vignetting) are
//! computed once per camera in [`SensorFields`].

use super::render::Geometry;
use super::texture::value_noise;
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

/// Per-pixel factors of the sensor models that are the same in every frame, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorFields {
    /// Image width (px).
    width: usize,
    /// `1 + bias` of each pixel's depth (radial distortion plus the smooth field).
    depth_gain: Vec<f64>,
    /// Vignetting of each pixel's colour, `1 - 0.22 r^2` (r = 1 at the farthest corner).
    vignette: Vec<f64>,
}

impl SensorFields {
    /// The fields for `camera` under `model`, whose smooth bias field follows `seed`.
    pub fn new(camera: &PinholeCamera, model: &DepthNoise, seed: u64) -> Self {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        let bias_seed = (seed as u32) ^ 0xB1A5;
        let r_max2 = (camera.cx().max(w as f64 - camera.cx())).powi(2)
            + (camera.cy().max(h as f64 - camera.cy())).powi(2);
        let mut depth_gain = Vec::with_capacity(w * h);
        let mut vignette = Vec::with_capacity(w * h);
        for row in 0..h {
            for col in 0..w {
                let (nx, ny) = (
                    (col as f64 - w as f64 / 2.0) / (w as f64 / 2.0),
                    (row as f64 - h as f64 / 2.0) / (h as f64 / 2.0),
                );
                let bias = model.bias_radial * (nx * nx + ny * ny) / 2.0
                    + model.bias_field
                        * value_noise(bias_seed, col as f64 / 160.0, row as f64 / 120.0);
                depth_gain.push(1.0 + bias);
                let r2 = ((col as f64 - camera.cx()).powi(2) + (row as f64 - camera.cy()).powi(2))
                    / r_max2;
                vignette.push(1.0 - 0.22 * r2);
            }
        }
        Self {
            width: w,
            depth_gain,
            vignette,
        }
    }
}

/// Applies the depth sensor model to clean z-depth; returns raw 16-bit units
/// (`round(z * depth_scale)`, 0 = no return). Randomness is a pure function of
/// `(seed, frame, pixel)`, so results do not depend on thread scheduling.
pub fn depth_sensor(
    geom: &Geometry,
    fields: &SensorFields,
    model: &DepthNoise,
    depth_scale: f64,
    seed: u64,
    frame: u64,
) -> Image<u16> {
    let width = fields.width;
    let n = geom.depth_z.len();
    let h = n / width.max(1);
    // Written in place, so the image's size is its construction's, never a fallback's.
    let mut out = Image::filled(width as u32, h as u32, 0u16);
    let frame_key = key(&[seed, frame, 0xDE97]);
    out.as_mut_slice()
        .par_chunks_mut(width.max(1))
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
                zm *= fields.depth_gain.get(pixel).copied().unwrap_or(1.0);
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
    out
}

/// Turns accumulated radiance into an 8-bit image with vignetting (`fields`), shot noise
/// and read noise (`read_noise_dn` standard deviation). `camera` gives the image size.
pub fn rgb_sensor(
    color: &[[f32; 3]],
    camera: &PinholeCamera,
    fields: &SensorFields,
    read_noise_dn: f64,
    seed: u64,
    frame: u64,
) -> RgbImage {
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    // Written in place, so the image's size is its construction's, never a fallback's.
    let mut out = Image::filled(w as u32, h as u32, [0u8; 3]);
    let frame_key = key(&[seed, frame, 0xC010]);
    out.as_mut_slice()
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(row, dst)| {
            for (col, px) in dst.iter_mut().enumerate() {
                let i = row * w + col;
                let c = color.get(i).copied().unwrap_or([0.0; 3]);
                let vig = fields.vignette.get(i).copied().unwrap_or(1.0);
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
    out
}
