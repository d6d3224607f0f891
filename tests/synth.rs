//! The synthetic legged-robot generator: depth against known geometry and the noise model,
//! blur against gait and speed, its output loading unchanged in the readers, bad parameters,
//! and determinism. Small images (320x240) keep these tests fast; the physics do not depend
//! on the resolution.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use nalgebra::Vector3;
use stride_core::camera::PinholeCamera;
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::grid_file::read_grid;
use stride_datasets::synth::motion::{Gait, MotionConfig};
use stride_datasets::synth::{generate, Synth, SynthConfig, TerrainSource};
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_eval::blur::{correlation, dominant_frequency_hz, laplacian_variance};

fn small_camera() -> CameraConfig {
    CameraConfig {
        camera: PinholeCamera::new(258.65, 258.23, 159.3, 127.6, 320, 240).unwrap(),
        depth_scale: 5000.0,
        rolling_shutter_s: 0.02,
        exposure_s: 0.0,
    }
}

fn config(frames: usize) -> SynthConfig {
    SynthConfig {
        frames,
        camera: small_camera(),
        ..SynthConfig::default()
    }
}

#[test]
fn depth_matches_the_geometry_within_the_noise_model() {
    // Flat floor (z = 0) with low boxes, no objects: the floor depth is known analytically.
    // The random part of the model is checked here; misregistration and the static bias
    // are switched off for this comparison and checked below.
    let mut depth_noise = SynthConfig::default().depth_noise;
    depth_noise.registration_offset_px = [0.0, 0.0];
    depth_noise.bias_radial = 0.0;
    depth_noise.bias_field = 0.0;
    let cfg = SynthConfig {
        terrain: TerrainSource::Procedural {
            name: "boxes".into(),
            resolution_m: 0.01,
        },
        objects: 0,
        depth_noise,
        ..config(1)
    };
    let synth = Synth::new(cfg.clone()).unwrap();
    let renderer = synth.renderer();
    let frame = synth.render_frame(&renderer, 0);
    let pose = frame.info.world_from_camera;
    let cam = *synth.camera();
    let gt = synth.ground_truth_elevation();
    let noise = cfg.depth_noise;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let o = pose.translation.vector;
    let (mut floor_px, mut exact) = (0usize, 0usize);
    let mut residuals = Vec::new();
    for v in 2..h - 2 {
        for u in 2..w - 2 {
            let d = pose.rotation
                * Vector3::new(
                    (u as f64 - cam.cx()) / cam.fx(),
                    (v as f64 - cam.cy()) / cam.fy(),
                    1.0,
                );
            if d.z >= -1e-6 {
                continue;
            }
            let s = -o.z / d.z; // d has unit camera-z: s is the z-depth of the floor point
            let (x, y) = (o.x + s * d.x, o.y + s * d.y);
            // Only floor points whose neighbourhood is flat and which nothing occludes.
            let flat = (-3..=3).all(|k| {
                (-3..=3).all(|l| gt.at(x + 0.01 * k as f64, y + 0.01 * l as f64) == Some(0.0))
            });
            if !flat || s > 4.0 {
                continue;
            }
            let i = v * w + u;
            let z_true = f64::from(frame.depth_true_m[i]);
            if (z_true - s).abs() > 0.05 {
                continue; // occluded by a box on the way
            }
            floor_px += 1;
            exact += usize::from((z_true - s).abs() < 1e-3);
            // Edge-free pixels: compare the sensor's depth with the noise model.
            let neighbours = [i - 1, i + 1, i - w, i + w];
            let edge = neighbours.iter().any(|&j| {
                (f64::from(frame.depth_true_m[j]) - z_true).abs() > noise.edge_rel * z_true
            });
            let raw = frame.depth_raw.as_slice()[i];
            if edge || raw == 0 {
                continue;
            }
            let z = f64::from(raw) / 5000.0;
            let quant = z * z / (noise.disparity_bf_px_m * noise.disparity_subpixel);
            let sigma = ((noise.sigma_coeff_per_m * z_true * z_true).powi(2)
                + quant * quant / 12.0
                + 1e-4f64.powi(2) / 12.0)
                .sqrt();
            residuals.push((z - z_true) / sigma);
        }
    }
    assert!(floor_px > 20_000, "too few floor pixels ({floor_px})");
    assert!(
        exact as f64 > 0.99 * floor_px as f64,
        "ray casting: {exact} of {floor_px} floor pixels within 1 mm"
    );
    let n = residuals.len() as f64;
    assert!(n > 0.8 * floor_px as f64, "{n} valid of {floor_px}");
    let mean = residuals.iter().sum::<f64>() / n;
    let std = (residuals.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n).sqrt();
    let within2 = residuals.iter().filter(|r| r.abs() < 2.0).count() as f64 / n;
    let within4 = residuals.iter().filter(|r| r.abs() < 4.0).count() as f64 / n;
    assert!(mean.abs() < 0.15, "bias {mean} sigma");
    assert!((0.8..1.25).contains(&std), "spread {std} sigma");
    assert!(
        within2 > 0.9 && within4 > 0.995,
        "{within2} within 2 sigma, {within4} within 4"
    );
    // No return outside the working range.
    for &raw in frame.depth_raw.as_slice() {
        assert!(raw == 0 || (2250..=22500).contains(&raw), "{raw}");
    }
    // With the default static bias, depth at the image corners reads long by about
    // bias_radial (plus the smooth field), at the centre by about nothing.
    let biased = Synth::new(SynthConfig {
        depth_noise: SynthConfig::default().depth_noise,
        ..cfg
    })
    .unwrap();
    let f2 = biased.render_frame(&biased.renderer(), 0);
    let rel = |u0: usize, v0: usize| {
        let mut r = Vec::new();
        for v in v0..v0 + 20 {
            for u in u0..u0 + 20 {
                let (raw, t) = (
                    f2.depth_raw.as_slice()[v * w + u],
                    f64::from(f2.depth_true_m[v * w + u]),
                );
                if raw > 0 && t > 0.0 {
                    r.push(f64::from(raw) / 5000.0 / t - 1.0);
                }
            }
        }
        r.sort_by(f64::total_cmp);
        r[r.len() / 2]
    };
    let (centre, corner) = (rel(w / 2 - 10, h / 2 - 10), rel(w - 22, h - 22));
    assert!(
        corner - centre > 0.0005 && corner - centre < 0.01,
        "relative bias centre {centre}, corner {corner}"
    );
}

fn sharpness_series(cfg: SynthConfig) -> (Vec<f64>, Vec<f64>, f64) {
    let synth = Synth::new(cfg).unwrap();
    let r = synth.renderer();
    let (mut sharp, mut motion) = (Vec::new(), Vec::new());
    for i in 0..synth.config().frames {
        let f = synth.render_frame(&r, i);
        sharp.push(laplacian_variance(&f.rgb.to_gray()));
        motion.push(f.info.image_motion_px);
    }
    (sharp, motion, synth.motion().step_hz())
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

#[test]
fn fast_tripod_blurs_more_than_slow_crawl_and_blur_follows_the_gait() {
    let frames = 60; // 2 s at 30 Hz
    let fast = config(frames);
    let fast = SynthConfig {
        motion: MotionConfig {
            gait: Gait::Tripod,
            speed_m_s: 0.15,
            ..fast.motion
        },
        ..fast
    };
    let slow = config(frames);
    let slow = SynthConfig {
        motion: MotionConfig {
            gait: Gait::Crawl,
            speed_m_s: 0.05,
            ..slow.motion
        },
        ..slow
    };
    let (s_fast, m_fast, step_hz) = sharpness_series(fast);
    let (s_slow, m_slow, _) = sharpness_series(slow);
    // Clearly more blur: image motion at least 2.5 times larger, sharpness clearly lower.
    assert!(
        median(&m_fast) > 2.5 * median(&m_slow),
        "image motion {} vs {} px",
        median(&m_fast),
        median(&m_slow)
    );
    assert!(
        median(&s_fast) < 0.75 * median(&s_slow),
        "sharpness {} vs {}",
        median(&s_fast),
        median(&s_slow)
    );
    // The blur rises and falls with the gait: sharpness follows the true image motion, and its
    // strongest frequency is the step frequency or its first harmonic (blur depends on the
    // speed's magnitude, which peaks twice per oscillation).
    let c = correlation(&s_fast, &m_fast).unwrap();
    assert!(c < -0.5, "correlation of sharpness with image motion: {c}");
    let f = dominant_frequency_hz(&s_fast, 30.0, 0.0).unwrap();
    let bin = 30.0 / frames as f64;
    assert!(
        (f - step_hz).abs() <= bin || (f - 2.0 * step_hz).abs() <= bin,
        "dominant frequency {f} Hz, steps at {step_hz} Hz (bin {bin} Hz)"
    );
}

#[test]
fn output_loads_unchanged_in_the_readers_and_is_deterministic() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let cfg = SynthConfig {
        camera: CameraConfig {
            camera: PinholeCamera::new(129.3, 129.1, 79.3, 59.8, 160, 120).unwrap(),
            depth_scale: 5000.0,
            rolling_shutter_s: 0.02,
            exposure_s: 0.0,
        },
        frames: 6,
        ..SynthConfig::default()
    };
    let summary = generate(&cfg, &a, false, &mut |_, _| {}).unwrap();
    generate(&cfg, &b, false, &mut |_, _| {}).unwrap();
    // Deterministic: every file identical.
    let mut files: Vec<_> = walk(&a);
    files.sort();
    assert!(files.len() >= 6 * 2 + 8, "{files:?}");
    for f in &files {
        let rel = f.strip_prefix(&a).unwrap();
        assert!(
            std::fs::read(f).unwrap() == std::fs::read(b.join(rel)).unwrap(),
            "{} differs between two runs",
            rel.display()
        );
    }
    // The TUM reader opens it unchanged, with its camera.json.
    let seq = TumSequence::open(&a, None, AssociationOptions::default()).unwrap();
    assert_eq!(seq.len(), 6);
    assert_eq!(seq.camera.camera.width(), 160);
    let frame = seq.load_frame(3).unwrap();
    assert!(
        frame
            .depth_m
            .as_slice()
            .iter()
            .filter(|&&z| z > 0.0)
            .count()
            > 160 * 120 / 2
    );
    let gt = read_tum_trajectory(&a.join("groundtruth.txt")).unwrap();
    assert_eq!(gt.len(), 6);
    assert_eq!(seq.groundtruth.as_ref().unwrap(), &gt);
    assert!(
        (gt.poses()[0].translation.vector - summary.groundtruth.poses()[0].translation.vector)
            .norm()
            < 1e-8
    );
    // The ground-truth terrain is a grid the mapper reads.
    let terrain = read_grid(&a.join("terrain.npy"), None).unwrap();
    assert!(terrain.geometry.resolution > 0.0 && terrain.at(0.0, 0.0).is_some());
    // stride eval takes the ground truth as is.
    let gt_path = a.join("groundtruth.txt");
    let v = common::run_json(&[
        "eval",
        "ate",
        "--gt",
        gt_path.to_str().unwrap(),
        "--est",
        gt_path.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(v["count"], 6);
    assert!(common::num(&v, "rmse") < 1e-9);
    // frames.csv has one row per frame with gait phase and stance legs.
    let csv = std::fs::read_to_string(a.join("frames.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7);
    assert!(csv.lines().skip(1).all(|l| {
        let legs: u8 = l.split(',').nth(3).unwrap().parse().unwrap();
        legs == 3 || legs == 6
    }));
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

#[test]
fn bad_parameters_get_clear_errors_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("seq");
    let o = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["--speed", "-0.1"], "speed -0.1 m/s"),
        (vec!["--frames", "0"], "frames must be at least 1"),
        (vec!["--fps", "1000"], "fps 1000"),
        (vec!["--fps", "0"], "fps 0"),
        (
            vec!["--terrain", "/nonexistent/terrain.png"],
            "/nonexistent/terrain.png",
        ),
        (
            vec!["--procedural", "lava"],
            "unknown procedural terrain 'lava'",
        ),
        (vec!["--exposure-ms", "100"], "exposure 0.1 s"),
    ] {
        let mut all = vec!["synth", "--out", o];
        all.extend(args.iter());
        let r = common::run(&all);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{args:?} should fail");
        assert!(
            err.contains(needle),
            "{args:?}: expected '{needle}' in {err}"
        );
        assert!(!err.contains("panicked"));
        assert!(!out.exists(), "{args:?} left output behind");
    }
    // An unreadable (non-PNG) terrain image names the file.
    let bad = tmp.path().join("terrain.png");
    std::fs::write(&bad, b"not a png").unwrap();
    let r = common::run(&[
        "synth",
        "--out",
        o,
        "--terrain",
        bad.to_str().unwrap(),
        "--frames",
        "1",
    ]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        !r.status.success() && err.contains("terrain.png: not a readable PNG"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn terrain_image_from_the_shared_data_renders() {
    let Some(img) = common::data("terrain/terrain.png") else {
        return;
    };
    let cfg = SynthConfig {
        terrain: TerrainSource::Image {
            path: img,
            height_scale_m: 0.2,
            resolution_m: 0.03,
        },
        ..config(1)
    };
    let synth = Synth::new(cfg).unwrap();
    let gt = synth.ground_truth_elevation();
    // 500 x 500 pixels at 3 cm: 15 m square; heights within [0, 0.2] m plus objects.
    assert_eq!((gt.geometry.rows, gt.geometry.cols), (500, 500));
    let f = synth.render_frame(&synth.renderer(), 0);
    let valid = f.depth_raw.as_slice().iter().filter(|&&z| z > 0).count();
    assert!(valid > 320 * 240 / 2, "{valid}");
}
