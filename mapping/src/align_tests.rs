//! Tests of `align`.

use super::*;
use crate::stack::{StackConfig, StackMapper};
use crate::ElevationMapper;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// A sensor 0.8 m above the origin looking along +x, pitched 30 degrees down (camera z
/// forward, x right, y down).
fn true_pose() -> Isometry3<f64> {
    let level =
        nalgebra::Rotation3::from_basis_unchecked(&[-Vector3::y(), -Vector3::z(), Vector3::x()]);
    let down = nalgebra::Rotation3::from_axis_angle(&Vector3::y_axis(), 30f64.to_radians());
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.8),
        UnitQuaternion::from_rotation_matrix(&(down * level)),
    )
}

/// Flat ground (z = 0) on a 5 mm lattice in front of the sensor (every 1 cm cell gets
/// points, wherever a tilt moves them).
fn ground() -> Vec<Point3<f64>> {
    (0..400)
        .flat_map(|i| {
            (0..320).map(move |j| {
                Point3::new(0.8 + 0.005 * f64::from(i), -0.8 + 0.005 * f64::from(j), 0.0)
            })
        })
        .collect()
}

/// The world points as seen by the sensor at `true_pose`, placed at `believed` (5 mm noise
/// model, no noise added).
fn frame_points(world: &[Point3<f64>]) -> (Vec<Point3<f64>>, Vec<Matrix3<f64>>) {
    let inv = true_pose().inverse();
    let pts: Vec<Point3<f64>> = world.iter().map(|p| inv * p).collect();
    let covs = vec![Matrix3::identity() * 2.5e-5; pts.len()];
    (pts, covs)
}

fn mapped_ground() -> StackMapper {
    let mut m = StackMapper::new(StackConfig {
        edge_filter: None,
        ..StackConfig::default()
    })
    .unwrap();
    let (pts, covs) = frame_points(&ground());
    for _ in 0..4 {
        m.integrate(&SensorFrame::points(&pts, &covs, true_pose(), 0.0).unwrap());
    }
    m
}

/// `true_pose` raised by `up_m` and tilted by `tilt_rad` about the world's x axis through
/// the sensor.
fn believed(up_m: f64, tilt_rad: f64) -> Isometry3<f64> {
    let c = true_pose().translation.vector;
    let err = Translation3::from(c + Vector3::new(0.0, 0.0, up_m))
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), tilt_rad)
        * Translation3::from(-c);
    err * true_pose()
}

fn align(m: &mut StackMapper, pose: Isometry3<f64>, cfg: &AlignConfig) -> AlignOutcome {
    let (pts, covs) = frame_points(&ground());
    m.align(&SensorFrame::points(&pts, &covs, pose, 0.0).unwrap(), cfg)
}

#[test]
fn a_raised_and_tilted_view_is_laid_back_onto_the_map() {
    let mut m = mapped_ground();
    let full = AlignConfig {
        gain: 1.0,
        ..AlignConfig::default()
    };
    let out = align(&mut m, believed(0.012, 0.6f64.to_radians()), &full);
    let AlignOutcome::Aligned(a) = out else {
        panic!("{out:?}");
    };
    // The corrected pose puts the ground back at z = 0 wherever the sensor sees it.
    let corrected = a.correction * believed(0.012, 0.6f64.to_radians());
    for p in [Point3::new(1.0, -0.8, 0.0), Point3::new(2.9, 0.9, 0.0)] {
        let seen = corrected * (true_pose().inverse() * p);
        assert!(seen.z.abs() < 1e-3, "{seen:?}");
    }
    assert!((a.shift_m + 0.012).abs() < 1e-3, "{a:?}");
    assert!(
        (a.tilt_rad - 0.6f64.to_radians()).abs() < 0.05f64.to_radians(),
        "{a:?}"
    );
    assert!(a.rms_after_m < 0.2 * a.rms_before_m, "{a:?}");
    // Part of it with a gain below 1.
    let half = AlignConfig {
        gain: 0.5,
        ..AlignConfig::default()
    };
    let AlignOutcome::Aligned(h) = align(&mut m, believed(0.012, 0.6f64.to_radians()), &half)
    else {
        panic!("not aligned");
    };
    assert!((h.shift_m + 0.006).abs() < 1e-3, "{h:?}");
    assert!(
        (h.tilt_rad - 0.3f64.to_radians()).abs() < 0.05f64.to_radians(),
        "{h:?}"
    );
}

#[test]
fn a_view_at_the_right_pose_is_left_alone() {
    let mut m = mapped_ground();
    let AlignOutcome::Aligned(a) = align(&mut m, true_pose(), &AlignConfig::default()) else {
        panic!("not aligned");
    };
    assert!(a.shift_m.abs() < 1e-4 && a.tilt_rad < 1e-4, "{a:?}");
}

#[test]
fn an_empty_map_or_a_large_correction_is_refused() {
    let mut empty = StackMapper::new(StackConfig::default()).unwrap();
    assert_eq!(
        align(&mut empty, true_pose(), &AlignConfig::default()),
        AlignOutcome::TooFewPoints(0)
    );
    let mut m = mapped_ground();
    let cfg = AlignConfig {
        gain: 1.0,
        outlier_m: 0.2,
        ..AlignConfig::default()
    };
    assert!(matches!(
        align(&mut m, believed(0.0, 3f64.to_radians()), &cfg),
        AlignOutcome::TooLarge(_)
    ));
    assert!(matches!(
        align(&mut m, believed(0.08, 0.0), &cfg),
        AlignOutcome::TooLarge(_)
    ));
}

#[test]
fn invalid_parameters_are_refused_by_name() {
    for (cfg, name) in [
        (
            AlignConfig {
                gain: 1.5,
                ..AlignConfig::default()
            },
            "gain",
        ),
        (
            AlignConfig {
                stride: 0,
                ..AlignConfig::default()
            },
            "stride",
        ),
        (
            AlignConfig {
                outlier_m: f64::NAN,
                ..AlignConfig::default()
            },
            "outlier_m",
        ),
    ] {
        match cfg.validate() {
            Err(crate::MappingError::Parameter { name: n, .. }) => assert_eq!(n, name),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn aligning_views_together_finds_what_aligning_each_alone_does() {
    let mut m = mapped_ground();
    let cfg = AlignConfig::default();
    let (pts, covs) = frame_points(&ground());
    let poses = [
        believed(0.01, 0.3f64.to_radians()),
        true_pose(),
        believed(-0.008, -0.5f64.to_radians()),
        believed(0.2, 0.0),
    ];
    let frames: Vec<SensorFrame<'_>> = poses
        .iter()
        .map(|&p| SensorFrame::points(&pts, &covs, p, 0.0).unwrap())
        .collect();
    let together = m.align_each(&frames, &cfg);
    let alone: Vec<AlignOutcome> = frames.iter().map(|f| m.align(f, &cfg)).collect();
    assert_eq!(together, alone);
    assert!(matches!(together.first(), Some(AlignOutcome::Aligned(_))));
    // 20 cm off: no point within the outlier distance of the map.
    assert!(
        matches!(together.last(), Some(AlignOutcome::TooFewPoints(_))),
        "{together:?}"
    );
}
