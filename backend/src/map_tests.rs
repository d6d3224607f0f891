//! Tests of the map's bookkeeping: observations, covisibility, merging, culling.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;
use nalgebra::{Translation3, UnitQuaternion};

fn feature(track_id: u64, z: f64) -> Feature {
    Feature {
        track_id,
        px: Point2::new(10.0, 10.0),
        measurement: Some(Measurement {
            p: Point3::new(0.1 * track_id as f64, 0.0, z),
            cov: Matrix3::identity() * 1e-4,
        }),
        descriptor: Some([track_id as u8; 32]),
        point: None,
    }
}

fn keyframe(id: u64, x: f64, n: usize) -> Keyframe {
    Keyframe {
        id,
        frame_index: id as usize,
        t_s: id as f64,
        world_from_camera: Isometry3::from_parts(
            Translation3::new(x, 0.0, 0.0),
            UnitQuaternion::identity(),
        ),
        features: (0..n as u64).map(|t| feature(t, 2.0)).collect(),
        covisibility: BTreeMap::new(),
        odometry: None,
    }
}

/// Every invariant of the module documentation.
fn check(map: &Map) {
    for (&pid, p) in map.points() {
        assert!(
            !p.observations.is_empty(),
            "point {pid} without observations"
        );
        for o in &p.observations {
            let f = &map.keyframe(o.keyframe).unwrap().features[o.feature];
            assert_eq!(f.point, Some(pid));
        }
    }
    for (&kid, kf) in map.keyframes() {
        for (fi, f) in kf.features.iter().enumerate() {
            if let Some(pid) = f.point {
                let p = map.point(pid).unwrap();
                assert!(p.observations.contains(&Observation {
                    keyframe: kid,
                    feature: fi
                }));
            }
        }
        for (&other, &n) in &kf.covisibility {
            let shared = kf
                .points()
                .filter(|p| {
                    map.point(*p)
                        .unwrap()
                        .observations
                        .iter()
                        .any(|o| o.keyframe == other)
                })
                .count() as u32;
            assert_eq!(n, shared, "covisibility {kid}-{other}");
        }
    }
}

#[test]
fn observations_and_covisibility_stay_consistent() {
    let mut map = Map::new();
    for k in 0..3 {
        assert!(map.insert_keyframe(keyframe(k, 0.1 * k as f64, 5)));
    }
    assert!(
        !map.insert_keyframe(keyframe(1, 0.0, 5)),
        "duplicate id refused"
    );
    let pts: Vec<PointId> = (0..5).map(|f| map.create_point(0, f).unwrap()).collect();
    for (f, &p) in pts.iter().enumerate().take(4) {
        assert!(map.add_observation(p, 1, f));
    }
    assert!(map.add_observation(pts[0], 2, 0));
    assert!(
        !map.add_observation(pts[1], 2, 0),
        "feature already observes a point"
    );
    assert!(
        !map.add_observation(pts[0], 2, 1),
        "keyframe already observes the point"
    );
    check(&map);
    assert_eq!(map.keyframe(0).unwrap().covisibility[&1], 4);
    assert_eq!(map.keyframe(1).unwrap().covisible(2), vec![(0, 4)]);
    map.remove_observation(pts[0], 1);
    check(&map);
    assert_eq!(map.keyframe(0).unwrap().covisibility[&1], 3);
    // A point's last observation removed: the point goes.
    map.remove_observation(pts[4], 0);
    assert!(map.point(pts[4]).is_none());
    check(&map);
}

#[test]
fn merging_moves_observations_and_culling_keeps_poses() {
    let mut map = Map::new();
    for k in 0..3 {
        map.insert_keyframe(keyframe(k, 0.5 * k as f64, 4));
    }
    let a = map.create_point(0, 0).unwrap();
    let b = map.create_point(1, 0).unwrap();
    map.add_observation(b, 2, 0);
    map.merge_points(a, b);
    assert!(map.point(b).is_none());
    assert_eq!(map.point(a).unwrap().observations.len(), 3);
    check(&map);
    let before = map.pose_of(1).unwrap();
    assert!(map.cull_keyframe(1, 0));
    check(&map);
    assert!(map.keyframe(1).is_none());
    let after = map.pose_of(1).unwrap();
    assert!((before.translation.vector - after.translation.vector).norm() < 1e-12);
    // Moving the parent moves the culled keyframe with it.
    map.set_pose(
        0,
        Isometry3::from_parts(Translation3::new(0.0, 1.0, 0.0), UnitQuaternion::identity()),
    );
    assert!((map.pose_of(1).unwrap().translation.y - 1.0).abs() < 1e-12);
    assert_eq!(map.point(a).unwrap().observations.len(), 2);
}

#[test]
fn dropping_unmapped_features_renumbers_observations() {
    let mut map = Map::new();
    for k in 0..2 {
        map.insert_keyframe(keyframe(k, 0.1 * k as f64, 6));
    }
    // Keyframe 0 observes points through features 1, 3 and 5 only.
    let pts: Vec<PointId> = [1, 3, 5]
        .iter()
        .map(|&f| map.create_point(0, f).unwrap())
        .collect();
    for (i, &p) in pts.iter().enumerate() {
        assert!(map.add_observation(p, 1, i));
    }
    check(&map);
    assert_eq!(map.drop_unmapped_features(0), 3);
    check(&map);
    let kf = map.keyframe(0).unwrap();
    assert_eq!(kf.features.len(), 3);
    assert_eq!(
        kf.features.iter().map(|f| f.track_id).collect::<Vec<_>>(),
        vec![1, 3, 5],
        "the kept features keep their order"
    );
    assert_eq!(kf.covisibility[&1], 3);
    assert_eq!(map.drop_unmapped_features(0), 0);
    assert_eq!(map.drop_unmapped_features(7), 0, "unknown keyframe");
}

#[test]
fn removed_keyframes_take_their_own_points_and_links_with_them() {
    let mut map = Map::new();
    for k in 0..4 {
        let mut kf = keyframe(k, 0.2 * k as f64, 4);
        kf.odometry = (k > 0).then(|| OdometryEdge {
            previous: k - 1,
            previous_from_this: Isometry3::identity(),
            information: Matrix6::identity(),
            active: false,
        });
        map.insert_keyframe(kf);
    }
    // Point `shared` is seen by keyframes 1 and 2; `own` by keyframe 2 alone.
    let shared = map.create_point(1, 0).unwrap();
    map.add_observation(shared, 2, 0);
    let own = map.create_point(2, 1).unwrap();
    let kept = map.create_point(0, 0).unwrap();
    let removed = map.remove_keyframes(&[2].into_iter().collect());
    check(&map);
    assert_eq!(removed, 1, "only the point nothing else sees");
    assert!(map.keyframe(2).is_none() && map.point(own).is_none());
    assert_eq!(map.point(shared).unwrap().observations.len(), 1);
    assert!(map.point(kept).is_some());
    assert!(map.keyframe(1).unwrap().covisibility.is_empty());
    assert!(map.keyframe(3).unwrap().odometry.is_none(), "its link went");
    assert!(map.keyframe(1).unwrap().odometry.is_some());
}
