//! The OctoMap peer of `stride bench map --octomap` (scripts/peers/octomap_peer.py): its
//! 2.5-D conversion on a hand-made octree with a known answer, and the bench's table on a
//! short synthetic walk. Needs a python with pyoctomap (`$STRIDE_OCTOMAP_PYTHON`; CI
//! installs it in its throwaway venv).

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{octomap_python, run_json};

const PEER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/octomap_peer.py");

#[test]
fn the_highest_occupied_voxel_of_each_column_becomes_its_height() {
    let Some(py) = octomap_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    // A 4 x 4 grid of 1 cm cells, cell centres at 0.5, 1.5, 2.5, 3.5 cm; a 1 cm octree.
    let mut nodes = vec![
        [0.005, 0.005, 0.105, 1.0], // cell (0, 0): one voxel
        [0.015, 0.005, 0.105, 1.0], // cell (0, 1): two voxels, the higher counts
        [0.015, 0.005, 0.305, 1.0],
        [0.025, 0.005, 0.505, 0.0], // cell (0, 2): free space only
    ];
    // A 2 x 2 x 2 cm block (which OctoMap prunes into one 2 cm leaf) over cells (2..4,
    // 2..4): its top layer's voxel centres are at 1.5 cm.
    for x in [0.025, 0.035] {
        for y in [0.025, 0.035] {
            for z in [0.005, 0.015] {
                nodes.push([x, y, z, 1.0]);
            }
        }
    }
    let spec = serde_json::json!({
        "grid": {"origin_x": 0.005, "origin_y": 0.005, "resolution": 0.01, "rows": 4, "cols": 4},
        "nodes": nodes,
    });
    let input = tmp.path().join("voxels.json");
    std::fs::write(&input, spec.to_string()).unwrap();
    let out = std::process::Command::new(&py)
        .args([PEER, "voxels"])
        .arg(&input)
        .arg(tmp.path())
        .arg("0.01")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bytes = std::fs::read(tmp.path().join("elevation.f32")).unwrap();
    let got: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let n = f32::NAN;
    #[rustfmt::skip]
    let want = [
        0.105, 0.305, n, n,
        n, n, n, n,
        n, n, 0.015, 0.015,
        n, n, 0.015, 0.015,
    ];
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let same = (g.is_nan() && w.is_nan()) || (g - w).abs() < 1e-5;
        assert!(same, "cell ({}, {}): {g}, expected {w}", i / 4, i % 4);
    }
}

#[test]
fn the_bench_scores_octomap_beside_our_maps_on_the_same_clouds() {
    let Some(py) = octomap_python() else {
        return;
    };
    let py = py.display().to_string();
    // The default synthetic walk, 4 frames, OctoMap at 2 cm only (1 cm takes seconds a frame).
    let j = run_json(&[
        "bench",
        "map",
        "--frames",
        "4",
        "--octomap",
        &py,
        "--octomap-resolution",
        "0.02",
        "--json",
    ]);
    let rows = j["rows"].as_array().unwrap();
    let names: Vec<&str> = rows.iter().map(|r| r["mapper"].as_str().unwrap()).collect();
    assert_eq!(names, ["stack", "fankhauser", "octomap 2 cm"]);
    for r in rows {
        // Every map covers part of the terrain, with an error below a few centimetres.
        let rmse = r["rmse_m"].as_f64().unwrap();
        let coverage = r["coverage"].as_f64().unwrap();
        assert!(rmse > 0.0 && rmse < 0.1, "{r}");
        assert!(coverage > 0.05 && coverage <= 1.0, "{r}");
        assert!(r["update_ms_median"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["memory_mb"].as_f64().unwrap() > 0.0, "{r}");
    }
}
