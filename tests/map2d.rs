//! Paper 003's terrain map from 2-D scans, end to end: `stride scans` simulates the
//! URG-04LX in the synthetic world (the rail run of section 6.1 and a walk over the lab's
//! terrain), `stride map2d` maps the logs; the reports are checked against the truth.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{mcap_python, report, run, run_ok, scratch};
use serde_json::Value;
use std::path::Path;

fn map(scans: &Path, out: &Path, extra: &[&str]) -> Value {
    let (s, o) = (scans.to_str().unwrap(), out.to_str().unwrap());
    let gt = scans.parent().unwrap().join("terrain.npy");
    let mut args = vec![
        "map2d",
        "--scans",
        s,
        "--out",
        o,
        "--gt-terrain",
        gt.to_str().unwrap(),
        "--overwrite",
    ];
    args.extend_from_slice(extra);
    run_ok(&args);
    for f in [
        "elevation.npy",
        "certainty.npy",
        "grid.json",
        "elevation.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    report(out)
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn the_rail_run_maps_the_boxes_and_the_filters_remove_mixed_returns() {
    let dir = scratch("rail");
    let sim = dir.join("sim");
    run_ok(&[
        "scans",
        "--scene",
        "rail",
        "--out",
        sim.to_str().unwrap(),
        "--footprint-mrad",
        "10",
    ]);
    let scans = sim.join("scans.txt");
    let on = map(&scans, &dir.join("on"), &[]);
    let off = map(&scans, &dir.join("off"), &["--no-mixed-pixel-filter"]);
    // The objects' heights within 5 % of the truth (the paper's Table 1 is within 18 %).
    for o in on["map"]["objects"].as_array().unwrap() {
        let e = num(&o["error_percent"]["height"]);
        assert!(e.abs() < 5.0, "{}: height off by {e:.1} %", o["name"]);
    }
    assert_eq!(on["map"]["objects"].as_array().unwrap().len(), 3);
    // The filters remove most mixed returns, and the certainty is low where they landed.
    let m = &on["mixed_returns"];
    assert!(num(&m["mixed_returns"]) > 100.0, "{m}");
    assert!(
        num(&m["removed_by_the_filters"]) > 0.5 * num(&m["mixed_returns"]),
        "{m}"
    );
    assert!(
        num(&m["mean_certainty_where_they_landed"]) < num(&m["mean_certainty_of_known_cells"]),
        "{m}"
    );
    // Removing them lowers the map's error.
    let rmse = |r: &Value, over: &str| num(&r["map"][over]["rmse_m"]);
    assert!(
        rmse(&on, "over_seen") < rmse(&off, "over_seen"),
        "{} vs {}",
        rmse(&on, "over_seen"),
        rmse(&off, "over_seen")
    );
    // Against the naive median of the same returns: better away from steps, and it covers
    // the cells between scan lines that no return hit (eq. 11's fill).
    let away = |r: &Value, k: &str| num(&r[k]["over_seen"]["rmse_away_m"]);
    assert!(away(&on, "map") < away(&on, "naive_median"));
    let cov = |k: &str| num(&on[k]["over_swept"]["coverage"]);
    assert!(
        cov("map") > cov("naive_median") + 0.03,
        "{} vs {}",
        cov("map"),
        cov("naive_median")
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn raw_urg_readings_need_eq4_and_bad_logs_are_errors() {
    let dir = scratch("raw");
    let (metric, raw) = (dir.join("metric"), dir.join("raw"));
    run_ok(&[
        "scans",
        "--scene",
        "rail",
        "--out",
        metric.to_str().unwrap(),
    ]);
    run_ok(&[
        "scans",
        "--scene",
        "rail",
        "--out",
        raw.to_str().unwrap(),
        "--raw",
    ]);
    let a = map(&metric.join("scans.txt"), &dir.join("a"), &[]);
    let b = map(&raw.join("scans.txt"), &dir.join("b"), &["--raw-urg"]);
    let c = map(&raw.join("scans.txt"), &dir.join("c"), &[]);
    let rmse = |r: &Value| num(&r["map"]["over_seen"]["rmse_m"]);
    // Corrected raw readings map like metric ones (returns beyond eq. 4's 1000 mm raw are
    // counted and dropped); uncorrected ones do not.
    assert!(num(&b["stats"]["uncalibrated"]) > 0.0);
    assert!(
        (rmse(&b) - rmse(&a)).abs() < 0.002,
        "{} vs {}",
        rmse(&b),
        rmse(&a)
    );
    assert!(rmse(&c) > 5.0 * rmse(&a), "{} vs {}", rmse(&c), rmse(&a));
    // A bad line is an error naming the file and the line; nothing is written.
    let bad = dir.join("bad.txt");
    std::fs::write(&bad, "# t ...\n0.0 0 0 0.26 0 0 0 1 -1 0.1 3 0.5 0.5\n").unwrap();
    let out = run(&[
        "map2d",
        "--scans",
        bad.to_str().unwrap(),
        "--out",
        dir.join("never").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("bad.txt:2: n = 3 ranges announced, 2 given"),
        "{err}"
    );
    assert!(!dir.join("never").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_walk_over_rough_terrain_beats_the_naive_median_over_the_swept_cells() {
    let dir = scratch("walk");
    let sim = dir.join("sim");
    run_ok(&[
        "scans",
        "--scene",
        "walk",
        "--seconds",
        "6",
        "--out",
        sim.to_str().unwrap(),
    ]);
    let r = map(&sim.join("scans.txt"), &dir.join("map"), &[]);
    let s = |k: &str, v: &str| num(&r[k]["over_swept"][v]);
    assert!(s("map", "coverage") > s("naive_median", "coverage") + 0.05);
    assert!(s("map", "rmse_m") < s("naive_median", "rmse_m"));
    let seen = |k: &str| num(&r[k]["over_seen"]["rmse_m"]);
    assert!(
        seen("map") < seen("naive_median"),
        "{} vs {}",
        seen("map"),
        seen("naive_median")
    );
    assert!(
        num(&r["scan_update_ms_median"]) < 1.0,
        "{}",
        r["scan_update_ms_median"]
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn scans_from_an_mcap_log_map_as_the_text_log_does() {
    let dir = scratch("mcap");
    let sim = dir.join("sim");
    run_ok(&[
        "scans",
        "--scene",
        "rail",
        "--mcap",
        "--out",
        sim.to_str().unwrap(),
    ]);
    let text = map(&sim.join("scans.txt"), &dir.join("text"), &[]);
    let log = map(&sim.join("scans.mcap"), &dir.join("mcap"), &[]);
    assert_eq!(log["scans_without_pose"], 0);
    assert_eq!(text["stats"]["returns"], log["stats"]["returns"]);
    let rmse = |r: &Value| num(&r["map"]["over_seen"]["rmse_m"]);
    assert!(
        (rmse(&text) - rmse(&log)).abs() < 1e-4,
        "{} vs {}",
        rmse(&text),
        rmse(&log)
    );
    // A wrong fixed frame is an error that lists the log's transforms.
    let out = run(&[
        "map2d",
        "--scans",
        sim.join("scans.mcap").to_str().unwrap(),
        "--tf-frame",
        "map",
        "--out",
        dir.join("never").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no transform from map") && err.contains("world -> laser"),
        "{err}"
    );
    // The Python mcap packages read the LaserScans stride wrote.
    let Some(python) = mcap_python() else { return };
    let peer = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/mcap_peer.py");
    let o = std::process::Command::new(&python)
        .args([peer, "read", sim.join("scans.mcap").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    let c = &j["channels"]["/scan"];
    assert_eq!(
        (c["schema"].as_str(), c["count"].as_u64()),
        (Some("sensor_msgs/msg/LaserScan"), Some(161))
    );
    assert_eq!(c["first"]["beams"], 683);
    assert!(num(&c["first"]["returns"]) > 300.0);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_stripe_sensor_maps_the_box_in_its_narrow_view() {
    let dir = scratch("stripe");
    let sim = dir.join("sim");
    run_ok(&[
        "scans",
        "--scene",
        "rail",
        "--sensor",
        "stripe",
        "--out",
        sim.to_str().unwrap(),
    ]);
    let r = map(
        &sim.join("scans.txt"),
        &dir.join("map"),
        &["--sensor", "stripe"],
    );
    let objects = r["map"]["objects"].as_array().unwrap();
    let box_a = &objects[0];
    assert_eq!(box_a["name"], "box A");
    assert!(
        num(&box_a["error_percent"]["height"]).abs() < 3.0,
        "{box_a}"
    );
    assert!(
        num(&box_a["error_percent"]["length"]).abs() < 10.0,
        "{box_a}"
    );
    // The stripe is narrow (paper 003, section 6.1): the cylinder beside the rail is not seen.
    assert!(objects[2]["map_m"]["height"].is_null(), "{}", objects[2]);
    // Away from steps the triangulation at 0.2-0.3 m is sub-millimetre.
    assert!(num(&r["map"]["over_seen"]["rmse_away_m"]) < 0.002);
    let out = run(&[
        "scans",
        "--scene",
        "walk",
        "--sensor",
        "stripe",
        "--out",
        dir.join("w").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}
