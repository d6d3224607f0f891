//! Tests of `stack`.

use super::*;
use crate::post::MedianFilter;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// A sensor 0.5 m above the origin looking along +x (camera z forward, x right, y down).
fn sensor_pose() -> Isometry3<f64> {
    let rot =
        nalgebra::Rotation3::from_basis_unchecked(&[-Vector3::y(), -Vector3::z(), Vector3::x()]);
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.5),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// Integrates world points (5 mm standard deviation) as one frame.
fn integrate(
    m: &mut dyn ElevationMapper,
    pose: Isometry3<f64>,
    world: &[Point3<f64>],
) -> UpdateStats {
    let inv = pose.inverse();
    let pts: Vec<Point3<f64>> = world.iter().map(|p| inv * p).collect();
    let covs = vec![Matrix3::identity() * 2.5e-5; pts.len()];
    m.integrate(&SensorFrame::points(&pts, &covs, pose, 0.0).unwrap())
}

/// Ground points (z = 0) on a 5 mm lattice over `[x0, x1] x [y0, y1]`.
fn ground(x0: f64, x1: f64, y0: f64, y1: f64) -> Vec<Point3<f64>> {
    let n = |a: f64, b: f64| ((b - a) / 0.005) as usize;
    (0..n(x0, x1))
        .flat_map(|i| {
            (0..n(y0, y1))
                .map(move |j| Point3::new(x0 + 0.005 * i as f64, y0 + 0.005 * j as f64, 0.0))
        })
        .collect()
}

fn height_at(m: &dyn ElevationMapper, x: f64, y: f64) -> Option<f32> {
    m.export().elevation.at(x, y).filter(|h| !h.is_nan())
}

/// The first difference between two maps (layer, cell, values), bit for bit.
fn first_difference(a: &MapLayers, b: &MapLayers) -> Option<String> {
    if a.elevation.geometry != b.elevation.geometry {
        return Some(format!(
            "geometry {:?} vs {:?}",
            a.elevation.geometry, b.elevation.geometry
        ));
    }
    let layers = [
        ("elevation", &a.elevation, &b.elevation),
        ("variance", &a.variance, &b.variance),
        ("vitality", &a.vitality, &b.vitality),
        ("updates", &a.updates, &b.updates),
    ];
    for (name, x, y) in layers {
        for (i, (u, v)) in x.as_slice().iter().zip(y.as_slice()).enumerate() {
            if u.to_bits() != v.to_bits() {
                return Some(format!("{name}[{i}]: {u} vs {v}"));
            }
        }
    }
    None
}

fn config() -> StackConfig {
    StackConfig {
        edge_filter: None,
        see_through_check: false,
        ..StackConfig::default()
    }
}

#[test]
fn vitality_establishes_a_column_after_three_updates_and_forgets_isolated_ones() {
    let mut m = StackMapper::new(config()).unwrap();
    let patch = ground(1.0, 1.05, 0.0, 0.05);
    let speck = [Point3::new(1.5, 0.5, 0.3)];
    integrate(
        &mut m,
        sensor_pose(),
        &[patch.clone(), speck.to_vec()].concat(),
    );
    assert!(
        height_at(&m, 1.02, 0.02).is_none(),
        "V = 3 after one update"
    );
    integrate(&mut m, sensor_pose(), &patch);
    assert!(height_at(&m, 1.02, 0.02).is_none(), "V = 6 after two");
    integrate(&mut m, sensor_pose(), &patch);
    let h = height_at(&m, 1.02, 0.02).expect("V = 9 > 7: established");
    assert!(h.abs() < 0.005, "{h}");
    for _ in 0..5 {
        integrate(&mut m, sensor_pose(), &patch);
    }
    assert!(
        height_at(&m, 1.5, 0.5).is_none(),
        "a single return never makes the map"
    );
}

#[test]
fn visibility_check_removes_an_obstacle_the_sensor_sees_past() {
    for check in [true, false] {
        let mut m = StackMapper::new(StackConfig {
            visibility_check: check,
            ..config()
        })
        .unwrap();
        // A spurious 30 cm obstacle at 1 m (e.g. from an earlier pose error), seen three
        // times so that it is established.
        let spurious: Vec<Point3<f64>> = ground(1.0, 1.03, -0.015, 0.015)
            .iter()
            .map(|p| Point3::new(p.x, p.y, 0.3))
            .collect();
        for _ in 0..3 {
            integrate(&mut m, sensor_pose(), &spurious);
        }
        assert!(height_at(&m, 1.01, 0.0).is_some_and(|h| (h - 0.3).abs() < 0.01));
        // Now the floor 2-3 m away is seen straight past where it stood: the line of
        // sight to it passes 0.33 m above the floor at 1 m, lower than the obstacle.
        for _ in 0..4 {
            integrate(&mut m, sensor_pose(), &ground(2.0, 3.0, -0.1, 0.1));
        }
        let h = height_at(&m, 1.01, 0.0);
        if check {
            assert!(h.is_none_or(|h| h < 0.25), "the occluder is cut: {h:?}");
        } else {
            assert!(
                h.is_some_and(|h| (h - 0.3).abs() < 0.01),
                "without the check it stays: {h:?}"
            );
        }
    }
}

/// A mapper with an established 1 m x 0.2 m patch of floor, and its exported layers.
fn mapped(m: &mut dyn ElevationMapper) -> MapLayers {
    for _ in 0..3 {
        integrate(m, sensor_pose(), &ground(1.0, 2.0, -0.1, 0.1));
    }
    m.export()
}

#[test]
fn bad_input_is_dropped_counted_and_leaves_the_map_as_it_was() {
    let mappers: [fn() -> Box<dyn ElevationMapper>; 2] = [
        || Box::new(StackMapper::new(config()).unwrap()),
        || {
            Box::new(
                crate::fankhauser::FankhauserMapper::new(
                    crate::fankhauser::FankhauserConfig::default(),
                )
                .unwrap(),
            )
        },
    ];
    for make in mappers {
        let mut m = make();
        let before = mapped(m.as_mut());
        assert!(before.cells_observed() > 1000, "{}", m.name());
        let pose = sensor_pose();
        // NaN and infinite points.
        let bad = [
            Point3::new(f64::NAN, 0.0, 1.0),
            Point3::new(0.0, f64::INFINITY, 1.0),
            Point3::new(0.0, 0.0, f64::NEG_INFINITY),
        ];
        let s = m.integrate(
            &SensorFrame::points(&bad, &[Matrix3::identity() * 1e-4; 3], pose, 0.1).unwrap(),
        );
        assert_eq!(
            (s.rejected.non_finite, s.points_used),
            (3, 0),
            "{}",
            m.name()
        );
        // Points outside the 4 m window (inside the sensor's range).
        let s = integrate(
            m.as_mut(),
            pose,
            &[Point3::new(1.5, 3.0, 0.0), Point3::new(1.5, -3.0, 0.0)],
        );
        assert_eq!(
            (s.rejected.outside_window, s.points_used),
            (2, 0),
            "{}",
            m.name()
        );
        // Zero, negative and NaN variances.
        let p = [Point3::new(0.0, 0.0, 1.5); 3];
        let covs = [
            Matrix3::zeros(),
            Matrix3::identity() * -1e-4,
            Matrix3::identity() * f64::NAN,
        ];
        let s = m.integrate(&SensorFrame::points(&p, &covs, pose, 0.2).unwrap());
        assert_eq!(
            (s.rejected.bad_variance, s.points_used),
            (3, 0),
            "{}",
            m.name()
        );
        // A NaN pose drops the whole frame.
        let nan_pose = Isometry3::from_parts(Translation3::new(f64::NAN, 0.0, 0.5), pose.rotation);
        let floor = ground(1.0, 2.0, -0.1, 0.1);
        let s = integrate(m.as_mut(), nan_pose, &floor);
        assert_eq!(
            (s.rejected.bad_pose, s.points_used),
            (floor.len(), 0),
            "{}",
            m.name()
        );
        assert_eq!(
            first_difference(&m.export(), &before),
            None,
            "{}: the map is unchanged",
            m.name()
        );
        // Absurd but positive variances are used (beside the floor patch), and the map
        // stays finite.
        let world = [Point3::new(1.5, -0.5, 0.2), Point3::new(1.5, 0.5, 0.2)];
        let p: Vec<Point3<f64>> = world.iter().map(|q| pose.inverse() * q).collect();
        let covs = [Matrix3::identity() * 1e-60, Matrix3::identity() * 1e300];
        for k in 0..3 {
            m.integrate(&SensorFrame::points(&p, &covs, pose, 0.3 + 0.1 * f64::from(k)).unwrap());
        }
        let after = m.export();
        let finite = |l: &MapLayers| {
            l.elevation
                .as_slice()
                .iter()
                .filter(|v| v.is_finite())
                .count()
        };
        assert!(
            after
                .elevation
                .as_slice()
                .iter()
                .chain(after.variance.as_slice())
                .all(|v| v.is_nan() || v.is_finite()),
            "{}",
            m.name()
        );
        assert_eq!(finite(&after), finite(&before) + 2, "{}", m.name());
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut m = StackMapper::new(StackConfig::default()).unwrap();
            let mut pts = ground(0.8, 2.5, -0.6, 0.6);
            pts.extend(
                ground(1.2, 1.4, -0.1, 0.1)
                    .iter()
                    .map(|p| Point3::new(p.x, p.y, 0.2)),
            );
            for k in 0..4 {
                let pose = Isometry3::from_parts(
                    Translation3::new(0.02 * k as f64, 0.0, 0.5),
                    sensor_pose().rotation,
                );
                integrate(&mut m, pose, &pts);
            }
            m.export()
        })
    };
    assert_eq!(first_difference(&run(1), &run(2)), None);
}

/// Layers equal bit for bit (NaN, unknown, equals NaN).
fn same_layers(a: &MapLayers, b: &MapLayers) -> bool {
    let bits = |g: &stride_core::grid::Grid<f32>| -> Vec<u32> {
        g.as_slice().iter().map(|v| v.to_bits()).collect()
    };
    [
        (&a.elevation, &b.elevation),
        (&a.variance, &b.variance),
        (&a.vitality, &b.vitality),
        (&a.updates, &b.updates),
    ]
    .iter()
    .all(|(x, y)| x.geometry == y.geometry && bits(x) == bits(y))
}

#[test]
fn finished_applies_the_configured_median_filter_and_only_it() {
    // A ground patch with a one-cell hole in the middle: the median fill closes it.
    let patch: Vec<Point3<f64>> = ground(1.0, 1.05, 0.0, 0.05)
        .into_iter()
        .filter(|p| !((1.02..1.03).contains(&p.x) && (0.02..0.03).contains(&p.y)))
        .collect();
    for filter in [None, Some(MedianFilter::default())] {
        let mut m = StackMapper::new(StackConfig {
            median_filter: filter,
            ..config()
        })
        .unwrap();
        for _ in 0..3 {
            integrate(&mut m, sensor_pose(), &patch);
        }
        let raw = m.export();
        let (done, stats) = m.finished();
        match filter {
            None => {
                assert!(same_layers(&done, &raw));
                assert_eq!(stats, MedianStats::default());
            }
            Some(f) => {
                let mut expected = raw.clone();
                let expected_stats =
                    median_filter(&mut expected.elevation, &mut expected.variance, &f);
                assert!(same_layers(&done, &expected));
                assert!(!same_layers(&done, &raw), "the hole is filled");
                assert_eq!(stats, expected_stats);
                assert!(stats.filled > 0, "{stats:?}");
            }
        }
    }
}

#[test]
fn mappers_refuse_invalid_parameters() {
    use crate::fankhauser::{FankhauserConfig, FankhauserMapper};
    use crate::MappingError;
    let name = |r: Result<usize, MappingError>| match r {
        Err(MappingError::Parameter { name, .. }) => name,
        other => panic!("expected a parameter error, got {other:?}"),
    };
    let d = StackConfig::default();
    assert_eq!(d.validate(), Ok(400));
    let bad = |cfg: StackConfig| name(cfg.validate());
    assert_eq!(
        bad(StackConfig {
            resolution_m: -0.01,
            ..d.clone()
        }),
        "resolution_m"
    );
    assert_eq!(
        bad(StackConfig {
            size_m: f64::NAN,
            ..d.clone()
        }),
        "size_m"
    );
    assert_eq!(
        bad(StackConfig {
            size_m: 0.05,
            ..d.clone()
        }),
        "size_m"
    );
    assert_eq!(
        bad(StackConfig {
            resolution_m: 1e-4,
            ..d.clone()
        }),
        "size_m"
    );
    assert_eq!(
        bad(StackConfig {
            voxel_height_m: 0.0,
            ..d.clone()
        }),
        "voxel_height_m"
    );
    let mut sensor = d.sensor;
    sensor.max_depth_m = sensor.min_depth_m;
    assert_eq!(
        bad(StackConfig {
            sensor,
            ..d.clone()
        }),
        "sensor.max_depth_m"
    );
    let edge_filter = Some(crate::input::EdgeFilter {
        min_grazing_rad: 2.0,
        sigmas: 3.0,
    });
    assert_eq!(
        bad(StackConfig {
            edge_filter,
            ..d.clone()
        }),
        "edge_filter.min_grazing_rad"
    );
    assert!(StackMapper::new(StackConfig {
        lookahead_m: -1.0,
        ..d
    })
    .is_err());
    let f = FankhauserConfig::default();
    assert_eq!(f.validate(), Ok(400));
    let fbad = |cfg: FankhauserConfig| name(cfg.validate());
    assert_eq!(
        fbad(FankhauserConfig {
            min_variance: 0.0,
            ..f.clone()
        }),
        "min_variance"
    );
    assert_eq!(
        fbad(FankhauserConfig {
            max_variance: 1e-5,
            ..f.clone()
        }),
        "max_variance"
    );
    assert_eq!(
        fbad(FankhauserConfig {
            mahalanobis_threshold: f64::INFINITY,
            ..f.clone()
        }),
        "mahalanobis_threshold"
    );
    assert!(FankhauserMapper::new(FankhauserConfig {
        resolution_m: 0.0,
        ..f
    })
    .is_err());
}

#[test]
fn a_column_left_behind_resumes_when_the_window_comes_back() {
    let mut m = StackMapper::new(config()).unwrap();
    let patch = |z: f64| -> Vec<Point3<f64>> {
        ground(1.0, 1.05, 0.0, 0.05)
            .into_iter()
            .map(|p| Point3::new(p.x, p.y, z))
            .collect()
    };
    for _ in 0..3 {
        integrate(&mut m, sensor_pose(), &patch(0.05));
    }
    let updates_at = |m: &StackMapper| m.export().updates.at(1.02, 0.02);
    assert_eq!(updates_at(&m), Some(3.0));
    // Walk 10 m away: the window leaves the patch behind (it stays in the map) ...
    let away = Isometry3::from_parts(Translation3::new(10.0, 0.0, 0.0), Default::default())
        * sensor_pose();
    let far: Vec<Point3<f64>> = ground(11.0, 11.05, 0.0, 0.05);
    integrate(&mut m, away, &far);
    assert!(!m.window.contains(m.window.world_cell(1.02, 0.02)));
    assert_eq!(updates_at(&m), Some(3.0));
    // ... and come back: the column resumes, established, and takes the next measurement
    // at once (starting afresh, one more update would leave it below the vitality threshold
    // and the map would still show the old 5 cm).
    integrate(&mut m, sensor_pose(), &patch(0.07));
    assert!(m.window.contains(m.window.world_cell(1.02, 0.02)));
    assert_eq!(updates_at(&m), Some(4.0));
    let h = height_at(&m, 1.02, 0.02).unwrap();
    assert!(h > 0.052 && h < 0.07, "moved towards the new 7 cm: {h}");
    assert!(
        m.archive.is_empty(),
        "the archive holds only columns outside the window"
    );
    let (kept, dropped, resumed) = m.archive_cells();
    assert_eq!((kept, dropped), (0, 0));
    // The 5 x 5 cm patch: 25 columns.
    assert!(resumed >= 25, "the patch's columns resumed: {resumed}");
}

#[test]
fn the_archive_keeps_its_cap_by_dropping_the_farthest_columns() {
    let mut m = StackMapper::new(StackConfig {
        archive_max_cells: 20_000,
        ..config()
    })
    .unwrap();
    // A walk along x leaving a 0.5 x 0.5 m patch (2,500 columns) every metre.
    for step in 0..12 {
        let x = f64::from(step);
        let pose = Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), Default::default())
            * sensor_pose();
        let patch = ground(x + 1.0, x + 1.5, 0.0, 0.5);
        for _ in 0..3 {
            integrate(&mut m, pose, &patch);
        }
    }
    let (kept, dropped, _) = m.archive_cells();
    assert!(
        kept <= 20_000 && dropped > 0,
        "{kept} kept, {dropped} dropped"
    );
    // The patches nearest the robot are kept, the first ones went.
    assert!(height_at(&m, 10.2, 0.2).is_some());
    assert!(height_at(&m, 1.2, 0.2).is_none());
}

/// A cell straddling a step follows the surface under its centre with the default
/// `step_support_fraction`, and the top of the step with paper 000's highest-voxel rule.
#[test]
fn a_cell_straddling_a_step_follows_the_surface_under_its_centre() {
    // Cells are centred on multiples of 1 cm: the cell at x = 1.00 m covers [0.995, 1.005).
    // The step (10 cm up) starts at x = 1.003, so that cell's centre lies on the ground and
    // only a strip at its far edge on the step.
    let step_x = 1.003;
    let mut world = Vec::new();
    for i in 0..300 {
        for j in 0..100 {
            let (x, y) = (0.9 + 0.001 * f64::from(i), -0.05 + 0.001 * f64::from(j));
            world.push(Point3::new(x, y, if x >= step_x { 0.10 } else { 0.0 }));
        }
    }
    let run = |fraction: f32| {
        let mut m = StackMapper::new(StackConfig {
            step_support_fraction: fraction,
            visibility_check: false,
            median_filter: None,
            ..config()
        })
        .unwrap();
        for _ in 0..4 {
            integrate(&mut m, sensor_pose(), &world);
        }
        (
            height_at(&m, 1.0, 0.0).unwrap(),
            height_at(&m, 0.99, 0.0).unwrap(),
            height_at(&m, 1.01, 0.0).unwrap(),
        )
    };
    let (straddling, below, above) = run(StackConfig::default().step_support_fraction);
    assert!(straddling.abs() < 0.01, "straddling cell at {straddling} m");
    assert!(below.abs() < 0.01 && (above - 0.10).abs() < 0.01);
    let (highest_rule, _, _) = run(0.0);
    assert!(
        (highest_rule - 0.10).abs() < 0.01,
        "the highest-voxel rule takes the step's top: {highest_rule} m"
    );
    assert!(StackMapper::new(StackConfig {
        step_support_fraction: 1.5,
        ..config()
    })
    .is_err());
}

/// `establish_smooth`: a floor seen once, from pixels whose neighbourhoods hold no depth
/// jump, is in the map at once; with paper 000's counter alone (or without the edge filter
/// that defines a jump) it needs three frames.
#[test]
fn a_floor_seen_once_from_smooth_pixels_is_established_at_once() {
    let cam = stride_core::camera::PinholeCamera::new(52.5, 52.0, 31.5, 23.5, 64, 48).unwrap();
    let depth = stride_core::image::DepthImage::filled(64, 48, 0.5);
    // Looking straight down from 0.5 m: camera x along +x, y along -y, z down.
    let rot =
        nalgebra::Rotation3::from_basis_unchecked(&[Vector3::x(), -Vector3::y(), -Vector3::z()]);
    let pose = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.5),
        UnitQuaternion::from_rotation_matrix(&rot),
    );
    let frame = SensorFrame::depth(&depth, &cam, pose, 0.0).unwrap();
    let mapped_after_one = |establish_smooth: bool, edge_filter: bool| {
        let d = StackConfig::default();
        let mut m = StackMapper::new(StackConfig {
            establish_smooth,
            edge_filter: d.edge_filter.filter(|_| edge_filter),
            ..d
        })
        .unwrap();
        m.integrate(&frame);
        m.export()
            .elevation
            .as_slice()
            .iter()
            .filter(|h| !h.is_nan())
            .count()
    };
    let (with, without) = (mapped_after_one(true, true), mapped_after_one(false, true));
    // The footprint is about 0.6 x 0.46 m: over 2,000 cells of 1 cm.
    assert!(with > 2000, "{with} cells");
    assert_eq!(without, 0);
    // Without the edge filter there is no notion of a jump: nothing counts as smooth.
    assert_eq!(mapped_after_one(true, false), 0);
}
