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
    #[inline(always)]
    fn fill_body(&mut self, depth: &DepthImage, v: usize, span: bool) {
        const R: usize = 2;
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let px = depth.as_slice();
        let [min3, min5, max5, holes5, max3] = &mut self.cols;
        min3.clear();
        min3.resize(w + 2 * R, f32::INFINITY);
        min5.clear();
        min5.resize(w + 2 * R, f32::INFINITY);
        max5.clear();
        max5.resize(w + 2 * R, 0.0);
        holes5.clear();
        holes5.resize(w + 2 * R, 0.0);
        max3.clear();
        max3.resize(w + 2 * R, 0.0);
        for y in v.saturating_sub(R)..(v + R + 1).min(h) {
            let Some(row) = px.get(y * w..(y + 1) * w) else {
                continue;
            };
            let middle = y + 1 >= v && y <= v + 1;
            let lo = if middle { &mut *min3 } else { &mut *min5 };
            for (m, &d) in lo.iter_mut().skip(R).zip(row) {
                let ok = returned(d);
                *m = min_of(*m, if ok { d } else { f32::INFINITY });
            }
            for (m, &d) in holes5.iter_mut().skip(R).zip(row) {
                let ok = returned(d);
                *m = max_of(*m, if ok { 0.0 } else { 1.0 });
            }
            if middle {
                for (m, &d) in max3.iter_mut().skip(R).zip(row) {
                    let ok = returned(d);
                    *m = max_of(*m, if ok { d } else { 0.0 });
                }
            }
            if span {
                for (m, &d) in max5.iter_mut().skip(R).zip(row) {
                    let ok = returned(d);
                    *m = max_of(*m, if ok { d } else { 0.0 });
                }
            }
        }
        for (a, &b) in min5.iter_mut().zip(min3.iter()) {
            *a = min_of(*a, b);
        }
        // Windows of three (around the middle of five) and of five columns, one shifted
        // slice at a time.
        window_fold(&mut self.near1, min3, 1..4, w, min_of);
        window_fold(&mut self.near2, min5, 0..5, w, min_of);
        window_fold(&mut self.hole2, holes5, 0..5, w, max_of);
        window_fold(&mut self.far1, max3, 1..4, w, max_of);
        if span {
            window_fold(&mut self.span2, max5, 0..5, w, max_of);
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

/// `out[i] = pick` over `padded[i + k]` for `k` in `ks`, for `i` below `w`: each pass an
/// element-wise `pick` of two slices, which vectorises.
#[inline(always)]
fn window_fold(
    out: &mut Vec<f32>,
    padded: &[f32],
    mut ks: std::ops::Range<usize>,
    w: usize,
    pick: fn(f32, f32) -> f32,
) {
    out.clear();
    let first = ks.next().unwrap_or(0);
    out.extend_from_slice(padded.get(first..first + w).unwrap_or(&[]));
    out.resize(w, f32::INFINITY);
    for k in ks {
        for (o, &c) in out.iter_mut().zip(padded.get(k..).unwrap_or(&[])) {
            *o = pick(*o, c);
        }
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
}
