//! Procedural surface colours (albedo) at several scales, band-limited to the pixel
//! footprint so that fine detail fades out with distance instead of aliasing into flicker.
//!
//! Ground: gravel and soil (value-noise octaves from 0.5 m down to 2 mm plus pebbles) with
//! plain, low-texture concrete patches, as real floors have. Objects: tinted, printed
//! surfaces (crates, cardboard). Walls: plaster with posters.
//!
//! The noise, the octaves, the pebbles and the ground's colour are written for `N` points
//! at once (`*_lanes`, stages of loops over fixed-size lane arrays, so that LLVM
//! vectorises them); the single-point functions are one lane of them, and
//! [`super::texture_batch`] runs eight.

/// A surface kind, for choosing its texture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Material {
    /// The terrain.
    Ground,
    /// A scene object (box), by index.
    Object(u32),
    /// A wall, by index.
    Wall(u32),
}

#[inline(always)]
pub(crate) fn hash2(seed: u32, x: i32, y: i32) -> u32 {
    let mut h = seed ^ (x as u32).wrapping_mul(0x27D4_EB2D) ^ (y as u32).wrapping_mul(0x1656_67B1);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297A_2D39);
    h ^ (h >> 15)
}

#[inline(always)]
pub(crate) fn unit(h: u32) -> f64 {
    f64::from(h) * (1.0 / 4_294_967_296.0)
}

/// Smooth value noise in `[-1, 1]` on a unit lattice.
#[inline(always)]
pub fn value_noise(seed: u32, x: f64, y: f64) -> f64 {
    let [v] = value_noise_lanes(seed, &[x], &[y]);
    v
}

/// [`value_noise`] at `N` points `(x[l], y[l])`, written lane by lane in stages (lattice
/// cells, the corners' hashes, the blend) so that a batch vectorises (`texture_batch`);
/// one lane is [`value_noise`].
#[inline(always)]
// Lanes of fixed-size arrays, all indexed below N.
#[allow(clippy::needless_range_loop)]
pub(crate) fn value_noise_lanes<const N: usize>(seed: u32, x: &[f64; N], y: &[f64; N]) -> [f64; N] {
    let (mut xi, mut yi, mut sx, mut sy) = ([0i32; N], [0i32; N], [0.0; N], [0.0; N]);
    for l in 0..N {
        let (xf, yf) = (x[l].floor(), y[l].floor());
        (xi[l], yi[l]) = (xf as i32, yf as i32);
        let (fx, fy) = (x[l] - xf, y[l] - yf);
        (sx[l], sy[l]) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    }
    let mut corner = [[0u32; N]; 4];
    for l in 0..N {
        corner[0][l] = hash2(seed, xi[l], yi[l]);
        corner[1][l] = hash2(seed, xi[l] + 1, yi[l]);
        corner[2][l] = hash2(seed, xi[l], yi[l] + 1);
        corner[3][l] = hash2(seed, xi[l] + 1, yi[l] + 1);
    }
    let mut out = [0.0; N];
    for l in 0..N {
        let (v00, v10) = (unit(corner[0][l]), unit(corner[1][l]));
        let (v01, v11) = (unit(corner[2][l]), unit(corner[3][l]));
        let a = v00 + (v10 - v00) * sx[l];
        let b = v01 + (v11 - v01) * sx[l];
        out[l] = (a + (b - a) * sy[l]) * 2.0 - 1.0;
    }
    out
}

/// Fractal sum of value noise from wavelength `longest` (m) down by factors of two while the
/// wavelength exceeds about twice the footprint (m per pixel); each octave's amplitude is
/// `gain` times the previous one's. Returns roughly `[-1, 1]`.
pub fn fbm(
    seed: u32,
    x: f64,
    y: f64,
    longest: f64,
    octaves: u32,
    gain: f64,
    footprint: f64,
) -> f64 {
    let [v] = fbm_lanes(seed, &[x], &[y], longest, octaves, gain, &[footprint]);
    v
}

/// [`fbm`] of `N` points: octaves run while any lane still weighs them; a lane whose
/// weight has reached 0 adds exact zeros, as a single point's loop stops (one lane is
/// [`fbm`]).
#[inline(always)]
pub(crate) fn fbm_lanes<const N: usize>(
    seed: u32,
    x: &[f64; N],
    y: &[f64; N],
    longest: f64,
    octaves: u32,
    gain: f64,
    footprint: &[f64; N],
) -> [f64; N] {
    let (mut sum, mut norm) = ([0.0; N], [0.0; N]);
    let mut amp = 1.0;
    let mut lambda = longest;
    // x / lambda as (x / longest) * 2^k: the same bits (scaling by a power of two commutes
    // with rounding), one division per point instead of one per octave.
    let (x, y) = (map(x, |x| x / longest), map(y, |y| y / longest));
    let mut scale = 1.0;
    for k in 0..octaves {
        let mut w = [0.0; N];
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
    let mut out = [0.0; N];
    for (o, (&s, &n)) in out.iter_mut().zip(sum.iter().zip(&norm)) {
        *o = if n > 0.0 { s / n * 1.6 } else { 0.0 };
    }
    out
}

/// `f(x[i])` for each lane.
#[inline(always)]
fn map<const N: usize>(x: &[f64; N], f: impl Fn(f64) -> f64) -> [f64; N] {
    let mut out = [0.0; N];
    for (o, &x) in out.iter_mut().zip(x) {
        *o = f(x);
    }
    out
}

/// The weight in [0, 1] of an octave of wavelength `lambda` (m) under a pixel footprint
/// `footprint` (m): 1 from three footprints up, 0 at 1.5 and below. It only falls as the
/// wavelength halves, so once 0 it stays 0.
#[inline(always)]
fn fbm_weight(lambda: f64, footprint: f64) -> f64 {
    let ratio = lambda / footprint.max(1e-6);
    ((ratio - 1.5) / 1.5).clamp(0.0, 1.0)
}

/// The soil's albedo (0..255) between pebbles, before its noise.
const SOIL: [f64; 3] = [128.0, 108.0, 84.0];
/// The plain concrete's albedo (0..255), before its noise.
const CONCRETE: [f64; 3] = [152.0, 150.0, 144.0];

/// Pebbles at `N` points `(x[l], y[l])` (m): the distance to the nearest jittered cell
/// centre (cell size `cell`, m), as `(brightness factor, edge darkening)` in `[0.6, 1.4]`
/// and `[0, 1]` per point. Stages over the lanes (each cell's hashes and centres, then the
/// nearest-two updates) so that a batch vectorises.
#[inline(always)]
// Lanes of fixed-size arrays, all indexed below N.
#[allow(clippy::needless_range_loop)]
pub(crate) fn pebbles_lanes<const N: usize>(
    seed: u32,
    x: &[f64; N],
    y: &[f64; N],
    cell: f64,
) -> [(f64, f64); N] {
    let (mut gx, mut gy, mut ix, mut iy) = ([0.0; N], [0.0; N], [0i32; N], [0i32; N]);
    for l in 0..N {
        (gx[l], gy[l]) = (x[l] / cell, y[l] / cell);
        (ix[l], iy[l]) = (gx[l].floor() as i32, gy[l].floor() as i32);
    }
    let (mut d1, mut d2, mut best) = ([f64::MAX; N], [f64::MAX; N], [0u32; N]);
    for dy in -1..=1 {
        for dx in -1..=1 {
            let mut h = [0u32; N];
            let (mut cx, mut cy) = ([0.0; N], [0.0; N]);
            for l in 0..N {
                let (cx_i, cy_i) = (ix[l] + dx, iy[l] + dy);
                h[l] = hash2(seed, cx_i, cy_i);
                cx[l] = f64::from(cx_i) + unit(h[l]);
                cy[l] = f64::from(cy_i) + unit(h[l].rotate_left(16));
            }
            for l in 0..N {
                let d = (gx[l] - cx[l]).powi(2) + (gy[l] - cy[l]).powi(2);
                // Nearest and second nearest.
                let closer = d < d1[l];
                d2[l] = if closer { d1[l] } else { d.min(d2[l]) };
                d1[l] = if closer { d } else { d1[l] };
                best[l] = if closer { h[l] } else { best[l] };
            }
        }
    }
    let mut out = [(0.0, 0.0); N];
    for l in 0..N {
        let edge = 1.0 - ((d2[l].sqrt() - d1[l].sqrt()) * 6.0).clamp(0.0, 1.0);
        out[l] = (0.6 + 0.8 * unit(best[l].rotate_left(7)), edge);
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

/// The ground's albedo of `N` points (see [`albedo`]): every lane computes every
/// branch's value and keeps what the single point would have; one lane is the ground of
/// [`albedo`], eight are a batch of `texture_batch`.
#[inline(always)]
pub(crate) fn ground_lanes<const N: usize>(
    seed: u32,
    u: &[f64; N],
    v: &[f64; N],
    footprint: &[f64; N],
) -> [[f64; 3]; N] {
    let noise = value_noise_lanes(seed ^ 0xA5, &map(u, |u| u / 2.2), &map(v, |v| v / 2.2));
    let mut plain = [0.0; N];
    for (p, ((&n, &u), &v)) in plain.iter_mut().zip(noise.iter().zip(u).zip(v)) {
        let zone = n - 0.6 * (-(u * u + v * v) / 2.0).exp();
        *p = ((zone - 0.55) / 0.15).clamp(0.0, 1.0);
    }
    let any_plain = plain.iter().any(|&p| p > 0.0);
    let all_plain = plain.iter().all(|&p| p >= 1.0);
    let concrete = if any_plain {
        fbm_lanes(seed ^ 0x3C, u, v, 0.8, 4, 0.5, footprint)
    } else {
        [0.0; N]
    };
    let detail = if all_plain {
        [0.0; N]
    } else {
        fbm_lanes(seed, u, v, 0.5, 8, 0.62, footprint)
    };
    let cell = 0.025;
    let mut pw = [0.0; N];
    for (w, &f) in pw.iter_mut().zip(footprint) {
        *w = ((cell / f.max(1e-6) - 2.0) / 2.0).clamp(0.0, 1.0);
    }
    let pebble = if pw.iter().any(|&w| w > 0.0) {
        pebbles_lanes(seed ^ 0x51, u, v, cell)
    } else {
        [(0.0, 0.0); N]
    };
    let mut out = [[0.0; 3]; N];
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

fn scale(c: [f64; 3], s: f64) -> [f64; 3] {
    [c[0] * s, c[1] * s, c[2] * s]
}

/// Albedo (0..255 per channel, before lighting) of a surface point.
///
/// `(u, v)` are surface coordinates in metres (world x-y on the ground, face coordinates on
/// objects and walls); `footprint` is the pixel's footprint on the surface (m).
pub fn albedo(material: Material, u: f64, v: f64, footprint: f64, seed: u32) -> [f64; 3] {
    match material {
        Material::Ground => {
            let [c] = ground_lanes(seed, &[u], &[v], &[footprint]);
            c
        }
        Material::Object(id) => {
            const PALETTE: [[f64; 3]; 6] = [
                [170.0, 130.0, 85.0],
                [70.0, 100.0, 160.0],
                [90.0, 140.0, 80.0],
                [175.0, 70.0, 60.0],
                [200.0, 195.0, 180.0],
                [120.0, 110.0, 140.0],
            ];
            let base = PALETTE[(id as usize) % PALETTE.len()];
            let s = seed ^ id.wrapping_mul(0x9E37);
            let grain = fbm(s, u, v, 0.3, 8, 0.6, footprint);
            let mut c = scale(base, 1.0 + 0.28 * grain);
            // Printed marks: dark blobs on a 12 cm lattice.
            let mark = value_noise(s ^ 0x77, u / 0.06, v / 0.06);
            if mark > 0.45 {
                c = scale(c, 0.45);
            }
            c
        }
        Material::Wall(id) => {
            let s = seed ^ 0x3A11 ^ id.wrapping_mul(0x45D9);
            let poster_cell = 0.9;
            let (pi, pj) = (
                (u / poster_cell).floor() as i32,
                (v / poster_cell).floor() as i32,
            );
            let h = hash2(s, pi, pj);
            let (fu, fv) = (
                u / poster_cell - f64::from(pi),
                v / poster_cell - f64::from(pj),
            );
            let inside = unit(h) > 0.45 && (0.12..0.88).contains(&fu) && (0.1..0.9).contains(&fv);
            if inside {
                let tint = [
                    60.0 + 150.0 * unit(h.rotate_left(3)),
                    60.0 + 150.0 * unit(h.rotate_left(11)),
                    60.0 + 150.0 * unit(h.rotate_left(19)),
                ];
                scale(
                    tint,
                    1.0 + 0.45 * fbm(s ^ 0x99, u, v, 0.25, 7, 0.7, footprint),
                )
            } else {
                scale(
                    [205.0, 200.0, 188.0],
                    1.0 + 0.07 * fbm(s, u, v, 0.6, 6, 0.55, footprint),
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_bounded_deterministic_and_band_limited() {
        for i in 0..1000 {
            let (x, y) = (i as f64 * 0.137, i as f64 * 0.071);
            let v = value_noise(1, x, y);
            assert!((-1.0..=1.0).contains(&v));
            assert_eq!(v, value_noise(1, x, y));
        }
        // Far away (large footprint) the fine octaves vanish: the curvature over 1 mm steps,
        // which the finest octaves dominate, nearly disappears.
        let curvature = |footprint: f64| {
            (0..200)
                .map(|i| {
                    let x = i as f64 * 0.001;
                    let f = |x: f64| fbm(3, x, 0.37, 0.5, 9, 0.6, footprint);
                    (f(x - 0.001) - 2.0 * f(x) + f(x + 0.001)).abs()
                })
                .sum::<f64>()
        };
        let (near, far) = (curvature(0.001), curvature(0.05));
        assert!(far < 0.05 * near, "{far} vs {near}");
        let c = albedo(Material::Ground, 1.0, 2.0, 0.002, 5);
        assert!(c.iter().all(|&v| (0.0..=400.0).contains(&v)));
    }
}
