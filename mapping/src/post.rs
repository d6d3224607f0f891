//! Post-processing of an exported map: the median filter of paper 000 (section 3.2) that
//! fills small holes.

use stride_core::grid::Grid;

/// Fills every unknown (NaN) cell that has at least `min_known` known cells among its eight
/// neighbours with their median height, and gives it the median of their variances. Known
/// cells are left as they are (smoothing them would blur steps). Returns the number of cells
/// filled. Fills use only originally known neighbours (one pass, order-independent).
pub fn median_fill(elevation: &mut Grid<f32>, variance: &mut Grid<f32>, min_known: usize) -> usize {
    let g = elevation.geometry;
    let mut fills: Vec<(usize, usize, f32, f32)> = Vec::new();
    let mut hs = Vec::with_capacity(8);
    let mut vs = Vec::with_capacity(8);
    for r in 0..g.rows {
        for c in 0..g.cols {
            if !elevation.get(r, c).is_some_and(|v| v.is_nan()) {
                continue;
            }
            hs.clear();
            vs.clear();
            for dr in -1i64..=1 {
                for dc in -1i64..=1 {
                    if dr == 0 && dc == 0 {
                        continue;
                    }
                    let (rr, cc) = (r as i64 + dr, c as i64 + dc);
                    if rr < 0 || cc < 0 {
                        continue;
                    }
                    if let Some(h) = elevation
                        .get(rr as usize, cc as usize)
                        .filter(|v| !v.is_nan())
                    {
                        hs.push(h);
                        vs.push(variance.get(rr as usize, cc as usize).unwrap_or(f32::NAN));
                    }
                }
            }
            if hs.len() >= min_known.max(1) {
                hs.sort_by(f32::total_cmp);
                vs.sort_by(f32::total_cmp);
                let mid = |v: &Vec<f32>| {
                    if v.len() % 2 == 1 {
                        v[v.len() / 2]
                    } else {
                        (v[v.len() / 2 - 1] + v[v.len() / 2]) / 2.0
                    }
                };
                fills.push((r, c, mid(&hs), mid(&vs)));
            }
        }
    }
    for &(r, c, h, v) in &fills {
        if let Some(slot) = elevation.get_mut(r, c) {
            *slot = h;
        }
        if let Some(slot) = variance.get_mut(r, c) {
            *slot = v;
        }
    }
    fills.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::grid::GridGeometry;

    #[test]
    fn fills_holes_but_not_open_areas() {
        let g = GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 1.0,
            rows: 5,
            cols: 5,
        };
        let mut h = Grid::filled(g, 1.0f32);
        let mut v = Grid::filled(g, 0.01f32);
        *h.get_mut(2, 2).unwrap() = f32::NAN; // a one-cell hole
        for c in 0..5 {
            *h.get_mut(4, c).unwrap() = f32::NAN; // an open edge
        }
        *h.get_mut(1, 1).unwrap() = 5.0; // an outlier among the hole's neighbours
        let n = median_fill(&mut h, &mut v, 5);
        assert_eq!(h.get(2, 2), Some(1.0), "the median ignores the outlier");
        assert!(
            h.get(4, 2).unwrap().is_nan(),
            "three known neighbours are not enough"
        );
        assert_eq!(n, 1);
        assert_eq!(v.get(2, 2), Some(0.01));
    }
}
