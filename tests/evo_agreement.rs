//! Runs evo (from a throwaway venv, never a project dependency) on the same files as stride
//! and compares every statistic. Skipped when evo is not installed, except under CI=true,
//! where that is a failure; `.ci/run` installs it.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, evo_python, run_json};
use std::process::Command;

fn evo_stats(args: &[&str]) -> serde_json::Value {
    let py = evo_python().expect("evo python");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/evo_stats.py");
    let out = Command::new(&py)
        .arg(script)
        .args(args)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "evo failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    serde_json::from_str(text.lines().last().unwrap()).unwrap()
}

fn compare(what: &str, ours: &serde_json::Value, evo: &serde_json::Value) {
    let evo_map = evo.as_object().unwrap();
    assert!(evo_map.len() >= 8, "{what}: evo gave {evo}");
    for (k, v) in evo_map {
        let e = v.as_f64().unwrap();
        let o = ours
            .get(k)
            .and_then(|x| x.as_f64())
            .unwrap_or_else(|| panic!("{what}: stride lacks '{k}'"));
        // 1e-6 absolute (metres or degrees); relative for large sums of squares.
        let tol = 1e-6 * e.abs().max(1.0);
        assert!((o - e).abs() <= tol, "{what}: {k} stride {o} vs evo {e}");
    }
}

/// Whether evo can run; a failure under CI=true when it cannot.
fn have_evo() -> bool {
    if evo_python().is_some() {
        return true;
    }
    common::missing_peer("evo (set STRIDE_EVO_PYTHON to a venv python with evo)");
    false
}

/// A copy of `src` with some lines followed by a duplicate of their timestamp holding
/// another pose (0.05 m away), as in some official TUM ground-truth files.
fn with_duplicates(src: &std::path::Path, dir: &std::path::Path, every: usize) -> String {
    let text = std::fs::read_to_string(src).unwrap();
    let mut out = String::new();
    let mut n = 0;
    for line in text.lines() {
        out.push_str(line);
        out.push('\n');
        if line.starts_with('#') || line.trim().is_empty() {
            continue;
        }
        n += 1;
        if n % every == 0 {
            let mut f: Vec<String> = line.split_whitespace().map(str::to_owned).collect();
            let x: f64 = f[1].parse().unwrap();
            f[1] = format!("{:.4}", x + 0.05);
            out.push_str(&f.join(" "));
            out.push('\n');
        }
    }
    let path = dir.join(src.file_name().unwrap());
    std::fs::write(&path, out).unwrap();
    path.display().to_string()
}

#[test]
fn duplicated_timestamps_give_evos_numbers() {
    if !have_evo() {
        return;
    }
    let Some((gt, est)) = common::xyz_pair() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (gt_dup, est_dup) = (
        with_duplicates(&gt, tmp.path(), 7),
        with_duplicates(&est, tmp.path(), 5),
    );
    let (gt, est) = (gt.display().to_string(), est.display().to_string());
    // In the ground truth (the longer one: evo searches it), in the estimate (the shorter
    // one: evo walks it, so both lines count), and in both.
    for (g, e) in [(&gt_dup, &est), (&gt, &est_dup), (&gt_dup, &est_dup)] {
        for align in ["se3", "none"] {
            let ours = run_json(&[
                "eval", "ate", "--gt", g, "--est", e, "--align", align, "--json",
            ]);
            let evo = evo_stats(&["ape", g, e, align, "0.01"]);
            compare(&format!("ATE {g} {e} {align}"), &ours, &evo);
        }
    }
}

#[test]
fn every_statistic_agrees_with_evo() {
    if !have_evo() {
        return;
    }
    let (Some(gt), Some(est), Some(drift), Some(mono)) = (
        data("trajectories/freiburg1_xyz-groundtruth.txt"),
        data("trajectories/freiburg1_xyz-rgbdslam.txt"),
        data("trajectories/freiburg1_xyz-rgbdslam_drift.txt"),
        data("trajectories/freiburg1_xyz-ORB_kf_mono.txt"),
    ) else {
        return;
    };
    let (gt, est, drift, mono) = (
        gt.display().to_string(),
        est.display().to_string(),
        drift.display().to_string(),
        mono.display().to_string(),
    );
    for (e, align) in [
        (&est, "se3"),
        (&est, "none"),
        (&est, "origin"),
        (&est, "sim3"),
        (&drift, "se3"),
        (&mono, "sim3"),
    ] {
        let ours = run_json(&[
            "eval", "ate", "--gt", &gt, "--est", e, "--align", align, "--json",
        ]);
        let evo = evo_stats(&["ape", &gt, e, align, "0.01"]);
        compare(&format!("ATE {e} {align}"), &ours, &evo);
    }
    for (e, delta, unit, all) in [
        (&est, "1", "f", "0"),
        (&est, "10", "f", "0"),
        (&est, "10", "f", "1"),
        (&drift, "0.1", "m", "0"),
        (&drift, "0.1", "m", "1"),
        (&drift, "1", "f", "0"),
    ] {
        let unit_name = if unit == "f" { "frames" } else { "metres" };
        let mut args = vec![
            "eval",
            "rpe",
            "--gt",
            &gt,
            "--est",
            e,
            "--delta",
            delta,
            "--delta-unit",
            unit_name,
            "--json",
        ];
        if all == "1" {
            args.push("--all-pairs");
        }
        let ours = run_json(&args);
        let evo = evo_stats(&["rpe", &gt, e, "none", "0.01", delta, unit, all]);
        compare(&format!("RPE {e} {delta}{unit} all={all}"), &ours, &evo);
    }
}

#[test]
fn a_suite_reproduces_evo_for_each_entry_and_its_junit_xml_parses() {
    if !have_evo() {
        return;
    }
    let (Some(gt), Some(est), Some(mono)) = (
        data("trajectories/freiburg1_xyz-groundtruth.txt"),
        data("trajectories/freiburg1_xyz-rgbdslam.txt"),
        data("trajectories/freiburg1_xyz-ORB_kf_mono.txt"),
    ) else {
        return;
    };
    let (gt, est, mono) = (
        gt.display().to_string(),
        est.display().to_string(),
        mono.display().to_string(),
    );
    let tmp = tempfile::tempdir().unwrap();
    let suite = tmp.path().join("suite.toml");
    std::fs::write(
        &suite,
        format!(
            "[[entry]]\nname = \"rgbdslam se3\"\ngt = \"{gt}\"\nest = \"{est}\"\nmetric = \"ate\"\nalign = \"se3\"\nmax_rmse = 0.02\n\n\
             [[entry]]\nname = \"orb mono sim3\"\ngt = \"{gt}\"\nest = \"{mono}\"\nmetric = \"ate\"\nalign = \"sim3\"\nmax_rmse = 0.005\n\n\
             [[entry]]\nname = \"rgbdslam rpe\"\ngt = \"{gt}\"\nest = \"{est}\"\nmetric = \"rpe\"\ndelta = 10\n"
        ),
    )
    .unwrap();
    let out = tmp.path().join("out");
    let o = common::run(&[
        "eval",
        "suite",
        suite.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    // The Sim(3) entry exceeds its limit (0.0098 m > 0.005 m): exit code 1, results written.
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(results["schema_version"], 1);
    let entries = results["entries"].as_array().unwrap();
    for (entry, evo_args) in entries.iter().zip([
        vec!["ape", &gt, &est, "se3", "0.01"],
        vec!["ape", &gt, &mono, "sim3", "0.01"],
        vec!["rpe", &gt, &est, "none", "0.01", "10", "f", "0"],
    ]) {
        let evo = evo_stats(&evo_args);
        compare(entry["name"].as_str().unwrap(), &entry["result"], &evo);
    }
    assert_eq!(
        entries
            .iter()
            .map(|e| e["passed"].as_bool().unwrap())
            .collect::<Vec<_>>(),
        [true, false, true]
    );
    // A reference JUnit parser (junitparser, in the same throwaway venv) reads the file:
    // one suite, three cases, the Sim(3) one failed.
    let py = evo_python().unwrap();
    let check = Command::new(&py)
        .args([
            "-c",
            "import sys, junitparser\n\
             x = junitparser.JUnitXml.fromfile(sys.argv[1])\n\
             suites = list(x)\n\
             assert len(suites) == 1, suites\n\
             cases = list(suites[0])\n\
             assert [c.name for c in cases] == ['rgbdslam se3', 'orb mono sim3', 'rgbdslam rpe'], cases\n\
             failed = [c.name for c in cases if any(isinstance(r, junitparser.Failure) for r in c.result)]\n\
             assert failed == ['orb mono sim3'], failed\n\
             assert suites[0].tests == 3 and suites[0].failures == 1\n\
             print('ok')",
            out.join("junit.xml").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "junitparser: {}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );
}
