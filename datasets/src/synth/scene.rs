//! The synthetic world: a terrain height field, objects (boxes) standing on it off the
//! robot's path, and walls around, all in the world frame (z up, metres).

use super::terrain::HeightField;
use super::texture::Material;
use nalgebra::{Isometry3, Point3};
use stride_core::camera::PinholeCamera;
use stride_core::grid::Grid;
use stride_core::rng::SplitMix64;

/// A box standing upright (rotated about z by `yaw`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBox {
    /// Centre x, y (m).
    pub cx: f64,
    /// Centre y (m).
    pub cy: f64,
    /// Bottom z (m).
    pub z0: f64,
    /// Top z (m).
    pub z1: f64,
    /// Half extent along the box's own x (m).
    pub hx: f64,
    /// Half extent along the box's own y (m).
    pub hy: f64,
    /// Rotation about z (rad).
    pub yaw: f64,
    /// Surface kind.
    pub material: Material,
    /// `(sin yaw, cos yaw)`, cached.
    sin_cos: (f64, f64),
}

/// A ray's first hit in the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the unit ray (m).
    pub t: f64,
    /// Unit surface normal (world).
    pub normal: [f64; 3],
    /// Surface kind.
    pub material: Material,
    /// Surface texture coordinates (m).
    pub uv: (f64, f64),
}

impl SceneBox {
    /// A box centred at `(cx, cy)` from `z0` up to `z1` (m), half extents `hx`, `hy` (m),
    /// rotated by `yaw` (rad) about z.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        cx: f64,
        cy: f64,
        z0: f64,
        z1: f64,
        hx: f64,
        hy: f64,
        yaw: f64,
        material: Material,
    ) -> Self {
        Self {
            cx,
            cy,
            z0,
            z1,
            hx,
            hy,
            yaw,
            material,
            sin_cos: yaw.sin_cos(),
        }
    }

    /// Ray-box intersection (slab test in the box frame): `(t, normal, uv)` of the entry.
    #[inline(always)]
    pub fn intersect(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
    ) -> Option<(f64, [f64; 3], (f64, f64))> {
        let (s, c) = self.sin_cos;
        let (ox, oy) = (o[0] - self.cx, o[1] - self.cy);
        let lo = [ox * c + oy * s, -ox * s + oy * c, o[2]];
        let ld = [d[0] * c + d[1] * s, -d[0] * s + d[1] * c, d[2]];
        let mins = [-self.hx, -self.hy, self.z0];
        let maxs = [self.hx, self.hy, self.z1];
        let (mut t0, mut t1) = (0.0f64, t_max);
        let mut axis = 3usize;
        let mut sign = 0.0;
        for k in 0..3 {
            if ld[k].abs() < 1e-12 {
                if lo[k] < mins[k] || lo[k] > maxs[k] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / ld[k];
            let (mut ta, mut tb) = ((mins[k] - lo[k]) * inv, (maxs[k] - lo[k]) * inv);
            let mut sg = -1.0;
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
                sg = 1.0;
            }
            if ta > t0 {
                t0 = ta;
                axis = k;
                sign = sg;
            }
            t1 = t1.min(tb);
            if t0 > t1 {
                return None;
            }
        }
        if axis == 3 {
            return None; // the ray starts inside the box
        }
        let p = [lo[0] + t0 * ld[0], lo[1] + t0 * ld[1], lo[2] + t0 * ld[2]];
        let (local_n, uv) = match axis {
            0 => ([sign, 0.0, 0.0], (p[1], p[2])),
            1 => ([0.0, sign, 0.0], (p[0], p[2])),
            _ => ([0.0, 0.0, sign], (p[0], p[1])),
        };
        let n = [
            local_n[0] * c - local_n[1] * s,
            local_n[0] * s + local_n[1] * c,
            local_n[2],
        ];
        Some((t0, n, uv))
    }

    /// True when `(x, y)` lies inside the footprint.
    pub fn covers(&self, x: f64, y: f64) -> bool {
        let (s, c) = self.sin_cos;
        let (dx, dy) = (x - self.cx, y - self.cy);
        (dx * c + dy * s).abs() <= self.hx && (-dx * s + dy * c).abs() <= self.hy
    }

    fn corners(&self) -> [[f64; 3]; 8] {
        let (s, c) = self.sin_cos;
        let mut out = [[0.0; 3]; 8];
        for (i, corner) in out.iter_mut().enumerate() {
            let u = if i & 1 == 0 { -self.hx } else { self.hx };
            let v = if i & 2 == 0 { -self.hy } else { self.hy };
            let z = if i & 4 == 0 { self.z0 } else { self.z1 };
            *corner = [self.cx + u * c - v * s, self.cy + u * s + v * c, z];
        }
        out
    }
}

/// Objects are rendered from this distance (m along the optical axis) on: a tenth of a
/// millimetre, far below any sensor's minimum range, and far enough from 0 that the
/// projection of a box's clipped corner stays finite.
pub const BOX_CLIP_M: f64 = 1e-4;

/// The world the camera sees.
pub struct Scene {
    /// The terrain.
    pub terrain: HeightField,
    /// Objects and walls.
    pub boxes: Vec<SceneBox>,
    /// Seed of the textures.
    pub texture_seed: u32,
}

/// Pixel-space bounding box of an object in one frame (inclusive).
#[derive(Debug, Clone, Copy)]
pub struct ScreenBox {
    index: usize,
    u0: f64,
    v0: f64,
    u1: f64,
    v1: f64,
}

impl Scene {
    /// Builds the scene: walls enclosing the path's bounding box with `margin_m` to spare
    /// (clamped to the terrain), and `n_objects` boxes at least `clearance_m` away from the
    /// path, standing on the terrain. Deterministic for a seed.
    pub fn build(
        terrain: HeightField,
        path: &[(f64, f64)],
        margin_m: f64,
        n_objects: usize,
        clearance_m: f64,
        seed: u64,
    ) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x5CE7E);
        let (tx0, ty0, tx1, ty1) = terrain.grid().geometry.extent();
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for &(x, y) in path {
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        let (x0, y0) = (
            (x0 - margin_m).max(tx0 + 0.1),
            (y0 - margin_m).max(ty0 + 0.1),
        );
        let (x1, y1) = (
            (x1 + margin_m).min(tx1 - 0.1),
            (y1 + margin_m).min(ty1 - 0.1),
        );
        let (lo, _) = terrain.range();
        let mut boxes = Vec::new();
        let wall = |cx, cy, hx, hy, id| {
            SceneBox::new(cx, cy, lo - 0.5, lo + 2.2, hx, hy, 0.0, Material::Wall(id))
        };
        let (mx, my) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
        let (hx, hy) = ((x1 - x0) / 2.0, (y1 - y0) / 2.0);
        boxes.push(wall(mx, y0, hx + 0.05, 0.05, 0));
        boxes.push(wall(mx, y1, hx + 0.05, 0.05, 1));
        boxes.push(wall(x0, my, 0.05, hy + 0.05, 2));
        boxes.push(wall(x1, my, 0.05, hy + 0.05, 3));
        let mut attempts = 0;
        let mut placed = 0u32;
        while (placed as usize) < n_objects && attempts < 2000 {
            attempts += 1;
            let (cx, cy) = (rng.range(x0 + 0.4, x1 - 0.4), rng.range(y0 + 0.4, y1 - 0.4));
            let (bhx, bhy) = (rng.range(0.12, 0.4), rng.range(0.12, 0.4));
            let height = rng.range(0.25, 1.1);
            let yaw = rng.range(0.0, std::f64::consts::PI);
            let reach = bhx.hypot(bhy) + clearance_m;
            if path
                .iter()
                .any(|&(px, py)| (px - cx).hypot(py - cy) < reach)
            {
                continue;
            }
            if boxes
                .iter()
                .skip(4)
                .any(|b: &SceneBox| (b.cx - cx).hypot(b.cy - cy) < reach + b.hx.hypot(b.hy))
            {
                continue;
            }
            let ground = terrain.height(cx, cy);
            boxes.push(SceneBox::new(
                cx,
                cy,
                ground - 0.05,
                ground + height,
                bhx,
                bhy,
                yaw,
                Material::Object(placed),
            ));
            placed += 1;
        }
        Self {
            terrain,
            boxes,
            texture_seed: (seed as u32) ^ 0x7E57,
        }
    }

    /// The objects whose projection may cover pixels in this frame, with their pixel
    /// bounding boxes: the bounding box of the box's part in front of [`BOX_CLIP_M`],
    /// projected (a box partly behind the camera covers only the pixels its front part can).
    pub fn screen_boxes(
        &self,
        camera: &PinholeCamera,
        world_from_camera: &Isometry3<f64>,
    ) -> Vec<ScreenBox> {
        self.screen_boxes_padded(camera, world_from_camera, 1.0)
    }

    /// As [`Self::screen_boxes`], with the boxes widened by `pad_px` pixels.
    pub fn screen_boxes_padded(
        &self,
        camera: &PinholeCamera,
        world_from_camera: &Isometry3<f64>,
        pad_px: f64,
    ) -> Vec<ScreenBox> {
        let camera_from_world = world_from_camera.inverse();
        let (w, h) = (f64::from(camera.width()), f64::from(camera.height()));
        self.boxes
            .iter()
            .enumerate()
            .filter_map(|(index, b)| {
                // The box's part in front of the clipping plane is the convex hull of its
                // corners in front and of the points where its edges cross the plane; its
                // image is the hull of their projections, so their bounding box is exact.
                let p_camera = b
                    .corners()
                    .map(|c| camera_from_world * Point3::new(c[0], c[1], c[2]));
                let (mut u0, mut v0, mut u1, mut v1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
                let mut add = |p: Point3<f64>| {
                    let u = camera.fx() * p.x / p.z + camera.cx();
                    let v = camera.fy() * p.y / p.z + camera.cy();
                    u0 = u0.min(u);
                    v0 = v0.min(v);
                    u1 = u1.max(u);
                    v1 = v1.max(v);
                };
                for (i, &p) in p_camera.iter().enumerate() {
                    if p.z >= BOX_CLIP_M {
                        add(p);
                    }
                    // The edges from corner i to the corners that differ in one bit.
                    for bit in [1, 2, 4] {
                        let Some(&q) = p_camera.get(i | bit).filter(|_| i & bit == 0) else {
                            continue;
                        };
                        if (p.z >= BOX_CLIP_M) != (q.z >= BOX_CLIP_M) {
                            let s = (BOX_CLIP_M - p.z) / (q.z - p.z);
                            add(p + (q - p) * s);
                        }
                    }
                }
                if u0 > u1 {
                    return None; // wholly behind the clipping plane
                }
                let sb = ScreenBox {
                    index,
                    u0: u0 - pad_px,
                    v0: v0 - pad_px,
                    u1: u1 + pad_px,
                    v1: v1 + pad_px,
                };
                (sb.u1 >= 0.0 && sb.v1 >= 0.0 && sb.u0 < w && sb.v0 < h).then_some(sb)
            })
            .collect()
    }

    /// First hit along the unit ray `o + t d`, `t <= t_max`, testing only the objects of
    /// `candidates` whose pixel box contains `(u, v)`.
    #[inline]
    pub fn trace(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        candidates: &[ScreenBox],
        u: f64,
        v: f64,
    ) -> Option<Hit> {
        let object = self.trace_objects(o, d, t_max, candidates, u, v);
        self.or_terrain(o, d, t_max, object)
    }

    /// The nearest object's hit along the unit ray `o + t d`, `t <= t_max`, testing only
    /// the objects of `candidates` whose pixel box contains `(u, v)` (the terrain is the
    /// caller's: the renderer intersects it with its rasterised patches, then decides with
    /// [`Self::ground_hit`]).
    #[inline]
    pub fn trace_objects(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        candidates: &[ScreenBox],
        u: f64,
        v: f64,
    ) -> Option<Hit> {
        let boxes = candidates
            .iter()
            .filter(|sb| u >= sb.u0 && u <= sb.u1 && v >= sb.v0 && v <= sb.v1)
            .filter_map(|sb| self.boxes.get(sb.index));
        self.nearest_object(o, d, t_max, boxes)
    }

    /// First hit along the unit ray `o + t d`, `t <= t_max`, testing every object (for rays
    /// that are not a camera's pixels, such as a laser scanner's beams).
    pub fn trace_ray(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> Option<Hit> {
        let object = self.nearest_object(o, d, t_max, self.boxes.iter());
        self.or_terrain(o, d, t_max, object)
    }

    /// The terrain's first hit along the unit ray `o + t d` before `object` (the nearest
    /// object's hit) or `t_max`, marched through the height field; else `object`.
    #[inline]
    fn or_terrain(&self, o: [f64; 3], d: [f64; 3], t_max: f64, object: Option<Hit>) -> Option<Hit> {
        match self.terrain.intersect(o, d, object.map_or(t_max, |h| h.t)) {
            Some(h) => Some(self.ground_hit(o, d, h.t, None)),
            None => object,
        }
    }

    /// The nearest hit among `boxes` along the unit ray `o + t d`, `t <= t_max`.
    #[inline]
    fn nearest_object<'s>(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        boxes: impl Iterator<Item = &'s SceneBox>,
    ) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut limit = t_max;
        for b in boxes {
            if let Some((t, normal, uv)) = b.intersect(o, d, limit) {
                limit = t;
                best = Some(Hit {
                    t,
                    normal,
                    material: b.material,
                    uv,
                });
            }
        }
        best
    }

    /// The terrain's hit `t` m along the unit ray `o + t d` (world), with its unit normal
    /// when known (else the height field's there).
    #[inline]
    pub fn ground_hit(&self, o: [f64; 3], d: [f64; 3], t: f64, normal: Option<[f64; 3]>) -> Hit {
        let (x, y) = (o[0] + t * d[0], o[1] + t * d[1]);
        Hit {
            t,
            normal: normal.unwrap_or_else(|| self.terrain.normal(x, y)),
            material: Material::Ground,
            uv: (x, y),
        }
    }

    /// The true terrain elevation at each cell centre of the terrain grid (m, world z up),
    /// NaN under objects and walls: those are obstacles standing up to 2.2 m tall whose tops
    /// a camera at walking-robot height never sees, so no map can be judged on them.
    pub fn ground_truth_elevation(&self) -> Grid<f32> {
        let mut grid = self.terrain.grid().clone();
        let g = grid.geometry;
        for b in &self.boxes {
            let reach = b.hx.hypot(b.hy);
            let (Some((r0, c0)), Some((r1, c1))) = (
                g.cell_of(
                    (b.cx - reach).max(g.extent().0),
                    (b.cy - reach).max(g.extent().1),
                ),
                g.cell_of(
                    (b.cx + reach).min(g.extent().2 - 1e-9),
                    (b.cy + reach).min(g.extent().3 - 1e-9),
                ),
            ) else {
                continue;
            };
            for r in r0..=r1 {
                for c in c0..=c1 {
                    let (x, y) = g.center(r, c);
                    if b.covers(x, y) {
                        if let Some(v) = grid.get_mut(r, c) {
                            *v = f32::NAN;
                        }
                    }
                }
            }
        }
        grid
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::grid::GridGeometry;

    fn flat() -> HeightField {
        HeightField::new(Grid::filled(
            GridGeometry::covering(-5.0, -5.0, 5.0, 5.0, 0.02),
            0.0,
        ))
    }

    #[test]
    fn box_faces_are_hit_with_outward_normals() {
        let b = SceneBox::new(2.0, 0.0, 0.0, 1.0, 0.5, 0.5, 0.0, Material::Object(0));
        let (t, n, _) = b.intersect([0.0, 0.0, 0.5], [1.0, 0.0, 0.0], 10.0).unwrap();
        assert!((t - 1.5).abs() < 1e-12 && n == [-1.0, 0.0, 0.0]);
        let (t, n, _) = b
            .intersect([2.0, 0.0, 3.0], [0.0, 0.0, -1.0], 10.0)
            .unwrap();
        assert!((t - 2.0).abs() < 1e-12 && (n[2] - 1.0).abs() < 1e-12);
        assert!(b
            .intersect([0.0, 2.0, 0.5], [1.0, 0.0, 0.0], 10.0)
            .is_none());
        let r = SceneBox::new(
            2.0,
            0.0,
            0.0,
            1.0,
            0.5,
            0.5,
            std::f64::consts::FRAC_PI_4,
            Material::Object(0),
        );
        let (t, _, _) = r.intersect([0.0, 0.0, 0.5], [1.0, 0.0, 0.0], 10.0).unwrap();
        assert!((t - (2.0 - 0.5 * 2f64.sqrt())).abs() < 1e-9);
    }

    /// Boxes partly behind the camera get a screen box of their front part only, and that
    /// loses no pixel: a camera 0.3 m from a wall, looking along it and past a box beside
    /// it, sees the same hit at every pixel whether the screen boxes choose the objects to
    /// test or every object is tested.
    #[test]
    fn screen_boxes_of_boxes_partly_behind_the_camera_lose_no_pixel() {
        let wall = SceneBox::new(0.0, 1.0, -0.5, 2.2, 4.0, 0.05, 0.0, Material::Wall(0));
        let side = SceneBox::new(0.2, -0.4, -0.1, 0.6, 0.3, 0.2, 0.4, Material::Object(0));
        let s = Scene {
            terrain: flat(),
            boxes: vec![wall, side],
            texture_seed: 1,
        };
        let camera = PinholeCamera::new(100.0, 100.0, 39.5, 29.5, 80, 60).unwrap();
        // Optical axis along +x, 0.3 m from the wall (y = 0.95) and inside neither box.
        let rot = nalgebra::Rotation3::from_basis_unchecked(&[
            -nalgebra::Vector3::y(),
            -nalgebra::Vector3::z(),
            nalgebra::Vector3::x(),
        ]);
        let pose = Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, 0.65, 0.3),
            nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
        );
        let cand = s.screen_boxes(&camera, &pose);
        let wall_box = cand.iter().find(|b| b.index == 0).unwrap();
        // The wall is on the image's left: its box ends well inside the image.
        assert!(
            wall_box.u1 < 60.0,
            "the wall's screen box spans {:?}",
            (wall_box.u0, wall_box.u1)
        );
        let o = pose.translation.vector;
        let (mut on_boxes, mut differ) = (0, 0);
        for v in 0..60 {
            for u in 0..80 {
                let ray = nalgebra::Vector3::new(
                    (f64::from(u) - 39.5) / 100.0,
                    (f64::from(v) - 29.5) / 100.0,
                    1.0,
                )
                .normalize();
                let d = pose.rotation * ray;
                let (o, d) = ([o.x, o.y, o.z], [d.x, d.y, d.z]);
                let all = s.trace_ray(o, d, 12.0);
                let culled = s.trace(o, d, 12.0, &cand, f64::from(u), f64::from(v));
                on_boxes += usize::from(all.is_some_and(|h| h.material != Material::Ground));
                differ += usize::from(all != culled);
            }
        }
        assert!(on_boxes > 1000, "only {on_boxes} pixels see a box");
        assert_eq!(differ, 0);
    }

    #[test]
    fn objects_keep_clear_of_the_path_and_ground_truth_includes_them() {
        let path: Vec<(f64, f64)> = (0..20).map(|i| (i as f64 * 0.1, 0.0)).collect();
        let s = Scene::build(flat(), &path, 2.5, 10, 0.6, 7);
        assert_eq!(s.boxes.len(), 14);
        for b in s.boxes.iter().skip(4) {
            for &(x, y) in &path {
                assert!(!b.covers(x, y));
                assert!((b.cx - x).hypot(b.cy - y) > 0.6);
            }
        }
        let gt = s.ground_truth_elevation();
        let b = s.boxes[4];
        assert!(
            gt.at(b.cx, b.cy).unwrap().is_nan(),
            "unobservable object tops are unknown"
        );
        assert_eq!(gt.at(1.0, 0.0).unwrap(), 0.0);
    }
}
