//! Passing the same place again: teddy_200 played forwards, backwards and forwards again
//! keeps the map near the size of one pass (keyframes where an earlier pass stood are
//! culled into the old ones) at about the accuracy of keeping them all.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, num, reordered};

#[test]
fn three_passes_over_teddy_keep_the_map_near_one_pass() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (one, three) = (tmp.path().join("one"), tmp.path().join("three"));
    reordered(&teddy, &one, &(0..200).collect::<Vec<_>>());
    let order: Vec<usize> = (0..200).chain((0..200).rev()).chain(0..200).collect();
    reordered(&teddy, &three, &order);
    let keep_all = tmp.path().join("keep_all.toml");
    std::fs::write(&keep_all, "[backend]\nrevisit_cull_radius_m = 0.0\n").unwrap();
    let keep_all = keep_all.display().to_string();
    let run = |seq: &std::path::Path, name: &str, extra: &[&str]| {
        let mut args = vec!["--deterministic", "--no-map", "--camera", "fr3"];
        args.extend_from_slice(extra);
        common::run_report("run", seq, &tmp.path().join(name), &args)
    };
    let first = run(&one, "first", &[]);
    let culled = run(&three, "culled", &[]);
    let all = run(&three, "all", &["--config", &keep_all]);
    let kf = |r: &serde_json::Value| r["map_keyframes"].as_u64().unwrap();
    let ate = |r: &serde_json::Value| num(&r["ate"], "rmse");
    assert_eq!(culled["frames_tracked"], 600, "{culled}");
    // Measured (seed 1, 15 Hz): 72 keyframes after one pass; after three 86 with the culling
    // and 209 without (641 and 1,602 points). ATE 3.92 mm over one pass, 3.82 over three
    // (4.01 keeping every keyframe): the "no worse than the first pass".
    assert!(
        kf(&culled) * 2 < kf(&all),
        "{} against {}",
        kf(&culled),
        kf(&all)
    );
    assert!(
        (kf(&culled) as f64) < 1.4 * kf(&first) as f64,
        "{} keyframes after three passes, {} after one",
        kf(&culled),
        kf(&first)
    );
    assert!(
        ate(&culled) < 1.1 * ate(&first),
        "ATE {} m over three passes, {} m over one",
        ate(&culled),
        ate(&first)
    );
    assert!(
        ate(&culled) < 1.15 * ate(&all),
        "ATE {} m against {} m keeping every keyframe",
        ate(&culled),
        ate(&all)
    );
}
