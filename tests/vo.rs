//! The visual odometry and `stride run`: accuracy on real data, synthetic gaits,
//! determinism, bad frames, and features on synthetic terrain.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, num, report, run, run_ok};
use std::path::{Path, PathBuf};
use stride_core::camera::PinholeCamera;
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::synth::motion::{Gait, MotionConfig};
use stride_datasets::synth::{generate, Synth, SynthConfig};
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_eval::{ate, Align, AteOptions, Preset};

#[test]
fn teddy_every_frame_tracked_and_ate_within_two_centimetres() {
    let Some(seq) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let r = common::run_report("run", &seq, &out, &["--vo-only"]);
    assert_eq!(r["frames"], 193);
    assert_eq!(r["frames_tracked"], 193, "every frame tracked: {r}");
    assert_eq!(r["frames_lost"], 0);
    assert_eq!(r["frames_skipped"], 0);
    let ate_rmse = num(&r["ate"], "rmse");
    assert!(ate_rmse <= 0.02, "ATE {ate_rmse} m");
    assert_eq!(r["ate"]["align"], "se3");
    assert_eq!(r["ate"]["preset"], "evo");
    assert_eq!(r["rpe"]["unit"], "frames");
    assert!(num(&r["rpe"], "rmse") < 0.01);
    for stage in ["decode", "detect", "track", "ransac", "refine", "total"] {
        let s = &r["timing_ms"][stage];
        assert!(
            s["median"].as_f64().unwrap() >= 0.0
                && s["p95"].as_f64().unwrap() >= s["median"].as_f64().unwrap(),
            "{stage}: {s}"
        );
    }
    assert!(num(&r, "fps") > 0.0);
    // The trajectory has every frame, in TUM format.
    let traj = read_tum_trajectory(&out.join("trajectory.tum")).unwrap();
    assert_eq!(traj.len(), 193);
    for f in [
        "frames.csv",
        "report.html",
        "ate.svg",
        "rpe.svg",
        "tracking.svg",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
}

#[test]
fn two_runs_with_the_same_seed_write_identical_trajectories() {
    let Some(seq) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let s = seq.to_str().unwrap();
    run_ok(&[
        "run",
        "--dataset",
        s,
        "--out",
        a.to_str().unwrap(),
        "--vo-only",
        "--max-frames",
        "80",
        "--seed",
        "7",
    ]);
    // The second run also pins OpenCV to one thread: results do not depend on it.
    run_ok(&[
        "run",
        "--dataset",
        s,
        "--out",
        b.to_str().unwrap(),
        "--vo-only",
        "--max-frames",
        "80",
        "--seed",
        "7",
        "--deterministic",
    ]);
    let ta = std::fs::read(a.join("trajectory.tum")).unwrap();
    let tb = std::fs::read(b.join("trajectory.tum")).unwrap();
    assert!(ta == tb, "trajectories differ between identical runs");
    assert_eq!(String::from_utf8_lossy(&ta).lines().count(), 81);
}

/// A copy of the first `n` frames of teddy, for damaging.
fn teddy_copy(src: &Path, dst: &Path, n: usize) -> Vec<(String, String)> {
    std::fs::create_dir_all(dst.join("rgb")).unwrap();
    std::fs::create_dir_all(dst.join("depth")).unwrap();
    let seq =
        stride_datasets::tum::TumSequence::open(src, Some("fr3"), Default::default()).unwrap();
    let (mut rgb_txt, mut depth_txt, mut names) = (String::new(), String::new(), Vec::new());
    for f in seq.frames.iter().take(n) {
        let rn = f.rgb_path.file_name().unwrap().to_str().unwrap().to_owned();
        let dn = f
            .depth_path
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_owned();
        std::fs::copy(&f.rgb_path, dst.join("rgb").join(&rn)).unwrap();
        std::fs::copy(&f.depth_path, dst.join("depth").join(&dn)).unwrap();
        rgb_txt += &format!("{:.6} rgb/{rn}\n", f.t_rgb_s);
        depth_txt += &format!("{:.6} depth/{dn}\n", f.t_depth_s);
        names.push((rn, dn));
    }
    std::fs::write(dst.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(dst.join("depth.txt"), depth_txt).unwrap();
    std::fs::copy(src.join("groundtruth.txt"), dst.join("groundtruth.txt")).unwrap();
    names
}

#[test]
fn missing_corrupt_wrong_size_and_empty_depth_frames_are_counted_not_fatal() {
    let Some(src) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("teddy_damaged");
    let names = teddy_copy(&src, &dir, 30);
    // Frame 5: missing colour PNG. Frame 10: corrupt colour PNG. Frame 15: a 320x240
    // colour image. Frame 20: a depth image without a single return.
    std::fs::remove_file(dir.join("rgb").join(&names[5].0)).unwrap();
    std::fs::write(
        dir.join("rgb").join(&names[10].0),
        b"\x89PNG\r\n\x1a\n garbage",
    )
    .unwrap();
    let small = stride_core::image::Image::filled(320, 240, [90u8, 90, 90]);
    std::fs::write(
        dir.join("rgb").join(&names[15].0),
        stride_datasets::png_io::encode_rgb(&small).unwrap(),
    )
    .unwrap();
    let zeros = stride_core::image::Image::filled(640, 480, 0u16);
    std::fs::write(
        dir.join("depth").join(&names[20].1),
        stride_datasets::png_io::encode_depth_u16(&zeros).unwrap(),
    )
    .unwrap();

    let out = tmp.path().join("out");
    let (r, err) = common::run_logged("run", &dir, &out, &["--camera", "fr3", "--vo-only"]);
    assert_eq!(r["frames"], 30);
    assert_eq!(r["frames_skipped"], 3, "{r}");
    assert_eq!(r["frames_lost"], 1, "the frame without depth: {r}");
    let reasons: Vec<String> = r["skipped"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["reason"].as_str().unwrap().to_owned())
        .collect();
    assert!(
        reasons.iter().any(|s| s.contains(&names[5].0)),
        "{reasons:?}"
    );
    assert!(
        reasons
            .iter()
            .any(|s| s.contains(&names[10].0) && s.contains("PNG")),
        "{reasons:?}"
    );
    assert!(
        reasons
            .iter()
            .any(|s| s.contains("image is 320x240 but the camera is 640x480")),
        "{reasons:?}"
    );
    assert!(
        err.contains("frame 20") && err.contains("tracking failed"),
        "{err}"
    );
    // Every frame has a finite pose, and tracking recovered after the bad frames.
    let traj = read_tum_trajectory(&out.join("trajectory.tum")).unwrap();
    assert_eq!(traj.len(), 30);
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    let last = csv.lines().last().unwrap();
    assert!(last.contains(",tracked,"), "{last}");
    assert!(num(&r["ate"], "rmse") < 0.05, "{}", r["ate"]);
}

#[test]
fn a_missing_dataset_or_camera_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run(&[
        "run",
        "--dataset",
        "/nonexistent/seq",
        "--out",
        tmp.path().join("x").to_str().unwrap(),
        "--vo-only",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/nonexistent/seq") && !err.contains("panicked"),
        "{err}"
    );
}

fn synthetic(dir: &Path, gait: Gait, speed: f64, frames: usize) -> PathBuf {
    let cfg = SynthConfig {
        camera: common::quarter_vga(0.02),
        frames,
        motion: MotionConfig {
            gait,
            speed_m_s: speed,
            ..MotionConfig::default()
        },
        ..SynthConfig::default()
    };
    generate(&cfg, dir, true, &mut |_, _| {}).unwrap();
    dir.to_path_buf()
}

#[test]
fn synthetic_tripod_and_crawl_are_tracked_accurately() {
    let tmp = tempfile::tempdir().unwrap();
    for (gait, speed) in [
        (Gait::Tripod, 0.15),
        (Gait::Tripod, 0.08),
        (Gait::Crawl, 0.05),
    ] {
        let seq = synthetic(
            &tmp.path().join(format!("{gait:?}{speed}")),
            gait,
            speed,
            45,
        );
        let out = tmp.path().join(format!("out{gait:?}{speed}"));
        run_ok(&[
            "run",
            "--dataset",
            seq.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--vo-only",
        ]);
        let r = report(&out);
        assert_eq!(r["frames_tracked"], 45, "{gait:?} {speed}: {r}");
        let e = num(&r["ate"], "rmse");
        assert!(e < 0.01, "{gait:?} {speed}: ATE {e}");
        // Against the generator's own ground truth, read independently.
        let gt = read_tum_trajectory(&seq.join("groundtruth.txt")).unwrap();
        let est = read_tum_trajectory(&out.join("trajectory.tum")).unwrap();
        let a = ate(
            &gt,
            &est,
            &AteOptions {
                align: Align::Se3,
                ..AteOptions::for_preset(Preset::Evo)
            },
        )
        .unwrap();
        assert!((a.trans_m.rmse - e).abs() < 1e-9);
    }
}

#[test]
fn synthetic_terrain_gives_at_least_300_well_spread_corners() {
    // Full resolution, as the detector is tuned for 640x480.
    let synth = Synth::new(SynthConfig {
        frames: 60,
        blur: false,
        ..SynthConfig::default()
    })
    .unwrap();
    let renderer = synth.renderer();
    let cfg = stride_frontend::VoConfig::default();
    let mut det = stride_frontend::features::Detector::new(&cfg).unwrap();
    for i in [0, 30, 59] {
        let f = synth.render_frame(&renderer, i);
        let gray = f.rgb.to_gray();
        let corners = det
            .detect(
                &stride_frontend::features::gray_mat(&gray).unwrap(),
                &[],
                &cfg,
            )
            .unwrap();
        let mut cells = std::collections::HashSet::new();
        for c in &corners {
            cells.insert(((c.px.x / 80.0) as i32, (c.px.y / 80.0) as i32));
        }
        assert!(corners.len() >= 300, "frame {i}: {} corners", corners.len());
        assert!(
            cells.len() >= 36,
            "frame {i}: corners in only {} of 48 cells",
            cells.len()
        );
    }
}

#[test]
fn rolling_shutter_correction_makes_a_shaky_walk_more_accurate() {
    // The generator reads the colour rows out over 30 ms (depth is global-shutter). With the
    // readout in the camera file, keypoints are brought back to the frame's time; a camera
    // file without it (a global shutter) leaves the distortion in every measurement.
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    let cfg = SynthConfig {
        camera: CameraConfig {
            camera: PinholeCamera::new(258.65, 258.23, 159.3, 127.6, 320, 240).unwrap(),
            depth_scale: 5000.0,
            rolling_shutter_s: 0.03,
            exposure_s: 0.0,
        },
        frames: 60,
        motion: MotionConfig {
            gait: Gait::Tripod,
            speed_m_s: 0.15,
            ..MotionConfig::default()
        },
        ..SynthConfig::default()
    };
    generate(&cfg, &seq, true, &mut |_, _| {}).unwrap();
    let global = tmp.path().join("global.json");
    let camera = CameraConfig {
        rolling_shutter_s: 0.0,
        ..cfg.camera
    };
    std::fs::write(&global, camera.to_json()).unwrap();
    let ate_with = |camera: Option<&Path>| {
        let out = tmp.path().join(format!("out{}", camera.is_some()));
        let mut args = vec!["run", "--dataset", seq.to_str().unwrap()];
        args.extend(["--out", out.to_str().unwrap(), "--vo-only"]);
        if let Some(c) = camera {
            args.extend(["--camera", c.to_str().unwrap()]);
        }
        run_ok(&args);
        num(&report(&out)["ate"], "rmse")
    };
    let (corrected, uncorrected) = (ate_with(None), ate_with(Some(&global)));
    eprintln!("rolling shutter: ATE {corrected} m corrected, {uncorrected} m not");
    assert!(
        corrected < 0.8 * uncorrected,
        "ATE {corrected} m with the readout, {uncorrected} m without"
    );
}
