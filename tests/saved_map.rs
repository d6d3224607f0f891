//! Maps that last: teddy_200's first 100 frames are mapped and saved; a second run over
//! frames 100-200 loads the map, relocalizes its first frame in it, and goes on in the map's
//! frame.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, derived};
use std::path::Path;
use stride_core::trajectory::Trajectory;
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_eval::align::Alignment;
use stride_eval::ate::{ate, AteOptions};
use stride_eval::options::Align;

/// ATE RMSE (m) of the poses of `est` from `from_s` on, placed in the ground truth's world
/// by the SE(3) alignment of the poses before `from_s` (no re-alignment of the later ones).
fn error_after(gt: &Trajectory, est: &Trajectory, from_s: f64) -> f64 {
    let split = |keep: &dyn Fn(f64) -> bool| {
        let (t, p): (Vec<f64>, Vec<_>) = est.iter().filter(|(t, _)| keep(*t)).unzip();
        Trajectory::from_parts(t, p.into_iter().copied().collect()).unwrap()
    };
    let options = stride::pipeline::slam_ate_options();
    let alignment = ate(gt, &split(&|t| t < from_s), &options)
        .unwrap()
        .alignment;
    error_in_world(gt, &split(&|t| t >= from_s), &alignment)
}

/// ATE RMSE (m) of `est` moved by `alignment`, without aligning again.
fn error_in_world(gt: &Trajectory, est: &Trajectory, alignment: &Alignment) -> f64 {
    let moved: Vec<_> = est.poses().iter().map(|p| alignment.apply(p)).collect();
    let moved = Trajectory::from_parts(est.stamps_s().to_vec(), moved).unwrap();
    let options = AteOptions {
        align: Align::None,
        ..stride::pipeline::slam_ate_options()
    };
    ate(gt, &moved, &options).unwrap().trans_m.rmse
}

fn trajectory(dir: &Path) -> Trajectory {
    read_tum_trajectory(&dir.join("trajectory.tum")).unwrap()
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
    let two = run(&second, "two", &["--load-map", map_arg]);
    assert_eq!(two["load_map"], map_arg, "{two}");
    assert_eq!(two["relocalizations"], 1, "{two}");
    assert_eq!(two["frames_by_status"]["relocalized"], 1, "{two}");
    assert_eq!(two["frames_lost"], 0, "{two}");
    assert_eq!(two["world_frame"]["source"], "saved map", "{two}");
    // The map grew: the saved map's points and the second run's new ones.
    assert!(
        two["map_points"].as_u64().unwrap() > one["map_points"].as_u64().unwrap(),
        "{one}\n{two}"
    );

    // The second run's poses are in the first run's world: the first run's alignment
    // with the ground truth places them. Against the single run over all 200 frames,
    // measured the same way (aligned on frames 0-99, scored on 100-199). Measured: 22.3
    // against 22.1 mm; with an alignment of their own, 5.6 and 4.6 mm. The 22 mm of
    // both is the alignment of a short first half extrapolated, not the saved map.
    let single = run(&teddy, "single", &[]);
    let gt = read_tum_trajectory(&teddy.join("groundtruth.txt")).unwrap();
    let boundary_s = trajectory(&out("two")).stamps_s()[0];
    let single_after = error_after(&gt, &trajectory(&out("single")), boundary_s);
    let first_alignment = ate(
        &gt,
        &trajectory(&out("one")),
        &stride::pipeline::slam_ate_options(),
    )
    .unwrap()
    .alignment;
    let two_in_world = error_in_world(&gt, &trajectory(&out("two")), &first_alignment);
    assert!(
        two_in_world < 1.3 * single_after,
        "second run in the saved map's world {two_in_world} m, single run {single_after} m ({single})"
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
