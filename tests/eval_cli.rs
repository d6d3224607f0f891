//! `stride eval` end to end: the reference figures of evo 1.38.1 and the TUM tools on real
//! trajectories (../shared/data/README.md), the output formats, and bad input.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, num, run, run_json};
use std::path::{Path, PathBuf};

/// Agreement demanded with the reference tools (metres, degrees).
const TOL: f64 = 1e-6;

fn traj(name: &str) -> Option<String> {
    data(&format!("trajectories/{name}")).map(|p| p.display().to_string())
}

fn close(v: &serde_json::Value, key: &str, expected: f64) {
    let got = num(v, key);
    assert!(
        (got - expected).abs() <= TOL,
        "{key}: got {got}, expected {expected}"
    );
}

#[test]
fn evo_preset_reproduces_evo_on_fr1_xyz() {
    let (Some(gt), Some(est), Some(mono)) = (
        traj("freiburg1_xyz-groundtruth.txt"),
        traj("freiburg1_xyz-rgbdslam.txt"),
        traj("freiburg1_xyz-ORB_kf_mono.txt"),
    ) else {
        return;
    };
    let a = run_json(&[
        "eval", "ate", "--gt", &gt, "--est", &est, "--preset", "evo", "--align", "se3", "--json",
    ]);
    assert_eq!(a["count"], 785);
    // evo_ape tum GT EST -a (evo 1.38.1), every statistic as evo prints it.
    for (k, v) in [
        ("rmse", 0.013470),
        ("mean", 0.012024),
        ("median", 0.011183),
        ("std", 0.006071),
        ("min", 0.000955),
        ("max", 0.034760),
        ("sse", 0.142433),
    ] {
        close(&a, k, v);
    }
    assert_eq!(a["align"], "se3");
    assert_eq!(a["preset"], "evo");
    let r = run_json(&[
        "eval",
        "rpe",
        "--gt",
        &gt,
        "--est",
        &est,
        "--delta",
        "1",
        "--delta-unit",
        "frames",
        "--json",
    ]);
    for (k, v) in [
        ("rmse", 0.005764),
        ("mean", 0.004816),
        ("median", 0.004139),
        ("std", 0.003168),
        ("min", 0.000171),
        ("max", 0.020866),
        ("sse", 0.026051),
    ] {
        close(&r, k, v);
    }
    assert_eq!(r["count"], 784);
    let s = run_json(&[
        "eval", "ate", "--gt", &gt, "--est", &mono, "--align", "sim3", "--json",
    ]);
    close(&s, "rmse", 0.009755);
    assert_eq!(s["count"], 32);
}

#[test]
fn tum_preset_reproduces_the_tum_scripts_on_fr1_xyz() {
    let (Some(gt), Some(est)) = (
        traj("freiburg1_xyz-groundtruth.txt"),
        traj("freiburg1_xyz-rgbdslam.txt"),
    ) else {
        return;
    };
    // evaluate_ate.py: 786 pairs, rmse 0.013473 (mean 0.012029, median 0.011176, std
    // 0.006068, min 0.000939, max 0.034727).
    let a = run_json(&[
        "eval", "ate", "--gt", &gt, "--est", &est, "--preset", "tum", "--json",
    ]);
    assert_eq!(a["count"], 786);
    assert_eq!(a["align"], "se3", "the TUM tool always aligns");
    for (k, v) in [
        ("rmse", 0.013473),
        ("mean", 0.012029),
        ("median", 0.011176),
        ("std", 0.006068),
        ("min", 0.000939),
        ("max", 0.034727),
    ] {
        close(&a, k, v);
    }
    // evaluate_rpe.py --fixed_delta --delta 1 --delta_unit s: 753 pairs, translation rmse
    // 0.021217 m, rotation rmse 0.934480 deg.
    let r = run_json(&[
        "eval", "rpe", "--gt", &gt, "--est", &est, "--preset", "tum", "--json",
    ]);
    assert_eq!(r["count"], 753);
    assert_eq!(r["unit"], "seconds");
    close(&r, "rmse", 0.021217);
    close(&r, "rot_deg_rmse", 0.934480);
}

#[test]
fn json_has_the_documented_keys() {
    let (Some(gt), Some(est)) = (
        traj("freiburg1_xyz-groundtruth.txt"),
        traj("freiburg1_xyz-rgbdslam_drift.txt"),
    ) else {
        return;
    };
    let a = run_json(&["eval", "ate", "--gt", &gt, "--est", &est, "--json"]);
    for k in [
        "rmse", "mean", "median", "std", "min", "max", "sse", "count", "align", "preset",
    ] {
        assert!(a.get(k).is_some(), "ATE JSON lacks '{k}': {a}");
    }
    assert_eq!(a["align"], "none", "evo aligns only when asked");
    let r = run_json(&[
        "eval",
        "rpe",
        "--gt",
        &gt,
        "--est",
        &est,
        "--delta",
        "0.5",
        "--delta-unit",
        "metres",
        "--json",
    ]);
    for k in [
        "rmse",
        "mean",
        "median",
        "std",
        "min",
        "max",
        "sse",
        "count",
        "align",
        "preset",
        "delta",
        "unit",
        "rot_deg_rmse",
        "rot_deg_mean",
        "rot_deg_median",
        "rot_deg_std",
        "rot_deg_min",
        "rot_deg_max",
    ] {
        assert!(r.get(k).is_some(), "RPE JSON lacks '{k}': {r}");
    }
    assert_eq!(r["unit"], "metres");
}

#[test]
fn table_plot_and_report_are_written() {
    let (Some(gt), Some(est)) = (
        traj("freiburg1_xyz-groundtruth.txt"),
        traj("freiburg1_xyz-rgbdslam.txt"),
    ) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("ate.svg");
    let rep = dir.path().join("report");
    let out = run(&[
        "eval",
        "ate",
        "--gt",
        &gt,
        "--est",
        &est,
        "--align",
        "se3",
        "--plot",
        svg.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8(out.stdout).unwrap();
    assert!(
        table.contains("rmse") && table.contains("0.013470"),
        "{table}"
    );
    let svg_text = std::fs::read_to_string(&svg).unwrap();
    assert!(svg_text.starts_with("<svg") && svg_text.contains("ATE over time"));
    for f in ["report.md", "report.html", "report.json", "ate.svg"] {
        assert!(rep.join(f).is_file(), "missing {f}");
    }
    let html = std::fs::read_to_string(rep.join("report.html")).unwrap();
    assert!(
        html.contains("<svg") && html.contains("0.013470"),
        "the HTML is self-contained"
    );
    let rpe_svg = dir.path().join("rpe.svg");
    let out = run(&[
        "eval",
        "rpe",
        "--gt",
        &gt,
        "--est",
        &est,
        "--plot",
        rpe_svg.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    assert!(std::fs::read_to_string(&rpe_svg)
        .unwrap()
        .contains("RPE rotation"));
}

// --- bad input -----------------------------------------------------------------------------

const GOOD: &str = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n4.0 0 1 1 0 0 0 1\n";

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Runs `eval ate` on GOOD vs `text`; returns (success, stderr).
fn ate_on(text: &str, extra: &[&str]) -> (bool, String, PathBuf) {
    let dir = tempfile::tempdir().unwrap().keep();
    let gt = write(&dir, "gt.txt", GOOD);
    let est = write(&dir, "est.txt", text);
    let mut args = vec![
        "eval",
        "ate",
        "--gt",
        gt.to_str().unwrap(),
        "--est",
        est.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = run(&args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!err.contains("panicked"), "stride panicked: {err}");
    (out.status.success(), err, est)
}

fn fails_naming(text: &str, needle: &str) {
    let (ok, err, est) = ate_on(text, &[]);
    assert!(!ok, "should fail on {text:?}");
    let expected = format!("{}{needle}", est.display());
    assert!(err.contains(&expected), "expected '{expected}' in: {err}");
}

#[test]
fn bad_lines_fail_with_file_and_line() {
    fails_naming(
        "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n",
        ":2: expected 8 fields",
    );
    fails_naming("1.0 0 0 abc 0 0 0 1\n", ":1: tz 'abc' is not a number");
    fails_naming("# c\n1.0 0 0 NaN 0 0 0 1\n", ":2: tz is NaN");
    fails_naming("1.0 inf 0 0 0 0 0 1\n", ":1: tx is inf");
    fails_naming(
        "1.0 0 0 0 0 0 0 0\n",
        ":1: quaternion (qx qy qz qw) has norm 0",
    );
    fails_naming(
        "2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n",
        ":2: timestamp 1.000000 is earlier than 2.000000 on line 1",
    );
    fails_naming("", ": no poses");
    fails_naming("# header only\n", ": no poses");
}

#[test]
fn duplicate_timestamps_are_accepted_with_a_warning_naming_both_lines() {
    let text = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n2.0 1 0.1 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n";
    let (ok, err, est) = ate_on(text, &[]);
    assert!(ok, "{err}");
    let expected = format!("{}: lines 2 and 3 have the same timestamp", est.display());
    assert!(err.contains(&expected), "expected '{expected}' in: {err}");
    // The TUM preset keeps the last of the two lines, as the TUM scripts' dictionary does.
    let (ok, err, _) = ate_on(text, &["--preset", "tum"]);
    assert!(ok, "{err}");
}

#[test]
fn non_unit_quaternion_is_normalised_with_a_warning() {
    let text = "1.0 0 0 0 0 0 0 2\n2.0 1 0 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n4.0 0 1 1 0 0 0 1\n";
    let (ok, err, est) = ate_on(text, &[]);
    assert!(ok, "{err}");
    assert!(
        err.contains(&format!("{}:1: quaternion norm is 2.000000", est.display())),
        "{err}"
    );
}

#[test]
fn missing_file_and_no_overlap_and_degenerate_alignment() {
    let out = run(&[
        "eval",
        "ate",
        "--gt",
        "/nonexistent/gt.txt",
        "--est",
        "/nonexistent/est.txt",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/nonexistent/gt.txt") && err.contains("ground truth"),
        "{err}"
    );

    let (ok, err, _) = ate_on("100.0 0 0 0 0 0 0 1\n101.0 1 0 0 0 0 0 1\n", &[]);
    assert!(!ok);
    assert!(
        err.contains("only 0 pose pair(s) associated within 0.01 s")
            && err.contains("1.000..4.000 s"),
        "{err}"
    );

    // Collinear positions: evo refuses SE(3) alignment, as evo does.
    let line = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 2 0 0 0 0 0 1\n4.0 3 0 0 0 0 0 1\n";
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.txt", line);
    let est = write(dir.path(), "est.txt", line);
    let args = |preset: &'static str| {
        vec![
            "eval".to_owned(),
            "ate".into(),
            "--gt".into(),
            gt.display().to_string(),
            "--est".into(),
            est.display().to_string(),
            "--preset".into(),
            preset.into(),
            "--align".into(),
            "se3".into(),
            "--json".into(),
        ]
    };
    let out = common::stride().args(args("evo")).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("se3 alignment is degenerate") && err.contains("--align origin"),
        "{err}"
    );
    // The TUM preset aligns anyway (as its tool) and warns.
    let out = common::stride().args(args("tum")).output().unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("degenerate"));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(num(&v, "rmse") < 1e-9);
}

#[test]
fn bad_options_fail_cleanly() {
    let (ok, err, _) = ate_on(GOOD, &["--align", "affine"]);
    assert!(!ok && err.contains("unknown alignment 'affine'"), "{err}");
    let (ok, err, _) = ate_on(GOOD, &["--t-max-diff", "-1"]);
    assert!(!ok && err.contains("--t-max-diff"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let gt = write(dir.path(), "gt.txt", GOOD);
    for extra in [
        vec!["--delta", "0"],
        vec!["--delta", "1.5"],
        vec!["--preset", "tum", "--all-pairs"],
        vec!["--delta", "50"],
    ] {
        let mut args = vec![
            "eval",
            "rpe",
            "--gt",
            gt.to_str().unwrap(),
            "--est",
            gt.to_str().unwrap(),
        ];
        args.extend(extra.iter());
        let out = run(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.starts_with("error: "),
            "{extra:?}: {err}"
        );
        assert!(!err.contains("panicked"));
    }
}

#[test]
fn limits_set_the_exit_code() {
    // evo's figures for this pair: ATE (SE(3)) rmse 0.013470 m; RPE rmse 0.005764 m.
    // 0 within the limits, 1 beyond one (with the statistic, its value and the limit on
    // stderr, the results still printed), 2 for bad input.
    let (Some(gt), Some(est)) = (
        traj("freiburg1_xyz-groundtruth.txt"),
        traj("freiburg1_xyz-rgbdslam.txt"),
    ) else {
        return;
    };
    let code = |extra: &[&str]| {
        let mut args = vec!["eval", "ate", &gt, &est, "--align", "se3"];
        args.extend_from_slice(extra);
        let out = run(&args);
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (c, stdout, _) = code(&["--max-rmse", "0.0135", "--max-mean", "0.013"]);
    assert_eq!(c, Some(0));
    assert!(stdout.contains("rmse"), "{stdout}");
    let (c, stdout, stderr) = code(&["--max-rmse", "0.0134"]);
    assert_eq!(c, Some(1), "{stderr}");
    assert!(stdout.contains("0.013470"), "results are printed: {stdout}");
    assert!(
        stderr.contains("ATE translation rmse 0.013470 m > --max-rmse 0.0134 m"),
        "{stderr}"
    );
    let (c, _, stderr) = code(&["--max-rot-deg", "0.5"]);
    assert!(c == Some(1) && stderr.contains("rotation rmse"), "{stderr}");
    let (c, _, stderr) = code(&["--max-rmse", "-1"]);
    assert!(c == Some(2) && stderr.contains("--max-rmse -1"), "{stderr}");
    let out = run(&[
        "eval",
        "ate",
        &gt,
        "/nonexistent/est.txt",
        "--max-rmse",
        "1",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let out = run(&["eval", "rpe", &gt, &est, "--max-rmse", "0.005"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.code() == Some(1) && stderr.contains("RPE translation rmse 0.005764"),
        "{stderr}"
    );
}
