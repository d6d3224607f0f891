//! Each depth pixel's neighbourhood, row by row: the nearest depths one and two pixels
//! around (the depth-edge filter's inputs), the farthest depth one pixel around and
//! whether a return is missing within two (where the filter's sliver test looks), and the
//! span of the 5 x 5 neighbourhood (the smoothness test's), from one branch-free pass over
//! five rows.

use stride_core::image::DepthImage;

/// A row's view of each pixel's neighbourhood in the depth image, the inputs of the edge
/// filter (`DepthSlice::is_edge` in `binned`) and of the smoothness test: the nearest non-zero depth
/// (m) one and two pixels around (the 3 x 3 and 5 x 5 neighbourhoods, the pixel included,
/// clipped at the image's borders; infinity where there is none, and everywhere without
/// an edge filter) and, on request, the span (largest minus smallest, m) of the non-zero
/// depths of the 5 x 5 neighbourhood (0 with one depth; infinity when not asked for).
/// Missing returns (0, NaN, infinities) are left out: a hole is no jump.
#[derive(Debug, Clone, Default)]
pub(crate) struct Neighbourhood {
    /// Nearest depth within one pixel.
    pub(crate) near1: Vec<f32>,
    /// Nearest depth within two pixels.
    pub(crate) near2: Vec<f32>,
    /// Span of the depths within two pixels.
    pub(crate) span2: Vec<f32>,
    /// 1 where a pixel within two (the 5 x 5 neighbourhood, clipped at the image's
    /// borders) has no return, else 0 (everywhere 0 without an edge filter).
    pub(crate) hole2: Vec<f32>,
    /// Farthest depth within one pixel (0 where there is none, and everywhere without an
    /// edge filter).
    pub(crate) far1: Vec<f32>,
    /// Scratch: per column, the minimum over the three middle rows, the minimum and the
    /// maximum over all five, whether one of the five has no return, and the maximum over
    /// the three middle rows, each padded with two neutral values at both ends.
    cols: [Vec<f32>; 5],
}

impl Neighbourhood {
    /// Bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        [
            &self.near1,
            &self.near2,
            &self.span2,
            &self.hole2,
            &self.far1,
        ]
        .into_iter()
        .chain(&self.cols)
        .map(|v| v.capacity() * std::mem::size_of::<f32>())
        .sum()
    }

    /// Fills the fields for row `v` of `depth` (`span` on request) in one pass over its five
    /// rows, branch-free so that it vectorises (in the copy for this CPU's instruction set:
    /// [`crate::simd`]; the same results).
    pub(crate) fn fill(&mut self, depth: &DepthImage, v: usize, span: bool) {
        crate::simd::dispatch(Fill {
            nb: self,
            depth,
            v,
            span,
        });
    }

    /// The body of [`Neighbourhood::fill`], inlined into each instruction set's copy.
    ///
    /// Every loop writes values computed from other buffers, never a minimum or maximum of
    /// the buffer it writes: such an update, where one choice keeps the old value, compiles
    /// to a masked store, which AMD's cores run microcoded (docs/mapping.md, "Minimum and
    /// maximum as integers").
    #[inline(always)]
    fn fill_body(&mut self, depth: &DepthImage, v: usize, span: bool) {
        const R: usize = 2;
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let px = depth.as_slice();
        let [min3, min5, max5, holes5, max3] = &mut self.cols;
        for (col, neutral) in [
            (&mut *min3, f32::INFINITY),
            (&mut *min5, f32::INFINITY),
            (&mut *max5, 0.0),
            (&mut *holes5, 0.0),
            (&mut *max3, 0.0),
        ] {
            col.clear();
            col.resize(w + 2 * R, neutral);
        }
        // The five rows around `v`; a row past the image's border is the pixel's own, which
        // changes no minimum, maximum or hole.
        let row = |y: usize| px.get(y * w..(y + 1) * w).filter(|_| y < h);
        let centre = row(v).unwrap_or(&[]);
        let at = |dy: isize| v.checked_add_signed(dy).and_then(&row).unwrap_or(centre);
        let rows = [at(-2), at(-1), centre, at(1), at(2)];
        let n = rows.iter().map(|r| r.len()).min().unwrap_or(0);
        let [r0, r1, r2, r3, r4] = rows.map(|r| r.get(..n).unwrap_or(&[]));
        // Padded by R on both sides, so pixel i is entry i + R.
        let (lo3, lo5) = (&mut min3[R..R + n], &mut min5[R..R + n]);
        let (hi3, hi5, any) = (
            &mut max3[R..R + n],
            &mut max5[R..R + n],
            &mut holes5[R..R + n],
        );
        for i in 0..n {
            let d = [r0[i], r1[i], r2[i], r3[i], r4[i]];
            let near = d.map(|d| if returned(d) { d } else { f32::INFINITY });
            let far = d.map(|d| if returned(d) { d } else { 0.0 });
            let hole = d.map(|d| if returned(d) { 0.0 } else { 1.0 });
            let m3 = min_of(min_of(near[1], near[2]), near[3]);
            lo3[i] = m3;
            lo5[i] = min_of(min_of(m3, near[0]), near[4]);
            let x3 = max_of(max_of(far[1], far[2]), far[3]);
            hi3[i] = x3;
            hi5[i] = max_of(max_of(x3, far[0]), far[4]);
            any[i] = max_of(
                max_of(max_of(hole[0], hole[1]), max_of(hole[2], hole[3])),
                hole[4],
            );
        }
        // Windows of three (around the middle of five) and of five columns.
        window_fold::<3>(&mut self.near1, min3, 1, w, min_of);
        window_fold::<5>(&mut self.near2, min5, 0, w, min_of);
        window_fold::<5>(&mut self.hole2, holes5, 0, w, max_of);
        window_fold::<3>(&mut self.far1, max3, 1, w, max_of);
        if span {
            window_fold::<5>(&mut self.span2, max5, 0, w, max_of);
            for (s, &lo) in self.span2.iter_mut().zip(&self.near2) {
                *s = (*s - lo).max(0.0);
            }
        } else {
            self.span2.clear();
            self.span2.resize(w, f32::INFINITY);
        }
    }

    /// Infinity everywhere and no hole (no edge filter): `w` pixels.
    pub(crate) fn none(&mut self, w: usize) {
        for f in [&mut self.near1, &mut self.near2, &mut self.span2] {
            f.clear();
            f.resize(w, f32::INFINITY);
        }
        for f in [&mut self.hole2, &mut self.far1] {
            f.clear();
            f.resize(w, 0.0);
        }
    }
}

/// The arguments of [`Neighbourhood::fill`], for [`crate::simd::dispatch`].
struct Fill<'a> {
    nb: &'a mut Neighbourhood,
    depth: &'a DepthImage,
    v: usize,
    span: bool,
}

impl pulp::WithSimd for Fill<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        self.nb.fill_body(self.depth, self.v, self.span);
    }
}

/// Whether a depth (m) is a return: positive and finite (0, NaN and the infinities are
/// missing returns). Free of branches, for the vectorised passes.
#[inline(always)]
pub(crate) fn returned(d: f32) -> bool {
    (d > 0.0) & (d < f32::INFINITY)
}

/// The smaller of two depths that are never NaN nor negative (missing returns are infinity
/// or +0 here). For such floats the order of their bit patterns as unsigned integers is the
/// order of their values, so this is one integer minimum per lane. A comparison and a
/// select compiled, in the read-modify-write loops of [`Neighbourhood::fill`], to a masked
/// store, which AMD's cores run microcoded, many times slower (docs/mapping.md, "Minimum
/// and maximum as integers").
#[inline(always)]
pub(crate) fn min_of(a: f32, b: f32) -> f32 {
    debug_assert!(a >= 0.0 && b >= 0.0 && a.is_sign_positive() && b.is_sign_positive());
    f32::from_bits(a.to_bits().min(b.to_bits()))
}

/// The larger of two depths that are never NaN nor negative (see [`min_of`]).
#[inline(always)]
fn max_of(a: f32, b: f32) -> f32 {
    debug_assert!(a >= 0.0 && b >= 0.0 && a.is_sign_positive() && b.is_sign_positive());
    f32::from_bits(a.to_bits().max(b.to_bits()))
}

/// `out[i] = pick` over `padded[i + first + k]` for `k` below `N`, for `i` below `w`, in
/// one pass that writes each entry once (see [`Neighbourhood::fill_body`]).
#[inline(always)]
fn window_fold<const N: usize>(
    out: &mut Vec<f32>,
    padded: &[f32],
    first: usize,
    w: usize,
    pick: fn(f32, f32) -> f32,
) {
    out.clear();
    out.resize(w, f32::INFINITY);
    let shifted: [&[f32]; N] =
        std::array::from_fn(|k| padded.get(first + k..first + k + w).unwrap_or(&[]));
    let n = shifted.iter().map(|s| s.len()).min().unwrap_or(0);
    let shifted = shifted.map(|s| s.get(..n).unwrap_or(&[]));
    for (i, o) in out.iter_mut().take(n).enumerate() {
        let mut m = shifted[0][i];
        for s in &shifted[1..] {
            m = pick(m, s[i]);
        }
        *o = m;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Missing returns are left out whatever their encoding (0, NaN, infinity), so no NaN
    /// reaches the passes' plain comparisons ([`min_of`]): a hole beside a depth jump gives
    /// the same nearest depths and span as a 0, and they are those of the depths around it.
    #[test]
    fn a_missing_return_is_left_out_however_it_is_encoded() {
        let fill = |hole: f32| {
            let mut depth = DepthImage::filled(8, 6, 2.0);
            for v in 0..6 {
                for u in 4..8 {
                    *depth.get_mut(u, v).unwrap() = 1.0;
                }
            }
            *depth.get_mut(3, 2).unwrap() = hole;
            let mut nb = Neighbourhood::default();
            nb.fill(&depth, 2, true);
            (nb.near1, nb.near2, nb.span2)
        };
        let zero = fill(0.0);
        for hole in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -1.0] {
            let got = fill(hole);
            assert_eq!(got, zero, "hole encoded as {hole}");
        }
        let (near1, near2, span2) = zero;
        // Pixel 3 (the hole) sees the 1 m side one pixel away, pixel 2 two away, pixel 1 not.
        assert_eq!(
            (near1[3], near1[2], near2[2], near2[1]),
            (1.0, 2.0, 1.0, 2.0)
        );
        assert_eq!((span2[0], span2[2], span2[7]), (0.0, 1.0, 0.0));
        assert!(near1
            .iter()
            .chain(&near2)
            .chain(&span2)
            .all(|v| !v.is_nan()));
    }

    /// Every channel equals its definition, computed pixel by pixel over the clipped window,
    /// on an image with holes in every encoding, at the borders too, for each row.
    #[test]
    fn every_channel_is_its_window_over_the_clipped_neighbourhood() {
        let (w, h) = (13u32, 7u32);
        let mut depth = DepthImage::filled(w, h, 0.0);
        let mut state = 12345u32;
        for v in 0..h {
            for u in 0..w {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                let r = (state >> 8) as f32 / (1u32 << 24) as f32;
                let d = match (state >> 4) % 9 {
                    0 => 0.0,
                    1 => f32::NAN,
                    2 => f32::INFINITY,
                    _ => 0.5 + 3.0 * r,
                };
                *depth.get_mut(u, v).unwrap() = d;
            }
        }
        let got = |u: i64, v: i64| -> Option<f32> {
            let inside = u >= 0 && v >= 0 && u < i64::from(w) && v < i64::from(h);
            inside.then(|| depth.get(u as u32, v as u32).unwrap())
        };
        let mut nb = Neighbourhood::default();
        for v in 0..h as usize {
            nb.fill(&depth, v, true);
            for u in 0..w as usize {
                let window = |r: i64| {
                    let mut ds = Vec::new();
                    for dv in -r..=r {
                        for du in -r..=r {
                            ds.extend(got(u as i64 + du, v as i64 + dv));
                        }
                    }
                    ds
                };
                let ret = |ds: &[f32]| {
                    ds.iter()
                        .copied()
                        .filter(|&d| returned(d))
                        .collect::<Vec<_>>()
                };
                let (w1, w2) = (ret(&window(1)), ret(&window(2)));
                let min = |ds: &[f32]| ds.iter().copied().fold(f32::INFINITY, f32::min);
                let max = |ds: &[f32]| ds.iter().copied().fold(0.0, f32::max);
                let hole = window(2).iter().any(|&d| !returned(d));
                let span = if w2.is_empty() {
                    0.0
                } else {
                    max(&w2) - min(&w2)
                };
                let at = format!("pixel ({u}, {v})");
                assert_eq!(nb.near1[u], min(&w1), "{at}");
                assert_eq!(nb.near2[u], min(&w2), "{at}");
                assert_eq!(nb.far1[u], max(&w1), "{at}");
                assert_eq!(nb.hole2[u], f32::from(u8::from(hole)), "{at}");
                assert_eq!(nb.span2[u], span, "{at}");
            }
        }
    }
}
