//! The library API (`stride::Pipeline`) on real frames: poses, the world frame from the
//! floor, the elevation map built inside the pipeline, and repeatability.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::data;
use stride::known_poses::views_map;
use stride::pipeline::terrain::TerrainConfig;
use stride::pipeline::world::WorldSource;
use stride::{Pipeline, PipelineConfig, PipelineOutput};
use stride_datasets::sequence::Sequence;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_eval::ate;

/// Feeds every frame of `seq` through a pipeline; returns the output and the map's size
/// read through `Pipeline::map` after frame 60.
fn feed(seq: &TumSequence) -> (PipelineOutput, usize) {
    let mut pipeline = Pipeline::new(&seq.camera, PipelineConfig::default()).unwrap();
    let mut cells_at_60 = 0;
    for (n, decoded) in seq.stream(None, 4).enumerate() {
        let d = decoded.unwrap();
        pipeline.process(&d.frame, d.decode_s).unwrap();
        if n == 60 {
            cells_at_60 = pipeline.map().unwrap().unwrap().cells_observed();
        }
    }
    (pipeline.finish().unwrap(), cells_at_60)
}

#[test]
fn teddy_through_the_library_gives_poses_and_a_level_map_the_same_on_every_run() {
    let Some(dir) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let seq = TumSequence::open(&dir, None, AssociationOptions::default()).unwrap();
    let (out, cells_at_60) = feed(&seq);
    let run = &out.run;
    let tracked = run
        .frames
        .iter()
        .filter(|f| f.status == stride::FrameStatus::Tracked)
        .count();
    assert_eq!(tracked, seq.len());
    let gt = seq.groundtruth.as_ref().unwrap();
    let traj = run.trajectory().unwrap();
    let rmse = ate(gt, &traj, &stride::pipeline::slam_ate_options())
        .unwrap()
        .trans_m
        .rmse;
    // Measured 6.64 mm (4.4 mm before the odometry took the back end's noise model; over
    // five starts of teddy_200 the mean fell, see tests/slam.rs); ORB-SLAM3 gets 6.2-7.6 mm
    // on these frames.
    assert!(rmse < 0.007, "ATE {rmse} m");
    assert!(matches!(run.world.source, WorldSource::Floor { .. }));
    let map = out.map.as_ref().expect("a map");
    let cells = map.layers.cells_observed();
    assert!(
        cells_at_60 > 10_000 && cells > cells_at_60,
        "{cells_at_60} then {cells}"
    );
    // The floor of the map is level in the gravity-aligned world (measured 0.67 deg).
    let floor = stride_mapping::metrics::floor_fit(&map.layers.elevation, 0.10).unwrap();
    assert!(floor.tilt_deg < 1.0 && floor.fraction > 0.9, "{floor:?}");
    assert!(floor.residual_std_m < 0.02, "{floor:?}");
    // As flat as the same views' floor at ground-truth poses, within 15 %. Measured 14.0
    // against 12.3 mm (1.14); 14.0 against 12.8 (1.09) before the odometry took the back
    // end's noise model, which changed the views more than the SLAM's floor; 14.1 against
    // 13.4 before the map smoothed its depth, 15.2 against 13.3 before the final alignment
    // of the views. Over teddy_200 started at frames 0, 4 and 8, seeds 1-3, both maps in
    // the ground truth's world (`stride run --world-from-groundtruth`): 1.015-1.133, mean
    // 1.07 (1.047-1.187, mean 1.11, before). The bound was 1.1. On 2026-11-27, after
    // points behind occluding edges were trusted less: 1.015-1.078, mean 1.05. On
    // 2026-11-28, with steep faces' points moved behind the faces: 1.008-1.045, mean 1.03;
    // with the 6-keyframe local window too, 1.024-1.060, mean 1.04; with the views'
    // alignment leaving steep faces out, 0.967-1.030, mean 0.99 (SLAM 12.5-13.8 mm,
    // ground-truth poses 12.2-14.0 mm).
    let frames: Vec<usize> = map
        .stats
        .view_frames
        .iter()
        .map(|&p| run.frames[p].index)
        .collect();
    let again_seq =
        Sequence::Tum(TumSequence::open(&dir, None, AssociationOptions::default()).unwrap());
    let (gt_views, outside) = views_map(&again_seq, &frames, gt, TerrainConfig::default()).unwrap();
    // The ground truth starts after the first images: 4 of the 132 views have none.
    assert!(outside <= 4, "{outside} views outside the ground truth");
    let gt_floor = stride_mapping::metrics::floor_fit(&gt_views.elevation, 0.10).unwrap();
    assert!(
        floor.residual_std_m < 1.15 * gt_floor.residual_std_m,
        "SLAM {floor:?} against ground truth {gt_floor:?}"
    );
    // The map's thread and the back end's do not change the result from run to run.
    let (again, _) = feed(&seq);
    assert_eq!(again.run.trajectory().unwrap(), traj);
    let again_map = again.map.as_ref().unwrap();
    // Bit for bit (NaN, unknown, compares unequal to itself).
    let bits = |m: &stride::MapOutput| -> Vec<u32> {
        let l = &m.layers;
        [&l.elevation, &l.variance, &l.vitality, &l.updates]
            .iter()
            .flat_map(|g| g.as_slice().iter().map(|v| v.to_bits()))
            .collect()
    };
    assert!(bits(again_map) == bits(map), "the maps of two runs differ");
    assert_eq!(
        again_map.layers.elevation.geometry,
        map.layers.elevation.geometry
    );
    assert_eq!(again_map.stats.rebuilds, map.stats.rebuilds);
}
