//! Tests of `terrain`.

use super::*;

fn flat_with_step() -> HeightField {
    let g = GridGeometry::covering(-2.0, -2.0, 6.0, 2.0, 0.01);
    let mut grid = Grid::filled(g, 0.0f32);
    for r in 0..g.rows {
        for c in 0..g.cols {
            let (x, _) = g.center(r, c);
            if x > 2.0 {
                *grid.get_mut(r, c).unwrap() = 0.1;
            }
        }
    }
    HeightField::new(grid)
}

#[test]
fn rays_hit_the_ground_and_the_step_where_expected() {
    let hf = flat_with_step();
    // From 0.4 m up, 45 degrees down along +x: hits z = 0 at x = 0.4.
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let hit = hf.intersect([0.0, 0.0, 0.4], [s, 0.0, -s], 10.0).unwrap();
    assert!((hit.t * s - 0.4).abs() < 1e-4, "{}", hit.t * s);
    // Shallow ray: would reach z = 0 at x = 4, but meets the 0.1 m step face first,
    // then the step's top at z = 0.1 -> x = 3.0.
    let d = [4.0, 0.0, -0.4];
    let n = (16.0f64 + 0.16).sqrt();
    let hit = hf
        .intersect([0.0, 0.0, 0.4], [d[0] / n, 0.0, d[2] / n], 10.0)
        .unwrap();
    let x = hit.t * d[0] / n;
    assert!((x - 3.0).abs() < 0.01, "{x}");
    // Upward rays miss.
    assert!(hf
        .intersect([0.0, 0.0, 0.4], [1.0, 0.0, 0.0], 10.0)
        .is_none());
    assert!(
        hf.intersect([0.0, 0.0, 0.4], [0.0, 0.0, -1.0], 0.3)
            .is_none(),
        "beyond t_max"
    );
    let n = hf.normal(0.0, 0.0);
    assert!((n[2] - 1.0).abs() < 1e-9);
}

#[test]
fn procedural_terrains_have_decimetres_of_relief_and_a_level_start() {
    let g = GridGeometry::covering(-3.0, -3.0, 6.0, 3.0, 0.02);
    for name in PROCEDURAL_NAMES {
        let grid = procedural(name, g, 3).unwrap();
        let (lo, hi) = grid.min_max().unwrap();
        assert!(
            hi - lo > 0.05 && hi - lo < 0.6,
            "{name}: relief {}",
            hi - lo
        );
        assert!(grid.at(0.0, 0.0).unwrap().abs() < 1e-6, "{name}");
    }
    assert!(procedural("lava", g, 1).is_err());
    assert_eq!(
        procedural("mixed", g, 5).unwrap(),
        procedural("mixed", g, 5).unwrap()
    );
}
