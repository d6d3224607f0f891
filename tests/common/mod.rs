//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A path inside the shared data (`$STRIDE_DATA` or `../shared/data`). Missing data fails the
/// test under `CI=true` and skips it (returns `None`) elsewhere.
pub fn data(relative: &str) -> Option<PathBuf> {
    let root = match std::env::var_os("STRIDE_DATA") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")),
    };
    match Some(root.join(relative)).filter(|p| p.exists()) {
        Some(p) => Some(p),
        None => {
            let ci = std::env::var("CI")
                .map(|v| v == "true" || v == "1")
                .unwrap_or(false);
            assert!(
                !ci,
                "shared data '{relative}' is missing (looked in $STRIDE_DATA or ../shared/data); \
                 under CI=true this is a failure"
            );
            eprintln!("SKIP: shared data '{relative}' not found");
            None
        }
    }
}

/// A TUM folder in `dst` with the lines of `src`'s rgb.txt whose (0-based, comments
/// excluded) index passes `keep`; depth.txt and the ground truth whole, images linked, not
/// copied: what `../shared/tools/seqtools.py subsample` and `range` make.
pub fn derived(src: &std::path::Path, dst: &std::path::Path, keep: impl Fn(usize) -> bool) {
    std::fs::create_dir_all(dst).unwrap();
    let rgb = std::fs::read_to_string(src.join("rgb.txt")).unwrap();
    let kept: String = rgb
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    std::fs::write(dst.join("rgb.txt"), kept).unwrap();
    for f in ["depth.txt", "groundtruth.txt"] {
        std::fs::copy(src.join(f), dst.join(f)).unwrap();
    }
    for d in ["rgb", "depth"] {
        std::os::unix::fs::symlink(src.join(d), dst.join(d)).unwrap();
    }
}

/// A quarter-VGA camera (320x240, TUM fr1's intrinsics halved) for synthetic sequences
/// that must render fast, with a colour readout of `rolling_shutter_s` (s).
pub fn quarter_vga(rolling_shutter_s: f64) -> stride_datasets::camera_config::CameraConfig {
    stride_datasets::camera_config::CameraConfig {
        camera: stride_core::camera::PinholeCamera::new(258.65, 258.23, 159.3, 127.6, 320, 240)
            .unwrap(),
        depth_scale: 5000.0,
        rolling_shutter_s,
        exposure_s: 0.0,
    }
}

/// The shared fr1/xyz trajectory pair (ground truth, RGB-D SLAM's estimate), as [`data`]
/// finds them.
pub fn xyz_pair() -> Option<(PathBuf, PathBuf)> {
    Some((
        data("trajectories/freiburg1_xyz-groundtruth.txt")?,
        data("trajectories/freiburg1_xyz-rgbdslam.txt")?,
    ))
}

/// The `stride` binary built for these tests.
pub fn stride() -> Command {
    Command::new(env!("CARGO_BIN_EXE_stride"))
}

/// Runs `stride` with arguments and returns its output.
pub fn run(args: &[&str]) -> Output {
    stride().args(args).output().expect("stride runs")
}

/// Runs `stride` with arguments, fails the test unless it succeeded without a panic, and
/// returns its stderr.
pub fn run_ok(args: &[&str]) -> String {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "stride {args:?} failed: {err}");
    assert!(!err.contains("panicked"));
    err
}

/// Runs `stride COMMAND --dataset DATASET --out OUT -q EXTRA...`, fails the test unless it
/// succeeded, and returns the report.json it wrote.
pub fn run_report(
    command: &str,
    dataset: &std::path::Path,
    out: &std::path::Path,
    extra: &[&str],
) -> serde_json::Value {
    run_logged(command, dataset, out, extra).0
}

/// [`run_report`], with the warnings and errors the command wrote on stderr.
pub fn run_logged(
    command: &str,
    dataset: &std::path::Path,
    out: &std::path::Path,
    extra: &[&str],
) -> (serde_json::Value, String) {
    let (d, o) = (dataset.display().to_string(), out.display().to_string());
    let mut args = vec![command, "--dataset", &d, "--out", &o, "-q"];
    args.extend_from_slice(extra);
    let err = run_ok(&args);
    (report(out), err)
}

/// The report.json a command wrote into `dir`.
pub fn report(dir: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("report.json")).expect("report.json is written");
    serde_json::from_str(&text).expect("report.json is JSON")
}

/// Runs `stride ... --json` and parses the single JSON object it prints.
pub fn run_json(args: &[&str]) -> serde_json::Value {
    let out = run(args);
    assert!(
        out.status.success(),
        "stride {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("utf-8");
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let line = lines.next().expect("one line of JSON");
    assert!(
        lines.next().is_none(),
        "more than one line on stdout: {text}"
    );
    serde_json::from_str(line).expect("valid JSON")
}

/// A number from a JSON object.
pub fn num(v: &serde_json::Value, key: &str) -> f64 {
    v.get(key)
        .and_then(|x| x.as_f64())
        .unwrap_or_else(|| panic!("no number '{key}' in {v}"))
}

/// The python of a venv with evo: `$STRIDE_EVO_PYTHON`, else the peers venv of
/// ../shared/tools/peers/README.md if it exists. `None` when evo is not installed.
pub fn evo_python() -> Option<PathBuf> {
    venv_with("evo", "STRIDE_EVO_PYTHON")
}

/// The python of a venv with pyoctomap (`$STRIDE_OCTOMAP_PYTHON`, else the peers venv).
/// Missing, it fails the test under `CI=true` and skips it (`None`) elsewhere.
pub fn octomap_python() -> Option<PathBuf> {
    let found = venv_with("pyoctomap", "STRIDE_OCTOMAP_PYTHON");
    if found.is_none() {
        missing_peer("pyoctomap ($STRIDE_OCTOMAP_PYTHON or /tmp/peers-venv)");
    }
    found
}

/// The python of a venv with the `mcap` and `mcap-ros2-support` packages
/// (`$STRIDE_MCAP_PYTHON`, else the peers venv). Missing, it fails the test under `CI=true`
/// and skips it (`None`) elsewhere.
pub fn mcap_python() -> Option<PathBuf> {
    let found = venv_with("mcap_ros2", "STRIDE_MCAP_PYTHON");
    if found.is_none() {
        missing_peer("mcap and mcap-ros2-support ($STRIDE_MCAP_PYTHON or /tmp/peers-venv)");
    }
    found
}

/// A peer tool the test needs is not installed: a failure under `CI=true`, a skip (with a
/// note on stderr) elsewhere.
pub fn missing_peer(what: &str) {
    let ci = std::env::var("CI").is_ok_and(|v| v == "true" || v == "1");
    assert!(
        !ci,
        "{what} is not installed; under CI=true this is a failure"
    );
    eprintln!("SKIP: {what} is not installed");
}

/// `$env_var`, else the peers venv's python if it can import `module`.
fn venv_with(module: &str, env_var: &str) -> Option<PathBuf> {
    if let Some(p) = std::env::var_os(env_var) {
        return Some(PathBuf::from(p));
    }
    let venv = PathBuf::from("/tmp/peers-venv/bin/python");
    let ok = venv.is_file()
        && Command::new(&venv)
            .args(["-c", &format!("import {module}")])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false);
    ok.then_some(venv)
}

/// A fresh temporary folder for one test.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("stride-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

pub fn data_lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(str::to_owned)
        .collect()
}

/// A TUM folder in `dst` that plays `src`'s colour frames in `order` (0-based indices,
/// comments excluded) at 15 Hz with fresh timestamps: each frame's depth image is the one
/// nearest it in time, and the ground truth the pose nearest it when one lies within
/// 0.02 s (TUM's association window; teddy's ground truth starts 0.14 s after its first
/// image, and a pose that late put the first frames 40-50 mm off), both written at the new
/// time. Paths are absolute: nothing is copied. A jump in `order` is a camera carried
/// elsewhere between two frames (the kidnapped robot).
pub fn reordered(src: &Path, dst: &Path, order: &[usize]) {
    let parse = |name: &str| -> Vec<(f64, String)> {
        data_lines(&src.join(name))
            .iter()
            .map(|l| {
                let (t, rest) = l.split_once(' ').unwrap();
                (t.parse().unwrap(), rest.to_owned())
            })
            .collect()
    };
    let (rgb, depth, gt) = (
        parse("rgb.txt"),
        parse("depth.txt"),
        parse("groundtruth.txt"),
    );
    let nearest = |list: &[(f64, String)], t: f64| {
        list.iter()
            .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
            .unwrap()
            .clone()
    };
    let t0 = rgb[0].0;
    let (mut r, mut d, mut g) = (String::new(), String::new(), String::new());
    for (k, &i) in order.iter().enumerate() {
        let (t, file) = &rgb[i];
        let tn = t0 + k as f64 / 15.0;
        r += &format!("{tn:.6} {}\n", src.join(file).display());
        d += &format!("{tn:.6} {}\n", src.join(nearest(&depth, *t).1).display());
        let (t_gt, pose) = nearest(&gt, *t);
        if (t_gt - t).abs() <= 0.02 {
            g += &format!("{tn:.6} {pose}\n");
        }
    }
    std::fs::create_dir_all(dst).unwrap();
    for (name, text) in [("rgb.txt", r), ("depth.txt", d), ("groundtruth.txt", g)] {
        std::fs::write(dst.join(name), text).unwrap();
    }
}
