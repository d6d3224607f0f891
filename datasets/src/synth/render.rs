//! Ray-cast rendering of the scene (CPU, rayon over image rows): depth, incidence and
//! Lambertian shading of procedural albedo, averaged over sub-frames spanning the exposure
//! (physical motion blur). The sensors' noise is applied afterwards ([`super::sensor`]).

use super::patch_hit::{intersect_neighbours, intersect_patches, RowHits};
use super::pool::BufferPool;
use super::raster::{PatchBuffer, TerrainRaster, NO_PATCH};
use super::scene::Scene;
use super::texture::{albedo, Material};
use super::texture_batch::ground_albedo;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;

/// Per-pixel result of tracing one pose.
pub struct Geometry {
    /// z-depth in the camera frame (m); 0 where nothing was hit.
    pub depth_z: Vec<f32>,
    /// |cos| of the angle between the ray and the surface normal.
    pub cos_inc: Vec<f32>,
    /// Shaded colour (linear, 0..255 scale); empty when the render asked for none.
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
    pool: BufferPool,
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
/// The colour (0..255 scale) of a ray that hits nothing.
const SKY: [f32; 3] = [120.0, 130.0, 140.0];

/// The surface point a pixel's ray hit, for shading.
#[derive(Debug, Clone, Copy)]
struct Surface {
    material: Material,
    /// Texture coordinates (m; see [`super::scene::Hit::uv`]).
    uv_m: (f64, f64),
    /// The pixel's footprint on the surface (m).
    footprint_m: f64,
    /// Lambertian shading factor (ambient plus diffuse).
    light: f64,
}

/// One task's buffers for tracing and shading a row: the rays, their hits on their own
/// patches, the pixels' depth, incidence and surfaces, then the ground points gathered for
/// the batch texture ([`ground_albedo`]).
#[derive(Default)]
struct Shading {
    /// The row's ray directions (world, unit).
    dirs: Vec<[f64; 3]>,
    /// Each ray's hit on its own rasterised patch.
    own: RowHits,
    /// Per pixel: z-depth (m), |cos| of the incidence, the surface to shade.
    z: Vec<f32>,
    cos: Vec<f32>,
    surfaces: Vec<Option<Surface>>,
    ground_u: Vec<f64>,
    ground_v: Vec<f64>,
    ground_footprint: Vec<f64>,
    ground_albedo: Vec<[f64; 3]>,
}

impl Shading {
    /// Shades [`Self::surfaces`] into `out` (one pixel each) through `put(pixel, rgb)`:
    /// albedo times light, the sky where nothing was hit. The ground's texture is computed
    /// for the whole row at once; the same colours as the texture point by point.
    fn shade(
        &mut self,
        seed: u32,
        out: &mut [[f32; 3]],
        mut put: impl FnMut(&mut [f32; 3], [f32; 3]),
    ) {
        self.ground_u.clear();
        self.ground_v.clear();
        self.ground_footprint.clear();
        for s in self.surfaces.iter().flatten() {
            if s.material == Material::Ground {
                self.ground_u.push(s.uv_m.0);
                self.ground_v.push(s.uv_m.1);
                self.ground_footprint.push(s.footprint_m);
            }
        }
        self.ground_albedo.clear();
        self.ground_albedo.resize(self.ground_u.len(), [0.0; 3]);
        ground_albedo(
            seed,
            &self.ground_u,
            &self.ground_v,
            &self.ground_footprint,
            &mut self.ground_albedo,
        );
        let mut ground = self.ground_albedo.iter();
        for (surface, px) in self.surfaces.iter().zip(out.iter_mut()) {
            let rgb = match surface {
                None => SKY,
                Some(s) => {
                    let a = if s.material == Material::Ground {
                        ground.next().copied().unwrap_or_default()
                    } else {
                        albedo(s.material, s.uv_m.0, s.uv_m.1, s.footprint_m, seed)
                    };
                    [
                        (a[0] * s.light) as f32,
                        (a[1] * s.light) as f32,
                        (a[2] * s.light) as f32,
                    ]
                }
            };
            put(px, rgb);
        }
    }
}

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
            pool: BufferPool::default(),
        }
    }

    /// The camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// Traces image row `row` from `pose` (origin `o`) into `scratch`: per pixel the
    /// z-depth (m, 0 where nothing was hit), |cos| of the incidence and, when `want_color`,
    /// the surface to shade. `patches` holds the rasterised patch per pixel (or `None` to
    /// march every ray). Returns the rays marched.
    #[allow(clippy::too_many_arguments)]
    fn trace_row(
        &self,
        pose: &Isometry3<f64>,
        o: [f64; 3],
        row: usize,
        cand: &[super::scene::ScreenBox],
        want_color: bool,
        patches: Option<&PatchBuffer>,
        scratch: &mut Shading,
    ) -> usize {
        let w = self.camera.width() as usize;
        let rays = self.rays.get(row * w..(row + 1) * w).unwrap_or(&[]);
        scratch.dirs.clear();
        scratch.dirs.extend(rays.iter().map(|rc| {
            let dw = pose.rotation * Vector3::new(rc[0], rc[1], rc[2]);
            [dw.x, dw.y, dw.z]
        }));
        let terrain = &self.scene.terrain;
        let pc = self.raster.patch_cols();
        let hints = patches.and_then(|p| p.patch.get(row * w..(row + 1) * w));
        // Each ray against its own patch, the whole row at once.
        scratch.own.hit.clear();
        if let Some(hints) = hints {
            intersect_patches(
                terrain,
                pc,
                hints,
                o,
                &scratch.dirs,
                self.max_t,
                &mut scratch.own,
            );
        }
        scratch.z.clear();
        scratch.cos.clear();
        scratch.surfaces.clear();
        let mut marched = 0usize;
        for (k, (rc, &d)) in rays.iter().zip(&scratch.dirs).enumerate() {
            let hint = hints.map(|h| h.get(k).copied().unwrap_or(NO_PATCH));
            let own = scratch.own.get(k);
            let object = self
                .scene
                .trace_objects(o, d, self.max_t, cand, k as f64, row as f64);
            let limit = object.map_or(self.max_t, |h| h.t);
            // The terrain's hit before the nearest object: on the pixel's patch or a
            // neighbour; marched where the raster has none to offer.
            let mut march = || {
                marched += 1;
                terrain.intersect(o, d, limit).map(|h| (h.t, None))
            };
            let ground = match hint {
                // No triangle of the terrain covers this pixel centre: no terrain.
                Some(NO_PATCH) => None,
                Some(patch) => {
                    let near =
                        own.or_else(|| intersect_neighbours(terrain, pc, patch, o, d, self.max_t));
                    match near {
                        Some((t, n)) => (t <= limit).then_some((t, Some(n))),
                        None => march(),
                    }
                }
                None => march(),
            };
            let hit = match ground {
                Some((t, n)) => Some(self.scene.ground_hit(o, d, t, n)),
                None => object,
            };
            let (z, cos, surface) = match hit {
                None => (0.0, 0.0, None),
                Some(hit) => {
                    let n = hit.normal;
                    let cos = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]).abs();
                    let z = (hit.t * rc[2]) as f32;
                    let lambert = (n[0] * LIGHT[0] + n[1] * LIGHT[1] + n[2] * LIGHT[2]).max(0.0);
                    let surface = want_color.then(|| Surface {
                        material: hit.material,
                        uv_m: hit.uv,
                        footprint_m: hit.t / self.camera.fx() / cos.max(0.25),
                        light: 0.42 + 0.62 * lambert,
                    });
                    (z, cos as f32, surface)
                }
            };
            scratch.z.push(z);
            scratch.cos.push(cos);
            scratch.surfaces.push(surface);
        }
        marched
    }

    /// Traces every pixel from `world_from_camera`: depth, incidence and (when `with_color`)
    /// colour; without colour the colour buffer is empty and shading is skipped. Hand the
    /// geometry back with [`Self::recycle`] when done, so the next frame reuses its buffers.
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
        let mut depth_z = self.pool.zeros(n);
        let mut cos_inc = self.pool.zeros(n);
        let mut color = if with_color {
            self.pool.black(n)
        } else {
            Vec::new()
        };
        let trace_row = |shade: &mut Shading,
                         row: usize,
                         dz: &mut [f32],
                         ci: &mut [f32],
                         col: Option<&mut [[f32; 3]]>| {
            let marched = self.trace_row(
                world_from_camera,
                o,
                row,
                &cand,
                with_color,
                patches.as_ref(),
                shade,
            );
            for (out, &z) in dz.iter_mut().zip(&shade.z) {
                *out = z;
            }
            for (out, &c) in ci.iter_mut().zip(&shade.cos) {
                *out = c;
            }
            if let Some(col) = col {
                shade.shade(self.scene.texture_seed, col, |px, rgb| *px = rgb);
            }
            marched
        };
        let rows = depth_z.par_chunks_mut(w).zip(cos_inc.par_chunks_mut(w));
        let marched_rays = if with_color {
            rows.zip(color.par_chunks_mut(w))
                .enumerate()
                .map_init(Shading::default, |shade, (row, ((dz, ci), col))| {
                    trace_row(shade, row, dz, ci, Some(col))
                })
                .sum()
        } else {
            rows.enumerate()
                .map_init(Shading::default, |shade, (row, (dz, ci))| {
                    trace_row(shade, row, dz, ci, None)
                })
                .sum()
        };
        if let Some(p) = patches {
            self.pool.give_patches(p);
        }
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
            let mut buffer = self.pool.patch_buffer();
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
        acc.par_chunks_mut(w)
            .enumerate()
            .for_each_init(Shading::default, |shade, (row, out)| {
                let pose = row_poses.get(row).or(row_poses.first()).unwrap_or(mid);
                let o = pose.translation.vector;
                let o = [o.x, o.y, o.z];
                self.trace_row(pose, o, row, &cand, true, patches.as_ref(), shade);
                shade.shade(self.scene.texture_seed, out, |px, rgb| {
                    px[0] += rgb[0];
                    px[1] += rgb[1];
                    px[2] += rgb[2];
                });
            });
        if let Some(p) = patches {
            self.pool.give_patches(p);
        }
    }

    /// A zeroed colour accumulator of one value per pixel, lent by the renderer (hand it
    /// back with [`Self::recycle_color`]).
    pub fn color_buffer(&self) -> Vec<[f32; 3]> {
        self.pool.black(self.rays.len())
    }

    /// Takes back a colour buffer for later frames.
    pub fn recycle_color(&self, color: Vec<[f32; 3]>) {
        self.pool.give_colours(color);
    }

    /// Takes back a geometry's buffers for later frames (the depth, if the caller keeps
    /// it, can be taken out first: an empty buffer is simply not kept).
    pub fn recycle(&self, geometry: Geometry) {
        for v in [geometry.depth_z, geometry.cos_inc] {
            if v.capacity() > 0 {
                self.pool.give_scalars(v);
            }
        }
        if geometry.color.capacity() > 0 {
            self.pool.give_colours(geometry.color);
        }
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
