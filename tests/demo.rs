//! `stride demo` end to end on a short sequence: every stage runs and the report holds the
//! numbers the README promises.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{num, run};

#[test]
fn demo_renders_tracks_maps_and_reports() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let o = run(&[
        "demo",
        "--out",
        out.to_str().unwrap(),
        "--frames",
        "30",
        "--no-blur",
        "-q",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("panicked"));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["slam"]["frames_tracked"], 30, "{r}");
    assert!(num(&r["slam"], "ate_rmse_m") < 0.01, "{r}");
    let (ours, base) = (
        &r["map_groundtruth_poses"]["stack"],
        &r["map_groundtruth_poses"]["fankhauser"],
    );
    assert!(num(ours, "mse") < num(base, "mse"), "{r}");
    assert_eq!(ours["phantoms"], 0, "{r}");
    assert!(
        num(&r["map_slam_poses"]["stack"], "mse") < num(base, "mse"),
        "{r}"
    );
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    for part in [
        "trajectory",
        "sequence/terrain.png",
        "map_groundtruth/stack/elevation.png",
        "map_slam/elevation.png",
        "sequence/blur.svg",
    ] {
        assert!(html.contains(part), "{part}");
    }
    for file in [
        "sequence/terrain.png",
        "sequence/blur.svg",
        "map_groundtruth/stack/elevation.png",
        "map_slam/elevation.png",
        "slam/trajectory_world.tum",
        "trajectory.svg",
    ] {
        assert!(out.join(file).is_file(), "{file}");
    }
    // A second run replaces the first instead of failing on the existing folders.
    let o = run(&[
        "demo",
        "--out",
        out.to_str().unwrap(),
        "--frames",
        "12",
        "--no-blur",
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
