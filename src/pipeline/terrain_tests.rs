//! The pipeline's map: views wait for their keyframe's pose, a moved keyframe rebuilds the
//! map where its views went, and old views settle.

use super::*;
use nalgebra::{Translation3, UnitQuaternion, Vector3};

/// Views per place: enough sightings for a voxel to count.
const VIEWS: usize = 5;

/// A camera `height_m` above the world origin looking straight down (camera x along world
/// x, camera y along world -y).
fn looking_down(height_m: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, height_m),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    )
}

/// Maps a flat floor 1 m below a downward-looking camera at each of `xs` (m along x):
/// `VIEWS` views per place, each place its own keyframe, placed and mapped at once.
fn map_floor_at(t: &mut Terrain, camera: &PinholeCamera, xs: &[f64]) {
    let floor = DepthImage::filled(camera.width(), camera.height(), 1.0);
    for (i, &x) in xs.iter().enumerate() {
        for v in 0..VIEWS {
            let frame = i * VIEWS + v;
            t.add_view(frame, frame as f64, &floor, i as u64, Isometry3::identity());
        }
        let pose =
            Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity())
                * looking_down(1.0);
        t.set_poses(&[(i as u64, pose)]);
        t.update().unwrap();
    }
}

/// The median height of the map's known cells (m) and their count.
fn median_height(t: &Terrain) -> (f64, usize) {
    let layers = t.layers().unwrap();
    let mut h: Vec<f64> = layers
        .elevation
        .as_slice()
        .iter()
        .filter(|v| !v.is_nan())
        .map(|&v| f64::from(v))
        .collect();
    h.sort_by(f64::total_cmp);
    (h.get(h.len() / 2).copied().unwrap_or(f64::NAN), h.len())
}

#[test]
fn a_keyframe_the_back_end_moves_moves_its_terrain_with_it() {
    let camera = PinholeCamera::KINECT_DEFAULT;
    let mut t = Terrain::new(&camera, TerrainConfig::default()).unwrap();
    let floor = DepthImage::filled(camera.width(), camera.height(), 1.0);
    // A voxel needs a few sightings to count (paper 000's vitality): five views of one
    // keyframe, tied to it by the identity.
    for frame in 0..VIEWS {
        t.add_view(frame, frame as f64, &floor, 7, Isometry3::identity());
    }
    t.update().unwrap();
    // No world frame and no pose yet: nothing is mapped.
    assert_eq!((t.stats().views_mapped, median_height(&t).1), (0, 0));
    t.set_world(Isometry3::identity());
    t.set_poses(&[(7, looking_down(1.0))]);
    t.update().unwrap();
    let (h, cells) = median_height(&t);
    assert_eq!(t.stats().views_mapped, VIEWS);
    // Every view's alignment is counted once: the first ones find no established cells,
    // the later ones meet the floor where the pose puts it (no correction).
    let s = t.stats();
    assert_eq!(
        s.aligned.len() + s.align_too_few_points + s.align_too_large,
        VIEWS
    );
    assert!(!s.aligned.is_empty() && s.align_too_few_points > 0, "{s:?}");
    assert!(
        s.aligned
            .iter()
            .all(|(dz, tilt)| dz.abs() < 1e-3 && *tilt < 1e-3),
        "{:?}",
        s.aligned
    );
    assert!(cells > 1000 && h.abs() < 0.003, "{h} m over {cells} cells");
    // The back end lifts the keyframe by 4 cm: the floor is rebuilt 4 cm higher, not
    // smeared between both heights.
    t.set_poses(&[(7, looking_down(1.04))]);
    t.update().unwrap();
    let (h, _) = median_height(&t);
    assert_eq!(t.stats().rebuilds, 1);
    assert!((h - 0.04).abs() < 0.003, "{h}");
    // A move below the threshold (1 mm) keeps the map as it is.
    t.set_poses(&[(7, looking_down(1.041))]);
    t.update().unwrap();
    assert_eq!(t.stats().rebuilds, 1);
    // The final poses rebuild it once more when they moved.
    let (layers, stats) = t.finish(|_| Some(looking_down(0.98)), |_| false).unwrap();
    assert_eq!(stats.rebuilds, 2);
    let known: Vec<f32> = layers
        .elevation
        .as_slice()
        .iter()
        .copied()
        .filter(|v| !v.is_nan())
        .collect();
    let mean = known.iter().map(|&v| f64::from(v)).sum::<f64>() / known.len() as f64;
    assert!((mean + 0.02).abs() < 0.003, "{mean}");
}

#[test]
fn old_views_settle_and_stay_in_the_map() {
    let camera = PinholeCamera::KINECT_DEFAULT;
    let config = TerrainConfig {
        max_stored_views: VIEWS,
        ..TerrainConfig::default()
    };
    let mut t = Terrain::new(&camera, config).unwrap();
    t.set_world(Isometry3::identity());
    // Two places 2 m apart.
    map_floor_at(&mut t, &camera, &[0.0, 2.0]);
    assert_eq!(
        (t.stats().views_settled, t.stats().views_mapped),
        (VIEWS, 2 * VIEWS)
    );
    let layers = t.layers().unwrap();
    let (x0, _, x1, _) = layers.elevation.geometry.extent();
    assert!(
        x0 < -0.5 && x1 > 2.5,
        "both views' floor is kept: x {x0} to {x1}"
    );
}

#[test]
fn invalid_settings_are_refused_by_key() {
    let camera = PinholeCamera::KINECT_DEFAULT;
    let cases = [
        (
            TerrainConfig {
                decimation: 0,
                ..TerrainConfig::default()
            },
            "map.decimation",
        ),
        (
            TerrainConfig {
                rebuild_translation_m: -1.0,
                ..TerrainConfig::default()
            },
            "map.rebuild_translation_m",
        ),
        (
            TerrainConfig {
                every_frames: 0,
                ..TerrainConfig::default()
            },
            "map.every_frames",
        ),
        (
            TerrainConfig {
                final_alignment_gain: 1.5,
                ..TerrainConfig::default()
            },
            "map.final_alignment_gain",
        ),
    ];
    for (config, key) in cases {
        let err = Terrain::new(&camera, config).err().unwrap().to_string();
        assert!(err.contains(key), "{err}");
    }
    let zero_resolution = TerrainConfig {
        stack: stride_mapping::stack::StackConfig {
            resolution_m: 0.0,
            ..Default::default()
        },
        ..TerrainConfig::default()
    };
    let err = Terrain::new(&camera, zero_resolution)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("resolution_m"), "{err}");
}

#[test]
fn columns_dropped_at_the_archive_cap_are_counted() {
    let camera = PinholeCamera::KINECT_DEFAULT;
    let dropped = |cap: usize| {
        let mut config = TerrainConfig::default();
        config.stack.archive_max_cells = cap;
        let mut t = Terrain::new(&camera, config).unwrap();
        t.set_world(Isometry3::identity());
        // Three places 2.5 m apart: the window leaves the first two behind.
        map_floor_at(&mut t, &camera, &[0.0, 2.5, 5.0]);
        t.stats().archive_dropped_cells
    };
    assert_eq!(dropped(8_000_000), 0);
    assert!(dropped(1_000) > 0);
}

#[test]
fn the_final_alignment_takes_the_tilt_errors_of_views_out_of_a_flat_floor() {
    let camera = PinholeCamera::KINECT_DEFAULT;
    let floor = DepthImage::filled(camera.width(), camera.height(), 1.0);
    // Places 15 cm apart along x, each keyframe's pose tilted by +-0.6 degree about x (a
    // SLAM's orientation error), each seen by VIEWS views of a flat floor 1 m below.
    let pose = |i: usize| {
        let tilt = if i % 2 == 0 { 0.6_f64 } else { -0.6 }.to_radians();
        Isometry3::from_parts(
            Translation3::new(0.15 * i as f64, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), tilt),
        ) * looking_down(1.0)
    };
    let floor_std = |passes: usize| {
        let config = TerrainConfig {
            final_alignment_passes: passes,
            ..TerrainConfig::default()
        };
        let mut t = Terrain::new(&camera, config).unwrap();
        t.set_world(Isometry3::identity());
        for i in 0..8 {
            for v in 0..VIEWS {
                let frame = i * VIEWS + v;
                t.add_view(frame, frame as f64, &floor, i as u64, Isometry3::identity());
            }
            t.set_poses(&[(i as u64, pose(i))]);
            t.update().unwrap();
        }
        let (layers, stats) = t
            .finish(|frame| Some(pose(frame / VIEWS)), |_| false)
            .unwrap();
        assert_eq!(stats.final_alignment.len(), passes);
        let fit = stride_mapping::metrics::floor_fit(&layers.elevation, 0.05).unwrap();
        (fit.residual_std_m, stats.final_alignment)
    };
    let (before, _) = floor_std(0);
    let (after, passes) = floor_std(8);
    // Each pass changes less than the one before it settles (the views converge).
    let first = passes.first().unwrap();
    let last = passes.last().unwrap();
    assert!(
        first.aligned > 0 && first.rotation_rms_rad > 1e-3,
        "{passes:?}"
    );
    assert!(
        last.rotation_rms_rad < 0.5 * first.rotation_rms_rad,
        "{passes:?}"
    );
    // Measured 0.73 -> 0.19 mm.
    assert!(after < 0.4 * before, "floor std {before} m -> {after} m");
}
