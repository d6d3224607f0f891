//! The odometry's wide-baseline recovery on real frames: teddy_200 with only every 20th
//! frame (0.67 s apart), where Lucas-Kanade loses the camera.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, num};
use std::path::Path;

/// A TUM folder in `dst` with every `k`-th line of `src`'s rgb.txt (depth and ground truth
/// whole; images linked, not copied), as `../shared/tools/seqtools.py subsample` makes.
fn subsample(src: &Path, dst: &Path, k: usize) {
    std::fs::create_dir_all(dst).unwrap();
    let rgb = std::fs::read_to_string(src.join("rgb.txt")).unwrap();
    let kept: String = rgb
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .step_by(k)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(dst.join("rgb.txt"), kept).unwrap();
    for f in ["depth.txt", "groundtruth.txt"] {
        std::fs::copy(src.join(f), dst.join(f)).unwrap();
    }
    for d in ["rgb", "depth"] {
        std::os::unix::fs::symlink(src.join(d), dst.join(d)).unwrap();
    }
}

#[test]
fn recovery_finds_frames_that_tracking_loses() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("teddy_every_20th");
    subsample(&teddy, &seq, 20);
    let off = tmp.path().join("off.toml");
    std::fs::write(
        &off,
        "map = false\n[odometry]\nrecovery_keyframes = false\n",
    )
    .unwrap();
    let off = off.display().to_string();
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec!["--camera", "fr3", "--no-map"];
        args.extend_from_slice(extra);
        common::run_report("run", &seq, &tmp.path().join(out), &args)
    };
    let with = run("with", &[]);
    let without = run("without", &["--config", &off]);
    assert_eq!(with["frames"], 10, "{with}");
    // Measured: without recovery 2 frames lost and 68 mm; with it none lost, one frame
    // recovered, 9.9 mm.
    assert!(without["frames_lost"].as_u64().unwrap() >= 1, "{without}");
    assert_eq!(with["frames_lost"], 0, "{with}");
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
