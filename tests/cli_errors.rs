//! Errors a new user meets, from a review of the CLI: each names the right thing once, and
//! comes before any work is done.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, run, run_json};

/// Runs stride, expects failure, and returns stderr.
fn fails(args: &[&str]) -> String {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "stride {args:?} should fail");
    assert!(!err.contains("panicked"), "{err}");
    err
}

#[test]
fn eval_takes_positional_files_like_evo() {
    let Some((gt, est)) = common::xyz_pair() else {
        return;
    };
    let (gt, est) = (gt.to_str().unwrap(), est.to_str().unwrap());
    let named = run_json(&["eval", "ate", "--gt", gt, "--est", est, "--json"]);
    let positional = run_json(&["eval", "ate", gt, est, "--json"]);
    assert_eq!(named, positional);
    let err = fails(&["eval", "ate", gt]);
    assert!(
        err.contains("give the ground truth and the estimate"),
        "{err}"
    );
    let err = fails(&["eval", "ate", gt, est, "--gt", gt]);
    assert!(err.contains("cannot be used with"), "{err}");
    // A plot is SVG: asking for .png is an error before any work, and writes nothing.
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("plot.png");
    let err = fails(&["eval", "ate", gt, est, "--plot", png.to_str().unwrap()]);
    assert!(err.contains("plots are written as SVG"), "{err}");
    assert!(!png.exists());
}

#[test]
fn a_missing_file_is_named_once_with_its_os_error_once() {
    let err = fails(&["eval", "ate", "/nonexistent/gt.txt", "/nonexistent/est.txt"]);
    assert!(err.contains("/nonexistent/gt.txt"), "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
    assert!(
        !err.contains('\u{1b}'),
        "no colour codes when stderr is not a terminal"
    );
}

#[test]
fn outputs_and_ranges_are_checked_before_the_work() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let teddy = teddy.to_str().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("a_file");
    std::fs::write(&file, "x").unwrap();
    let f = file.to_str().unwrap();
    for args in [
        vec!["run", "--dataset", teddy, "--out", f],
        vec!["map", "--dataset", teddy, "--out", f],
        vec!["synth", "--out", f, "--frames", "2"],
        vec!["demo", "--out", f],
    ] {
        let err = fails(&args);
        assert!(
            err.contains(&format!("--out {f}: exists and is not a folder")),
            "{args:?}: {err}"
        );
    }
    let out = tmp.path().join("m");
    let o = out.to_str().unwrap();
    let err = fails(&["map", "--dataset", teddy, "--out", o, "--resolution", "-1"]);
    assert!(
        err.contains("--resolution -1") && err.contains("must be positive"),
        "{err}"
    );
    let err = fails(&["synth", "--out", o, "--depth-bias-scale", "-1"]);
    assert!(
        err.contains("--depth-bias-scale -1") && err.contains("0 or more"),
        "{err}"
    );
    let err = fails(&[
        "map",
        "--dataset",
        teddy,
        "--out",
        o,
        "--gt-terrain",
        "/nonexistent/nope.npy",
    ]);
    assert!(err.contains("/nonexistent/nope.npy"), "{err}");
    assert!(!err.contains("grid.json"), "{err}");
    assert!(!out.exists());
}

#[test]
fn an_output_folder_with_contents_is_refused_unless_overwritten() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let teddy = teddy.to_str().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("earlier");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), "an earlier result").unwrap();
    let o = out.to_str().unwrap();
    let gt = format!("{teddy}/groundtruth.txt");
    for args in [
        vec!["run", "--dataset", teddy, "--out", o, "--max-frames", "3"],
        vec!["map", "--dataset", teddy, "--out", o, "--max-frames", "3"],
        vec!["demo", "--out", o, "--frames", "3"],
        vec!["eval", "ate", &gt, &gt, "--report", o],
    ] {
        let flag = if args[0] == "eval" {
            "--report"
        } else {
            "--out"
        };
        let err = fails(&args);
        assert!(
            err.contains(&format!("{flag} {o}: the folder exists and is not empty"))
                && err.contains("--overwrite"),
            "{args:?}: {err}"
        );
        assert_eq!(
            std::fs::read_to_string(out.join("keep.txt")).unwrap(),
            "an earlier result"
        );
    }
    // With --overwrite the folder is replaced whole by the new result.
    common::run_ok(&[
        "run",
        "--dataset",
        teddy,
        "--out",
        o,
        "--overwrite",
        "--vo-only",
        "--max-frames",
        "5",
    ]);
    assert!(!out.join("keep.txt").exists() && out.join("trajectory.tum").is_file());
}

#[test]
fn the_camera_is_reported_by_name_not_as_a_debug_string() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("r");
    common::run_ok(&[
        "run",
        "--dataset",
        teddy.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--vo-only",
        "--max-frames",
        "5",
    ]);
    let r = common::report(&out);
    assert_eq!(r["camera"], "fr3 (from the folder name)");
}

#[test]
fn the_configuration_file_is_documented_checked_and_overridden_by_flags() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let teddy = teddy.to_str().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    // The printed defaults are a valid file.
    let defaults = run(&["config", "--print-defaults"]);
    assert!(defaults.status.success());
    let text = String::from_utf8_lossy(&defaults.stdout).into_owned();
    assert!(
        text.contains("[map.stack]") && text.contains("# "),
        "{text}"
    );
    let file = tmp.path().join("defaults.toml");
    std::fs::write(&file, &text).unwrap();
    common::run_ok(&["config", "--check", file.to_str().unwrap()]);
    // A typo and a value out of range are named, before any work and without output.
    let out = tmp.path().join("never");
    let o = out.to_str().unwrap();
    for (body, expected) in [
        ("[odometry]\nseed = 3\nklt_level = 2\n", "klt_level"),
        ("[map]\ndecimation = 9\n", "map.decimation = 9: 1 to 8"),
    ] {
        let bad = tmp.path().join("bad.toml");
        std::fs::write(&bad, body).unwrap();
        let b = bad.to_str().unwrap();
        let err = fails(&["run", "--dataset", teddy, "--out", o, "--config", b]);
        assert!(err.contains(b) && err.contains(expected), "{err}");
        assert!(!out.exists());
        let err = fails(&["config", "--check", b]);
        assert!(err.contains(expected), "{err}");
    }
    // The file's values apply, a flag overrides them, and the run records what it used.
    let cfg = tmp.path().join("mine.toml");
    std::fs::write(&cfg, "map = false\n[odometry]\nseed = 5\n").unwrap();
    let c = cfg.to_str().unwrap();
    let r = common::run_report(
        "run",
        std::path::Path::new(teddy),
        &out,
        &["--config", c, "--max-frames", "8"],
    );
    assert_eq!(r["seed"], 5);
    assert_eq!(r["config"]["map"], false);
    assert!(r.get("map").is_none() && !out.join("map").exists());
    let used = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(
        used.contains("seed = 5") && used.contains("map = false"),
        "{used}"
    );
    let again = tmp.path().join("again");
    let r = common::run_report(
        "run",
        std::path::Path::new(teddy),
        &again,
        &["--config", c, "--seed", "2", "--max-frames", "8"],
    );
    assert_eq!(r["seed"], 2);
    // The odometry alone keeps its own defaults where the file is silent.
    let alone = tmp.path().join("alone");
    let r = common::run_report(
        "run",
        std::path::Path::new(teddy),
        &alone,
        &["--config", c, "--vo-only", "--max-frames", "8"],
    );
    assert_eq!(r["seed"], 5);
    assert_eq!(
        r["config"]["odometry"]["model_noise_m"], 0.002,
        "{}",
        r["config"]
    );
    assert_eq!(r["config"]["odometry"]["redetect_fraction"], 0.6);
    // `stride map` takes the file's [map.stack]; its flags override it.
    std::fs::write(
        &cfg,
        "[map.stack]\nresolution_m = 0.02\nsee_through_check = false\n",
    )
    .unwrap();
    let seq = std::path::Path::new(teddy);
    let m = common::run_report(
        "map",
        seq,
        &tmp.path().join("m1"),
        &["--config", c, "--max-frames", "10"],
    );
    assert_eq!(m["stack_config"]["resolution_m"], 0.02);
    assert_eq!(m["stack_config"]["see_through_check"], false);
    let m = common::run_report(
        "map",
        seq,
        &tmp.path().join("m2"),
        &["--config", c, "--resolution", "0.05", "--max-frames", "10"],
    );
    assert_eq!(m["stack_config"]["resolution_m"], 0.05);
}

#[test]
fn a_camera_of_the_wrong_size_lists_a_few_frames_then_the_error() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let teddy = teddy.to_str().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let camera = tmp.path().join("small.json");
    std::fs::write(
        &camera,
        r#"{"fx": 535.4, "fy": 539.2, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240, "depth_scale": 5000}"#,
    )
    .unwrap();
    let c = camera.to_str().unwrap();
    for command in ["run", "map"] {
        let out = tmp.path().join(command);
        let o = out.to_str().unwrap();
        let err = fails(&[
            command,
            "--dataset",
            teddy,
            "--camera",
            c,
            "--out",
            o,
            "--max-frames",
            "12",
        ]);
        // Every frame fails the same way: the first few are listed, then the error.
        assert!(
            err.contains("image is 640x480 but the camera is 320x240"),
            "{err}"
        );
        assert_eq!(err.matches(" skipped: ").count(), 6, "{command}: {err}");
        assert!(
            err.contains("further skipped frames are counted, not listed"),
            "{err}"
        );
        // Nothing about a world frame or a map, which no frame could give.
        assert!(
            !err.contains("no floor seen") && !err.contains("no elevation map"),
            "{err}"
        );
        assert!(!out.exists(), "{command}: nothing written");
    }
}
