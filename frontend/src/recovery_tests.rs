//! Tests of recovery's building blocks: descriptor matching and the remembered points.

use super::*;
use nalgebra::{Matrix3, Point3};
use opencv::core::Point2f;

/// A point whose descriptor has the first `ones` bits set.
fn point(ones: usize) -> OrbPoint {
    let mut descriptor = [0u8; 32];
    for bit in 0..ones {
        descriptor[bit / 8] |= 1 << (bit % 8);
    }
    OrbPoint {
        px: Point2f::new(0.0, 0.0),
        descriptor,
        p_camera: Measurement {
            p: Point3::origin(),
            cov: Matrix3::identity(),
        },
    }
}

#[test]
fn a_packed_feature_gives_its_feature_back_to_f32_precision() {
    let f = PlaceFeature {
        px: Point2::new(321.25, 17.5),
        descriptor: [0xa5; 32],
        measurement: Measurement {
            p: Point3::new(-0.123_456_789, 0.5, 2.345_678_9),
            cov: Matrix3::new(1e-5, 2e-6, 3e-6, 2e-6, 4e-5, 5e-6, 3e-6, 5e-6, 9e-4),
        },
    };
    let back = PackedFeature::new(&f).feature();
    assert_eq!((back.px, back.descriptor), (f.px, f.descriptor));
    assert!((back.measurement.p - f.measurement.p).norm() < 1e-6);
    assert!((back.measurement.cov - f.measurement.cov).norm() < 1e-10);
    assert_eq!(back.measurement.cov, back.measurement.cov.transpose());
    // Through the matcher's point and back, nothing changes.
    assert_eq!(PlaceFeature::from(&OrbPoint::from(back)), back);
}

#[test]
fn matches_pass_the_distance_bound_the_ratio_test_and_uniqueness() {
    // Reference descriptors with 0, 100, 140 and 250 bits set.
    let reference = [point(0), point(100), point(140), point(250)];
    let query = [
        point(2),   // 2 from the first, 98 from the second: kept
        point(120), // 20 from the second and the third: ambiguous, dropped
        point(245), // 5 from the fourth: kept
        point(247), // 3 from the fourth: it wins the fourth from the previous one
        point(195), // 55 from the third and the fourth: too far, and ambiguous
    ];
    let matches = match_points(&query, &reference);
    assert_eq!(matches, vec![(0, 0), (3, 3)]);
    assert!(match_points(&query, &[]).is_empty());
}
