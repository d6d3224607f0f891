//! Maps that last: teddy_200's first 100 frames are mapped and saved; a second run over
//! frames 100-200 loads the map, relocalizes its first frame in it, and goes on in the map's
//! frame; a run the map cannot place at first starts a piece of its own, joined to the map
//! when it comes back over the mapped place.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, derived, reordered};
use std::path::Path;
use stride_core::trajectory::Trajectory;
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_eval::ate;

/// ATE RMSE (m) of two runs' trajectories together, each against its own ground truth,
/// under one SE(3) alignment: small only when both are in the same frame. The second run
/// and its ground truth are moved 1,000 s on, so that the runs' stamps may overlap (a
/// reordered sequence restarts the clock).
fn joint_ate(a: (&Trajectory, &Trajectory), b: (&Trajectory, &Trajectory)) -> f64 {
    let join = |x: &Trajectory, y: &Trajectory| {
        let mut stamps = x.stamps_s().to_vec();
        stamps.extend(y.stamps_s().iter().map(|t| t + 1000.0));
        let mut poses = x.poses().to_vec();
        poses.extend_from_slice(y.poses());
        Trajectory::from_parts(stamps, poses).unwrap()
    };
    let (gt, est) = (join(a.0, b.0), join(a.1, b.1));
    ate(&gt, &est, &stride::pipeline::slam_ate_options())
        .unwrap()
        .trans_m
        .rmse
}

fn trajectory(dir: &Path) -> Trajectory {
    read_tum_trajectory(&dir.join("trajectory.tum")).unwrap()
}

/// Maps teddy_200's first 100 frames (run "one" under `dir`) and saves the map to
/// `dir/teddy.map.json`; returns its path.
fn map_of_the_first_100_frames(teddy: &Path, dir: &Path) -> std::path::PathBuf {
    let first = dir.join("first");
    derived(teddy, &first, |i| i < 100);
    let map = dir.join("teddy.map.json");
    let save = [
        "--camera",
        "fr3",
        "--no-map",
        "--save-map",
        map.to_str().unwrap(),
    ];
    common::run_report("run", &first, &dir.join("one"), &save);
    map
}

#[test]
fn a_second_run_localizes_in_a_saved_map_and_extends_it() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (first, second) = (tmp.path().join("first"), tmp.path().join("second"));
    derived(&teddy, &first, |i| i < 100);
    derived(&teddy, &second, |i| i >= 100);
    let map = tmp.path().join("teddy.map.json");
    let map_arg = map.to_str().unwrap();
    let out = |name: &str| tmp.path().join(name);
    let run = |seq: &Path, name: &str, extra: &[&str]| {
        let mut args = vec!["--camera", "fr3", "--no-map"];
        args.extend_from_slice(extra);
        common::run_report("run", seq, &out(name), &args)
    };
    let one = run(&first, "one", &["--save-map", map_arg]);
    assert_eq!(one["save_map"], map_arg, "{one}");
    assert!(map.is_file());
    let again = tmp.path().join("teddy_extended.map.json");
    let again_arg = again.to_str().unwrap();
    let two = run(
        &second,
        "two",
        &["--load-map", map_arg, "--save-map", again_arg],
    );
    assert_eq!(two["load_map"], map_arg, "{two}");
    assert_eq!(two["relocalizations"], 1, "{two}");
    assert_eq!(two["frames_by_status"]["relocalized"], 1, "{two}");
    assert_eq!(two["frames_lost"], 0, "{two}");
    assert_eq!(two["world_frame"]["source"], "saved map", "{two}");
    // The map grew: the saved map's points and the second run's new ones; saved again, it
    // keeps its keyframes and where its world came from.
    assert!(
        two["map_points"].as_u64().unwrap() > one["map_points"].as_u64().unwrap(),
        "{one}\n{two}"
    );
    let json = |p: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    let (saved, extended) = (json(&map), json(&again));
    let count = |v: &serde_json::Value| v["keyframes"].as_array().unwrap().len();
    assert!(count(&extended) > count(&saved));
    assert_eq!(extended["world"], saved["world"]);
    assert_eq!(extended["world_from_map"], saved["world_from_map"]);

    // The second run's poses are in the first run's world: one alignment fits both runs
    // about as well as it fits the single run over all 200 frames. Measured: 8.13 mm
    // against 6.64 (2026-11-27, the odometry with the back end's noise model; before it
    // 5.34 against 4.40, relocalized by 211 inliers); the second run alone, in a world of
    // its own, gives 580 mm with the first.
    let single = run(&teddy, "single", &[]);
    let alone = run(&second, "alone", &[]);
    let gt = read_tum_trajectory(&teddy.join("groundtruth.txt")).unwrap();
    let joint = joint_ate(
        (&gt, &trajectory(&out("one"))),
        (&gt, &trajectory(&out("two"))),
    );
    let single_ate = common::num(&single["ate"], "rmse");
    eprintln!("two runs under one alignment: {joint} m, the single run {single_ate} m");
    assert!(
        joint < 2.0 * single_ate,
        "both runs under one alignment {joint} m, the single run {single_ate} m"
    );
    let apart = joint_ate(
        (&gt, &trajectory(&out("one"))),
        (&gt, &trajectory(&out("alone"))),
    );
    assert!(
        apart > 10.0 * joint,
        "without the map {apart} m, with it {joint} m ({alone})"
    );
    assert!(common::num(&two["ate"], "rmse") < 0.008, "{two}");
}

#[test]
fn a_bad_map_file_is_a_clear_error() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let map = tmp.path().join("cut.json");
    std::fs::write(
        &map,
        "{\"format\": \"stride-map\", \"version\": 1, \"camera\"",
    )
    .unwrap();
    let out = tmp.path().join("out");
    let run = |extra: &[&str]| {
        let mut args = vec!["run", "--dataset", teddy.to_str().unwrap()];
        args.extend_from_slice(&["--out", out.to_str().unwrap(), "--no-map"]);
        args.extend_from_slice(extra);
        common::run(&args)
    };
    let o = run(&["--load-map", map.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("cut.json") && err.contains("not a stride map"),
        "{err}"
    );
    assert!(!out.exists(), "nothing is written");
    let o = run(&["--vo-only", "--save-map", map.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("--save-map needs a back end"), "{err}");
}

#[test]
fn the_saved_place_features_place_a_later_start_and_close_loops_with_the_map() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let later = tmp.path().join("later");
    // Starting half a second after the map's last frame, where the view has moved on.
    derived(&teddy, &later, |i| i >= 115);
    let map = map_of_the_first_100_frames(&teddy, tmp.path());
    let map_arg = map.to_str().unwrap();
    // The same map as version 1 wrote it: no place features.
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&map).unwrap()).unwrap();
    assert_eq!(v["version"], 2);
    let keyframes = v["keyframes"].as_array_mut().unwrap();
    let with_places = keyframes
        .iter_mut()
        .filter_map(|k| k.as_object_mut().unwrap().remove("place_features"))
        .count();
    assert_eq!(with_places, keyframes.len());
    v["version"] = 1.into();
    let old = tmp.path().join("teddy.v1.map.json");
    std::fs::write(&old, serde_json::to_vec(&v).unwrap()).unwrap();

    let load = ["--camera", "fr3", "--no-map", "--load-map", map_arg];
    let (two, log) = common::run_logged("run", &later, &tmp.path().join("two"), &load);
    // Measured: ATE 4.7 mm (5.4 mm, relocalized by 41 inliers, before the odometry took
    // the back end's noise model); the saved keyframes' mapped features alone (the
    // tracking's corners, 20-60 a keyframe) matched 24 at most.
    assert_eq!(two["relocalizations"], 1, "{two}\n{log}");
    assert_eq!(two["frames_lost"], 0, "{two}");
    assert!(common::num(&two["ate"], "rmse") < 0.008, "{two}");
    // Nothing in the version-1 copy places that start: the run goes on in a piece of its
    // own, started by a guess at the newest saved keyframe's pose, and says so.
    // Saved again, the map leaves that piece out and keeps its own keyframes and points:
    // the piece matched only its own points (the map around the guessed pose is not what
    // the camera saw), so none of the map's was counted unseen and culled. Measured: 29
    // keyframes, 541 of 605-607 points (the 64-66 seen by one keyframe go in any run in the
    // map);
    // a run from frame 140 on, matching the map around the guess, left 365.
    let again = tmp.path().join("again.map.json");
    let (old_arg, again_arg) = (old.to_str().unwrap(), again.to_str().unwrap());
    let load_v1 = ["--camera", "fr3", "--no-map", "--load-map", old_arg];
    let save_again = [&load_v1[..], &["--save-map", again_arg]].concat();
    let three = common::run_report("run", &later, &tmp.path().join("three"), &save_again);
    assert_eq!(three["relocalizations"], 0, "{three}");
    assert_eq!(three["frames_by_status"]["lost"], 1, "{three}");
    assert_eq!(three["frames_in_saved_map"], 0, "{three}");
    let ids = |v: &serde_json::Value, what: &str| -> Vec<u64> {
        let list = v[what].as_array().unwrap();
        list.iter().map(|k| k["id"].as_u64().unwrap()).collect()
    };
    let again: serde_json::Value = serde_json::from_slice(&std::fs::read(&again).unwrap()).unwrap();
    assert_eq!(ids(&again, "keyframes"), ids(&v, "keyframes"));
    let (kept, had) = (ids(&again, "points").len(), ids(&v, "points").len());
    eprintln!("saved again after a piece never joined: {kept} of {had} points");
    assert!(10 * kept > 8 * had, "{kept} of {had} points");

    // A run that goes on from the map's end and then walks back over the mapped place
    // closes loops with the saved keyframes by their place features. Measured (seed 1): 3
    // loops, ATE 6.7 mm; with the version-1 copy 0 loops, 7.6 mm (before the odometry took
    // the back end's noise model, seeds 1-3: 4 loops, 5.2-5.3 mm against 5.9-6.8 mm).
    let back: Vec<usize> = (100..195).chain((0..195).rev()).collect();
    let back_over = tmp.path().join("back_over");
    reordered(&teddy, &back_over, &back);
    let loops = |map: &str, name: &str| {
        let load = ["--camera", "fr3", "--no-map", "--load-map", map];
        let r = common::run_report("run", &back_over, &tmp.path().join(name), &load);
        (
            r["loop_closures"].as_u64().unwrap(),
            common::num(&r["ate"], "rmse"),
        )
    };
    let (with, without) = (loops(map_arg, "four"), loops(old.to_str().unwrap(), "five"));
    eprintln!("back over the saved map: {with:?} (loops, ATE m), version 1: {without:?}");
    assert!(with.0 >= 1 && with.0 > without.0, "{with:?} {without:?}");
    assert!(with.1 < 0.008, "{with:?}");
}

#[test]
fn a_start_the_map_cannot_place_is_joined_to_it_when_the_run_comes_back() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let map = map_of_the_first_100_frames(&teddy, tmp.path());
    let map_arg = map.to_str().unwrap();
    let gt = |dir: &Path| read_tum_trajectory(&dir.join("groundtruth.txt")).unwrap();
    let in_map = |name: &str, order: &[usize]| {
        let seq = tmp.path().join(name);
        reordered(&teddy, &seq, order);
        let load = ["--camera", "fr3", "--no-map", "--load-map", map_arg];
        let out = tmp.path().join(format!("{name}_out"));
        let r = common::run_report("run", &seq, &out, &load);
        assert_eq!(r["frames_by_status"]["lost"], 1, "{name}: {r}");
        assert_eq!(r["frames_in_saved_map"], r["frames"], "{name}: {r}");
        assert!(r["loop_closures"].as_u64().unwrap() >= 1, "{name}: {r}");
        // Live, the frames are in the map's world only once the first loop joined them.
        let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
        let live: Vec<&str> = csv.lines().skip(1).map(|l| &l[l.len() - 1..]).collect();
        assert_eq!(
            (live[0], live[live.len() - 1]),
            ("0", "1"),
            "{name}: {live:?}"
        );
        let joint = joint_ate(
            (&gt(&teddy), &trajectory(&tmp.path().join("one"))),
            (&gt(&seq), &trajectory(&out)),
        );
        eprintln!("{name}: both runs under one alignment {joint} m");
        assert!(joint < 0.010, "{name}: {joint} m\n{r}");
    };
    // Frame 140 has no saved keyframe in view (15 inliers at most, even by OpenCV's ORB on
    // the raw images). Walking back over the mapped place, the piece started by a guess is
    // joined to the map by the first loop with a saved keyframe. Measured: both runs under
    // one alignment 5.0 mm (seed 1). Before the odometry took the back end's noise model
    // (seeds 1-3): 4-5 loops, the first moving the piece 0.40 m and 22 degrees, 5.2-6.3 mm.
    in_map("from_140", &(0..=140).rev().collect::<Vec<_>>());
    // The same start, then a jump of 0.27 m and 15 degrees to frame 125 that tracking
    // follows: the link that placed the start must give way to it, or the frames before the
    // jump stay where the guess put them. Measured: 5.1 mm (seed 1). (The jump was to frame
    // 105, 0.48 m and 27 degrees, which the odometry followed on 13 inliers while it took
    // 2 cm of noise for every point: 6.4-6.7 mm, 46 mm with the guess held as firmly as a
    // lost frame's prediction. With the back end's 2 mm it relocalizes jumps to frames
    // 100-110 in the map, which then leaves the 11 frames before them apart, as the jump to
    // frame 60 below does; and at this sequence's 15 Hz the speed bound, 5 m/s, refuses any
    // step beyond 0.33 m.)
    in_map(
        "jump_to_125",
        &(140..=150).chain((0..=125).rev()).collect::<Vec<_>>(),
    );

    // A jump to frame 60 that tracking loses: relocalized in the map (412 inliers), the run
    // goes on there, but nothing ties its 11 frames before the jump to it and no loop comes
    // back to them: they stay apart, their views stay out of the elevation map, and the
    // map saved again leaves their keyframes out. Measured: the floor's residual 16.4 mm
    // and tilt 0.29 degree; with their views in it, 33.4 mm and 1.87 degrees.
    let seq = tmp.path().join("jump_to_60");
    let order: Vec<usize> = (140..=150).chain((0..=60).rev()).collect();
    reordered(&teddy, &seq, &order);
    let again = tmp.path().join("again.map.json");
    let again_arg = again.to_str().unwrap();
    let args = [
        "--camera",
        "fr3",
        "--load-map",
        map_arg,
        "--save-map",
        again_arg,
    ];
    let r = common::run_report("run", &seq, &tmp.path().join("jump_to_60_out"), &args);
    assert_eq!(r["frames_by_status"]["relocalized"], 1, "{r}");
    assert_eq!(r["frames_in_saved_map"], 61, "{r}");
    assert_eq!(r["segment_frames"], serde_json::json!([61, 11]), "{r}");
    // frames.csv says which, by the end (`piece`: the 11 before the jump in a piece of
    // their own) and live (`live_in_world`: from the relocalized frame on).
    let csv = std::fs::read_to_string(tmp.path().join("jump_to_60_out/frames.csv")).unwrap();
    let last_two = |l: &str| -> (String, String) {
        let mut fields = l.rsplit(',');
        let live = fields.next().unwrap().to_owned();
        (fields.next().unwrap().to_owned(), live)
    };
    let rows: Vec<(String, String)> = csv.lines().skip(1).map(last_two).collect();
    assert!(
        rows[..11].iter().all(|(p, l)| p != "0" && l == "0"),
        "{rows:?}"
    );
    assert!(
        rows[11..].iter().all(|(p, l)| p == "0" && l == "1"),
        "{rows:?}"
    );
    assert!(
        r["map"]["views_left_out"].as_u64().unwrap() >= 1,
        "{}",
        r["map"]
    );
    let floor = &r["map"]["floor"];
    assert!(common::num(floor, "residual_std_m") < 0.025, "{floor}");
    assert!(common::num(floor, "tilt_deg") < 1.0, "{floor}");
    let keyframes = |p: &Path| -> Vec<(u64, u64)> {
        let v: serde_json::Value = serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap();
        let list = v["keyframes"].as_array().unwrap().iter();
        list.map(|k| {
            (
                k["id"].as_u64().unwrap(),
                k["frame_index"].as_u64().unwrap(),
            )
        })
        .collect()
    };
    let newest_saved = keyframes(&map).iter().map(|k| k.0).max().unwrap();
    let added: Vec<u64> = keyframes(&again)
        .into_iter()
        .filter(|k| k.0 > newest_saved)
        .map(|k| k.1)
        .collect();
    assert!(
        !added.is_empty() && added.iter().all(|&f| f >= 11),
        "{added:?}"
    );
}
