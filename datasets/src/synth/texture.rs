//! Procedural surface colours (albedo) at several scales, band-limited to the pixel
//! footprint so that fine detail fades out with distance instead of aliasing into flicker.
//!
//! Ground: gravel and soil (value-noise octaves from 0.5 m down to 2 mm plus pebbles) with
//! plain, low-texture concrete patches, as real floors have. Objects: tinted, printed
//! surfaces (crates, cardboard). Walls: plaster with posters.

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
    let mut sum = 0.0;
    let mut amp = 1.0;
    let mut norm = 0.0;
    let mut lambda = longest;
    for k in 0..octaves {
        let w = fbm_weight(lambda, footprint);
        if w <= 0.0 {
            break;
        }
        sum += w * amp * value_noise(seed.wrapping_add(k * 7919), x / lambda, y / lambda);
        norm += amp;
        amp *= gain;
        lambda *= 0.5;
    }
    if norm > 0.0 {
        sum / norm * 1.6
    } else {
        0.0
    }
}

/// The weight in [0, 1] of an octave of wavelength `lambda` (m) under a pixel footprint
/// `footprint` (m): 1 from three footprints up, 0 at 1.5 and below. It only falls as the
/// wavelength halves, so once 0 it stays 0.
#[inline(always)]
pub(crate) fn fbm_weight(lambda: f64, footprint: f64) -> f64 {
    let ratio = lambda / footprint.max(1e-6);
    ((ratio - 1.5) / 1.5).clamp(0.0, 1.0)
}

/// The soil's albedo (0..255) between pebbles, before its noise.
pub(crate) const SOIL: [f64; 3] = [128.0, 108.0, 84.0];
/// The plain concrete's albedo (0..255), before its noise.
pub(crate) const CONCRETE: [f64; 3] = [152.0, 150.0, 144.0];

/// Pebbles: distance to the nearest jittered cell centre (cell size `cell`, m), as
/// `(brightness factor, edge darkening)` in `[0.6, 1.4]` and `[0, 1]`.
#[inline(always)]
pub(crate) fn pebbles(seed: u32, x: f64, y: f64, cell: f64) -> (f64, f64) {
    let [p] = pebbles_lanes(seed, &[x], &[y], cell);
    p
}

/// [`pebbles`] of `N` points `(x[l], y[l])` (m), written lane by lane in stages so that a
/// batch of points vectorises (`texture_batch`); one lane is [`pebbles`].
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

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
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
            // Large zones: plain concrete patches (low texture) among gravel and soil.
            // About one tenth of the floor is plain; never the start area around the origin.
            let zone =
                value_noise(seed ^ 0xA5, u / 2.2, v / 2.2) - 0.6 * (-(u * u + v * v) / 2.0).exp();
            let plain = ((zone - 0.55) / 0.15).clamp(0.0, 1.0);
            if plain >= 1.0 {
                return scale(
                    CONCRETE,
                    1.0 + 0.035 * fbm(seed ^ 0x3C, u, v, 0.8, 4, 0.5, footprint),
                );
            }
            let detail = fbm(seed, u, v, 0.5, 8, 0.62, footprint);
            let mut c = scale(SOIL, 1.0 + 0.32 * detail);
            // Pebbles about 2.5 cm across, fading out when smaller than ~3 pixels.
            let cell = 0.025;
            let pw = ((cell / footprint.max(1e-6) - 2.0) / 2.0).clamp(0.0, 1.0);
            if pw > 0.0 {
                let (b, edge) = pebbles(seed ^ 0x51, u, v, cell);
                let tint = [b * 1.05, b, b * 0.92];
                let pebble = [c[0] * tint[0], c[1] * tint[1], c[2] * tint[2]];
                let pebble = scale(pebble, 1.0 - 0.45 * edge);
                c = mix(c, pebble, pw * 0.9);
            }
            if plain <= 0.0 {
                return c;
            }
            let concrete = scale(
                CONCRETE,
                1.0 + 0.035 * fbm(seed ^ 0x3C, u, v, 0.8, 4, 0.5, footprint),
            );
            mix(c, concrete, plain)
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
