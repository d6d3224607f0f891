//! The ground's albedo for many surface points at once, bit for bit what
//! [`super::texture::albedo`] gives for each, in a layout that vectorises.
//!
//! The scalar texture walks one point through its octaves and pebble cells with early exits.
//! Here [`LANES`] points go through each step together: every lane computes every octave
//! up to the last one any lane needs and every branch's value, and selects per lane what
//! the scalar code would have kept. Nothing is reordered, and an octave a lane would have
//! skipped adds an exact zero, so each lane's arithmetic is the scalar's. The loops run
//! through `stride_core::simd::dispatch`, which compiles them once more for AVX2 (4 f64
//! lanes) on CPUs that have it.

use super::texture::{fbm_weight, pebbles_lanes, value_noise_lanes, CONCRETE, SOIL};

/// Points per batch: two AVX2 registers of f64.
pub const LANES: usize = 8;

type L = [f64; LANES];

/// The ground's albedo (0..255 per channel, before lighting) at the surface points
/// `(u[i], v[i])` (world x, y, m) with pixel footprints `footprint[i]` (m), into `out[i]`;
/// exactly `albedo(Material::Ground, u[i], v[i], footprint[i], seed)`. Uses the shortest
/// of the four slices' lengths.
pub fn ground_albedo(seed: u32, u: &[f64], v: &[f64], footprint: &[f64], out: &mut [[f64; 3]]) {
    stride_core::simd::dispatch(Ground {
        seed,
        u,
        v,
        footprint,
        out,
    });
}

struct Ground<'a> {
    seed: u32,
    u: &'a [f64],
    v: &'a [f64],
    footprint: &'a [f64],
    out: &'a mut [[f64; 3]],
}

impl pulp::WithSimd for Ground<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let chunks = self
            .u
            .chunks(LANES)
            .zip(self.v.chunks(LANES))
            .zip(self.footprint.chunks(LANES))
            .zip(self.out.chunks_mut(LANES));
        for (((u, v), f), out) in chunks {
            // A short last chunk is padded with copies of its first point.
            let (Some(&u0), Some(&v0), Some(&f0)) = (u.first(), v.first(), f.first()) else {
                continue;
            };
            let (mut ul, mut vl, mut fl) = ([u0; LANES], [v0; LANES], [f0; LANES]);
            copy_into(&mut ul, u);
            copy_into(&mut vl, v);
            copy_into(&mut fl, f);
            let c = ground_lanes(self.seed, &ul, &vl, &fl);
            for (o, c) in out.iter_mut().zip(c) {
                *o = c;
            }
        }
    }
}

#[inline(always)]
fn copy_into(dst: &mut L, src: &[f64]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d = *s;
    }
}

/// `f(x[i])` for each lane.
#[inline(always)]
fn map(x: &L, f: impl Fn(f64) -> f64) -> L {
    let mut out = [0.0; LANES];
    for (o, &x) in out.iter_mut().zip(x) {
        *o = f(x);
    }
    out
}

/// The ground's albedo of [`LANES`] points (see [`super::texture::albedo`]).
#[inline(always)]
fn ground_lanes(seed: u32, u: &L, v: &L, footprint: &L) -> [[f64; 3]; LANES] {
    let noise = value_noise_lanes(seed ^ 0xA5, &map(u, |u| u / 2.2), &map(v, |v| v / 2.2));
    let mut plain = [0.0; LANES];
    for (p, ((&n, &u), &v)) in plain.iter_mut().zip(noise.iter().zip(u).zip(v)) {
        let zone = n - 0.6 * (-(u * u + v * v) / 2.0).exp();
        *p = ((zone - 0.55) / 0.15).clamp(0.0, 1.0);
    }
    let any_plain = plain.iter().any(|&p| p > 0.0);
    let all_plain = plain.iter().all(|&p| p >= 1.0);
    let concrete = if any_plain {
        fbm_lanes(seed ^ 0x3C, u, v, 0.8, 4, 0.5, footprint)
    } else {
        [0.0; LANES]
    };
    let detail = if all_plain {
        [0.0; LANES]
    } else {
        fbm_lanes(seed, u, v, 0.5, 8, 0.62, footprint)
    };
    let cell = 0.025;
    let mut pw = [0.0; LANES];
    for (w, &f) in pw.iter_mut().zip(footprint) {
        *w = ((cell / f.max(1e-6) - 2.0) / 2.0).clamp(0.0, 1.0);
    }
    let pebble = if pw.iter().any(|&w| w > 0.0) {
        pebbles_lanes(seed ^ 0x51, u, v, cell)
    } else {
        [(0.0, 0.0); LANES]
    };
    let mut out = [[0.0; 3]; LANES];
    for (l, o) in out.iter_mut().enumerate() {
        let (Some(&p), Some(&cn), Some(&dt), Some(&w), Some(&(b, edge))) = (
            plain.get(l),
            concrete.get(l),
            detail.get(l),
            pw.get(l),
            pebble.get(l),
        ) else {
            continue;
        };
        let concrete = CONCRETE.map(|x| x * (1.0 + 0.035 * cn));
        if p >= 1.0 {
            *o = concrete;
            continue;
        }
        let mut c = SOIL.map(|x| x * (1.0 + 0.32 * dt));
        if w > 0.0 {
            let tint = [b * 1.05, b, b * 0.92];
            let pebble = [c[0] * tint[0], c[1] * tint[1], c[2] * tint[2]];
            let s = 1.0 - 0.45 * edge;
            let pebble = pebble.map(|x| x * s);
            c = mix(c, pebble, w * 0.9);
        }
        *o = if p <= 0.0 { c } else { mix(c, concrete, p) };
    }
    out
}

#[inline(always)]
fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

/// [`super::texture::fbm`] of [`LANES`] points: octaves run while any lane still weighs
/// them; a lane whose weight has reached 0 adds exact zeros, as the scalar loop stops.
#[inline(always)]
fn fbm_lanes(seed: u32, x: &L, y: &L, longest: f64, octaves: u32, gain: f64, footprint: &L) -> L {
    let (mut sum, mut norm) = ([0.0; LANES], [0.0; LANES]);
    let mut amp = 1.0;
    let mut lambda = longest;
    // x / lambda as (x / longest) * 2^k: the same bits (scaling by a power of two commutes
    // with rounding), one division per point instead of one per octave.
    let (x, y) = (map(x, |x| x / longest), map(y, |y| y / longest));
    let mut scale = 1.0;
    for k in 0..octaves {
        let mut w = [0.0; LANES];
        for (w, &f) in w.iter_mut().zip(footprint) {
            *w = fbm_weight(lambda, f);
        }
        if w.iter().all(|&w| w <= 0.0) {
            break;
        }
        let s = seed.wrapping_add(k * 7919);
        let n = value_noise_lanes(s, &map(&x, |x| x * scale), &map(&y, |y| y * scale));
        for (((sum, norm), &w), &n) in sum.iter_mut().zip(&mut norm).zip(&w).zip(&n) {
            *sum += w * amp * n;
            if w > 0.0 {
                *norm += amp;
            }
        }
        amp *= gain;
        lambda *= 0.5;
        scale *= 2.0;
    }
    let mut out = [0.0; LANES];
    for (o, (&s, &n)) in out.iter_mut().zip(sum.iter().zip(&norm)) {
        *o = if n > 0.0 { s / n * 1.6 } else { 0.0 };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::texture::{albedo, value_noise, Material};

    /// Every point of a walk over gravel, pebbles and plain concrete, near and far (the
    /// octaves and pebbles fade with the footprint), gets the scalar texture's colour bit
    /// for bit, in a batch whose length is no multiple of the lanes, from both copies of the
    /// loops.
    #[test]
    fn the_batch_gives_the_scalar_texture_bit_for_bit() {
        let n = 4001;
        let mut u = Vec::with_capacity(n);
        let mut v = Vec::with_capacity(n);
        let mut f = Vec::with_capacity(n);
        for i in 0..n {
            let t = i as f64;
            u.push(-6.0 + 12.0 * (t * 0.618_034).fract());
            v.push(-6.0 + 12.0 * (t * 0.414_214).fract());
            // Footprints from 0.5 mm to 8 cm, shuffled over the lanes.
            f.push(0.0005 * 160f64.powf((t * 0.732_051).fract()));
        }
        let mut out = vec![[0.0; 3]; n];
        // Both copies of the loops: the portable one and the CPU's best (AVX2 where present).
        for (seed, portable) in [(5u32, true), (5, false), (0x7E57, true), (0x7E57, false)] {
            stride_core::simd::force_portable(portable);
            ground_albedo(seed, &u, &v, &f, &mut out);
            stride_core::simd::force_portable(false);
            let (mut plain, mut mixed, mut differ) = (0, 0, 0);
            for i in 0..n {
                let want = albedo(Material::Ground, u[i], v[i], f[i], seed);
                differ += usize::from(want.map(f64::to_bits) != out[i].map(f64::to_bits));
                // The zones of plain concrete and their borders, as the texture finds them.
                let zone = value_noise(seed ^ 0xA5, u[i] / 2.2, v[i] / 2.2)
                    - 0.6 * (-(u[i] * u[i] + v[i] * v[i]) / 2.0).exp();
                plain += usize::from(zone >= 0.7);
                mixed += usize::from(zone > 0.55 && zone < 0.7);
            }
            assert_eq!(differ, 0, "seed {seed}: {differ} of {n} colours differ");
            assert!(
                plain > 20 && mixed > 20,
                "seed {seed}: {plain} plain, {mixed} mixed"
            );
        }
    }
}
