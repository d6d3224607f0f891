//! Trajectory evaluation in CI: a suite's exit codes and outputs, and comparisons between
//! results (an injected drift is a regression; a baseline stored in the previous schema
//! still reads).

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, run};

/// Runs stride; returns its exit code, stdout and stderr.
fn exit(args: &[&str]) -> (Option<i32>, String, String) {
    let o = run(args);
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn a_suite_exits_0_when_within_its_limits_1_beyond_them_and_2_on_bad_input() {
    let Some((gt, est)) = common::xyz_pair() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let entry = |limit: f64| {
        format!(
            "[[entry]]\nname = \"xyz\"\ngt = \"{}\"\nest = \"{}\"\nmetric = \"ate\"\nalign = \"se3\"\nmax_rmse = {limit}\n",
            gt.display(),
            est.display()
        )
    };
    let file = |name: &str, text: &str| {
        let p = tmp.path().join(name);
        std::fs::write(&p, text).unwrap();
        p.display().to_string()
    };
    // RMSE 0.013470 m.
    let pass = file("pass.toml", &entry(0.02));
    let out = tmp.path().join("out");
    let (code, stdout, _) = exit(&["eval", "suite", &pass, "--out", out.to_str().unwrap()]);
    assert_eq!(code, Some(0));
    assert!(
        stdout.contains("1 of 1 entries passed") && stdout.contains("| xyz |"),
        "{stdout}"
    );
    for f in ["results.json", "summary.md", "junit.xml", "report.html"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let summary = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(
        summary.lines().count() < 10,
        "short enough for a pull request: {summary}"
    );
    let fail = file("fail.toml", &entry(0.01));
    let (code, stdout, stderr) = exit(&["eval", "suite", &fail]);
    assert_eq!(code, Some(1));
    assert!(stdout.contains("**FAIL**"), "{stdout}");
    assert!(
        stderr.contains("translation rmse 0.013470 m > max_rmse 0.01 m"),
        "{stderr}"
    );
    for (text, expected) in [
        (entry(0.02).replace("metric", "metrics"), "metrics"),
        (
            entry(0.02).replace("\"ate\"", "\"ape\""),
            "metric = \"ape\"",
        ),
        (entry(0.02).replace("se3", "se4"), "se4"),
        (entry(-1.0), "max_rmse"),
        (
            entry(0.02).replace(&est.display().to_string(), "/nonexistent/est.txt"),
            "/nonexistent/est.txt",
        ),
        (
            format!("{}{}", entry(0.02), entry(0.02)),
            "two entries are named 'xyz'",
        ),
        (String::new(), "entry"),
    ] {
        let bad = file("bad.toml", &text);
        let (code, _, stderr) = exit(&["eval", "suite", &bad]);
        assert_eq!(code, Some(2), "{text}: {stderr}");
        assert!(stderr.contains(expected), "{expected}: {stderr}");
    }
}

#[test]
fn compare_flags_an_injected_drift_and_reads_a_baseline_from_the_previous_schema() {
    let (Some(gt), Some(est), Some(drift)) = (
        data("trajectories/freiburg1_xyz-groundtruth.txt"),
        data("trajectories/freiburg1_xyz-rgbdslam.txt"),
        data("trajectories/freiburg1_xyz-rgbdslam_drift.txt"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let report = |est: &std::path::Path, name: &str| {
        let dir = tmp.path().join(name);
        let (code, _, stderr) = exit(&[
            "eval",
            "ate",
            gt.to_str().unwrap(),
            est.to_str().unwrap(),
            "--report",
            dir.to_str().unwrap(),
        ]);
        assert_eq!(code, Some(0), "{stderr}");
        dir.display().to_string()
    };
    let (base, new) = (report(&est, "base"), report(&drift, "drift"));
    let (code, stdout, stderr) =
        exit(&["eval", "compare", &base, &new, "--fail-on-regression", "10"]);
    assert_eq!(code, Some(1), "{stdout}{stderr}");
    assert!(stdout.contains("**regression**"), "{stdout}");
    assert!(stderr.contains("ATE rmse 0.020079 -> 0.134185"), "{stderr}");
    // Without --fail-on-regression the table is printed and the exit code is 0.
    let (code, _, _) = exit(&["eval", "compare", &base, &new]);
    assert_eq!(code, Some(0));
    // A baseline written before result files carried a schema version: the same numbers
    // as today's result, so nothing regressed.
    let v0 = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/eval_v0");
    let out = tmp.path().join("cmp");
    let (code, stdout, stderr) = exit(&[
        "eval",
        "compare",
        v0,
        &base,
        "--fail-on-regression",
        "0.001",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert!(
        stdout.contains("| result | ATE | rmse | 0.020079 | 0.020079 |"),
        "{stdout}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("compare.json")).unwrap()).unwrap();
    assert_eq!(json["rows"].as_array().unwrap().len(), 6);
    // A file that is not a stride result, and a newer schema, are refused (exit code 2).
    let not = tmp.path().join("not.json");
    std::fs::write(&not, "{\"hello\": 1}").unwrap();
    let (code, _, stderr) = exit(&["eval", "compare", not.to_str().unwrap(), &base]);
    assert_eq!(code, Some(2));
    assert!(stderr.contains("not a stride eval result"), "{stderr}");
    let newer = tmp.path().join("newer.json");
    std::fs::write(
        &newer,
        "{\"schema\": \"stride-eval-result\", \"schema_version\": 99, \"rmse\": 1.0}",
    )
    .unwrap();
    let (code, _, stderr) = exit(&["eval", "compare", newer.to_str().unwrap(), &base]);
    assert_eq!(code, Some(2));
    assert!(stderr.contains("newer"), "{stderr}");
}
