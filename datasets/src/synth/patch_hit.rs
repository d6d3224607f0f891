//! Exact ray hits on the terrain's bilinear patches: one ray ([`intersect_patch`]), one ray
//! and the patches around it ([`intersect_near_patch`]), and a row of rays at once
//! ([`intersect_patches`]), the last written to vectorise and giving each ray's hit bit for
//! bit as the first.
//!
//! Frames: the terrain and the rays are in the world frame (z up, m). A patch is the square
//! between four cell centres of the height field, indexed `row * patch_cols + col`
//! ([`super::raster::PatchBuffer`]).

use super::raster::NO_PATCH;
use super::terrain::HeightField;
use stride_core::grid::GridGeometry;

/// A hit: distance along the unit ray (m) and the surface's unit normal (world).
pub type PatchHit = (f64, [f64; 3]);

/// Rays per batch of [`intersect_patches`]: two AVX2 registers of f64.
const LANES: usize = 8;

/// The terrain's first hit along the unit ray `o + t d` (world, m), `t <= t_max`, looked
/// for in rasterised `patch` and, if the ray misses it (the raster came from a slightly
/// different pose, or a triangle's edge differs from the bilinear surface), in its eight
/// neighbours. Returns the distance (m) and the unit surface normal (world); `None` means:
/// march the ray.
pub fn intersect_near_patch(
    terrain: &HeightField,
    patch_cols: usize,
    patch: u32,
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
) -> Option<PatchHit> {
    intersect_patch(terrain, patch_cols, patch, o, d, t_max)
        .or_else(|| intersect_neighbours(terrain, patch_cols, patch, o, d, t_max))
}

/// The nearest hit along the ray in the eight patches around `patch` (see
/// [`intersect_near_patch`]).
pub fn intersect_neighbours(
    terrain: &HeightField,
    patch_cols: usize,
    patch: u32,
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
) -> Option<PatchHit> {
    let pc = patch_cols.max(1) as i64;
    let rows = (terrain.grid().geometry.rows as i64 - 1).max(0);
    let (i, j) = (i64::from(patch) / pc, i64::from(patch) % pc);
    let mut best: Option<PatchHit> = None;
    for di in -1..=1 {
        for dj in -1..=1 {
            let (ni, nj) = (i + di, j + dj);
            if (di, dj) == (0, 0) || ni < 0 || nj < 0 || ni >= rows || nj >= pc {
                continue;
            }
            let limit = best.map_or(t_max, |b| b.0);
            if let Some(t) =
                intersect_patch(terrain, patch_cols, (ni * pc + nj) as u32, o, d, limit)
            {
                best = Some(t);
            }
        }
    }
    best
}

/// Exact first intersection of the unit ray `o + t d` (world, m) with bilinear patch
/// `patch` (`row * patch_cols + col`) for `t` in `[0, t_max]`: the distance (m) and the
/// patch's unit normal there (as [`HeightField::normal`]). `None` when the ray misses the
/// patch, or enters it below the surface (its first crossing is then elsewhere).
pub fn intersect_patch(
    terrain: &HeightField,
    patch_cols: usize,
    patch: u32,
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
) -> Option<PatchHit> {
    let (corners, i, j) = corners(terrain, patch_cols, patch)?;
    hit(&terrain.grid().geometry, corners, i, j, o, d, t_max)
}

/// `hits[k] = intersect_patch(terrain, patch_cols, patches[k], o, dirs[k], t_max)` for
/// each ray `k` of a row, and `None` where `patches[k]` is [`NO_PATCH`]; bit for bit the
/// same. Rays go through the arithmetic [`LANES`] at a time, compiled for AVX2 where the
/// CPU has it (`stride_core::simd`). Uses the shortest of the three slices' lengths.
pub fn intersect_patches(
    terrain: &HeightField,
    patch_cols: usize,
    patches: &[u32],
    o: [f64; 3],
    dirs: &[[f64; 3]],
    t_max: f64,
    hits: &mut [Option<PatchHit>],
) {
    stride_core::simd::dispatch(Row {
        terrain,
        patch_cols,
        patches,
        o,
        dirs,
        t_max,
        hits,
    });
}

struct Row<'a> {
    terrain: &'a HeightField,
    patch_cols: usize,
    patches: &'a [u32],
    o: [f64; 3],
    dirs: &'a [[f64; 3]],
    t_max: f64,
    hits: &'a mut [Option<PatchHit>],
}

impl pulp::WithSimd for Row<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let g = self.terrain.grid().geometry;
        let chunks = self
            .patches
            .chunks(LANES)
            .zip(self.dirs.chunks(LANES))
            .zip(self.hits.chunks_mut(LANES));
        for ((patches, dirs), hits) in chunks {
            // Gather each lane's corners; a lane without a patch computes on zeros and is
            // dropped below.
            let mut lanes = [([0.0; 4], 0.0, 0.0, [0.0; 3], false); LANES];
            for ((lane, &patch), &d) in lanes.iter_mut().zip(patches).zip(dirs) {
                if patch == NO_PATCH {
                    continue;
                }
                if let Some((c, i, j)) = corners(self.terrain, self.patch_cols, patch) {
                    *lane = (c, i, j, d, true);
                }
            }
            let mut out = [None; LANES];
            for (out, &(c, i, j, d, _)) in out.iter_mut().zip(&lanes) {
                *out = hit(&g, c, i, j, self.o, d, self.t_max);
            }
            for ((h, out), lane) in hits.iter_mut().zip(out).zip(&lanes) {
                *h = out.filter(|_| lane.4);
            }
        }
    }
}

/// Patch `patch`'s corner heights `[v00, v01, v10, v11]` (m; `v01` is one column on) and
/// its row and column as floats, or `None` outside the grid.
#[inline(always)]
fn corners(terrain: &HeightField, patch_cols: usize, patch: u32) -> Option<([f64; 4], f64, f64)> {
    let g = terrain.grid().geometry;
    let (i, j) = (
        patch as usize / patch_cols.max(1),
        patch as usize % patch_cols.max(1),
    );
    let data = terrain.grid().as_slice();
    let k = i * g.cols + j;
    let corners = [
        f64::from(*data.get(k)?),
        f64::from(*data.get(k + 1)?),
        f64::from(*data.get(k + g.cols)?),
        f64::from(*data.get(k + g.cols + 1)?),
    ];
    Some((corners, i as f64, j as f64))
}

/// [`intersect_patch`] on the patch at row `i`, column `j` with corner heights `v`.
#[inline(always)]
fn hit(
    g: &GridGeometry,
    v: [f64; 4],
    i: f64,
    j: f64,
    o: [f64; 3],
    d: [f64; 3],
    t_max: f64,
) -> Option<PatchHit> {
    let [v00, v01, v10, v11] = v;
    let inv_res = 1.0 / g.resolution;
    // Patch-local coordinates: X along columns, Y along rows, both in [0, 1] on the patch.
    let (ox, oy) = (
        (o[0] - g.origin_x) * inv_res - j,
        (o[1] - g.origin_y) * inv_res - i,
    );
    let (dx, dy) = (d[0] * inv_res, d[1] * inv_res);
    let (mut t_in, mut t_out) = (0.0f64, t_max);
    for (oc, dc) in [(ox, dx), (oy, dy)] {
        if dc.abs() < 1e-15 {
            if !(0.0..=1.0).contains(&oc) {
                return None;
            }
        } else {
            let (ta, tb) = (-oc / dc, (1.0 - oc) / dc);
            t_in = t_in.max(ta.min(tb));
            t_out = t_out.min(ta.max(tb));
        }
    }
    if t_in > t_out {
        return None;
    }
    // f(t) = ray height - surface height = c0 + c1 t + c2 t^2.
    let (ex, ey, kk) = (v01 - v00, v10 - v00, v00 - v01 - v10 + v11);
    let c0 = o[2] - v00 - ex * ox - ey * oy - kk * ox * oy;
    let c1 = d[2] - ex * dx - ey * dy - kk * (ox * dy + dx * oy);
    let c2 = -kk * dx * dy;
    let f = |t: f64| c0 + t * (c1 + t * c2);
    if f(t_in) <= 0.0 {
        return None;
    }
    let slack = 1e-9 * (1.0 + t_out);
    let in_range = |t: f64| t >= t_in && t <= t_out + slack;
    let t = if c2.abs() <= 1e-12 * (c1.abs() + c0.abs()) {
        let t = -c0 / c1;
        if c1 == 0.0 || !in_range(t) {
            return None;
        }
        t.min(t_out)
    } else {
        let disc = c1 * c1 - 4.0 * c2 * c0;
        if disc < 0.0 {
            return None;
        }
        let q = -0.5 * (c1 + c1.signum() * disc.sqrt());
        let (r1, r2) = (q / c2, if q != 0.0 { c0 / q } else { f64::INFINITY });
        let (lo, hi) = (r1.min(r2), r1.max(r2));
        let t = if in_range(lo) {
            lo
        } else if in_range(hi) {
            hi
        } else {
            return None;
        };
        t.min(t_out)
    };
    // Slopes (m/m) of the bilinear patch at the hit, clamped to the patch.
    let (fx, fy) = ((ox + t * dx).clamp(0.0, 1.0), (oy + t * dy).clamp(0.0, 1.0));
    let sx = (ex + kk * fy) * inv_res;
    let sy = (ey + kk * fx) * inv_res;
    let n = (sx * sx + sy * sy + 1.0).sqrt();
    Some((t, [-sx / n, -sy / n, 1.0 / n]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::terrain::procedural;

    /// Rays from a camera 0.45 m above rough terrain, each sent against the patch under its
    /// ground point, a neighbour, a far patch or none: the row batch gives each ray's
    /// single-ray hit bit for bit (hits and misses both occur), from both copies of the
    /// loops, in a row whose length is no multiple of the lanes.
    #[test]
    fn the_row_batch_gives_each_rays_hit_bit_for_bit() {
        let g = GridGeometry::covering(-2.0, -2.0, 2.0, 2.0, 0.02);
        let terrain = HeightField::new(procedural("rubble", g, 3).unwrap());
        let pc = g.cols - 1;
        let o = [0.1, -0.2, terrain.height(0.1, -0.2) + 0.45];
        let (mut patches, mut dirs) = (Vec::new(), Vec::new());
        for k in 0..1237u32 {
            let (a, e) = (
                f64::from(k) * 2.399_963,
                0.2 + 0.9 * f64::from(k % 97) / 97.0,
            );
            let d = [e * a.cos(), e * a.sin(), -1.0];
            let n = (d[0] * d[0] + d[1] * d[1] + 1.0).sqrt();
            let d = [d[0] / n, d[1] / n, d[2] / n];
            // The patch under the ray's crossing of the terrain's mean height, roughly.
            let t = (o[2] - terrain.height(0.0, 0.0)) / -d[2];
            let (x, y) = (o[0] + t * d[0], o[1] + t * d[1]);
            let (j, i) = (
                ((x - g.origin_x) / g.resolution) as u32,
                ((y - g.origin_y) / g.resolution) as u32,
            );
            let patch = match k % 5 {
                0 => NO_PATCH,
                1 => (i + 1) * pc as u32 + j,
                2 => 7,
                _ => i * pc as u32 + j,
            };
            patches.push(patch);
            dirs.push(d);
        }
        let mut hits = vec![None; patches.len()];
        for portable in [true, false] {
            stride_core::simd::force_portable(portable);
            intersect_patches(&terrain, pc, &patches, o, &dirs, 12.0, &mut hits);
            stride_core::simd::force_portable(false);
            let (mut found, mut differ) = (0, 0);
            for ((&p, &d), h) in patches.iter().zip(&dirs).zip(&hits) {
                let want = (p != NO_PATCH)
                    .then(|| intersect_patch(&terrain, pc, p, o, d, 12.0))
                    .flatten();
                let bits = |h: Option<PatchHit>| h.map(|(t, n)| (t.to_bits(), n.map(f64::to_bits)));
                differ += usize::from(bits(want) != bits(*h));
                found += usize::from(want.is_some());
            }
            assert_eq!(differ, 0, "portable {portable}: {differ} hits differ");
            assert!(
                found > 300 && found < 1000,
                "{found} hits of {}",
                hits.len()
            );
        }
    }
}
