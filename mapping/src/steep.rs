//! Points of steep faces moved behind them, before the stack map reads a depth image.
//!
//! Depth noise moves a point along its ray. At range the rays are nearly horizontal, so the
//! points of a wall or a box's face seen head-on spread over several 1 cm cells in front of
//! it, and the floor's cells there take the face's heights: on the synthetic lab's walks
//! most of the map's error near steps. Smoothing ([`crate::denoise`]) shrinks the
//! independent part of that noise, not the part a structured-light sensor shares between
//! neighbouring pixels (its disparity steps, its correlated blocks).
//!
//! A face steeper than [`STEEP_DEG`] is solid behind itself in a 2.5-D map: its cells are
//! the obstacle's. So each pixel on such a face is moved `sigmas` standard deviations
//! `sigma_d(d)` farther along its ray, which puts nearly all of its points at or behind
//! the face, where the obstacle's cells are, and leaves the floor before it to the floor's
//! points. Its height changes by the ray's slope times that distance only. Nothing else
//! moves: floors, ramps, box tops, pixels at a depth jump (where the slope is not the
//! surface's) and pixels without a return.
//!
//! The surface's slope comes from the 3-D points [`RADIUS_PX`] pixels to either side of the
//! pixel, along the row and along the column (the cross product of the two differences),
//! against the world's up direction seen in the camera frame. Within [`RADIUS_PX`] of the
//! image's border the pixel itself stands in for the missing side. The border matters: a
//! wall's highest points are in the image's top rows, and unmoved they would lift the
//! floor's cells before it to the wall's height.

use crate::input::{F32Consts, HeightModel};
use nalgebra::Vector3;
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// Half the baseline of the slope estimate (px): the neighbours 3 pixels away on each side,
/// far enough apart that the sensor's disparity steps (about 2.6 cm at 3 m for a Kinect)
/// do not tip a wall's slope, near enough to stay on one face of a 10 cm box at 3 m.
pub const RADIUS_PX: usize = 3;

/// A face is steep when its normal is more than this far from the vertical (deg): walls,
/// box faces and step risers, not walkable slopes.
pub const STEEP_DEG: f32 = 45.0;

/// The neighbours joining the slope estimate differ from the pixel's depth by at most this
/// fraction of it: a face seen 80 degrees from head-on still passes, a depth jump (the
/// top edge of a box against the floor behind it) does not.
const JUMP_REL: f32 = 0.1;

/// The buffer of the moved image, kept from frame to frame so that a frame allocates
/// nothing.
#[derive(Debug, Default)]
pub(crate) struct SteepPush {
    out: Option<DepthImage>,
    /// 1 for each pixel of the last frame that was moved, row-major.
    moved: Vec<u8>,
}

/// What [`SteepPush::push`] needs of the frame besides its depth image.
pub(crate) struct PushFrame<'a, M: ?Sized> {
    /// The camera the depth image is registered to.
    pub(crate) camera: &'a PinholeCamera,
    /// The world's up direction in the camera frame (unit).
    pub(crate) up_camera: Vector3<f64>,
    /// The sensor model giving `sigma_d`.
    pub(crate) model: &'a M,
    /// How far a steep pixel moves, in `sigma_d`.
    pub(crate) sigmas: f32,
}

impl SteepPush {
    /// Bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        self.out
            .as_ref()
            .map_or(0, |o| std::mem::size_of_val(o.as_slice()))
            + self.moved.capacity()
    }

    /// Which pixels of the last [`SteepPush::push`] moved (1) or not (0), row-major: their
    /// points are on a face, a bound below the height of the cell they land in, not a
    /// measurement of its top ([`crate::input::CellPoint::face`]).
    pub(crate) fn moved(&self) -> &[u8] {
        &self.moved
    }

    /// Takes the output image out (to be given back with [`SteepPush::restore`]): `depth`
    /// (m, 0 or non-finite without a return) with each pixel on a steep face moved
    /// `f.sigmas` `sigma_d` farther, and the number of pixels moved. The image has
    /// `depth`'s size.
    pub(crate) fn push<M: HeightModel + ?Sized>(
        &mut self,
        depth: &DepthImage,
        f: &PushFrame<'_, M>,
    ) -> (DepthImage, usize) {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let mut out = match self.out.take() {
            Some(o) if (o.width(), o.height()) == (depth.width(), depth.height()) => o,
            _ => DepthImage::filled(depth.width(), depth.height(), 0.0),
        };
        let src = depth.as_slice();
        self.moved.clear();
        self.moved.resize(src.len(), 0);
        let consts = Consts::new(f.camera, &f.up_camera, f.sigmas, f.model.f32_consts());
        let r = consts.r;
        if w <= r || h <= r {
            // Too small for a slope: nothing moves.
            out.as_mut_slice().copy_from_slice(src);
            return (out, 0);
        }
        let pushed = out
            .as_mut_slice()
            .par_chunks_mut(w.max(1))
            .zip(self.moved.par_chunks_mut(w.max(1)))
            .enumerate()
            .map(|(v, (dst, moved))| {
                let at = |y: usize| src.get(y * w..(y + 1) * w).unwrap_or(&[]);
                // The rows r above and below, or the pixel's own at the border.
                let (va, vb) = (v.saturating_sub(r), (v + r).min(h - 1));
                let ys = [va, v, vb].map(|y| (y as f32 - consts.c[1]) * consts.inv_f[1]);
                // The row pass does pixels r..w - r, the scalar test the columns beside.
                crate::simd::dispatch(PushRow {
                    rows: [at(v), at(va), at(vb)],
                    ys,
                    dst: &mut *dst,
                    moved: &mut *moved,
                    k: consts,
                    model: std::marker::PhantomData::<&M>,
                });
                for u in (0..r.min(w)).chain(w.saturating_sub(r).max(r)..w) {
                    let d = src.get(v * w + u).copied().unwrap_or(0.0);
                    let steep = steep_pixel(src, w, h, u, v, &consts);
                    if let (Some(o), Some(m)) = (dst.get_mut(u), moved.get_mut(u)) {
                        *o = if steep { consts.pushed::<M>(d) } else { d };
                        *m = u8::from(steep);
                    }
                }
                moved.iter().map(|&m| usize::from(m)).sum::<usize>()
            })
            .sum();
        (out, pushed)
    }

    /// Gives back the image [`SteepPush::push`] returned, for the next frame.
    pub(crate) fn restore(&mut self, out: DepthImage) {
        self.out = Some(out);
    }
}

/// Whether a pixel lies on a steep face: `d` = [its depth, the depths of its neighbours
/// left, right, above and below] (m), `xs` = the normalised x of [the left neighbour, the
/// pixel, the right neighbour], `ys` = the normalised y of [the row above, the pixel's,
/// the row below], `up` the world's up in the camera frame and `cos2` the squared cosine of
/// [`STEEP_DEG`]. False when a depth is missing or a neighbour lies beyond [`JUMP_REL`].
/// Free of branches (it runs in vectorised loops).
#[inline(always)]
fn steep_at(
    [d, dl, dr, da, db]: [f32; 5],
    [xl, x, xr]: [f32; 3],
    [ya, y, yb]: [f32; 3],
    [ux, uy, uz]: [f32; 3],
    cos2: f32,
) -> bool {
    let near = |q: f32| (q > 0.0) & ((q - d).abs() <= JUMP_REL * d);
    let ok = (d > 0.0) & (d < f32::INFINITY) & near(dl) & near(dr) & near(da) & near(db);
    // The 3-D differences across the pixel along the row and along the column.
    let a = [xr * dr - xl * dl, y * (dr - dl), dr - dl];
    let b = [x * (db - da), yb * db - ya * da, db - da];
    let nrm = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let up_n = nrm[0] * ux + nrm[1] * uy + nrm[2] * uz;
    let nn = nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2];
    ok & (up_n * up_n < cos2 * nn)
}

/// The test [`SteepPush`] moves pixels by, one pixel at a time (for sampled pixels, as the
/// view alignment takes them), with a view's constants computed once.
pub(crate) struct SteepTest(Consts);

impl SteepTest {
    /// The test for a view seen by `camera` whose frame has the world's up along
    /// `up_camera`.
    pub(crate) fn new(camera: &PinholeCamera, up_camera: &Vector3<f64>) -> Self {
        Self(Consts::new(camera, up_camera, 0.0, F32Consts::default()))
    }

    /// Whether pixel `(u, v)` of `depth` (m) lies on a face steeper than [`STEEP_DEG`];
    /// false where a depth is missing or across a depth jump.
    pub(crate) fn at(&self, depth: &DepthImage, u: usize, v: usize) -> bool {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        steep_pixel(depth.as_slice(), w, h, u, v, &self.0)
    }
}

/// [`steep_at`] for pixel `(u, v)` of the row-major `w` x `h` depths `src` (m), its
/// neighbours [`RADIUS_PX`] away or, at the border, the pixel itself on the missing side.
/// False outside the image or when it is too small for a slope.
fn steep_pixel(src: &[f32], w: usize, h: usize, u: usize, v: usize, k: &Consts) -> bool {
    let r = k.r;
    if u >= w || v >= h || w <= r || h <= r {
        return false;
    }
    let at = |u: usize, v: usize| src.get(v * w + u).copied().unwrap_or(0.0);
    let (ul, ur) = (u.saturating_sub(r), (u + r).min(w - 1));
    let (va, vb) = (v.saturating_sub(r), (v + r).min(h - 1));
    let [ifx, ify] = k.inv_f;
    let [cx, cy] = k.c;
    steep_at(
        [at(u, v), at(ul, v), at(ur, v), at(u, va), at(u, vb)],
        [ul, u, ur].map(|x| (x as f32 - cx) * ifx),
        [va, v, vb].map(|y| (y as f32 - cy) * ify),
        k.up,
        k.cos2,
    )
}

/// A frame's constants of [`PushRow`], taken by value so that its loop holds them in
/// registers.
#[derive(Debug, Clone, Copy)]
struct Consts {
    /// [`RADIUS_PX`].
    r: usize,
    /// Squared cosine of [`STEEP_DEG`].
    cos2: f32,
    /// The world's up direction in the camera frame.
    up: [f32; 3],
    /// `1 / fx`, `1 / fy` (1/px) and the principal point `cx`, `cy` (px).
    inv_f: [f32; 2],
    c: [f32; 2],
    /// How far a steep pixel moves, in `sigma_d`.
    sigmas: f32,
    /// The sensor model's constants ([`HeightModel::f32_consts`]).
    model: F32Consts,
}

impl Consts {
    /// The constants for `camera`, the world's up `up_camera` in its frame and a push of
    /// `sigmas` `sigma_d` of the sensor model whose constants are `model`.
    fn new(
        camera: &PinholeCamera,
        up_camera: &Vector3<f64>,
        sigmas: f32,
        model: F32Consts,
    ) -> Self {
        Self {
            r: RADIUS_PX,
            cos2: STEEP_DEG.to_radians().cos().powi(2),
            up: up_camera.cast::<f32>().into(),
            inv_f: [1.0 / camera.fx() as f32, 1.0 / camera.fy() as f32],
            c: [camera.cx() as f32, camera.cy() as f32],
            sigmas,
            model,
        }
    }

    /// Depth `d` (m) moved `sigmas` `sigma_d` farther.
    #[inline(always)]
    fn pushed<M: HeightModel + ?Sized>(&self, d: f32) -> f32 {
        d + self.sigmas * M::depth_sigma_f32(&self.model, d)
    }
}

/// One row of [`SteepPush::push`], run by [`crate::simd::dispatch`] in the copy for this
/// CPU's instruction set (the same results): `rows` are the depths of the row, of the row
/// above and of the row below (m), `ys` their normalised y; `dst` takes the depths of
/// pixels `r..w - r`, moved or not, and `moved` a 1 for each pixel moved.
struct PushRow<'a, M: ?Sized> {
    rows: [&'a [f32]; 3],
    ys: [f32; 3],
    dst: &'a mut [f32],
    moved: &'a mut [u8],
    k: Consts,
    model: std::marker::PhantomData<&'a M>,
}

impl<M: HeightModel + ?Sized> pulp::WithSimd for PushRow<'_, M> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let Self {
            rows: [row, above, below],
            ys: [y_up, y, y_down],
            dst,
            moved,
            k,
            model: _,
        } = self;
        let r = k.r;
        let w = row.len().min(above.len()).min(below.len());
        let Some(n) = w.checked_sub(2 * r) else {
            return;
        };
        // Every slice has length `n` (pixel u = i + r), so the bounds checks go and the
        // loop, free of branches, vectorises.
        let (Some(c), Some(left), Some(right), Some(up_d), Some(down_d)) = (
            row.get(r..r + n),
            row.get(..n),
            row.get(2 * r..2 * r + n),
            above.get(r..r + n),
            below.get(r..r + n),
        ) else {
            return;
        };
        let (Some(dst), Some(moved)) = (dst.get_mut(r..r + n), moved.get_mut(r..r + n)) else {
            return;
        };
        let [ifx, _] = k.inv_f;
        let [cx, _] = k.c;
        let dx = r as f32 * ifx;
        for i in 0..n {
            let d = c[i];
            let x = ((i + r) as f32 - cx) * ifx;
            let steep = steep_at(
                [d, left[i], right[i], up_d[i], down_d[i]],
                [x - dx, x, x + dx],
                [y_up, y, y_down],
                k.up,
                k.cos2,
            );
            let pushed = k.pushed::<M>(d);
            dst[i] = if steep { pushed } else { d };
            moved[i] = u8::from(steep);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::PrimeSenseHeight;

    const CAM: PinholeCamera = PinholeCamera::KINECT_DEFAULT;

    /// A depth image of `depth(u, v)` (m), pushed by 2 `sigma_d` for a camera looking
    /// horizontally (the world's up is the camera's -y): the input, the output, the pixels
    /// moved and which.
    fn pushed(depth: impl Fn(usize, usize) -> f32) -> (DepthImage, DepthImage, usize, Vec<u8>) {
        let (w, h) = (CAM.width(), CAM.height());
        let data = (0..h as usize)
            .flat_map(|v| (0..w as usize).map(move |u| (u, v)))
            .map(|(u, v)| depth(u, v))
            .collect();
        let image = DepthImage::from_vec(w, h, data).unwrap();
        let model = PrimeSenseHeight::default();
        let f = PushFrame {
            camera: &CAM,
            up_camera: -Vector3::y(),
            model: &model,
            sigmas: 2.0,
        };
        let mut push = SteepPush::default();
        let (out, n) = push.push(&image, &f);
        (image, out, n, push.moved().to_vec())
    }

    fn at(image: &DepthImage, u: usize, v: usize) -> f32 {
        image.as_slice()[v * image.width() as usize + u]
    }

    #[test]
    fn a_wall_seen_head_on_moves_back_by_its_noise() {
        let (before, after, n, _) = pushed(|_, _| 2.0);
        let sigma =
            PrimeSenseHeight::depth_sigma_f32(&PrimeSenseHeight::default().f32_consts(), 2.0);
        // Every pixel moves, the border too (its own depth stands in for the missing side):
        // a wall's top rows are its highest points.
        assert_eq!(n, 640 * 480);
        for (u, v) in [(320, 240), (0, 240), (320, 0), (639, 479)] {
            let moved = at(&after, u, v) - at(&before, u, v);
            assert!((moved - 2.0 * sigma).abs() < 1e-6, "({u}, {v}): {moved}");
        }
    }

    #[test]
    fn a_floor_and_a_ramp_stay() {
        // The floor 0.5 m below a camera looking horizontally (y down), seen below the
        // horizon; nothing above it.
        let floor = |_: usize, v: usize| {
            let yn = (v as f32 - 239.5) / 525.0;
            if yn > 0.05 {
                0.5 / yn
            } else {
                0.0
            }
        };
        assert_eq!(pushed(floor).2, 0);
        // A ramp rising 40 degrees away from the camera: still walkable, not moved.
        let t = 40f32.to_radians().tan();
        let ramp = |_: usize, v: usize| {
            // Points (y, z) with y = 0.5 - t (z - 1) and y = yn z: z = (0.5 + t) / (yn + t).
            let yn = (v as f32 - 239.5) / 525.0;
            let z = (0.5 + t) / (yn + t);
            if z > 0.0 && z < 4.0 {
                z
            } else {
                0.0
            }
        };
        assert_eq!(pushed(ramp).2, 0);
    }

    #[test]
    fn pixels_beside_a_depth_jump_and_without_returns_stay() {
        // A wall at 2 m on the left, 3 m on the right, a hole in the middle row.
        let (_, after, n, _) = pushed(|u, v| match (u < 320, v == 240) {
            (_, true) => 0.0,
            (true, false) => 2.0,
            (false, false) => 3.0,
        });
        let r = RADIUS_PX;
        // Within r of the jump nothing moves, nor r rows from the hole's row (a
        // neighbour without a return), nor the hole.
        assert_eq!(at(&after, 319, 100), 2.0);
        assert_eq!(at(&after, 320, 100), 3.0);
        assert_eq!(at(&after, 100, 240 - r), 2.0);
        assert_eq!(at(&after, 100, 240), 0.0);
        assert!(at(&after, 100, 240 - 1) > 2.0);
        assert!(at(&after, 100, 100) > 2.0);
        assert!(at(&after, 500, 100) > 3.0);
        // Rows r above and below the hole see it as a neighbour; the border moves.
        assert!(at(&after, 0, 0) > 2.0 && at(&after, 639, 479) > 3.0);
        assert_eq!(n, (640 - 2 * r) * (480 - 3));
    }

    #[test]
    fn the_one_pixel_test_agrees_with_the_push() {
        // A wall at 2 m on the left and the floor on the right half, below the horizon.
        let depth = |u: usize, v: usize| {
            let yn = (v as f32 - 239.5) / 525.0;
            match (u < 320, yn > 0.05) {
                (true, _) => 2.0,
                (false, true) => 0.5 / yn,
                (false, false) => 0.0,
            }
        };
        let (image, _, n, moved) = pushed(depth);
        let test = SteepTest::new(&CAM, &-Vector3::y());
        let mut agree = 0;
        for v in (0..480).step_by(7) {
            for u in (0..640).step_by(7) {
                let one = test.at(&image, u, v);
                assert_eq!(one, moved[v * 640 + u] == 1, "({u}, {v})");
                agree += usize::from(one);
            }
        }
        assert!(agree > 1000 && n > 100_000, "{agree} {n}");
    }
}
