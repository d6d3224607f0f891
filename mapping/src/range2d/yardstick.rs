//! Yardsticks for the scan map, computed from the scans themselves: the naive per-cell
//! median of every return, the cells seen (a return within 3 cm of the true surface), the
//! cells swept (between the returns of neighbouring beams in consecutive scans), the
//! mixed returns a simulator marked against what the filters removed, and objects' sizes
//! read from a map.

use super::certainty::weighted_median;
use stride_core::grid::{Grid, GridGeometry};
use stride_core::scan::Scan;

/// The cells the sensor swept: cells inside the quadrilaterals of returns of neighbouring
/// beams in consecutive scans (all four returns present and within 5 cm of each other, so
/// no depth edge is bridged). A map that fills the gaps between scan lines covers them; the
/// returns alone do not.
pub fn swept(scans: &[Scan], g: GridGeometry, max_range_m: f64) -> Grid<f32> {
    let mut out = Grid::filled(g, f32::NAN);
    let point = |s: &Scan, i: usize| {
        s.ranges
            .get(i)
            .filter(|&&r| r <= max_range_m)
            .and_then(|_| s.p_world(i))
    };
    for pair in scans.windows(2) {
        let [a, b] = pair else { continue };
        for i in 0..a.ranges.len().min(b.ranges.len()).saturating_sub(1) {
            let (Some(p0), Some(p1), Some(q0), Some(q1)) =
                (point(a, i), point(a, i + 1), point(b, i), point(b, i + 1))
            else {
                continue;
            };
            let quad = [p0, p1, q1, q0];
            let close = quad
                .iter()
                .all(|p| quad.iter().all(|q| (p - q).norm() <= 0.05));
            if !close {
                continue;
            }
            let (x0, x1) = quad
                .iter()
                .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p.x), h.max(p.x)));
            let (y0, y1) = quad
                .iter()
                .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p.y), h.max(p.y)));
            let (Some((r0, c0)), Some((r1, c1))) = (g.cell_of(x0, y0), g.cell_of(x1, y1)) else {
                continue;
            };
            for r in r0..=r1 {
                for c in c0..=c1 {
                    let (x, y) = g.center(r, c);
                    if inside_quad(&quad, x, y) {
                        if let Some(v) = out.get_mut(r, c) {
                            *v = 1.0;
                        }
                    }
                }
            }
        }
    }
    out
}

/// Whether `(x, y)` lies in the convex quadrilateral `q` (its x-y projection, either
/// winding).
fn inside_quad(q: &[nalgebra::Point3<f64>; 4], x: f64, y: f64) -> bool {
    let mut sign = 0.0f64;
    for k in 0..4 {
        let (a, b) = (q[k], q[(k + 1) % 4]);
        let cross = (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x);
        if cross.abs() < 1e-15 {
            continue;
        }
        if sign == 0.0 {
            sign = cross.signum();
        } else if cross.signum() != sign {
            return false;
        }
    }
    true
}

/// An object of known size on the floor, as a simulated scene lists it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KnownObject {
    /// Centre x, y (m).
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Extent along x (m).
    pub length_m: f64,
    /// Extent along y (m).
    pub width_m: f64,
    /// Height (m).
    pub height_m: f64,
}

/// An object's size read from a map (m), `None` where the map does not show it.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MeasuredSize {
    /// Along x through the centre: the cells above half the true height.
    pub length_m: Option<f64>,
    /// Along y, likewise.
    pub width_m: Option<f64>,
    /// The median height of the cells inside the true footprint (when the map knows at
    /// least half of them).
    pub height_m: Option<f64>,
}

/// Reads an object's size from a map (paper 003's Table 1).
pub fn measure_object(map: &Grid<f32>, o: &KnownObject) -> MeasuredSize {
    let g = map.geometry;
    let mut inside: Vec<(f32, f32)> = Vec::new();
    let mut footprint = 0usize;
    for r in 0..g.rows {
        for c in 0..g.cols {
            let (cx, cy) = g.center(r, c);
            if (cx - o.x).abs() <= o.length_m / 2.0 && (cy - o.y).abs() <= o.width_m / 2.0 {
                footprint += 1;
                if let Some(v) = map.get(r, c).filter(|v| !v.is_nan()) {
                    inside.push((v, 1.0));
                }
            }
        }
    }
    let above = |px: f64, py: f64| {
        map.at(px, py)
            .is_some_and(|v| f64::from(v) > o.height_m / 2.0)
    };
    let extent = |dx: f64, dy: f64| {
        let step = g.resolution;
        let (mut lo, mut hi) = (0.0, 0.0);
        while lo < 1.0 && above(o.x - (lo + step) * dx, o.y - (lo + step) * dy) {
            lo += step;
        }
        while hi < 1.0 && above(o.x + (hi + step) * dx, o.y + (hi + step) * dy) {
            hi += step;
        }
        above(o.x, o.y).then_some(lo + hi + step)
    };
    MeasuredSize {
        length_m: extent(1.0, 0.0),
        width_m: extent(0.0, 1.0),
        height_m: (!inside.is_empty() && 2 * inside.len() >= footprint)
            .then(|| f64::from(weighted_median(&mut inside))),
    }
}

/// The simulator's mixed returns (`mixed.json` beside the log: per scan, the beams whose
/// return is mixed) against what the filters removed: how many there were, how many the
/// filters removed, how many good returns they removed with them, and the cells the mixed
/// returns landed in.
pub fn mixed_truth(
    scans: &[Scan],
    filtered: &[Scan],
    mixed: &[Vec<usize>],
    g: GridGeometry,
    max_range_m: f64,
) -> (usize, usize, usize, Vec<(usize, usize)>) {
    let (mut n, mut caught, mut good_removed, mut cells) = (0, 0, 0, Vec::new());
    for ((s, f), m) in scans.iter().zip(filtered).zip(mixed) {
        for i in 0..s.ranges.len() {
            if !s.valid(i) || s.ranges.get(i).is_some_and(|&r| r > max_range_m) {
                continue;
            }
            let is_mixed = m.contains(&i);
            let removed = !f.valid(i);
            if is_mixed {
                n += 1;
                caught += usize::from(removed);
                if let Some(p) = s.p_world(i) {
                    cells.extend(g.cell_of(p.x, p.y));
                }
            } else {
                good_removed += usize::from(removed);
            }
        }
    }
    (n, caught, good_removed, cells)
}

/// The per-cell median of every return (the naive reference), and the cells seen: cells
/// with a return within 3 cm of the true surface.
pub fn naive_and_seen(
    scans: &[Scan],
    g: GridGeometry,
    truth: Option<&Grid<f32>>,
    max_range_m: f64,
) -> (Grid<f32>, Grid<f32>) {
    let mut cells: Vec<Vec<(f32, f32)>> = vec![Vec::new(); g.len()];
    let mut seen = Grid::filled(g, f32::NAN);
    for s in scans {
        for i in 0..s.ranges.len() {
            let Some(p) = s.p_world(i) else { continue };
            if s.ranges.get(i).is_none_or(|&r| r > max_range_m) {
                continue;
            }
            let Some((r, c)) = g.cell_of(p.x, p.y) else {
                continue;
            };
            let Some(k) = g.index(r, c) else { continue };
            if let Some(v) = cells.get_mut(k) {
                v.push((p.z as f32, 1.0));
            }
            let on_surface = truth
                .and_then(|t| t.sample_bilinear(p.x, p.y))
                .is_some_and(|t| (f64::from(t) - p.z).abs() <= 0.03);
            if on_surface {
                if let Some(v) = seen.get_mut(r, c) {
                    *v = 1.0;
                }
            }
        }
    }
    let naive = cells
        .iter_mut()
        .map(|v| {
            if v.is_empty() {
                f32::NAN
            } else {
                weighted_median(v)
            }
        })
        .collect();
    (
        Grid::from_vec(g, naive).unwrap_or_else(|| Grid::filled(g, f32::NAN)),
        seen,
    )
}
