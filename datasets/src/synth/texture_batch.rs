//! The ground's albedo for a row of surface points at once, bit for bit what
//! [`super::texture::albedo`] gives for each.
//!
//! The ground's texture is written lane by lane ([`super::texture`]'s `_lanes` functions:
//! every lane computes every octave up to the last one any lane needs and every branch's
//! value, and keeps what a single point would have; an octave a lane does not need adds an
//! exact zero). One lane is [`super::texture::albedo`]'s ground; here [`LANES`] points go
//! through together, in loops that vectorise, through `stride_core::simd::dispatch`, which
//! compiles them once more for AVX2 (4 f64 lanes) on CPUs that have it.

use super::texture::ground_lanes;

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
