//! Rasterised visibility for the terrain: which bilinear patch each pixel sees.
//!
//! Marching every pixel's ray through the height field's maximum mipmap costs about 0.6 µs
//! a ray. Rasterising instead projects each patch (the square between four cell centres,
//! split into two triangles) once per frame into a depth buffer, which names the nearest
//! patch under every pixel centre; the ray is then intersected exactly with that one
//! bilinear patch ([`super::patch_hit::intersect_patch`]), or with a neighbour when it
//! misses that one. Where all of those fail, the caller marches the ray as before. A pixel
//! that no triangle covers sees no terrain; the triangles share their edges with the
//! bilinear patches, so such a pixel could only differ where a patch bulges above its two
//! triangles at a silhouette.
//! Against the marched reference (tests/render_raster.rs) no pixel changed from hit to
//! miss or back, and depth moved by more than 1 mm at under 0.01 % of pixels.
//!
//! Frames: the terrain is in the world frame (z up, m); triangles are clipped against the
//! camera's near plane in the camera frame (x right, y down, z forward, m) and projected
//! with the pinhole model, pixel centres at integer coordinates.

use super::terrain::HeightField;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;

/// Patches per side of a culling block.
const BLOCK: usize = 16;
/// Near clipping distance (m along the optical axis).
const NEAR_M: f64 = 0.02;
/// Image rows per rasterisation band (one rayon task each).
const BAND_ROWS: usize = 24;
/// Marker of a pixel that no patch covers.
pub const NO_PATCH: u32 = u32::MAX;

/// Per-scene data for rasterising a height field: the height range of each block of
/// `BLOCK x BLOCK` patches, for culling blocks outside the view.
#[derive(Debug, Clone)]
pub struct TerrainRaster {
    /// Patch rows and columns (cell-centre rows and columns minus one).
    patch_rows: usize,
    patch_cols: usize,
    /// Block rows and columns.
    block_rows: usize,
    block_cols: usize,
    /// Lowest and highest vertex height (m) of each block.
    block_range: Vec<(f32, f32)>,
}

/// The nearest patch under each pixel centre of one view.
#[derive(Debug, Clone, Default)]
pub struct PatchBuffer {
    /// Image width (px).
    pub width: usize,
    /// Patch index (`row * patch_cols + col`) per pixel, row-major; [`NO_PATCH`] if none.
    pub patch: Vec<u32>,
    /// `1 / z` (1/m, camera frame) of the nearest triangle per pixel; 0 if none.
    inv_z: Vec<f32>,
}

/// One projected terrain vertex: camera-frame position (m) and, in front of the near
/// plane, pixel coordinates and `1 / z`.
#[derive(Debug, Clone, Copy, Default)]
struct Vertex {
    p_camera: [f32; 3],
    uvw: [f32; 3],
}

/// A visible block's projected vertices, `(BLOCK + 1)^2` at most, row-major.
struct ProjectedBlock {
    /// First patch row and column of the block.
    row0: usize,
    col0: usize,
    /// Patches in the block along rows and columns.
    rows: usize,
    cols: usize,
    /// Rows of the image the block may cover (inclusive).
    v_range: (f32, f32),
    /// The same per patch row of the block.
    row_v_range: Vec<(f32, f32)>,
    vertices: Vec<Vertex>,
}

impl TerrainRaster {
    /// Precomputes the block height ranges of `terrain`.
    pub fn new(terrain: &HeightField) -> Self {
        let g = terrain.grid().geometry;
        let data = terrain.grid().as_slice();
        let (patch_rows, patch_cols) = (g.rows.saturating_sub(1), g.cols.saturating_sub(1));
        let (block_rows, block_cols) = (patch_rows.div_ceil(BLOCK), patch_cols.div_ceil(BLOCK));
        let mut block_range = vec![(f32::INFINITY, f32::NEG_INFINITY); block_rows * block_cols];
        for r in 0..g.rows {
            let br = (r.min(patch_rows.saturating_sub(1)) / BLOCK).min(block_rows.max(1) - 1);
            // A vertex on a block border belongs to both blocks.
            let brs = [br, r.saturating_sub(1) / BLOCK];
            for c in 0..g.cols {
                let Some(&h) = data.get(r * g.cols + c) else {
                    continue;
                };
                let bc = c.min(patch_cols.saturating_sub(1)) / BLOCK;
                for &bri in &brs {
                    for bci in [bc, c.saturating_sub(1) / BLOCK] {
                        if let Some(e) = block_range.get_mut(bri * block_cols + bci) {
                            e.0 = e.0.min(h);
                            e.1 = e.1.max(h);
                        }
                    }
                }
            }
        }
        Self {
            patch_rows,
            patch_cols,
            block_rows,
            block_cols,
            block_range,
        }
    }

    /// Patch columns (for decoding [`PatchBuffer::patch`] indices).
    pub fn patch_cols(&self) -> usize {
        self.patch_cols
    }

    /// Fills `out` with the nearest patch under each pixel centre, up to `max_z_m` along
    /// the optical axis. `row_poses` holds `world_from_camera` for each image row (a
    /// rolling shutter) or one pose for all rows; with per-row poses each band of rows is
    /// projected with the pose of its middle row, and `pad_px` (the image motion across the
    /// rows, px) widens the culling.
    pub fn rasterize(
        &self,
        terrain: &HeightField,
        camera: &PinholeCamera,
        row_poses: &[Isometry3<f64>],
        pad_px: f64,
        max_z_m: f64,
        out: &mut PatchBuffer,
    ) {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        out.width = w;
        out.patch.clear();
        out.patch.resize(w * h, NO_PATCH);
        out.inv_z.clear();
        out.inv_z.resize(w * h, 0.0);
        let Some(mid) = row_poses.get(row_poses.len() / 2) else {
            return;
        };
        if self.patch_rows == 0 || self.patch_cols == 0 {
            return;
        }
        let per_row = row_poses.len() > 1;
        let pad = if per_row { pad_px.max(1.0) } else { 1.0 };
        let camera_from_mid = mid.inverse();
        let blocks: Vec<ProjectedBlock> = (0..self.block_rows * self.block_cols)
            .into_par_iter()
            .filter(|&b| self.in_view(b, terrain, camera, &camera_from_mid, pad, max_z_m))
            .filter_map(|b| self.project_block(b, terrain, camera, &camera_from_mid))
            .collect();
        let pc = self.patch_cols;
        out.patch
            .par_chunks_mut(w * BAND_ROWS)
            .zip(out.inv_z.par_chunks_mut(w * BAND_ROWS))
            .enumerate()
            .for_each(|(band, (patch, inv_z))| {
                let r0 = band * BAND_ROWS;
                let r1 = r0 + patch.len() / w.max(1); // exclusive
                let mut target = Band {
                    width: w,
                    row0: r0,
                    row1: r1,
                    patch,
                    inv_z,
                };
                let margin = if per_row { pad as f32 } else { 1.0 };
                let camera_from_band = row_poses
                    .get((r0 + r1) / 2)
                    .or(row_poses.last())
                    .map(|p| p.inverse())
                    .filter(|_| per_row);
                for blk in &blocks {
                    if blk.v_range.1 < r0 as f32 - margin || blk.v_range.0 > r1 as f32 + margin {
                        continue;
                    }
                    match &camera_from_band {
                        None => blk.rasterize(camera, pc, &mut target),
                        Some(cfw) => {
                            let b = (blk.row0 / BLOCK) * self.block_cols + blk.col0 / BLOCK;
                            if let Some(own) = self.project_block(b, terrain, camera, cfw) {
                                own.rasterize(camera, pc, &mut target);
                            }
                        }
                    }
                }
            });
    }

    /// Block `b`'s first patch row and column and its patch rows and columns (fewer than
    /// `BLOCK` at the terrain's far edges), or `None` past the last block.
    fn block_extent(&self, b: usize) -> Option<(usize, usize, usize, usize)> {
        let (row0, col0) = ((b / self.block_cols) * BLOCK, (b % self.block_cols) * BLOCK);
        let rows = BLOCK.min(self.patch_rows.checked_sub(row0)?);
        let cols = BLOCK.min(self.patch_cols.checked_sub(col0)?);
        Some((row0, col0, rows, cols))
    }

    /// Whether block `b`'s bounding box may be seen (pixel bounds widened by `pad_px`).
    fn in_view(
        &self,
        b: usize,
        terrain: &HeightField,
        camera: &PinholeCamera,
        camera_from_world: &Isometry3<f64>,
        pad_px: f64,
        max_z_m: f64,
    ) -> bool {
        let (Some(&(lo, hi)), Some((row0, col0, rows, cols))) =
            (self.block_range.get(b), self.block_extent(b))
        else {
            return false;
        };
        let g = terrain.grid().geometry;
        let (x0, y0) = g.center(row0, col0);
        let (x1, y1) = g.center(row0 + rows, col0 + cols);
        let (w, h) = (f64::from(camera.width()), f64::from(camera.height()));
        let (xl, xr) = (
            (-pad_px - camera.cx()) / camera.fx(),
            (w - 1.0 + pad_px - camera.cx()) / camera.fx(),
        );
        let (yt, yb) = (
            (-pad_px - camera.cy()) / camera.fy(),
            (h - 1.0 + pad_px - camera.cy()) / camera.fy(),
        );
        let mut outside = [true; 6];
        for &x in &[x0, x1] {
            for &y in &[y0, y1] {
                for &z in &[f64::from(lo), f64::from(hi)] {
                    let p = camera_from_world * Point3::new(x, y, z);
                    let tests = [
                        p.z < NEAR_M,
                        p.z > max_z_m,
                        p.x < xl * p.z,
                        p.x > xr * p.z,
                        p.y < yt * p.z,
                        p.y > yb * p.z,
                    ];
                    for (o, t) in outside.iter_mut().zip(tests) {
                        *o &= t;
                    }
                }
            }
        }
        !outside.iter().any(|&o| o)
    }

    /// Projects block `b`'s vertices into the camera.
    fn project_block(
        &self,
        b: usize,
        terrain: &HeightField,
        camera: &PinholeCamera,
        camera_from_world: &Isometry3<f64>,
    ) -> Option<ProjectedBlock> {
        let (row0, col0, rows, cols) = self.block_extent(b)?;
        let g = terrain.grid().geometry;
        let data = terrain.grid().as_slice();
        let mut vertices = Vec::with_capacity((rows + 1) * (cols + 1));
        let (mut vmin, mut vmax) = (f32::INFINITY, f32::NEG_INFINITY);
        let (fx, fy, cx, cy) = (camera.fx(), camera.fy(), camera.cx(), camera.cy());
        for r in row0..=row0 + rows {
            for c in col0..=col0 + cols {
                let z_world = f64::from(*data.get(r * g.cols + c)?);
                let (x, y) = g.center(r, c);
                let p = camera_from_world * Point3::new(x, y, z_world);
                let mut v = Vertex {
                    p_camera: [p.x as f32, p.y as f32, p.z as f32],
                    uvw: [0.0; 3],
                };
                if p.z >= NEAR_M {
                    let inv = 1.0 / p.z;
                    let (u, vv) = (fx * p.x * inv + cx, fy * p.y * inv + cy);
                    v.uvw = [u as f32, vv as f32, inv as f32];
                    vmin = vmin.min(vv as f32);
                    vmax = vmax.max(vv as f32);
                } else {
                    // Clipped triangles may reach any row.
                    vmin = f32::NEG_INFINITY;
                    vmax = f32::INFINITY;
                }
                vertices.push(v);
            }
        }
        // Each patch row spans its two vertex rows; a clipped vertex may reach any row.
        let vertex_row_range = |r: usize| {
            vertices
                .get(r * (cols + 1)..(r + 1) * (cols + 1))
                .unwrap_or(&[])
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
                    if v.p_camera[2] >= NEAR_M as f32 {
                        (lo.min(v.uvw[1]), hi.max(v.uvw[1]))
                    } else {
                        (f32::NEG_INFINITY, f32::INFINITY)
                    }
                })
        };
        let mut row_v_range = Vec::with_capacity(rows);
        let mut above = vertex_row_range(0);
        for i in 0..rows {
            let below = vertex_row_range(i + 1);
            row_v_range.push((above.0.min(below.0), above.1.max(below.1)));
            above = below;
        }
        Some(ProjectedBlock {
            row0,
            col0,
            rows,
            cols,
            v_range: (vmin, vmax),
            row_v_range,
            vertices,
        })
    }
}

/// The rows of the buffers one task fills.
struct Band<'a> {
    width: usize,
    row0: usize,
    row1: usize,
    patch: &'a mut [u32],
    inv_z: &'a mut [f32],
}

impl ProjectedBlock {
    fn rasterize(&self, camera: &PinholeCamera, patch_cols: usize, band: &mut Band<'_>) {
        let stride = self.cols + 1;
        let (top, bottom) = (band.row0 as f32, band.row1 as f32 - 1.0);
        for i in 0..self.rows {
            // A patch row wholly above or below the band has no pixel centre in it.
            let (lo, hi) = self
                .row_v_range
                .get(i)
                .copied()
                .unwrap_or((f32::NEG_INFINITY, f32::INFINITY));
            if hi.floor() < top || lo.ceil() > bottom {
                continue;
            }
            let (Some(upper), Some(lower)) = (
                self.vertices.get(i * stride..(i + 1) * stride),
                self.vertices.get((i + 1) * stride..(i + 2) * stride),
            ) else {
                continue;
            };
            let work = triangle_work(upper, lower, band);
            for (j, &work) in work.iter().enumerate().take(self.cols) {
                if work == 0 {
                    continue;
                }
                let (Some(&a), Some(&b), Some(&c), Some(&d)) = (
                    upper.get(j),
                    upper.get(j + 1),
                    lower.get(j),
                    lower.get(j + 1),
                ) else {
                    continue;
                };
                let id = ((self.row0 + i) * patch_cols + self.col0 + j) as u32;
                for (t, tri) in [[a, b, d], [a, d, c]].iter().enumerate() {
                    match (work >> (2 * t)) & 3 {
                        DRAW => band.triangle(tri[0].uvw, tri[1].uvw, tri[2].uvw, id),
                        CLIP => clip_near(tri, camera, |p, q, r| band.triangle(p, q, r, id)),
                        _ => {}
                    }
                }
            }
        }
    }
}

/// [`triangle_work`]'s code for a triangle to draw as it is.
const DRAW: u8 = 1;
/// [`triangle_work`]'s code for a triangle to clip at the near plane first.
const CLIP: u8 = 2;

/// What the band must do with each patch's two triangles `[a, b, d]` and `[a, d, c]`
/// between two rows of projected vertices (`a`, `b` in `upper`, `c`, `d` below them in
/// `lower`): per patch, the first triangle's code in bits 0-1 and the second's in bits
/// 2-3, [`DRAW`] when all its vertices are in front of the near plane and its bounding box
/// holds a pixel centre of the band, [`CLIP`] when some are in front, 0 when there is
/// nothing to draw. [`Band::triangle`] would leave the others at once; deciding that for
/// a whole row of patches together, in a loop that vectorises, saves the per-triangle
/// set-up of the many triangles smaller than a pixel (1 cm patches a few metres away).
#[allow(clippy::needless_range_loop)]
fn triangle_work(upper: &[Vertex], lower: &[Vertex], band: &Band<'_>) -> [u8; BLOCK] {
    let row = |vs: &[Vertex]| {
        let (mut u, mut v, mut front) =
            ([0.0f32; BLOCK + 1], [0.0f32; BLOCK + 1], [0u8; BLOCK + 1]);
        for (((u, v), f), x) in u.iter_mut().zip(&mut v).zip(&mut front).zip(vs) {
            (*u, *v) = (x.uvw[0], x.uvw[1]);
            *f = u8::from(x.p_camera[2] >= NEAR_M as f32);
        }
        (u, v, front)
    };
    let ((ua, va, fa), (uc, vc, fc)) = (row(upper), row(lower));
    let (u_last, v_first, v_last) = (
        band.width as f32 - 1.0,
        band.row0 as f32,
        band.row1 as f32 - 1.0,
    );
    let holds_pixel = |u: [f32; 3], v: [f32; 3]| pixel_box(u, v, u_last, v_first, v_last).is_some();
    let code = |front: u8, holds: bool| match front {
        3 => DRAW * u8::from(holds),
        0 => 0,
        _ => CLIP,
    };
    let mut work = [0u8; BLOCK];
    // j + 1 <= BLOCK: every index is inside the arrays of BLOCK + 1 vertices.
    for j in 0..BLOCK {
        let (a, b, c, d) = (ua[j], ua[j + 1], uc[j], uc[j + 1]);
        let (va_, vb, vc_, vd) = (va[j], va[j + 1], vc[j], vc[j + 1]);
        let (fa_, fb, fc_, fd) = (fa[j], fa[j + 1], fc[j], fc[j + 1]);
        let first = code(fa_ + fb + fd, holds_pixel([a, b, d], [va_, vb, vd]));
        let second = code(fa_ + fd + fc_, holds_pixel([a, d, c], [va_, vd, vc_]));
        work[j] = first | (second << 2);
    }
    work
}

/// The pixel centres a triangle with vertices at columns `u` and rows `v` (px) may cover:
/// its bounding box rounded inwards and clipped to columns `0..=u_last` and rows
/// `v_first..=v_last`, as `(umin, umax, vmin, vmax)`; `None` when it holds none.
#[inline(always)]
fn pixel_box(
    u: [f32; 3],
    v: [f32; 3],
    u_last: f32,
    v_first: f32,
    v_last: f32,
) -> Option<(f32, f32, f32, f32)> {
    let umin = u[0].min(u[1]).min(u[2]).ceil().max(0.0);
    let umax = u[0].max(u[1]).max(u[2]).floor().min(u_last);
    let vmin = v[0].min(v[1]).min(v[2]).ceil().max(v_first);
    let vmax = v[0].max(v[1]).max(v[2]).floor().min(v_last);
    (!(umin > umax || vmin > vmax)).then_some((umin, umax, vmin, vmax))
}

/// Clips a triangle against the near plane and emits the projected pieces (one or two).
fn clip_near(
    tri: &[Vertex; 3],
    camera: &PinholeCamera,
    mut emit: impl FnMut([f32; 3], [f32; 3], [f32; 3]),
) {
    let near = NEAR_M as f32;
    let project = |p: [f32; 3]| -> [f32; 3] {
        let inv = 1.0 / p[2];
        [
            camera.fx() as f32 * p[0] * inv + camera.cx() as f32,
            camera.fy() as f32 * p[1] * inv + camera.cy() as f32,
            inv,
        ]
    };
    let mut poly: [[f32; 3]; 4] = [[0.0; 3]; 4];
    let mut n = 0;
    for k in 0..3 {
        let (p, q) = (tri[k].p_camera, tri[(k + 1) % 3].p_camera);
        let (pin, qin) = (p[2] >= near, q[2] >= near);
        if pin {
            if let Some(slot) = poly.get_mut(n) {
                *slot = p;
                n += 1;
            }
        }
        if pin != qin {
            let s = (near - p[2]) / (q[2] - p[2]);
            let x = [p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]), near];
            if let Some(slot) = poly.get_mut(n) {
                *slot = x;
                n += 1;
            }
        }
    }
    if n >= 3 {
        let (a, b, c) = (project(poly[0]), project(poly[1]), project(poly[2]));
        emit(a, b, c);
        if n == 4 {
            emit(a, c, project(poly[3]));
        }
    }
}

impl Band<'_> {
    /// Rasterises one projected triangle `(u, v, 1/z)` into the band: every pixel centre
    /// inside it (edges included, so shared edges leave no cracks) whose `1/z` is larger.
    #[inline]
    fn triangle(&mut self, a: [f32; 3], b: [f32; 3], c: [f32; 3], id: u32) {
        let Some((umin, umax, vmin, vmax)) = pixel_box(
            [a[0], b[0], c[0]],
            [a[1], b[1], c[1]],
            self.width as f32 - 1.0,
            self.row0 as f32,
            self.row1 as f32 - 1.0,
        ) else {
            return;
        };
        let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        if area.abs() < 1e-9 {
            return;
        }
        let inv_area = 1.0 / area;
        const EPS: f32 = -1e-5;
        for v in (vmin as usize)..=(vmax as usize) {
            let py = v as f32;
            let row = (v - self.row0) * self.width;
            for u in (umin as usize)..=(umax as usize) {
                let px = u as f32;
                let w0 = ((c[0] - b[0]) * (py - b[1]) - (c[1] - b[1]) * (px - b[0])) * inv_area;
                let w1 = ((a[0] - c[0]) * (py - c[1]) - (a[1] - c[1]) * (px - c[0])) * inv_area;
                let w2 = 1.0 - w0 - w1;
                if w0 < EPS || w1 < EPS || w2 < EPS {
                    continue;
                }
                let iz = w0 * a[2] + w1 * b[2] + w2 * c[2];
                let idx = row + u;
                if let (Some(dz), Some(dp)) = (self.inv_z.get_mut(idx), self.patch.get_mut(idx)) {
                    if iz > *dz {
                        *dz = iz;
                        *dp = id;
                    }
                }
            }
        }
    }
}
