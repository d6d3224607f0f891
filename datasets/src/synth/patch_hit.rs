//! Exact ray hits on the terrain's bilinear patches: one ray ([`intersect_patch`]), one ray
//! and the patches around one ([`intersect_neighbours`]), and a row of rays at once
//! ([`intersect_patches`]), the last written to vectorise and giving each ray's hit bit for
//! bit as the first (one source: the single ray is one lane).
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

/// The nearest hit along the unit ray `o + t d` (world, m), `t <= t_max`, in the eight
/// patches around `patch`: where a ray misses its rasterised patch (the raster came from a
/// slightly different pose, or a triangle's edge differs from the bilinear surface), the
/// renderer looks here before it marches the ray. Returns the distance (m) and the unit
/// surface normal (world).
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
    let (v, i, j) = corners(terrain, patch_cols, patch)?;
    let rays = Rays::<1> {
        v: v.map(|v| [v]),
        i: [i],
        j: [j],
        d: d.map(|d| [d]),
    };
    let hits = hit(&terrain.grid().geometry, &rays, o, t_max);
    hits.ok[0].then_some((hits.t[0], [hits.n[0][0], hits.n[1][0], hits.n[2][0]]))
}

/// One row's hits on their patches, one entry per ray, in separate arrays (the renderer
/// reads them ray by ray; an array of `Option<PatchHit>` cost it a stall per ray copying
/// the option through memory).
#[derive(Debug, Default, Clone)]
pub struct RowHits {
    /// Whether the ray hits its patch.
    pub hit: Vec<bool>,
    /// Distance along the ray (m), where it hits.
    pub t_m: Vec<f64>,
    /// Unit surface normal (world), where it hits.
    pub normal: Vec<[f64; 3]>,
}

impl RowHits {
    /// Ray `k`'s hit, if any.
    #[inline]
    pub fn get(&self, k: usize) -> Option<PatchHit> {
        match (self.hit.get(k), self.t_m.get(k), self.normal.get(k)) {
            (Some(true), Some(&t), Some(&n)) => Some((t, n)),
            _ => None,
        }
    }
}

/// Fills `hits` with, for each ray `k` of a row, `intersect_patch(terrain, patch_cols,
/// patches[k], o, dirs[k], t_max)`, and no hit where `patches[k]` is [`NO_PATCH`]; bit for
/// bit the same. Rays go through the arithmetic eight at a time, compiled for AVX2
/// where the CPU has it (`stride_core::simd`). One entry per ray of the shorter of
/// `patches` and `dirs`.
pub fn intersect_patches(
    terrain: &HeightField,
    patch_cols: usize,
    patches: &[u32],
    o: [f64; 3],
    dirs: &[[f64; 3]],
    t_max: f64,
    hits: &mut RowHits,
) {
    let n = patches.len().min(dirs.len());
    hits.hit.clear();
    hits.hit.resize(n, false);
    hits.t_m.clear();
    hits.t_m.resize(n, 0.0);
    hits.normal.clear();
    hits.normal.resize(n, [0.0; 3]);
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
    hits: &'a mut RowHits,
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
            .zip(self.hits.hit.chunks_mut(LANES))
            .zip(self.hits.t_m.chunks_mut(LANES))
            .zip(self.hits.normal.chunks_mut(LANES));
        for ((((patches, dirs), hit_out), t_m), normal) in chunks {
            // Gather each lane's corners; a lane without a patch computes on zeros and is
            // dropped below.
            let mut rays = Rays::<LANES> {
                v: [[0.0; LANES]; 4],
                i: [0.0; LANES],
                j: [0.0; LANES],
                d: [[0.0; LANES]; 3],
            };
            let mut used = [false; LANES];
            for (l, (&patch, &d)) in patches.iter().zip(dirs).enumerate() {
                let Some((v, i, j)) = (patch != NO_PATCH)
                    .then(|| corners(self.terrain, self.patch_cols, patch))
                    .flatten()
                else {
                    continue;
                };
                if let Some(u) = used.get_mut(l) {
                    *u = true;
                }
                for (lane, value) in rays.v.iter_mut().zip(v) {
                    if let Some(x) = lane.get_mut(l) {
                        *x = value;
                    }
                }
                for (lane, value) in rays.d.iter_mut().zip(d) {
                    if let Some(x) = lane.get_mut(l) {
                        *x = value;
                    }
                }
                if let (Some(ri), Some(rj)) = (rays.i.get_mut(l), rays.j.get_mut(l)) {
                    (*ri, *rj) = (i, j);
                }
            }
            let out = hit(&g, &rays, self.o, self.t_max);
            for (l, ((h, t), n)) in hit_out.iter_mut().zip(t_m).zip(normal).enumerate() {
                if let (Some(true), Some(true), Some(&t_l)) =
                    (used.get(l), out.ok.get(l), out.t.get(l))
                {
                    *h = true;
                    *t = t_l;
                    *n = out.n.map(|n| n.get(l).copied().unwrap_or(0.0));
                }
            }
        }
    }
}

/// Rays against patches, one per lane: the patch's corner heights `v[c][lane]` (m, in
/// the order of [`corners`]), its row and column, and the unit ray direction `d[axis][lane]`
/// (world).
struct Rays<const N: usize> {
    v: [[f64; N]; 4],
    i: [f64; N],
    j: [f64; N],
    d: [[f64; N]; 3],
}

/// Per lane: whether the ray hits its patch, the distance (m) and the unit normal
/// `n[axis][lane]` (world).
struct Hits<const N: usize> {
    ok: [bool; N],
    t: [f64; N],
    n: [[f64; N]; 3],
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

/// [`intersect_patch`] for each lane, from rays that start at `o` (world, m). The steps
/// run lane by lane in stages so that they vectorise; a lane that the single-ray code
/// would have left early carries on with values it then drops (`ok` false).
#[inline(always)]
// Lanes of fixed-size arrays, all indexed below N; `!(a > b)` keeps a lane going on NaN,
// as the tests it stands for did (`if a > b { return None }`).
#[allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]
fn hit<const N: usize>(g: &GridGeometry, r: &Rays<N>, o: [f64; 3], t_max: f64) -> Hits<N> {
    let inv_res = 1.0 / g.resolution;
    let [v00, v01, v10, v11] = &r.v;
    let mut ok = [true; N];
    // Patch-local coordinates: X along columns, Y along rows, both in [0, 1] on the patch.
    let (mut ox, mut oy, mut dx, mut dy) = ([0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    for l in 0..N {
        ox[l] = (o[0] - g.origin_x) * inv_res - r.j[l];
        oy[l] = (o[1] - g.origin_y) * inv_res - r.i[l];
        dx[l] = r.d[0][l] * inv_res;
        dy[l] = r.d[1][l] * inv_res;
    }
    // The span of t over which the ray is above the patch's square.
    let (mut t_in, mut t_out) = ([0.0f64; N], [t_max; N]);
    for (oc, dc) in [(&ox, &dx), (&oy, &dy)] {
        for l in 0..N {
            let parallel = dc[l].abs() < 1e-15;
            let (ta, tb) = (-oc[l] / dc[l], (1.0 - oc[l]) / dc[l]);
            let (ti, to) = (t_in[l].max(ta.min(tb)), t_out[l].min(ta.max(tb)));
            ok[l] &= !parallel || (0.0..=1.0).contains(&oc[l]);
            t_in[l] = if parallel { t_in[l] } else { ti };
            t_out[l] = if parallel { t_out[l] } else { to };
        }
    }
    // f(t) = ray height - surface height = c0 + c1 t + c2 t^2.
    let (mut ex, mut ey, mut kk) = ([0.0; N], [0.0; N], [0.0; N]);
    let (mut c0, mut c1, mut c2) = ([0.0; N], [0.0; N], [0.0; N]);
    for l in 0..N {
        ex[l] = v01[l] - v00[l];
        ey[l] = v10[l] - v00[l];
        kk[l] = v00[l] - v01[l] - v10[l] + v11[l];
        c0[l] = o[2] - v00[l] - ex[l] * ox[l] - ey[l] * oy[l] - kk[l] * ox[l] * oy[l];
        c1[l] = r.d[2][l] - ex[l] * dx[l] - ey[l] * dy[l] - kk[l] * (ox[l] * dy[l] + dx[l] * oy[l]);
        c2[l] = -kk[l] * dx[l] * dy[l];
        let f_in = c0[l] + t_in[l] * (c1[l] + t_in[l] * c2[l]);
        ok[l] &= !(t_in[l] > t_out[l]) && !(f_in <= 0.0);
    }
    // The first root in the span (the linear case when the quadratic term vanishes).
    let mut t = [0.0; N];
    for l in 0..N {
        let slack = 1e-9 * (1.0 + t_out[l]);
        let in_range = |t: f64| t >= t_in[l] && t <= t_out[l] + slack;
        let linear = c2[l].abs() <= 1e-12 * (c1[l].abs() + c0[l].abs());
        let t_lin = -c0[l] / c1[l];
        let ok_lin = c1[l] != 0.0 && in_range(t_lin);
        let disc = c1[l] * c1[l] - 4.0 * c2[l] * c0[l];
        let q = -0.5 * (c1[l] + c1[l].signum() * disc.sqrt());
        let (r1, r2) = (q / c2[l], if q != 0.0 { c0[l] / q } else { f64::INFINITY });
        let (lo, hi) = (r1.min(r2), r1.max(r2));
        let t_quad = if in_range(lo) { lo } else { hi };
        let ok_quad = !(disc < 0.0) && (in_range(lo) || in_range(hi));
        ok[l] &= if linear { ok_lin } else { ok_quad };
        t[l] = if linear { t_lin } else { t_quad }.min(t_out[l]);
    }
    // Slopes (m/m) of the bilinear patch at the hit, clamped to the patch, and the normal.
    let mut n = [[0.0; N]; 3];
    for l in 0..N {
        let (fx, fy) = (
            (ox[l] + t[l] * dx[l]).clamp(0.0, 1.0),
            (oy[l] + t[l] * dy[l]).clamp(0.0, 1.0),
        );
        let sx = (ex[l] + kk[l] * fy) * inv_res;
        let sy = (ey[l] + kk[l] * fx) * inv_res;
        let norm = (sx * sx + sy * sy + 1.0).sqrt();
        n[0][l] = -sx / norm;
        n[1][l] = -sy / norm;
        n[2][l] = 1.0 / norm;
    }
    Hits { ok, t, n }
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
        let mut hits = RowHits::default();
        for portable in [true, false] {
            stride_core::simd::force_portable(portable);
            intersect_patches(&terrain, pc, &patches, o, &dirs, 12.0, &mut hits);
            stride_core::simd::force_portable(false);
            let (mut found, mut differ) = (0, 0);
            assert_eq!(hits.hit.len(), patches.len());
            for (k, (&p, &d)) in patches.iter().zip(&dirs).enumerate() {
                let want = (p != NO_PATCH)
                    .then(|| intersect_patch(&terrain, pc, p, o, d, 12.0))
                    .flatten();
                let bits = |h: Option<PatchHit>| h.map(|(t, n)| (t.to_bits(), n.map(f64::to_bits)));
                differ += usize::from(bits(want) != bits(hits.get(k)));
                found += usize::from(want.is_some());
            }
            assert_eq!(differ, 0, "portable {portable}: {differ} hits differ");
            assert!(
                found > 300 && found < 1000,
                "{found} hits of {}",
                patches.len()
            );
        }
    }
}
