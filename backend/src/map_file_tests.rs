//! Tests of saved maps: the round trip, and a clear error for each way a file can be bad.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;
use crate::map::Feature;
use nalgebra::{Translation3, UnitQuaternion};
use serde_json::Value;

fn camera() -> PinholeCamera {
    PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480).unwrap()
}

/// Two place features, every number exact in f32 (the file's precision for them).
fn places(k: u8) -> Vec<PlaceFeature> {
    (0..2u8)
        .map(|i| PlaceFeature {
            px: Point2::new(100.5 + f32::from(i), 50.25),
            descriptor: [k ^ (3 * i + 1); 32],
            measurement: Measurement {
                p: Point3::new(0.25 * f64::from(i), -0.5, 1.5),
                cov: Matrix3::new(
                    0.0009765625,
                    0.000244140625,
                    0.0,
                    0.000244140625,
                    0.001953125,
                    0.0,
                    0.0,
                    0.0,
                    0.0078125,
                ),
            },
        })
        .collect()
}

/// Three keyframes 0.1 m apart, each with `n` features; keyframes 0 and 1 share every
/// point, keyframe 2 shares the first half with them. One odometry link. Keyframes 0 and
/// 1 have two place features each.
fn sample() -> SavedMap {
    let n = 6u64;
    let mut map = Map::new();
    for k in 0..3u64 {
        let world_from_camera = Isometry3::from_parts(
            Translation3::new(0.1 * k as f64, 0.02, -0.01),
            UnitQuaternion::from_euler_angles(0.01 * k as f64, -0.2, 0.03),
        );
        let features = (0..n)
            .map(|t| Feature {
                track_id: 100 * k + t,
                px: Point2::new(10.5 + t as f32, 20.25),
                measurement: (t != 5).then(|| Measurement {
                    p: Point3::new(0.1 * t as f64, -0.05, 1.5 + 0.01 * k as f64),
                    cov: Matrix3::new(2e-4, 1e-5, 0.0, 1e-5, 3e-4, 0.0, 0.0, 0.0, 9e-4),
                }),
                descriptor: (t != 4).then_some([(7 * t + k) as u8; 32]),
                point: None,
            })
            .collect();
        let odometry = (k == 2).then(|| OdometryEdge {
            previous: 1,
            previous_from_this: Isometry3::translation(0.1, 0.0, 0.0),
            information: Matrix6::identity() * 1e4,
            active: true,
        });
        map.insert_keyframe(Keyframe {
            id: k,
            frame_index: 10 * k as usize,
            t_s: 0.5 * k as f64,
            world_from_camera,
            features,
            covisibility: BTreeMap::new(),
            odometry,
        });
    }
    for f in 0..5usize {
        let p = map.create_point(0, f).unwrap();
        assert!(map.add_observation(p, 1, f));
        if f < 3 {
            assert!(map.add_observation(p, 2, f));
        }
        map.set_position(p, Point3::new(0.3 * f as f64, 0.1, 1.7));
    }
    SavedMap {
        camera: camera(),
        map,
        world_from_map: Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 1.2),
            UnitQuaternion::from_euler_angles(-1.9, 0.0, 0.1),
        ),
        world: "the floor".into(),
        gravity_aligned: true,
        place_features: [(0, places(0)), (1, places(1))].into_iter().collect(),
    }
}

fn saved(dir: &tempfile::TempDir) -> PathBuf {
    let path = dir.path().join("map.json");
    sample().save(&path).unwrap();
    path
}

/// Rewrites the saved file with `edit` applied to its JSON, returns the load error.
fn load_edited(edit: impl FnOnce(&mut Value)) -> MapFileError {
    let dir = tempfile::tempdir().unwrap();
    let path = saved(&dir);
    let mut v: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
    SavedMap::load(&path, &camera()).unwrap_err()
}

#[test]
fn a_saved_map_reads_back_identical() {
    let dir = tempfile::tempdir().unwrap();
    let path = saved(&dir);
    let original = sample();
    let back = SavedMap::load(&path, &camera()).unwrap();
    assert_eq!(back.world_from_map, original.world_from_map);
    assert_eq!(
        (back.world.as_str(), back.gravity_aligned),
        ("the floor", true)
    );
    // Point identifiers are the map's own business; everything else is exact.
    assert_eq!(back.map.keyframes(), original.map.keyframes());
    let points = |m: &Map| m.points().values().cloned().collect::<Vec<_>>();
    assert_eq!(points(&back.map), points(&original.map));
    assert_eq!(back.place_features, original.place_features);
    assert_eq!(back.next_keyframe_id(), 3);
    // Nothing but the file is left in the folder (the write was atomic).
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn anchors_place_the_map_points_in_their_keyframes() {
    let s = sample();
    let anchors = s.anchors();
    assert_eq!(anchors.len(), 3);
    // Keyframe 0: 5 features observe points, one of them (4) has no descriptor; then its
    // two place features, as measured. Keyframe 2: 3 mapped features, no place features.
    assert_eq!(anchors.first().unwrap().points.len(), 4 + 2);
    assert_eq!(anchors.last().unwrap().points.len(), 3);
    for a in &anchors {
        let kf = s.map.keyframe(a.id).unwrap();
        let place = s.place_features.get(&a.id).map_or(0, Vec::len);
        let (mapped, placed) = a.points.split_at(a.points.len() - place);
        for p in mapped {
            let f = kf.features.iter().find(|f| f.px == p.px).unwrap();
            let world = s.map.point(f.point.unwrap()).unwrap().p_world;
            assert!((a.world_from_camera * p.p_camera.p - world).norm() < 1e-12);
        }
        for (p, f) in placed
            .iter()
            .zip(s.place_features.get(&a.id).into_iter().flatten())
        {
            assert_eq!(
                (p.px, p.descriptor, p.p_camera),
                (f.px, f.descriptor, f.measurement)
            );
        }
    }
}

#[test]
fn a_version_1_map_without_place_features_still_reads() {
    let dir = tempfile::tempdir().unwrap();
    let path = saved(&dir);
    let mut v: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    v["version"] = 1.into();
    for k in v["keyframes"].as_array_mut().unwrap() {
        k.as_object_mut().unwrap().remove("place_features");
    }
    std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
    let back = SavedMap::load(&path, &camera()).unwrap();
    assert!(back.place_features.is_empty());
    assert_eq!(back.map.keyframes(), sample().map.keyframes());
}

#[test]
fn bad_files_get_an_error_that_says_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let path = saved(&dir);
    let text = std::fs::read_to_string(&path).unwrap();
    let message = |e: MapFileError| e.to_string();

    let cut = dir.path().join("cut.json");
    std::fs::write(&cut, &text[..text.len() / 2]).unwrap();
    let e = SavedMap::load(&cut, &camera()).unwrap_err();
    assert!(matches!(e, MapFileError::Parse { .. }), "{e}");
    assert!(message(e).contains("cut.json"));

    let e = SavedMap::load(&dir.path().join("none.json"), &camera()).unwrap_err();
    assert!(matches!(e, MapFileError::Io { .. }), "{e}");

    let other = PinholeCamera::new(517.3, 516.5, 318.6, 255.3, 640, 480).unwrap();
    let e = SavedMap::load(&path, &other).unwrap_err();
    assert!(matches!(e, MapFileError::Camera { .. }), "{e}");

    let e = load_edited(|v| v["version"] = 3.into());
    assert!(matches!(e, MapFileError::Version { version: 3, .. }), "{e}");
    let e = load_edited(|v| v["format"] = "orb-atlas".into());
    assert!(matches!(e, MapFileError::Version { .. }), "{e}");

    let corrupt = |e: MapFileError, what: &str| {
        let m = message(e);
        assert!(m.contains("corrupt map") && m.contains(what), "{m}");
    };
    corrupt(
        load_edited(|v| v["keyframes"][0]["features"][0]["point"] = 999.into()),
        "point 999",
    );
    corrupt(
        load_edited(|v| v["keyframes"][1]["covisibility"][0][1] = 77.into()),
        "keyframe 1: its covisibility",
    );
    corrupt(
        load_edited(|v| v["keyframes"][0]["features"][1]["descriptor"] = "zz".into()),
        "keyframe 0 feature 1: descriptor",
    );
    corrupt(
        load_edited(|v| v["keyframes"][2]["odometry"]["previous"] = 9.into()),
        "unknown keyframe 9",
    );
    corrupt(
        load_edited(|v| v["keyframes"][1]["world_from_camera"]["rotation_xyzw"][3] = 3.0.into()),
        "keyframe 1: pose",
    );
    corrupt(
        load_edited(|v| {
            let points = v["points"].as_array_mut().unwrap();
            let first = points[0].clone();
            points.push(first);
        }),
        "appears twice",
    );
    corrupt(
        load_edited(|v| {
            let px = v["keyframes"][1]["place_features"]["px"]
                .as_array_mut()
                .unwrap();
            px.pop();
        }),
        "keyframe 1: place feature columns disagree",
    );
    corrupt(
        load_edited(|v| v["keyframes"][0]["place_features"]["cov_camera_m2"][9] = (-1.0).into()),
        "keyframe 0 place feature 1: point behind the camera or variance not positive",
    );
    corrupt(
        load_edited(|v| {
            let d = v["keyframes"][0]["place_features"]["descriptors"]
                .as_str()
                .unwrap();
            v["keyframes"][0]["place_features"]["descriptors"] = d.replacen('0', "g", 1).into();
        }),
        "keyframe 0 place feature",
    );
    let e = load_edited(|v| v["keyframes"][0]["surprise"] = 1.into());
    assert!(matches!(e, MapFileError::Parse { .. }), "{e}");
}
