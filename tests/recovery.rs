//! The odometry's wide-baseline recovery on real frames: teddy_200 with only every 20th
//! frame (0.67 s apart), where Lucas-Kanade loses the camera.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, derived, num};

#[test]
fn recovery_finds_frames_that_tracking_loses() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("teddy_every_20th");
    derived(&teddy, &seq, |i| i % 20 == 0);
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
