//! Loop closure on the back end's synthetic sweep (there and back in front of a point
//! cloud) with an odometry that drifts too far for the way back to find the old points
//! near their predicted positions.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::backend::Backend;
use crate::backend_tests::{camera, rms, synthetic_run, synthetic_run_textured, Run};
use crate::config::BackendConfig;
use crate::LoopParams;
use nalgebra::Isometry3;

/// RMS (m) over the keyframes of the way back of the error of their position relative to
/// the keyframe at the same place on the way out: how consistent the revisit is.
fn revisit_error(est: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
    let n = est.len();
    let pairs: Vec<f64> = (0..n / 2 - 10)
        .map(|i| {
            let rel = |p: &[Isometry3<f64>]| (p[i].inverse() * p[n - 1 - i]).translation.vector;
            (rel(est) - rel(truth)).norm_squared()
        })
        .collect();
    (pairs.iter().sum::<f64>() / pairs.len() as f64).sqrt()
}

/// Final poses and the loops closed `(keyframe, matched)` of the back end on `run`.
fn run_on(run: &Run, loops: bool) -> (Vec<Isometry3<f64>>, Vec<(u64, u64)>) {
    let params = LoopParams {
        enabled: loops,
        ..LoopParams::default()
    };
    run_with(run, params)
}

/// [`run_on`] with the given loop-closure parameters.
fn run_with(run: &Run, params: LoopParams) -> (Vec<Isometry3<f64>>, Vec<(u64, u64)>) {
    let config = BackendConfig {
        loop_closure: params,
        ..BackendConfig::default()
    };
    let mut backend = Backend::new(camera(), config).unwrap();
    let mut closed = Vec::new();
    for input in run.inputs.clone() {
        let u = backend.add_keyframe(input).unwrap();
        assert!(crate::se3::is_finite(&u.world_from_keyframe));
        if let Some(l) = &u.report.loop_closure {
            closed.push((u.keyframe_id, l.matched));
        }
    }
    backend.finish().unwrap();
    let n = run.inputs.len() as u64;
    let est = (0..n).map(|k| backend.map().pose_of(k).unwrap()).collect();
    (est, closed)
}

/// [`run_on`] a fresh [`synthetic_run`]; the number of loops.
fn run(n: usize, drift: f64, seed: u64, loops: bool) -> (Vec<Isometry3<f64>>, usize) {
    let (est, closed) = run_on(&synthetic_run(n, drift, seed), loops);
    (est, closed.len())
}

#[test]
fn closing_the_loop_removes_the_drift_the_local_map_cannot() {
    // Measured (revisit error with / without, mm), candidates by position alone: drift
    // 0.005 no loop needed (3.8 / 3.8); 0.007: 12.8 / 18.7; 0.009: 14.3 / 51.7 and 9.5 /
    // 46.7 (seeds 5, 6); 0.012: 205.7 / 332.3 and 36.7 / 286.8 (the pose graph cannot undo
    // a drift that large everywhere). With appearance candidates too, 0.009: 11.3 / 51.7
    // and 6.6 / 46.7.
    for seed in [5, 6] {
        check_loop_closure(60, 0.009, seed);
    }
}

fn check_loop_closure(n: usize, drift: f64, seed: u64) {
    let truth = synthetic_run(n, drift, seed);
    let (with, closed) = run(n, drift, seed, true);
    let (without, none) = run(n, drift, seed, false);
    let (r_with, r_without) = (
        revisit_error(&with, &truth.truth),
        revisit_error(&without, &truth.truth),
    );
    let (e_with, e_without) = (rms(&with, &truth.truth), rms(&without, &truth.truth));
    eprintln!(
        "loops {closed}; revisit error with {:.1} mm, without {:.1} mm, odometry {:.1} mm; \
         absolute {:.1} against {:.1} mm",
        r_with * 1e3,
        r_without * 1e3,
        revisit_error(&truth.odometry, &truth.truth) * 1e3,
        e_with * 1e3,
        e_without * 1e3
    );
    assert_eq!(none, 0);
    assert!(closed >= 1, "no loop closed");
    assert!(
        r_with < 0.5 * r_without,
        "revisit error with loop closure {:.1} mm, without {:.1} mm",
        r_with * 1e3,
        r_without * 1e3
    );
    // The way out keeps its own drift (nothing observes it again): the absolute error
    // moves less (47.3 / 60.1 and 34.4 / 29.4 mm), and stays bounded.
    assert!(e_with < 1.5 * e_without, "{e_with} against {e_without}");
}

#[test]
fn a_repetitive_scene_closes_no_false_loop() {
    // 500 points sharing 20 looks: descriptors cannot tell places apart.
    let run = synthetic_run_textured(60, 0.009, 7, 20);
    let (with, closed) = run_on(&run, true);
    let (without, _) = run_on(&run, false);
    for (k, m) in &closed {
        let (a, b) = (&run.truth[*k as usize], &run.truth[*m as usize]);
        let apart = (a.translation.vector - b.translation.vector).norm();
        assert!(apart < 0.3, "false loop {k} -> {m}: {apart} m apart");
    }
    let (e_with, e_without) = (rms(&with, &run.truth), rms(&without, &run.truth));
    eprintln!(
        "repetitive scene: {} loops closed (each a true revisit)",
        closed.len()
    );
    assert!(e_with <= 1.2 * e_without, "{e_with} against {e_without}");
}

#[test]
fn appearance_finds_loops_whose_drift_exceeds_the_search_radius() {
    // A search radius of 1 mm stands for a drift far beyond any radius: only the bags of
    // words can propose the old keyframes.
    let run = synthetic_run(60, 0.009, 5);
    let params = |appearance_candidates| LoopParams {
        search_radius_m: 0.001,
        appearance_candidates,
        ..LoopParams::default()
    };
    let (blind, none) = run_with(&run, params(0));
    let (seeing, closed) = run_with(&run, params(3));
    let (r_blind, r_seeing) = (
        revisit_error(&blind, &run.truth),
        revisit_error(&seeing, &run.truth),
    );
    eprintln!(
        "appearance: {} loops, revisit error {:.1} mm against {:.1} mm by position alone",
        closed.len(),
        r_seeing * 1e3,
        r_blind * 1e3
    );
    assert!(none.is_empty(), "{none:?}");
    assert!(!closed.is_empty(), "no loop found by appearance");
    // Appearance also proposes keyframes farther along the sweep than the nearest; with
    // points 1.8-4 m away, keyframes up to about half a metre apart share most of them
    // (measured: the farthest loop was 0.38 m apart).
    for (k, m) in &closed {
        let (a, b) = (&run.truth[*k as usize], &run.truth[*m as usize]);
        let apart = (a.translation.vector - b.translation.vector).norm();
        assert!(apart < 0.6, "false loop {k} -> {m}: {apart} m apart");
    }
    assert!(r_seeing < 0.5 * r_blind, "{r_seeing} against {r_blind}");
}

#[test]
fn a_piece_placed_by_a_guess_joins_the_map_at_once() {
    // The odometry loses keyframe 20 of the way out: its pose is a guess 25 cm off (a link
    // without information), every track starts afresh, and the keyframes after it carry the
    // error. The keyframes it should join are recent, far fewer than `min_age_keyframes`
    // (here 40) before it, which a loop between places mapped long apart needs.
    let (n, lost) = (60, 20);
    let params = |enabled| LoopParams {
        enabled,
        min_age_keyframes: 40,
        ..LoopParams::default()
    };
    let mut run = synthetic_run(n, 0.0005, 5);
    let offset = Isometry3::translation(0.25, 0.0, -0.1);
    for input in run.inputs.iter_mut().skip(lost) {
        input.world_from_camera = offset * input.world_from_camera;
        for f in &mut input.info.features {
            f.track_id += 1_000_000;
        }
    }
    if let Some(link) = run.inputs[lost].info.odometry.as_mut() {
        link.previous_from_this = run.odometry[lost - 1].inverse() * offset * run.odometry[lost];
        link.information = nalgebra::Matrix6::zeros();
        link.inliers = 0;
    }
    let (joined, closed) = run_with(&run, params(true));
    let (apart, none) = run_with(&run, params(false));
    let piece_error = |est: &[Isometry3<f64>]| rms(&est[lost..], &run.truth[lost..]);
    eprintln!(
        "lost piece: loops {closed:?}; its error {:.1} mm joined, {:.1} mm apart",
        piece_error(&joined) * 1e3,
        piece_error(&apart) * 1e3
    );
    assert!(none.is_empty());
    let (k, m) = *closed.first().expect("the piece never joined");
    assert!(
        k < lost as u64 + 3 && m < lost as u64,
        "joined at keyframe {k} with {m}"
    );
    assert!(piece_error(&apart) > 0.2, "{}", piece_error(&apart));
    assert!(piece_error(&joined) < 0.02, "{}", piece_error(&joined));
}
