//! The back end end to end on synthetic keyframes: a camera sweeping back and forth in
//! front of a cloud of points, an odometry that drifts, features with the sensor model's
//! noise, tracks that break when points leave the view (so that re-observing them takes ORB
//! matching). Also the bad inputs: keyframes without depth, features that match nothing,
//! a non-finite pose, and a back-end thread that fails.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::ba::SolveReport;
use crate::backend::{Backend, KeyframeInput};
use crate::config::{BackendConfig, BackendMode};
use crate::thread::BackendThread;
use nalgebra::{Isometry3, Matrix6, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;
use stride_core::camera::PinholeCamera;
use stride_core::rng::SplitMix64;
use stride_core::uncertainty::PrimeSenseModel;
use stride_frontend::points::Measurement;
use stride_frontend::{KeyframeFeature, KeyframeInfo, OdometryLink};

pub(crate) fn camera() -> PinholeCamera {
    PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480).unwrap()
}

/// The synthetic run: true poses, the odometry's drifting poses, and the keyframe inputs.
pub(crate) struct Run {
    pub(crate) truth: Vec<Isometry3<f64>>,
    pub(crate) odometry: Vec<Isometry3<f64>>,
    pub(crate) inputs: Vec<KeyframeInput>,
    /// Observations of points seen before under another track: what only ORB matching
    /// can associate.
    pub(crate) reobservations: usize,
}

pub(crate) fn descriptor(point: usize, rng: &mut SplitMix64) -> [u8; 32] {
    let mut d = [0u8; 32];
    let mut s = SplitMix64::new(point as u64 * 7919 + 1);
    for b in &mut d {
        *b = (s.next_u64() & 0xFF) as u8;
    }
    // A few bits differ from view to view.
    for _ in 0..6 {
        let bit = rng.below(256);
        d[bit / 8] ^= 1 << (bit % 8);
    }
    d
}

/// `n` keyframes sweeping right then back left in front of the points (so that the way
/// back re-observes points whose tracks broke), odometry drifting by `drift` per step.
pub(crate) fn synthetic_run(n: usize, drift: f64, seed: u64) -> Run {
    synthetic_run_textured(n, drift, seed, usize::MAX)
}

/// [`synthetic_run`] where points share `textures` descriptors (point `j` looks like
/// point `j % textures`): a repetitive scene.
pub(crate) fn synthetic_run_textured(n: usize, drift: f64, seed: u64, textures: usize) -> Run {
    let cam = camera();
    let model = PrimeSenseModel::default();
    let mut rng = SplitMix64::new(seed);
    let points: Vec<Point3<f64>> = (0..500)
        .map(|_| {
            Point3::new(
                rng.range(-2.5, 3.5),
                rng.range(-1.2, 1.2),
                rng.range(1.8, 4.0),
            )
        })
        .collect();
    let truth: Vec<Isometry3<f64>> = (0..n)
        .map(|i| {
            let s = i as f64 / (n - 1) as f64;
            let x = if s < 0.5 { 2.0 * s } else { 2.0 * (1.0 - s) };
            Isometry3::from_parts(
                Translation3::new(1.2 * x, 0.05 * (7.0 * s).sin(), 0.1 * x),
                UnitQuaternion::from_euler_angles(0.02 * (5.0 * s).sin(), 0.15 * x, 0.01),
            )
        })
        .collect();
    // Odometry: true relative motions with a bias (drift) and noise.
    let mut odometry = vec![truth[0]];
    for i in 1..n {
        let rel = truth[i - 1].inverse() * truth[i];
        let err = Isometry3::from_parts(
            Translation3::new(
                drift + 0.001 * rng.normal(),
                0.001 * rng.normal(),
                0.5 * drift,
            ),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 2.0 * drift, 0.0)),
        );
        odometry.push(odometry[i - 1] * rel * err);
    }
    let mut track_of: HashMap<usize, u64> = HashMap::new();
    let mut ever_seen = std::collections::HashSet::new();
    let mut reobservations = 0;
    let mut next_track = 0u64;
    let mut inputs = Vec::new();
    for (i, t) in truth.iter().enumerate() {
        let mut features = Vec::new();
        let mut visible_now = Vec::new();
        for (j, p) in points.iter().enumerate() {
            let q = t.inverse() * p;
            let Some(px) = cam.project(&q).filter(|px| q.z > 0.5 && cam.contains(px)) else {
                continue;
            };
            let cov = model.covariance(&cam, px.x, px.y, q.z);
            let noise = cov.cholesky().unwrap().l()
                * Vector3::new(rng.normal(), rng.normal(), rng.normal());
            if !track_of.contains_key(&j) && !ever_seen.insert(j) {
                reobservations += 1;
            }
            let track = *track_of.entry(j).or_insert_with(|| {
                next_track += 1;
                next_track
            });
            visible_now.push(j);
            features.push(KeyframeFeature {
                track_id: track,
                px: Point2::new(px.x as f32, px.y as f32),
                measurement: Some(Measurement { p: q + noise, cov }),
                descriptor: Some(descriptor(j % textures, &mut rng)),
            });
        }
        // Tracks of points out of view end; a point seen again gets a new track.
        track_of.retain(|j, _| visible_now.contains(j));
        let odometry_link = (i > 0).then(|| OdometryLink {
            previous_id: i as u64 - 1,
            previous_from_this: odometry[i - 1].inverse() * odometry[i],
            information: Matrix6::identity() * 1e4,
            inliers: 100,
        });
        inputs.push(KeyframeInput {
            frame_index: i * 3,
            t_s: i as f64 * 0.1,
            world_from_camera: odometry[i],
            info: KeyframeInfo {
                id: i as u64,
                features,
                place_features: Vec::new(),
                odometry: odometry_link,
                depth_links: Vec::new(),
            },
            depth_m: None,
        });
    }
    Run {
        truth,
        odometry,
        inputs,
        reobservations,
    }
}

/// RMS position error (m) of `est` against `truth` (same gauge: the first pose is shared).
pub(crate) fn rms(est: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    let s: f64 = est
        .iter()
        .zip(truth)
        .map(|(a, b)| (a.translation.vector - b.translation.vector).norm_squared())
        .sum();
    (s / est.len().max(1) as f64).sqrt()
}

#[test]
fn bundle_adjustment_removes_most_of_the_odometry_drift() {
    let run = synthetic_run(40, 0.004, 1);
    let mut backend = Backend::new(camera(), BackendConfig::default()).unwrap();
    let mut by_orb = 0;
    for input in run.inputs.clone() {
        let u = backend.add_keyframe(input).unwrap();
        assert!(crate::se3::is_finite(&u.world_from_keyframe));
        by_orb += u.report.by_orb;
    }
    backend.finish().unwrap();
    let est: Vec<Isometry3<f64>> = (0..40).map(|k| backend.map().pose_of(k).unwrap()).collect();
    let (e_ba, e_odo) = (rms(&est, &run.truth), rms(&run.odometry, &run.truth));
    assert!(
        e_ba < 0.25 * e_odo,
        "bundle adjustment {:.1} mm against odometry {:.1} mm",
        e_ba * 1e3,
        e_odo * 1e3
    );
    assert!(e_ba < 0.01, "{e_ba}");
    // The way back re-observes points whose tracks broke: only ORB matching finds them.
    assert!(
        by_orb * 2 > run.reobservations,
        "ORB matches {by_orb} of {} re-observations",
        run.reobservations
    );
    let grace = backend.config().point_grace_keyframes;
    for p in backend.map().points().values() {
        assert!(
            p.observations.len() >= 2 || 39 - p.created_by < grace,
            "single-observation points are culled after {grace} keyframes"
        );
    }
}

#[test]
fn the_pose_graph_mode_also_corrects_drift() {
    let run = synthetic_run(40, 0.004, 2);
    let cfg = BackendConfig {
        mode: BackendMode::PoseGraph,
        ..BackendConfig::default()
    };
    let mut backend = Backend::new(camera(), cfg).unwrap();
    for input in run.inputs.clone() {
        backend.add_keyframe(input).unwrap();
    }
    backend.finish().unwrap();
    let est: Vec<Isometry3<f64>> = (0..40).map(|k| backend.map().pose_of(k).unwrap()).collect();
    let (e_pg, e_odo) = (rms(&est, &run.truth), rms(&run.odometry, &run.truth));
    assert!(
        e_pg < 0.6 * e_odo,
        "pose graph {:.1} mm, odometry {:.1} mm",
        e_pg * 1e3,
        e_odo * 1e3
    );
}

#[test]
fn keyframes_without_depth_or_matches_keep_a_finite_pose_from_the_odometry() {
    let mut run = synthetic_run(20, 0.002, 3);
    // Keyframe 8 has no depth at all; keyframe 12's features match nothing (new tracks,
    // foreign descriptors, measurements far from any map point).
    for f in &mut run.inputs[8].info.features {
        f.measurement = None;
    }
    let mut rng = SplitMix64::new(99);
    for f in &mut run.inputs[12].info.features {
        f.track_id += 1_000_000;
        f.descriptor = Some(descriptor(100_000 + rng.below(1000), &mut rng));
        if let Some(m) = f.measurement.as_mut() {
            m.p += Vector3::new(0.5, -0.4, 0.7);
        }
    }
    let mut backend = Backend::new(camera(), BackendConfig::default()).unwrap();
    for input in run.inputs.clone() {
        let id = input.info.id;
        let u = backend.add_keyframe(input).unwrap();
        assert!(
            crate::se3::is_finite(&u.world_from_keyframe),
            "keyframe {id}"
        );
        if id == 8 {
            assert_eq!(u.report.by_track + u.report.by_orb + u.report.new_points, 0);
            assert!(u.report.odometry_edge, "tied by its odometry");
        }
        if id == 12 {
            assert_eq!(u.report.by_track + u.report.by_orb, 0, "{:?}", u.report);
            assert!(u.report.odometry_edge);
        }
    }
    backend.finish().unwrap();
    // The keyframe without depth sits where the odometry puts it relative to its
    // neighbours (within the drift), not somewhere arbitrary.
    let p8 = backend.map().pose_of(8).unwrap();
    assert!((p8.translation.vector - run.truth[8].translation.vector).norm() < 0.05);
}

#[test]
fn a_bad_keyframe_is_an_error_through_the_thread_too() {
    let run = synthetic_run(6, 0.002, 4);
    let mut bad = run.inputs[3].clone();
    bad.world_from_camera.translation.vector.x = f64::NAN;
    let mut backend = Backend::new(camera(), BackendConfig::default()).unwrap();
    for input in run.inputs.iter().take(3).cloned() {
        backend.add_keyframe(input).unwrap();
    }
    let err = backend.add_keyframe(bad.clone()).unwrap_err();
    assert!(err.to_string().contains("keyframe 3"), "{err}");
    // In the thread: the error comes back with the next answer, and later calls say so
    // too instead of hanging or pretending.
    let mut thread =
        BackendThread::spawn(Backend::new(camera(), BackendConfig::default()).unwrap()).unwrap();
    for input in run.inputs.iter().take(3).cloned() {
        thread.send(input).unwrap();
    }
    thread.send(bad).unwrap();
    for _ in 0..3 {
        thread.recv().unwrap();
    }
    let err = thread.recv().unwrap_err();
    assert!(err.to_string().contains("not finite"), "{err}");
    assert!(thread.send(run.inputs[4].clone()).is_err());
}

#[test]
fn identical_runs_give_identical_maps() {
    let run = synthetic_run(25, 0.003, 5);
    let poses = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut b = Backend::new(camera(), BackendConfig::default()).unwrap();
                for input in run.inputs.clone() {
                    b.add_keyframe(input).unwrap();
                }
                b.finish().unwrap();
                (0..25)
                    .map(|k| b.map().pose_of(k).unwrap())
                    .collect::<Vec<_>>()
            })
    };
    assert_eq!(poses(1), poses(2));
}

#[test]
fn the_thread_gives_the_map_and_final_optimization_of_the_back_end_run_directly() {
    // The thread runs bundle adjustment, the final optimization included, on a pool of its
    // own: the same numbers as on the caller's.
    let run = synthetic_run(25, 0.003, 5);
    let mut direct = Backend::new(camera(), BackendConfig::default()).unwrap();
    for input in run.inputs.clone() {
        direct.add_keyframe(input).unwrap();
    }
    let direct_solve = direct.finish().unwrap();
    let mut thread =
        BackendThread::spawn(Backend::new(camera(), BackendConfig::default()).unwrap()).unwrap();
    for input in run.inputs.clone() {
        thread.send(input).unwrap();
    }
    let done = thread.finish().unwrap();
    // Everything but the time it took.
    let untimed = |r: Option<SolveReport>| r.map(|r| SolveReport { time_s: 0.0, ..r });
    assert!(direct_solve.is_some(), "a final optimization ran");
    assert_eq!(untimed(done.final_solve), untimed(direct_solve));
    for k in 0..25 {
        assert_eq!(
            done.backend.map().pose_of(k),
            direct.map().pose_of(k),
            "keyframe {k}"
        );
    }
}

#[test]
fn invalid_configurations_are_refused() {
    let bad = BackendConfig {
        window_keyframes: 1,
        ..BackendConfig::default()
    };
    assert!(Backend::new(camera(), bad).is_err());
    let bad = BackendConfig {
        depth_noise_scale: 0.5,
        ..BackendConfig::default()
    };
    let err = Backend::new(camera(), bad).err().unwrap().to_string();
    assert!(err.contains("depth_noise_scale"), "{err}");
    let bad = BackendConfig {
        final_max_keyframes: 1,
        ..BackendConfig::default()
    };
    let err = Backend::new(camera(), bad).err().unwrap().to_string();
    assert!(err.contains("final_max_keyframes"), "{err}");
    let mut bad = BackendConfig::default();
    bad.revisit.min_paired_fraction = 0.0;
    let err = Backend::new(camera(), bad).err().unwrap().to_string();
    assert!(
        err.contains("revisit") && err.contains("min_paired_fraction"),
        "{err}"
    );
}

/// A back end with `config` fed a 20-keyframe synthetic run (drift 4 mm per keyframe),
/// before its final optimization; the map's keyframes and their poses.
fn fed_twenty_keyframes(config: BackendConfig) -> (Backend, Vec<u64>, Vec<Isometry3<f64>>) {
    let run = synthetic_run(20, 0.004, 2);
    let mut backend = Backend::new(camera(), config).unwrap();
    for input in run.inputs {
        backend.add_keyframe(input).unwrap();
    }
    let ids: Vec<u64> = backend.map().keyframes().keys().copied().collect();
    let poses = ids
        .iter()
        .map(|&k| backend.map().pose_of(k).unwrap())
        .collect();
    (backend, ids, poses)
}

#[test]
fn the_final_optimization_frees_only_the_newest_keyframes_when_capped() {
    let (mut backend, live, before) = fed_twenty_keyframes(BackendConfig {
        final_max_keyframes: 5,
        ..BackendConfig::default()
    });
    backend.finish().unwrap();
    let moved = |i: usize| {
        let after = backend.map().pose_of(live[i]).unwrap();
        (after.inverse() * before[i]).translation.vector.norm()
    };
    let n = live.len();
    assert!(n > 5, "{n} keyframes in the map");
    for (i, k) in live.iter().enumerate().take(n - 5) {
        assert_eq!(moved(i), 0.0, "keyframe {k} is held fixed");
    }
    assert!((n - 5..n).any(|i| moved(i) > 0.0), "the newest five move");
}

#[test]
fn the_final_optimization_frees_the_newest_window_unless_links_tie_keyframes() {
    // No keyframe culled, so that the window is a part of the map.
    let (mut backend, all, before) = fed_twenty_keyframes(BackendConfig {
        redundant_observers: 1000,
        ..BackendConfig::default()
    });
    let last = *all.last().unwrap();
    let active = |b: &Backend| {
        b.map()
            .keyframes()
            .values()
            .any(|kf| kf.odometry.as_ref().is_some_and(|e| e.active))
    };
    assert!(
        backend.pose_edges.is_empty() && !active(&backend),
        "no link yet"
    );
    let free = crate::window::final_free(&backend.map, &backend.pose_edges, &backend.config);
    let window = crate::window::local_window(&backend.map, last, &backend.config);
    assert_eq!(free, window);
    assert!(
        free.len() < all.len(),
        "{} of {} free",
        free.len(),
        all.len()
    );
    backend.finish().unwrap();
    for (k, b) in all.iter().zip(&before) {
        let after = backend.map().pose_of(*k).unwrap();
        if !free.contains(k) {
            assert_eq!(after, *b, "keyframe {k} outside the window is held");
        }
    }
    // A link from the fourth keyframe frees every keyframe from it on.
    backend.pose_edges.push(crate::window::KeyframeEdge {
        from: all[3],
        to: last,
        from_from_to: Isometry3::identity(),
        information: nalgebra::Matrix6::identity(),
        kind: crate::window::EdgeKind::Odometry,
    });
    let free = crate::window::final_free(&backend.map, &backend.pose_edges, &backend.config);
    assert_eq!(free, all[3..].to_vec());
    // The same link as a revisit link reaches back only over the newest
    // `final_revisit_link_keyframes`.
    backend
        .pose_edges
        .iter_mut()
        .for_each(|e| e.kind = crate::window::EdgeKind::Revisit);
    backend.config.final_revisit_link_keyframes = 5;
    let free = crate::window::final_free(&backend.map, &backend.pose_edges, &backend.config);
    assert_eq!(free, all[all.len() - 5..].to_vec());
    backend.config.final_revisit_link_keyframes = 1;
    assert!(backend.config.validate().is_err());
}

#[test]
fn the_keyframe_budget_bounds_the_map_and_keeps_culled_poses() {
    // Keyframes over the same scene, the window's redundancy rule off: with a budget of 8
    // (the final span 5), the map never holds more than 8, and a keyframe culled for the
    // budget keeps the pose it had.
    let run = synthetic_run(30, 0.004, 3);
    let config = BackendConfig {
        final_max_keyframes: 5,
        max_keyframes: 8,
        redundant_observers: 1000,
        ..BackendConfig::default()
    };
    let mut backend = Backend::new(camera(), config).unwrap();
    let mut poses_at_cull: Vec<(u64, Isometry3<f64>)> = Vec::new();
    for input in run.inputs.clone() {
        backend.add_keyframe(input).unwrap();
        assert!(backend.map().keyframes().len() <= 8);
        for &k in backend.map().culled().keys() {
            if !poses_at_cull.iter().any(|(c, _)| *c == k) {
                poses_at_cull.push((k, backend.map().pose_of(k).unwrap()));
            }
        }
    }
    backend.finish().unwrap();
    assert!(poses_at_cull.len() >= 5, "{} culled", poses_at_cull.len());
    let kept = poses_at_cull
        .iter()
        .filter(|(k, pose)| {
            let now = backend.map().pose_of(*k).unwrap();
            (now.inverse() * pose).translation.vector.norm() < 1e-12
        })
        .count();
    assert_eq!(
        kept,
        poses_at_cull.len(),
        "culled keyframes that moved afterwards"
    );
    let bad = BackendConfig {
        max_keyframes: 300,
        ..BackendConfig::default()
    };
    let err = Backend::new(camera(), bad).err().unwrap().to_string();
    assert!(err.contains("max_keyframes"), "{err}");
}

#[test]
fn optimizing_every_second_keyframe_still_removes_the_drift() {
    let run = synthetic_run(40, 0.004, 1);
    let config = BackendConfig {
        optimize_every_keyframes: 2,
        ..BackendConfig::default()
    };
    let mut backend = Backend::new(camera(), config).unwrap();
    for input in run.inputs.clone() {
        let id = input.info.id;
        let u = backend.add_keyframe(input).unwrap();
        // Local optimizations run on even keyframes only (the first has nothing to solve).
        if id > 0 {
            assert_eq!(u.report.solve.is_some(), id % 2 == 0, "keyframe {id}");
        }
    }
    backend.finish().unwrap();
    let est: Vec<Isometry3<f64>> = (0..40).map(|k| backend.map().pose_of(k).unwrap()).collect();
    let (e_ba, e_odo) = (rms(&est, &run.truth), rms(&run.odometry, &run.truth));
    assert!(
        e_ba < 0.25 * e_odo && e_ba < 0.01,
        "every second keyframe {:.1} mm against odometry {:.1} mm",
        e_ba * 1e3,
        e_odo * 1e3
    );
}

#[test]
fn a_depth_link_still_holds_after_the_outliers_are_removed() {
    // Keyframe 8 has no depth measurement of its own, and its odometry is 5 cm off: only
    // its depth link (the true relative pose, 1 mm) says where it is. Keyframe 9 carries three
    // outliers, so the window optimized when it arrives is solved a second time
    // without it; that second solve must keep the link too.
    let mut run = synthetic_run(12, 0.0, 4);
    for f in &mut run.inputs[8].info.features {
        f.measurement = None;
    }
    let truth_7_from_8 = run.truth[7].inverse() * run.truth[8];
    let off = Isometry3::translation(0.05, 0.0, 0.0);
    if let Some(o) = run.inputs[8].info.odometry.as_mut() {
        o.previous_from_this = truth_7_from_8 * off;
        o.inliers = 10;
    }
    run.inputs[8].info.depth_links = vec![stride_frontend::DepthLink {
        keyframe_id: 7,
        keyframe_from_this: truth_7_from_8,
        information: Matrix6::identity() * 1e6,
    }];
    for f in run.inputs[10].info.features.iter_mut().take(3) {
        if let Some(m) = f.measurement.as_mut() {
            m.p += Vector3::new(0.3, -0.2, 0.4);
        }
    }
    // A gate wide open lets the outliers be associated, for the solve to find them.
    let mut cfg = BackendConfig::default();
    cfg.matching.chi2_gate = 1e9;
    let mut backend = Backend::new(camera(), cfg).unwrap();
    let mut outliers = 0;
    for input in run.inputs.iter().take(11).cloned() {
        let u = backend.add_keyframe(input).unwrap();
        if u.report.keyframe_id == 8 {
            assert_eq!(u.report.depth_edges, 1, "the link joined the map");
        }

        if u.report.keyframe_id == 10 {
            outliers = u.report.outliers;
        }
    }
    assert!(
        outliers > 0,
        "the outlier was found, so the window was solved again"
    );
    let map = backend.map();
    let est_7_from_8 = map.pose_of(7).unwrap().inverse() * map.pose_of(8).unwrap();
    let error_m = (est_7_from_8.translation.vector - truth_7_from_8.translation.vector).norm();
    assert!(error_m < 0.005, "keyframe 8 is {:.1} mm off", error_m * 1e3);
}
