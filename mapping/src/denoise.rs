//! Edge-preserving smoothing of depth images before the stack map.
//!
//! A structured-light or time-of-flight depth pixel is off along its ray by `sigma_d`
//! (1.8 cm at 2.4 m for the PrimeSense model), which puts it in the wrong cell whenever the
//! ray is not vertical: points of a wall seen head-on land several 1 cm cells in front of
//! it and raise the floor's cells there to the wall's heights. Averaging each pixel with its
//! neighbours on the same surface shrinks that error before the points are binned, as
//! KinectFusion's bilateral filter does before its surface estimate.
//!
//! The average is of inverse depth, over pairs of neighbours placed symmetrically about the
//! pixel, each pair joining only when both lie within `sigmas` standard deviations of the
//! pixel's depth. Inverse depth is an affine function of the pixel coordinates on a plane,
//! so a symmetric pair averages to the centre's value and a plane keeps its place exactly,
//! whichever pairs the threshold leaves out. Across a depth jump the far side fails the
//! test, so edges, and the flying pixels the edge filter then looks for, stay where they
//! were. A pixel without a return stays without one.

use crate::error::MappingError;
use crate::input::{F32Consts, HeightModel};
use rayon::prelude::*;
use stride_core::image::DepthImage;

/// Columns processed together: the accumulators live on the stack.
const BLOCK: usize = 64;

/// Parameters of the depth smoothing ([`crate::stack::StackConfig::depth_smoothing`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthSmoothing {
    /// Half-width of the square window (px): 2 averages over 5 x 5 pixels.
    pub radius_px: usize,
    /// A neighbour joins the average when its depth is within this many standard
    /// deviations `sigma_d(d)` of the pixel's depth `d` (the sensor model's).
    pub sigmas: f64,
}

impl Default for DepthSmoothing {
    /// 5 x 5 pixels, neighbours within 2 `sigma_d`.
    fn default() -> Self {
        Self {
            radius_px: 2,
            sigmas: 2.0,
        }
    }
}

impl DepthSmoothing {
    /// Largest accepted [`DepthSmoothing::radius_px`].
    pub const MAX_RADIUS_PX: usize = 4;

    /// Checks the parameters: the radius within 1 to [`DepthSmoothing::MAX_RADIUS_PX`],
    /// `sigmas` finite and positive (errors name them as keys of the stack map's
    /// configuration, `depth_smoothing.radius_px` and `depth_smoothing.sigmas`).
    pub fn validate(&self) -> Result<(), MappingError> {
        if !(1..=Self::MAX_RADIUS_PX).contains(&self.radius_px) {
            return Err(MappingError::Parameter {
                name: "depth_smoothing.radius_px",
                value: self.radius_px as f64,
                reason: "must lie within 1 to 4 pixels",
            });
        }
        crate::error::positive("depth_smoothing.sigmas", self.sigmas)
    }
}

/// The smoothing's buffers, kept from frame to frame so that a frame allocates nothing.
#[derive(Debug, Default)]
pub(crate) struct Smoother {
    /// Inverse depth (1/m, 0 without a return), padded by the radius on every side.
    inverse: Vec<f32>,
    /// After the pass along the rows, padded the same way.
    across: Vec<f32>,
    /// The largest inverse-depth difference a neighbour of each pixel may have (1/m).
    tol: Vec<f32>,
    /// The smoothed image of the last frame.
    out: Option<DepthImage>,
}

impl Smoother {
    /// Bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        (self.inverse.capacity() + self.across.capacity() + self.tol.capacity())
            * std::mem::size_of::<f32>()
            + self
                .out
                .as_ref()
                .map_or(0, |o| std::mem::size_of_val(o.as_slice()))
    }

    /// Takes the output image out (to be given back with [`Smoother::restore`]) after
    /// smoothing `depth` (m, 0 or non-finite without a return) with `cfg`, `sigma_d` from
    /// `model`. The image has `depth`'s size.
    ///
    /// The window is separable: pairs along the row, then pairs along the column of the
    /// row pass's means, each pair tested against the pixel's own (row-pass) value. On a
    /// plane both passes are exact, and they average `(2 r + 1)²` pixels as the square
    /// window would, at a third of the work for `r` = 2.
    pub(crate) fn smooth<M: HeightModel + ?Sized>(
        &mut self,
        depth: &DepthImage,
        model: &M,
        cfg: &DepthSmoothing,
    ) -> DepthImage {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let mut out = match self.out.take() {
            Some(o) if (o.width(), o.height()) == (depth.width(), depth.height()) => o,
            _ => DepthImage::filled(depth.width(), depth.height(), 0.0),
        };
        if w == 0 || h == 0 {
            return out;
        }
        let r = cfg.radius_px;
        let pw = w + 2 * r;
        let padded = pw * (h + 2 * r);
        for buf in [&mut self.inverse, &mut self.across] {
            buf.clear();
            buf.resize(padded, 0.0);
        }
        self.tol.clear();
        self.tol.resize(w * h, 0.0);
        let (k, sigma) = (cfg.sigmas as f32, model.f32_consts());
        // The padding rows are left out by slicing, not by rayon's `skip`, which spawns a
        // task (a heap allocation) for the rows it skips.
        let inner = r * pw..(r + h) * pw;
        self.inverse
            .get_mut(inner.clone())
            .unwrap_or(&mut [])
            .par_chunks_mut(pw)
            .zip(self.tol.par_chunks_mut(w))
            .zip(depth.as_slice().par_chunks(w))
            .for_each(|((q, tol), d)| {
                let q = q.get_mut(r..).unwrap_or(&mut []);
                crate::simd::dispatch(InvertRow {
                    q,
                    tol,
                    d,
                    k,
                    sigma,
                    model: std::marker::PhantomData::<&M>,
                });
            });
        let (inverse, tol) = (&self.inverse, &self.tol);
        // Along the rows.
        self.across
            .get_mut(inner)
            .unwrap_or(&mut [])
            .par_chunks_mut(pw)
            .enumerate()
            .for_each(|(v, dst)| {
                let row = inverse.get((v + r) * pw..(v + r + 1) * pw).unwrap_or(&[]);
                let t = tol.get(v * w..(v + 1) * w).unwrap_or(&[]);
                let pairs = (1..=r).map(|dx| {
                    (
                        row.get(r + dx..r + dx + w).unwrap_or(&[]),
                        row.get(r - dx..r - dx + w).unwrap_or(&[]),
                    )
                });
                let centre = row.get(r..r + w).unwrap_or(&[]);
                let dst = dst.get_mut(r..r + w).unwrap_or(&mut []);
                crate::simd::dispatch(MeanRow {
                    centre,
                    tol: t,
                    pairs,
                    dst,
                    depth: None,
                });
            });
        let across = &self.across;
        // Along the columns, into depth.
        out.as_mut_slice()
            .par_chunks_mut(w)
            .zip(depth.as_slice().par_chunks(w))
            .enumerate()
            .for_each(|(v, (dst, d))| {
                let at = |y: usize| across.get(y * pw + r..y * pw + r + w).unwrap_or(&[]);
                let t = tol.get(v * w..(v + 1) * w).unwrap_or(&[]);
                let pairs = (1..=r).map(|dy| (at(v + r + dy), at(v + r - dy)));
                crate::simd::dispatch(MeanRow {
                    centre: at(v + r),
                    tol: t,
                    pairs,
                    dst,
                    depth: Some(d),
                });
            });
        out
    }

    /// Gives back the image [`Smoother::smooth`] returned, for the next frame.
    pub(crate) fn restore(&mut self, out: DepthImage) {
        self.out = Some(out);
    }
}

/// A row of [`Smoother::smooth`]'s first pass, run by [`crate::simd::dispatch`] in the
/// copy for this CPU's instruction set (the same results): `q[i]` the inverse depth of
/// `d[i]` (1/m, 0 without a return), `tol[i]` the largest inverse-depth difference a
/// neighbour may have (1/m): that of a depth `k sigma_d(d)` away, to first order.
struct InvertRow<'a, M: ?Sized> {
    q: &'a mut [f32],
    tol: &'a mut [f32],
    d: &'a [f32],
    k: f32,
    /// The sensor model's constants ([`HeightModel::f32_consts`]), by value so that the
    /// loop holds them in registers.
    sigma: F32Consts,
    model: std::marker::PhantomData<&'a M>,
}

impl<M: HeightModel + ?Sized> pulp::WithSimd for InvertRow<'_, M> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let Self {
            q,
            tol,
            d,
            k,
            sigma,
            ..
        } = self;
        for ((q, t), &d) in q.iter_mut().zip(tol.iter_mut()).zip(d) {
            let ok = (d > 0.0) & (d < f32::INFINITY);
            let inv = 1.0 / d;
            *q = if ok { inv } else { 0.0 };
            let t_ok = k * M::depth_sigma_f32(&sigma, d) * inv * inv;
            *t = if ok { t_ok } else { 0.0 };
        }
    }
}

/// A row of a pass along rows or columns, run as [`InvertRow`]: [`mean_of_pairs`]; with
/// `depth` (the row's input depths, m) the means are turned back into depths, and a pixel
/// without a return keeps its own value (0 or non-finite).
struct MeanRow<'a, P> {
    centre: &'a [f32],
    tol: &'a [f32],
    pairs: P,
    dst: &'a mut [f32],
    depth: Option<&'a [f32]>,
}

impl<'a, P> pulp::WithSimd for MeanRow<'a, P>
where
    P: Iterator<Item = (&'a [f32], &'a [f32])> + Clone,
{
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        mean_of_pairs(self.centre, self.tol, self.pairs, &mut *self.dst);
        for (o, &d) in self.dst.iter_mut().zip(self.depth.unwrap_or(&[])) {
            let ok = (d > 0.0) & (d < f32::INFINITY);
            let smoothed = 1.0 / *o;
            *o = if ok { smoothed } else { d };
        }
    }
}

/// `dst[i]`: the mean of `centre[i]` and of each pair `(a[i], b[i])` whose two values are
/// present (above 0) and within `tol[i]` of `centre[i]`; 0 where `centre[i]` is 0. In
/// blocks whose accumulators stay on the stack, by loops the compiler vectorises.
#[inline(always)]
fn mean_of_pairs<'p>(
    centre: &[f32],
    tol: &[f32],
    pairs: impl Iterator<Item = (&'p [f32], &'p [f32])> + Clone,
    dst: &mut [f32],
) {
    let w = dst.len().min(centre.len()).min(tol.len());
    let mut u0 = 0;
    while u0 < w {
        let n = BLOCK.min(w - u0);
        let (mut sum, mut count) = ([0f32; BLOCK], [0f32; BLOCK]);
        let (Some(q), Some(t)) = (centre.get(u0..u0 + n), tol.get(u0..u0 + n)) else {
            break;
        };
        let (sum, count) = (&mut sum[..n], &mut count[..n]);
        sum.copy_from_slice(q);
        count.fill(1.0);
        for (a, b) in pairs.clone() {
            let (Some(a), Some(b)) = (a.get(u0..u0 + n), b.get(u0..u0 + n)) else {
                continue;
            };
            for ((s, c), ((&qi, &ti), (&ai, &bi))) in sum
                .iter_mut()
                .zip(count.iter_mut())
                .zip(q.iter().zip(t).zip(a.iter().zip(b)))
            {
                let ok =
                    (ai > 0.0) & (bi > 0.0) & ((ai - qi).abs() <= ti) & ((bi - qi).abs() <= ti);
                *s += if ok { ai + bi } else { 0.0 };
                *c += if ok { 2.0 } else { 0.0 };
            }
        }
        for ((o, &qi), (&s, &c)) in dst
            .iter_mut()
            .skip(u0)
            .zip(q)
            .zip(sum.iter().zip(count.iter()))
        {
            *o = if qi > 0.0 { s / c } else { 0.0 };
        }
        u0 += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::PrimeSenseHeight;

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> DepthImage {
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y));
        DepthImage::from_vec(w, h, data.collect()).unwrap()
    }

    /// A tilted plane (inverse depth affine in the pixel) keeps every depth, the image's
    /// borders included, and noise on it shrinks.
    #[test]
    fn a_plane_stays_in_place_and_its_noise_shrinks() {
        let plane = |x: u32, y: u32| 1.0 / (0.4 + 0.001 * x as f32 + 0.002 * y as f32);
        let clean = image(40, 30, plane);
        let model = PrimeSenseHeight::default();
        let mut s = Smoother::default();
        let out = s.smooth(&clean, &model, &DepthSmoothing::default());
        for (a, b) in out.as_slice().iter().zip(clean.as_slice()) {
            assert!((a - b).abs() < 1e-5 * b, "{a} against {b}");
        }
        s.restore(out);
        // Alternating +-5 mm on a plane at about 2.4 m turning 4 mm per pixel: the 5 x 5
        // average leaves 1/25 of it.
        let plane = |x: u32, y: u32| 1.0 / (0.4 + 0.0002 * x as f32 + 0.0004 * y as f32);
        let noisy = image(40, 30, |x, y| {
            plane(x, y) + if (x + y) % 2 == 0 { 0.005 } else { -0.005 }
        });
        let out = s.smooth(&noisy, &model, &DepthSmoothing::default());
        let err = |i: &DepthImage| {
            let inner = (5..25).flat_map(|y| (5..35).map(move |x| (x, y)));
            inner
                .map(|(x, y)| (i.get(x, y).unwrap() - plane(x, y)).abs())
                .fold(0f32, f32::max)
        };
        assert!(err(&out) < 0.0005, "{}", err(&out));
    }

    /// A jump of 20 cm at 2 m (11 sigma_d) is left sharp: no pixel on either side moves
    /// towards the other, and holes stay holes.
    #[test]
    fn a_depth_jump_and_holes_are_kept() {
        let step = image(20, 10, |x, y| match (x, y) {
            (3, 3) => 0.0,
            (x, _) if x < 10 => 2.0,
            _ => 2.2,
        });
        let mut s = Smoother::default();
        let out = s.smooth(
            &step,
            &PrimeSenseHeight::default(),
            &DepthSmoothing::default(),
        );
        for (a, b) in out.as_slice().iter().zip(step.as_slice()) {
            assert!((a - b).abs() <= 1e-6 * b, "{a} against {b}");
        }
    }

    #[test]
    fn parameters_are_checked() {
        let bad = |radius_px, sigmas| DepthSmoothing { radius_px, sigmas }.validate().is_err();
        assert!(bad(0, 2.0) && bad(5, 2.0) && bad(2, 0.0) && bad(2, f64::NAN));
        assert!(!bad(1, 0.5));
    }
}
