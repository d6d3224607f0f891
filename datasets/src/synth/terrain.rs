//! Terrain height fields (world z up) and ray casting against them.
//!
//! A [`HeightField`] wraps a [`Grid`] of heights (m), interpolated bilinearly between cell
//! centres. For ray casting it keeps a maximum mipmap (Tevs et al. 2008): level 0 holds the
//! highest corner of each bilinear patch (the square between four cell centres), level `k`
//! the maximum over `2^k x 2^k` patches. A ray descends the levels only where it comes close
//! to the surface, so it crosses open space in a few large steps.

use crate::error::DatasetError;
use std::path::Path;
use stride_core::grid::{Grid, GridGeometry};
use stride_core::rng::SplitMix64;

/// Mipmap level where ray traversal starts (cells of 2^3 patches).
const START_LEVEL: usize = 5;

/// A height field with ray-casting acceleration.
#[derive(Debug, Clone)]
pub struct HeightField {
    grid: Grid<f32>,
    inv_res: f64,
    last_row: f64,
    last_col: f64,
    /// `levels[k]`: maxima over 2^k x 2^k patches, with its (rows, cols).
    levels: Vec<(usize, usize, Vec<f32>)>,
    min_h: f64,
    max_h: f64,
}

/// A ray's hit on the terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerrainHit {
    /// Ray parameter (m along a unit direction).
    pub t: f64,
}

impl HeightField {
    /// Wraps a height grid (at least 2 x 2 cells); NaN cells become the lowest height.
    pub fn new(mut grid: Grid<f32>) -> Self {
        let (lo, hi) = grid.min_max().unwrap_or((0.0, 0.0));
        for v in grid.as_mut_slice() {
            if v.is_nan() {
                *v = lo;
            }
        }
        let g = grid.geometry;
        let (pr, pc) = (
            g.rows.saturating_sub(1).max(1),
            g.cols.saturating_sub(1).max(1),
        );
        let at = |r: usize, c: usize| grid.get(r.min(g.rows - 1), c.min(g.cols - 1)).unwrap_or(lo);
        let mut base = vec![0.0f32; pr * pc];
        for r in 0..pr {
            for c in 0..pc {
                base[r * pc + c] = at(r, c)
                    .max(at(r, c + 1))
                    .max(at(r + 1, c))
                    .max(at(r + 1, c + 1));
            }
        }
        let mut levels = vec![(pr, pc, base)];
        while let Some((r, c, prev)) = levels.last() {
            if *r <= 1 && *c <= 1 {
                break;
            }
            let (nr, nc) = (r.div_ceil(2), c.div_ceil(2));
            let mut next = vec![f32::NEG_INFINITY; nr * nc];
            for i in 0..*r {
                for j in 0..*c {
                    let k = (i / 2) * nc + j / 2;
                    next[k] = next[k].max(prev[i * c + j]);
                }
            }
            levels.push((nr, nc, next));
        }
        Self {
            inv_res: 1.0 / g.resolution,
            last_row: (g.rows - 1) as f64,
            last_col: (g.cols - 1) as f64,
            grid,
            levels,
            min_h: f64::from(lo),
            max_h: f64::from(hi),
        }
    }

    /// The height grid.
    pub fn grid(&self) -> &Grid<f32> {
        &self.grid
    }

    /// Lowest and highest heights (m).
    pub fn range(&self) -> (f64, f64) {
        (self.min_h, self.max_h)
    }

    /// Height at `(x, y)` (m), bilinear; outside the grid the nearest edge value.
    #[inline]
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let g = &self.grid.geometry;
        self.height_cells(
            (x - g.origin_x) * self.inv_res,
            (y - g.origin_y) * self.inv_res,
        )
    }

    /// Height (m) at continuous cell coordinates (`c` along columns, `r` along rows; cell
    /// centres at integers), bilinear, clamped to the grid.
    #[inline]
    fn height_cells(&self, c: f64, r: f64) -> f64 {
        let r = r.max(0.0).min(self.last_row);
        let c = c.max(0.0).min(self.last_col);
        let (r0, c0) = (r as usize, c as usize);
        let (fr, fc) = (r - r0 as f64, c - c0 as f64);
        let cols = self.grid.geometry.cols;
        let d = self.grid.as_slice();
        let i = r0 * cols + c0;
        // Right/down neighbours, clamped at the last row/column.
        let di = usize::from(c0 + 1 < cols);
        let dr = if (r0 as f64) < self.last_row { cols } else { 0 };
        let (Some(&v00), Some(&v01), Some(&v10), Some(&v11)) =
            (d.get(i), d.get(i + di), d.get(i + dr), d.get(i + dr + di))
        else {
            return 0.0;
        };
        let top = f64::from(v00) + (f64::from(v01) - f64::from(v00)) * fc;
        let bottom = f64::from(v10) + (f64::from(v11) - f64::from(v10)) * fc;
        top + (bottom - top) * fr
    }

    /// Unit surface normal at `(x, y)`: the normal of the bilinear patch there.
    pub fn normal(&self, x: f64, y: f64) -> [f64; 3] {
        let g = &self.grid.geometry;
        let r = ((y - g.origin_y) * self.inv_res)
            .max(0.0)
            .min(self.last_row);
        let c = ((x - g.origin_x) * self.inv_res)
            .max(0.0)
            .min(self.last_col);
        let (r0, c0) = (r as usize, c as usize);
        let (fr, fc) = (r - r0 as f64, c - c0 as f64);
        let cols = g.cols;
        let d = self.grid.as_slice();
        let i = r0 * cols + c0;
        let di = usize::from(c0 + 1 < cols);
        let dr = if (r0 as f64) < self.last_row { cols } else { 0 };
        let (Some(&v00), Some(&v01), Some(&v10), Some(&v11)) =
            (d.get(i), d.get(i + di), d.get(i + dr), d.get(i + dr + di))
        else {
            return [0.0, 0.0, 1.0];
        };
        let (v00, v01, v10, v11) = (
            f64::from(v00),
            f64::from(v01),
            f64::from(v10),
            f64::from(v11),
        );
        // Slopes in m/m of the bilinear patch.
        let dx = ((v01 - v00) * (1.0 - fr) + (v11 - v10) * fr) * self.inv_res;
        let dy = ((v10 - v00) * (1.0 - fc) + (v11 - v01) * fc) * self.inv_res;
        let n = (dx * dx + dy * dy + 1.0).sqrt();
        [-dx / n, -dy / n, 1.0 / n]
    }

    /// First intersection of the ray `o + t d` (`d` unit) with the terrain for
    /// `t` in `[0, t_max]`, within the grid's extent (between its outermost cell centres).
    pub fn intersect(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> Option<TerrainHit> {
        let g = &self.grid.geometry;
        let res = g.resolution;
        // Patch space: patch (i, j) spans columns j..j+1 and rows i..i+1 of cell centres.
        let px = |x: f64| (x - g.origin_x) / res;
        let py = |y: f64| (y - g.origin_y) / res;
        let (ox, oy) = (px(o[0]), py(o[1]));
        let (dx, dy) = (d[0] / res, d[1] / res); // patch units per metre along the ray
        let (w, h) = ((g.cols - 1) as f64, (g.rows - 1) as f64);
        let mut t0 = 0.0f64;
        let mut t1 = t_max;
        // Height band.
        if d[2].abs() < 1e-12 {
            if o[2] > self.max_h {
                return None;
            }
        } else {
            let ta = (self.max_h - o[2]) / d[2];
            let tb = (self.min_h - 1e-6 - o[2]) / d[2];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb) + 1e-9);
        }
        // Extent.
        for (oi, di, hi) in [(ox, dx, w), (oy, dy, h)] {
            if di.abs() < 1e-15 {
                if oi < 0.0 || oi > hi {
                    return None;
                }
            } else {
                let (ta, tb) = ((0.0 - oi) / di, (hi - oi) / di);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        if t0 > t1 {
            return None;
        }
        let f = |t: f64| o[2] + t * d[2] - self.height_cells(ox + t * dx, oy + t * dy);
        let mut f_t = f(t0);
        if f_t <= 0.0 {
            return Some(TerrainHit { t: t0 });
        }
        let top = self.levels.len() - 1;
        // The height band already brought t0 near the surface: start fine (8-patch cells) and
        // climb only where the ray leaves cells above the terrain.
        let mut level = top.min(START_LEVEL);
        let mut f_valid = true; // f_t holds f(t)
        let mut t = t0;
        let mut guard = 0usize;
        // Reciprocals of the direction (patch units per metre); infinite along an axis the
        // ray does not move on.
        let (inv_dx, inv_dy) = (1.0 / dx, 1.0 / dy);
        let (max_i, max_j) = (g.rows.saturating_sub(2), g.cols.saturating_sub(2));
        while t < t1 && guard < 100_000 {
            guard += 1;
            let (lr, lc, maxima) = self.levels.get(level)?;
            // Level-0 patch just past t (coordinates are >= 0 inside the extent, so
            // truncation is floor).
            let te = t + 1e-9;
            let (x, y) = ((ox + te * dx).max(0.0), (oy + te * dy).max(0.0));
            let (i0, j0) = ((y as usize).min(max_i), (x as usize).min(max_j));
            let (ci, cj) = ((i0 >> level).min(lr - 1), (j0 >> level).min(lc - 1));
            let size = (1usize << level) as f64;
            let tx = if dx > 0.0 {
                ((cj + 1) as f64 * size - ox) * inv_dx
            } else if dx < 0.0 {
                (cj as f64 * size - ox) * inv_dx
            } else {
                f64::INFINITY
            };
            let ty = if dy > 0.0 {
                ((ci + 1) as f64 * size - oy) * inv_dy
            } else if dy < 0.0 {
                (ci as f64 * size - oy) * inv_dy
            } else {
                f64::INFINITY
            };
            let mut t_exit = if tx < ty { tx } else { ty };
            if t_exit > t1 {
                t_exit = t1;
            }
            if t_exit < t {
                t_exit = t;
            }
            let m = f64::from(maxima.get(ci * lc + cj).copied().unwrap_or(f32::INFINITY));
            // The ray's lowest z over [t, t_exit]: at the end it leaves if it descends.
            let z_min = o[2] + if d[2] < 0.0 { t_exit } else { t } * d[2];
            if z_min > m {
                // Above everything in this cell: skip it. Go up a level only when the ray
                // also leaves the parent cell (otherwise the parent would send it back down).
                t = t_exit + 1e-9;
                f_valid = false;
                if level < top {
                    let (x2, y2) = ((ox + t * dx).max(0.0), (oy + t * dy).max(0.0));
                    let (i2, j2) = ((y2 as usize).min(max_i), (x2 as usize).min(max_j));
                    if (i2 >> (level + 1), j2 >> (level + 1)) != (ci >> 1, cj >> 1) {
                        level += 1;
                    }
                }
                continue;
            }
            if level > 0 {
                level -= 1;
                continue;
            }
            // A single bilinear patch: the crossing, if any, lies between t (above) and the
            // patch exit.
            if !f_valid {
                f_t = f(t);
                if f_t <= 0.0 {
                    return Some(TerrainHit { t });
                }
            }
            let f_exit = f(t_exit);
            if f_exit <= 0.0 {
                let (mut a, mut b, mut fa, mut fb) = (t, t_exit, f_t, f_exit);
                for _ in 0..2 {
                    let mid = a + (b - a) * (fa / (fa - fb)).clamp(0.02, 0.98);
                    let fmid = f(mid);
                    if fmid > 0.0 {
                        a = mid;
                        fa = fmid;
                    } else {
                        b = mid;
                        fb = fmid;
                    }
                }
                let th = a + (b - a) * (fa / (fa - fb)).clamp(0.0, 1.0);
                return (th <= t_max).then_some(TerrainHit { t: th });
            }
            f_t = f_exit;
            f_valid = true;
            t = t_exit;
        }
        None
    }
}

/// Reads a terrain image: grey level (the mean of R, G, B) 0..255 maps linearly to
/// `0..height_scale_m`; fully transparent pixels (alpha < 128) are floor (0 m). The image's
/// top row is the far +y edge; the grid is centred on the world origin with `resolution_m`
/// per pixel.
pub fn from_image(
    path: &Path,
    height_scale_m: f64,
    resolution_m: f64,
) -> Result<Grid<f32>, DatasetError> {
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| DatasetError::Image {
        path: path.into(),
        message: format!("not a readable PNG: {e}"),
    })?;
    let mut buf = vec![0u8; reader.output_buffer_size().unwrap_or(0)];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| DatasetError::Image {
            path: path.into(),
            message: format!("corrupt PNG data: {e}"),
        })?;
    let channels = info.color_type.samples();
    let (w, h) = (info.width as usize, info.height as usize);
    if w < 2 || h < 2 {
        return Err(DatasetError::Image {
            path: path.into(),
            message: format!("terrain image is {w}x{h}; need at least 2x2"),
        });
    }
    let geometry = GridGeometry {
        origin_x: -(w as f64 - 1.0) * resolution_m / 2.0,
        origin_y: -(h as f64 - 1.0) * resolution_m / 2.0,
        resolution: resolution_m,
        rows: h,
        cols: w,
    };
    let mut data = vec![0.0f32; w * h];
    for row in 0..h {
        // Image row 0 is the top (+y edge): grid row h-1.
        let src = (h - 1 - row) * w;
        for col in 0..w {
            let px = buf
                .get((src + col) * channels..(src + col + 1) * channels)
                .unwrap_or(&[]);
            let (grey, alpha) = match px {
                [g] => (f64::from(*g), 255u8),
                [g, a] => (f64::from(*g), *a),
                [r, g, b] => ((f64::from(*r) + f64::from(*g) + f64::from(*b)) / 3.0, 255),
                [r, g, b, a] => ((f64::from(*r) + f64::from(*g) + f64::from(*b)) / 3.0, *a),
                _ => (0.0, 255),
            };
            let v = if alpha < 128 {
                0.0
            } else {
                grey / 255.0 * height_scale_m
            };
            data[row * w + col] = v as f32;
        }
    }
    Grid::from_vec(geometry, data).ok_or_else(|| DatasetError::invalid(path, "size mismatch"))
}

/// Names accepted by [`procedural`].
pub const PROCEDURAL_NAMES: [&str; 6] = ["mixed", "steps", "ramps", "boxes", "rubble", "slopes"];

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Lattice value noise in `[-1, 1]`, smooth (used for gentle relief).
fn relief_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (xi, yi) = (x.floor(), y.floor());
    let (fx, fy) = (x - xi, y - yi);
    let h = |i: f64, j: f64| {
        let k = stride_core::rng::key(&[seed, i as i64 as u64, j as i64 as u64]);
        stride_core::rng::hash_uniform(k) * 2.0 - 1.0
    };
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let a = h(xi, yi) + (h(xi + 1.0, yi) - h(xi, yi)) * sx;
    let b = h(xi, yi + 1.0) + (h(xi + 1.0, yi + 1.0) - h(xi, yi + 1.0)) * sx;
    a + (b - a) * sy
}

/// A procedural terrain of a few decimetres of relief over `geometry`: `steps` (stairs up
/// and down across the path), `ramps`, `boxes` (blocks to step over), `rubble` (stones on
/// rough ground), `slopes` (rolling hills), or `mixed` (a stretch of each along +x, rubble
/// and gentle slopes elsewhere). The area within 0.3 m of the start is flat so the robot
/// starts level. Deterministic for a seed.
pub fn procedural(name: &str, geometry: GridGeometry, seed: u64) -> Result<Grid<f32>, String> {
    if !PROCEDURAL_NAMES.contains(&name) {
        return Err(format!(
            "unknown procedural terrain '{name}' (expected one of: {})",
            PROCEDURAL_NAMES.join(", ")
        ));
    }
    let mut rng = SplitMix64::new(seed ^ 0x007E_44A1);
    // Random boxes and stones, placed once.
    let boxes: Vec<(f64, f64, f64, f64, f64, f64)> = (0..220)
        .map(|_| {
            let (x0, y0, x1, y1) = geometry.extent();
            (
                rng.range(x0, x1),
                rng.range(y0, y1),
                rng.range(0.08, 0.25), // half size x
                rng.range(0.08, 0.25), // half size y
                rng.range(0.04, 0.12), // height
                rng.range(0.0, std::f64::consts::PI),
            )
        })
        .collect();
    let stones: Vec<(f64, f64, f64, f64)> = (0..6000)
        .map(|_| {
            let (x0, y0, x1, y1) = geometry.extent();
            (
                rng.range(x0, x1),
                rng.range(y0, y1),
                rng.range(0.015, 0.06),
                rng.range(0.01, 0.05),
            )
        })
        .collect();
    let mut grid = Grid::filled(geometry, 0.0f32);
    let g = geometry;
    let steps = |x: f64| {
        // Stairs every 0.45 m: up three steps of 6 cm, then down again.
        let k = (x / 0.45).floor();
        let level = [0.0, 1.0, 2.0, 3.0, 2.0, 1.0][(k.rem_euclid(6.0)) as usize];
        0.06 * level
    };
    let ramps = |x: f64| {
        let u = x.rem_euclid(3.0);
        if u < 1.0 {
            0.18 * u
        } else if u < 1.6 {
            0.18
        } else if u < 2.6 {
            0.18 * (2.6 - u)
        } else {
            0.0
        }
    };
    let slopes = |x: f64, y: f64| {
        0.12 * relief_noise(seed, x / 1.7, y / 1.7)
            + 0.05 * relief_noise(seed ^ 9, x / 0.6, y / 0.6)
    };
    let rubble = |x: f64, y: f64| 0.02 * (relief_noise(seed ^ 3, x / 0.15, y / 0.15) + 1.0);
    for r in 0..g.rows {
        for c in 0..g.cols {
            let (x, y) = g.center(r, c);
            let dist0 = (x * x + y * y).sqrt();
            let h = match name {
                "steps" => steps(x.max(0.0)),
                "ramps" => ramps(x.max(0.0)),
                "slopes" => slopes(x, y),
                "rubble" => rubble(x, y),
                "boxes" => 0.0,
                _ => {
                    // mixed: rubble ground with gentle slopes, then features along +x.
                    let base =
                        0.5 * rubble(x, y) + 0.4 * slopes(x, y) * smoothstep(0.5, 2.0, dist0);
                    let feature = if (0.8..2.2).contains(&x) && y.abs() < 1.2 {
                        steps(x - 0.8)
                    } else if (2.6..4.4).contains(&x) && y.abs() < 1.2 {
                        ramps((x - 2.6) * 1.6 / 1.8)
                    } else {
                        0.0
                    };
                    base + feature
                }
            };
            if let Some(v) = grid.get_mut(r, c) {
                *v = h as f32;
            }
        }
    }
    // Objects, each rasterised over its own bounding cells.
    let mut raise = |cx: f64, cy: f64, radius: f64, height_at: &dyn Fn(f64, f64) -> Option<f64>| {
        let (Some((r0, c0)), Some((r1, c1))) = (
            g.cell_of(
                (cx - radius).max(g.extent().0),
                (cy - radius).max(g.extent().1),
            ),
            g.cell_of(
                (cx + radius).min(g.extent().2 - 1e-9),
                (cy + radius).min(g.extent().3 - 1e-9),
            ),
        ) else {
            return;
        };
        for r in r0..=r1 {
            for c in c0..=c1 {
                let (x, y) = g.center(r, c);
                if let (Some(hh), Some(v)) = (height_at(x, y), grid.get_mut(r, c)) {
                    *v = v.max(hh as f32);
                }
            }
        }
    };
    if matches!(name, "boxes" | "mixed" | "rubble") {
        for &(bx, by, hx, hy, bh, yaw) in &boxes {
            let keep = name == "boxes"
                || (name == "mixed" && (bx - 5.0).abs() < 0.8)
                || (name == "rubble" && bh < 0.06);
            if !keep {
                continue;
            }
            let (s, co) = yaw.sin_cos();
            raise(bx, by, hx.hypot(hy), &|x, y| {
                let (dx, dy) = (x - bx, y - by);
                let (u, v) = (dx * co + dy * s, -dx * s + dy * co);
                (u.abs() <= hx && v.abs() <= hy).then_some(bh)
            });
        }
    }
    if matches!(name, "rubble" | "mixed") {
        let (count, base) = if name == "rubble" {
            (6000, 0.02)
        } else {
            (1500, 0.0)
        };
        for &(sx, sy, sr, sh) in stones.iter().take(count) {
            raise(sx, sy, sr, &|x, y| {
                let d2 = (x - sx).powi(2) + (y - sy).powi(2);
                (d2 < sr * sr).then(|| base + sh * (1.0 - d2 / (sr * sr)).sqrt())
            });
        }
    }
    // Level start pad.
    for r in 0..g.rows {
        for c in 0..g.cols {
            let (x, y) = g.center(r, c);
            let pad = smoothstep(0.3, 0.6, (x * x + y * y).sqrt());
            if let Some(v) = grid.get_mut(r, c) {
                *v = (f64::from(*v) * pad) as f32;
            }
        }
    }
    Ok(grid)
}

#[cfg(test)]
#[path = "terrain_tests.rs"]
mod tests;
