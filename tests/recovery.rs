//! The odometry's wide-baseline recovery on real frames: teddy_200 with only every 20th
//! frame (0.67 s apart), where Lucas-Kanade loses the camera; and relocalization by
//! appearance when the camera is carried back to where the run began, or to a place it
//! passed.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, derived, num, reordered};
use std::path::{Path, PathBuf};
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_frontend::{TrackingStatus, VisualOdometry, VoConfig};

/// `stride run` reports on `seq` (fr3, no map) with the defaults and with the configuration
/// `off` (TOML), written under `dir`.
fn with_and_without(seq: &Path, dir: &Path, off: &str) -> (serde_json::Value, serde_json::Value) {
    let config = dir.join("off.toml");
    std::fs::write(&config, off).unwrap();
    let config = config.display().to_string();
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec!["--camera", "fr3", "--no-map"];
        args.extend_from_slice(extra);
        common::run_report("run", seq, &dir.join(out), &args)
    };
    (run("with", &[]), run("without", &["--config", &config]))
}

#[test]
fn recovery_finds_frames_that_tracking_loses() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("teddy_every_20th");
    derived(&teddy, &seq, |i| i % 20 == 0);
    let (with, without) = with_and_without(
        &seq,
        tmp.path(),
        "map = false\n[odometry]\nrecovery_keyframes = false\n",
    );
    assert_eq!(with["frames"], 10, "{with}");
    // Measured: without recovery 2 frames lost and 68 mm; with it none lost, one frame
    // recovered, 9.9 mm.
    assert!(without["frames_lost"].as_u64().unwrap() >= 1, "{without}");
    assert_eq!(with["frames_lost"], 0, "{with}");
    // Each lost frame starts a piece placed by a guess; no loop joins them here.
    assert_eq!(with["segments"], 1, "{with}");
    assert_eq!(
        without["segments"].as_u64().unwrap(),
        1 + without["frames_lost"].as_u64().unwrap(),
        "{without}"
    );
    assert!(with["frames_recovered"].as_u64().unwrap() >= 1, "{with}");
    let (ate_with, ate_without) = (num(&with["ate"], "rmse"), num(&without["ate"], "rmse"));
    assert!(ate_with < 0.02, "ATE with recovery {ate_with} m");
    assert!(
        ate_with < 0.5 * ate_without,
        "ATE with recovery {ate_with} m, without {ate_without} m"
    );
    assert!(num(&with["timing_ms"]["recover"], "p95") > 0.0, "{with}");
    let by_status = &with["frames_by_status"];
    assert_eq!(by_status["recovered"], with["frames_recovered"], "{with}");
    assert_eq!(by_status["lost"], 0, "{with}");
}

#[test]
fn a_camera_carried_back_to_the_start_is_relocalized_in_its_own_map() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    // The even frames forwards, then, in one jump of about 1.5 m and 100 degrees, the odd
    // frames from the start again: no image is seen twice.
    let order: Vec<usize> = (0..200).step_by(2).chain((1..200).step_by(2)).collect();
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("kidnapped");
    reordered(&teddy, &seq, &order);
    // Without relocalization, and without the back end's loop closure (which now joins the
    // piece after the lost frame to the map: 10.5 mm).
    let (with, without) = with_and_without(
        &seq,
        tmp.path(),
        "[odometry]\nrelocalization_keyframes = false\n[backend.loop_closure]\nenabled = false\n",
    );
    // Measured: relocalized at the jump (168 inliers), ATE 6.8 mm (seeds 1-3: 6.8-8.3 mm;
    // 7.0-9.4 when keyframes were remembered by the tracking's corners, 65 inliers);
    // without either, the frame is lost, tracking restarts at a guessed pose, ATE 933 mm.
    assert_eq!(with["frames_relocalized"], 1, "{with}");
    assert_eq!(with["frames_lost"], 0, "{with}");
    assert_eq!(without["frames_lost"], 1, "{without}");
    assert_eq!(with["segments"], 1, "{with}");
    let (ate_with, ate_without) = (num(&with["ate"], "rmse"), num(&without["ate"], "rmse"));
    eprintln!("kidnapped: ATE {ate_with} m relocalized, {ate_without} m without");
    assert!(ate_with < 0.015, "ATE with relocalization {ate_with} m");
    assert!(
        ate_with < 0.3 * ate_without,
        "ATE with relocalization {ate_with} m, without {ate_without} m"
    );
}

#[test]
fn a_keyframe_after_dropped_frames_is_tied_to_the_last_by_its_depth() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 1 s of frames dropped at 1.5 s: Lucas-Kanade still follows, on few inliers.
    let seq = frames_dropped(&teddy, tmp.path(), 45..75);
    let (with, without) = with_and_without(
        &seq,
        tmp.path(),
        "map = false\n[odometry]\nkeyframe_depth_link_inliers = 0\n",
    );
    let links = |r: &serde_json::Value| r["associations"]["depth_edges"].as_u64().unwrap();
    assert!(links(&with) >= 1, "{with}");
    assert_eq!(links(&without), 0, "{without}");
    assert_eq!(
        with["frames_by_status"]["tracked"], with["frames"],
        "{with}"
    );
    // Measured (2026-11-27, seeds 1-3, `seqtools.py gap ... 1.5 1`, RANSAC drawing at least
    // 100 samples): 5.4-7.1 mm with the depth link, 5.3-8.1 mm without (ratios 0.73, 0.88,
    // 1.03; mean 6.1 against 7.2; teddy_200 whole: 5.1-5.8 mm). Elsewhere the link gains
    // or is neutral: every 15th frame 7.8 against 8.8 mm, every 10th 7.0 against 7.4, 1 s
    // dropped at 3 s 6.7 against 6.7. Until 2026-11-27 the run "without" also swapped the
    // odometry's noise model (a config-file bug), which made the link look harmful.
    let (ate_with, ate_without) = (num(&with["ate"], "rmse"), num(&without["ate"], "rmse"));
    assert!(
        ate_with < 0.95 * ate_without && ate_with < 0.0075,
        "ATE with the depth link {ate_with} m, without {ate_without} m"
    );
}

#[test]
fn a_frame_after_a_gap_is_aligned_by_its_depth_from_where_its_few_tracks_agree() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 1.5 s of frames dropped at 3 s: the camera moves about 0.45 m. The next frame keeps
    // 20 tracks, too few agree to place it, and neither recovery nor relocalization finds
    // enough ORB matches; aligned by its depth from the motion model's guess it pairs 6 %
    // of its samples, from the pose its agreeing tracks give 37 %.
    let seq = frames_dropped(&teddy, tmp.path(), 90..135);
    // Without depth alignment, and without recovery (whose looser last chance places the
    // frame at 10.3 mm there).
    let (with, without) = with_and_without(
        &seq,
        tmp.path(),
        "[odometry]\ndepth_alignment = false\nrecovery_keyframes = false\n",
    );
    assert_one_frame_placed_by_depth(&with);
    assert_eq!(without["frames_lost"], 1, "{without}");
    // Measured (seeds 1-3, `seqtools.py gap ... 3 1.5`): 4.5-4.6 mm, against 66 mm when
    // the frame is lost and its piece placed by the guess (the alignment from the guess
    // alone is refused there too).
    assert_far_better(&with, &without, 0.008, ("1.5 s gap", "aligned", "lost"));
}

#[test]
fn a_frame_after_a_two_second_gap_is_placed_by_a_search_over_depth_alignments() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 2 s of frames dropped at 3 s: the camera moves about 0.6 m and 37 degrees, and the
    // motion model's guess is over 0.5 m off. No tracks, ORB matches or alignment from the
    // guess place the next frame; from the grid of starts the alignment pairs about a
    // quarter of its samples near the true pose.
    let seq = frames_dropped(&teddy, tmp.path(), 90..150);
    let (with, without) = with_and_without(&seq, tmp.path(), "[odometry]\ndepth_search = false\n");
    assert_one_frame_placed_by_depth(&with);
    assert_eq!(without["frames_lost"], 1, "{without}");
    // Measured: 4.7 mm here, against 101 mm when the frame is lost and its piece placed by
    // the guess; `seqtools.py gap ... 3 2`, seeds 1-3: 5.6 / 6.2 / 5.7 mm against 98 mm.
    assert_far_better(&with, &without, 0.010, ("2 s gap", "searched", "lost"));
}

#[test]
fn a_frame_after_a_gap_is_placed_by_its_depth_where_its_small_overlap_agrees() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 2 s of frames dropped at 4 s (frames 120-178), seed 3: the newest keyframe is three
    // frames before the gap, and at the true pose 19.9 % of the next frame's depth samples
    // pair with its surface, under the 20 % the search takes on overlap alone, while 44 %
    // of those that land on that surface lie on it (the wrong poses of teddy's gaps: 11-22 %).
    let seq = frames_dropped(&teddy, tmp.path(), 120..179);
    let out = tmp.path().join("out");
    let args = ["--camera", "fr3", "--no-map", "--seed", "3"];
    let report = common::run_report("run", &seq, &out, &args);
    assert_one_frame_placed_by_depth(&report);
    // Measured: 3.6 mm; 33.6 mm when the frame was lost and its piece placed by the guess.
    let ate = num(&report["ate"], "rmse");
    eprintln!("2 s gap at 4 s, seed 3: ATE {ate} m");
    assert!(ate < 0.008, "ATE {ate} m");
}

#[test]
fn a_pose_from_few_orb_matches_after_a_gap_is_corrected_by_the_depth() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 2 s of frames dropped at 2 s: the camera moves 0.53 m. ORB matches within the looser
    // bounds place the next frame on about 20 inliers, 0.11-0.13 m and 7-8 degrees off; the
    // depth alignment started there pairs a quarter of its samples within 13 mm and 2
    // degrees of the true pose, and nothing later corrects the ORB pose.
    let seq = frames_dropped(&teddy, tmp.path(), 60..120);
    let (with, without) = with_and_without(&seq, tmp.path(), "[odometry]\ndepth_search = false\n");
    assert_one_frame_placed_by_depth(&with);
    assert_eq!(without["frames_by_status"]["recovered"], 1, "{without}");
    // Measured: `seqtools.py gap ... 2 2`, seeds 1-3: 4.0 / 4.4 / 4.1 mm, against
    // 47 / 50 / 38 mm with the ORB pose.
    assert_far_better(&with, &without, 0.010, ("2 s gap at 2 s", "checked", "ORB"));
}

#[test]
fn a_frame_lost_after_a_gap_is_recovered_by_orb_matches_within_looser_bounds() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 1.25 s of frames dropped at 1 s: the camera moves 0.53 m and 33 degrees. 7 tracks
    // survive, none agree; within the usual bounds (Hamming 50, ratio 0.8) the recent
    // keyframes give at most 8 ORB matches, within 100 and 0.95 144, 32 of them inliers.
    let seq = frames_dropped(&teddy, tmp.path(), 30..68);
    let (with, without) =
        with_and_without(&seq, tmp.path(), "[odometry]\nrecovery_keyframes = false\n");
    assert_eq!(with["frames_lost"], 0, "{with}");
    assert_eq!(with["frames_recovered"], 1, "{with}");
    assert_eq!(with["segments"], 1, "{with}");
    assert_eq!(without["frames_lost"], 1, "{without}");
    // Measured (seeds 1-3, `seqtools.py gap ... 1 1.25`): 6.0 / 5.6 / 8.8 mm, against 53 mm
    // before the looser pass, when the frame was lost (ORB-SLAM3: 5.4 mm).
    assert_far_better(&with, &without, 0.012, ("1.25 s gap", "recovered", "lost"));
}

#[test]
fn a_frame_after_a_gap_is_recovered_by_matches_near_a_rough_pose() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 1.75 s of frames dropped at 1.5 s: within the looser bounds the recent keyframes give
    // 11-18 RANSAC inliers, too few; near where that rough pose projects a keyframe's
    // points, 30 or more.
    let report = run_with_frames_dropped(&teddy, tmp.path(), 45..98);
    assert_eq!(report["frames_lost"], 0, "{report}");
    assert_eq!(report["segments"], 1, "{report}");
    // Measured (seeds 1-3): 11.6 / 16.4 / 11.4 mm; lost before, 99.4 / 47.6 / 99.3 mm.
    let ate = num(&report["ate"], "rmse");
    assert!(ate < 0.025, "ATE {ate} m");
}

#[test]
fn a_frame_after_two_seconds_dropped_is_recovered_or_placed_at_the_recent_velocity() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // 2 s of frames dropped at 2.5 s: the camera moves 0.57 m and 32 degrees, and at its
    // true pose at most 18 % of the next frame's points lie within 3 cm of any earlier
    // frame's. Since points behind occluding edges are trusted less, recovery places that
    // frame. Measured: 5.2 mm here; seqtools' 2 s gap at 2.5 s, seeds 1-2: 5.2 / 4.8 mm
    // (lost before, 36.5 / 36.8 mm).
    let seq = frames_dropped(&teddy, tmp.path(), 75..135);
    let off = "[odometry]\nrecovery_keyframes = false\nrelocalization_keyframes = false\n";
    let (with, without) = with_and_without(&seq, tmp.path(), off);
    assert_eq!(with["frames_lost"], 0, "{with}");
    assert_eq!(with["segments"], 1, "{with}");
    let ate = num(&with["ate"], "rmse");
    assert!(ate < 0.012, "ATE {ate} m");
    // Without recovery and relocalization the frame is lost and put where the recent
    // velocity takes it. Measured on seqtools' gap: 34.7 mm; 211-220 mm when the lost
    // frame took five frames' worth of the last frame's motion, as it did before.
    assert_eq!(without["frames_lost"], 1, "{without}");
    assert_eq!(without["segments"], 2, "{without}");
    let ate = num(&without["ate"], "rmse");
    assert!(ate < 0.05, "ATE {ate} m");
}

#[test]
fn a_piece_after_a_lost_frame_joins_the_map_when_the_camera_comes_back() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    // Forwards to frame 119, a jump to frame 195 that nothing can bridge (the frame is
    // lost and the new piece starts at a guess), then backwards over the first pass.
    let order: Vec<usize> = (0..120).chain((0..=195).rev()).collect();
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("lost_and_back");
    reordered(&teddy, &seq, &order);
    let (with, without) =
        with_and_without(&seq, tmp.path(), "[odometry]\nplace_features = false\n");
    // Measured: the keyframes' own ORB features join the two pieces at the first keyframes
    // of the way back (ATE 7.2 mm); the tracking's corners, whose descriptors drift with
    // the tracks, match too few to verify a loop and the pieces stay apart (368 mm).
    assert_eq!(with["frames_lost"], 1, "{with}");
    assert_eq!(with["segments"], 1, "{with}");
    assert_eq!(without["segments"], 2, "{without}");
    assert_far_better(&with, &without, 0.015, ("lost and back", "joined", "apart"));
}

/// The report of `stride run` (fr3, no map) on teddy with the frames `dropped` removed.
fn run_with_frames_dropped(
    teddy: &Path,
    dir: &Path,
    dropped: std::ops::Range<usize>,
) -> serde_json::Value {
    let seq = frames_dropped(teddy, dir, dropped);
    let out = dir.join("out");
    common::run_report("run", &seq, &out, &["--camera", "fr3", "--no-map"])
}

/// Asserts that the run placed one frame by its depth, lost none, and stayed one piece.
fn assert_one_frame_placed_by_depth(report: &serde_json::Value) {
    assert_eq!(report["frames_lost"], 0, "{report}");
    assert_eq!(report["frames_by_status"]["depth"], 1, "{report}");
    assert_eq!(report["segments"], 1, "{report}");
}

/// Asserts that the run `with` a mechanism ends below `max_ate_m` and below 0.3 times the
/// ATE of the run `without` it; `(case, with, without)` name them in the log and the message.
fn assert_far_better(
    with: &serde_json::Value,
    without: &serde_json::Value,
    max_ate_m: f64,
    (case, named_with, named_without): (&str, &str, &str),
) {
    let (ate_with, ate_without) = (num(&with["ate"], "rmse"), num(&without["ate"], "rmse"));
    eprintln!("{case}: ATE {ate_with} m {named_with}, {ate_without} m {named_without}");
    assert!(
        ate_with < max_ate_m && ate_with < 0.3 * ate_without,
        "ATE {named_with} {ate_with} m, {named_without} {ate_without} m"
    );
}

/// teddy_200 without its frames `dropped` (indices into rgb.txt), written under `dir`.
fn frames_dropped(teddy: &Path, dir: &Path, dropped: std::ops::Range<usize>) -> PathBuf {
    let seq = dir.join(format!("teddy_without_{}_{}", dropped.start, dropped.end));
    derived(teddy, &seq, |i| !dropped.contains(&i));
    seq
}

/// teddy_200's frames 0-149, then, in one jump back of about 3.7 s, frames 40-194 again:
/// the frame after the jump shows a place the run passed (written under `dir`).
fn jumped_back(teddy: &Path, dir: &Path) -> PathBuf {
    let order: Vec<usize> = (0..150).chain(40..195).collect();
    let seq = dir.join("jumped_back");
    reordered(teddy, &seq, &order);
    seq
}

#[test]
fn a_camera_that_jumps_back_to_a_place_it_passed_is_relocalized_there() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let seq = jumped_back(&teddy, tmp.path());
    let (with, without) = with_and_without(
        &seq,
        tmp.path(),
        "[odometry]\nrelocalization_keyframes = false\n",
    );
    // Measured (seeds 1-3): relocalized at the jump by 98 inliers, live ATE 6.9-8.4 mm;
    // without relocalization the frame is lost, its pose 1 m off and the live poses after
    // it about 40 mm off until loop closure joins the pieces (live ATE 111-130 mm).
    // Remembered by the tracking's corners, as before, the keyframes matched 43 features
    // at most and the frame was lost as well.
    assert_eq!(with["frames_relocalized"], 1, "{with}");
    assert_eq!(with["frames_lost"], 0, "{with}");
    assert_eq!(without["frames_lost"], 1, "{without}");
    let live = |r: &serde_json::Value| num(&r["ate_live"], "rmse");
    let (live_with, live_without) = (live(&with), live(&without));
    eprintln!("jumped back: live ATE {live_with} m relocalized, {live_without} m lost");
    assert!(
        live_with < 0.012 && live_with < 0.3 * live_without,
        "live ATE relocalized {live_with} m, lost {live_without} m"
    );
    assert!(num(&with["ate"], "rmse") < 0.012, "{with}");
}

#[test]
fn a_relocalized_keyframe_is_linked_to_the_keyframe_it_was_found_against() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let seq = jumped_back(&teddy, tmp.path());
    let seq = TumSequence::open(&seq, Some("fr3"), AssociationOptions::default()).unwrap();
    let mut vo = VisualOdometry::new(seq.camera.camera, VoConfig::default()).unwrap();
    let mut relocalized = Vec::new();
    for decoded in seq.stream(None, 2) {
        let r = vo.process(&decoded.unwrap().frame).unwrap();
        if r.status == TrackingStatus::Relocalized {
            relocalized.push(r);
        }
    }
    assert_eq!(relocalized.len(), 1);
    let r = &relocalized[0];
    let matched = r.matched_keyframe.unwrap();
    let link = r.new_keyframe.as_ref().unwrap().odometry.as_ref().unwrap();
    // Linked to the previous keyframe instead, the link would carry the odometry's drift
    // since the matched one as if measured (the kidnapped run: 10.1 mm instead of 7.9,
    // seeds 1-3 mean).
    assert_eq!(link.previous_id, matched);
    assert!(matched + 10 < r.keyframe_id, "{matched} {}", r.keyframe_id);
    assert_eq!(link.inliers, r.inliers);
}
