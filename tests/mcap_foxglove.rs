//! `stride run --mcap-out`: the run as an MCAP log with Foxglove's schemas, read back by the
//! Python `mcap` package (an independent implementation; `$STRIDE_MCAP_PYTHON`, CI installs
//! it in its throwaway venv) and checked against the run's other outputs.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, data_lines, mcap_python, run_ok, scratch};
use std::process::Command;
use stride_datasets::mcap::ros2::Time;

#[test]
fn a_run_written_as_mcap_opens_with_foxglove_schemas() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let Some(python) = mcap_python() else { return };
    let dir = scratch("foxglove");
    let (out, log) = (dir.join("run"), dir.join("run.mcap"));
    run_ok(&[
        "run",
        "--dataset",
        teddy.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--max-frames",
        "80",
        "--mcap-out",
        log.to_str().unwrap(),
        "-q",
    ]);
    let peer = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/mcap_peer.py");
    let o = Command::new(&python)
        .args([peer, "read", log.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let ch = &j["channels"];
    for (topic, schema) in [
        ("/tf", "foxglove.FrameTransform"),
        ("/stride/trajectory", "foxglove.PosesInFrame"),
        ("/stride/keyframes", "foxglove.PosesInFrame"),
        ("/stride/map_points", "foxglove.PointCloud"),
        ("/stride/elevation", "foxglove.Grid"),
    ] {
        let c = &ch[topic];
        assert_eq!(
            (c["schema"].as_str(), c["schema_title"].as_str()),
            (Some(schema), Some(schema)),
            "{topic}"
        );
        assert_eq!(
            (
                c["schema_encoding"].as_str(),
                c["message_encoding"].as_str()
            ),
            (Some("jsonschema"), Some("json"))
        );
        assert_eq!(
            c["first"]["frame_id"]
                .as_str()
                .or(c["first"]["parent"].as_str()),
            Some("world"),
            "{topic}"
        );
    }
    // Camera transforms: one per frame, the trajectory's poses at its stamps.
    let traj: Vec<Vec<String>> = data_lines(&out.join("trajectory.tum"))
        .iter()
        .map(|l| l.split_whitespace().map(str::to_owned).collect())
        .collect();
    assert_eq!(ch["/tf"]["count"], traj.len());
    let tf = &ch["/tf"]["first"];
    let t0 = Time::parse_decimal(&traj[0][0]).unwrap();
    assert_eq!(tf["timestamp"], serde_json::json!([t0.sec, t0.nanosec]));
    assert_eq!(tf["child"], "camera");
    for i in 0..3 {
        let want: f64 = traj[0][1 + i].parse().unwrap();
        assert!((tf["translation"][i].as_f64().unwrap() - want).abs() < 1e-8);
    }
    let path = &ch["/stride/trajectory"]["first"];
    assert_eq!(path["poses"], traj.len());
    let last = traj.last().unwrap();
    for i in 0..3 {
        let want: f64 = last[1 + i].parse().unwrap();
        assert!((path["last"][i].as_f64().unwrap() - want).abs() < 1e-8);
    }
    assert_eq!(
        ch["/stride/keyframes"]["first"]["poses"],
        data_lines(&out.join("keyframes.tum")).len()
    );
    // The feature map and the elevation map, as report.json and map/ have them.
    let report = common::report(&out);
    let cloud = &ch["/stride/map_points"]["first"];
    assert_eq!(cloud["points"], report["map_points"]);
    assert_eq!(
        cloud["fields"],
        serde_json::json!([["x", 0, 7], ["y", 4, 7], ["z", 8, 7]])
    );
    let grid = stride_datasets::grid_file::read_grid(&out.join("map/elevation.npy"), None).unwrap();
    let g = &ch["/stride/elevation"]["first"];
    assert_eq!(
        (g["columns"].as_u64(), g["rows"].as_u64()),
        (
            Some(grid.geometry.cols as u64),
            Some(grid.geometry.rows as u64)
        )
    );
    assert_eq!(g["cell_size"][0].as_f64(), Some(grid.geometry.resolution));
    let corner_x = grid.geometry.origin_x - grid.geometry.resolution / 2.0;
    assert!((g["corner"][0].as_f64().unwrap() - corner_x).abs() < 1e-9);
    let known: Vec<f32> = grid
        .as_slice()
        .iter()
        .copied()
        .filter(|h| !h.is_nan())
        .collect();
    assert!(known.len() > 1000, "the map is nearly empty");
    assert_eq!(g["known"], known.len());
    let mean = known.iter().map(|&h| f64::from(h)).sum::<f64>() / known.len() as f64;
    assert!((g["mean_elevation"].as_f64().unwrap() - mean).abs() < 1e-5);
    assert_eq!(
        g["fields"],
        serde_json::json!([["elevation", 0, 7], ["variance", 4, 7]])
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
