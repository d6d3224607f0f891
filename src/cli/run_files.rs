//! What `stride run` writes: the trajectories, the map layers, frames.csv, report.json
//! and the self-contained report.html, all published at once.

use super::run::RunArgs;
use super::run_report::RunPage;
use anyhow::{Context, Result};
use serde_json::{json, Map, Value};
use std::fmt::Write as _;
use std::path::Path;
use stride::config::Config;
use stride::known_poses::{score_near_and_away_from_steps, views_map};
use stride::pipeline::world::WorldSource;
use stride::pipeline::{median_p95, FrameStatus, RunOutput};
use stride::{MapOutput, PipelineOutput};
use stride_core::grid::Grid;
use stride_datasets::grid_file::read_grid;
use stride_datasets::sequence::Sequence;
use stride_datasets::trajectory_file::write_tum_trajectory;
use stride_eval::{ate, rpe, AteResult, Preset, RpeOptions, RpeResult};
use stride_mapping::metrics::{compare, floor_fit, MapScore};
use stride_mapping::MapLayers;
use stride_output::fs::{write_atomic, StagedDir};

/// Everything a run measured.
pub struct RunSummary {
    /// The report.json object.
    pub json: Value,
    /// ATE against ground truth, when there is ground truth.
    pub ate: Option<AteResult>,
    /// RPE against ground truth, when there is ground truth.
    pub rpe: Option<RpeResult>,
    /// The per-frame records.
    pub output: RunOutput,
    /// The elevation map on the SLAM's poses, when there is one.
    pub map: Option<MapOutput>,
    /// The map against the true terrain (the folder's terrain.npy), when there is one.
    pub map_score: Option<MapScore>,
    /// The same views mapped at ground-truth poses (world frame, z up), when the run's
    /// world is the ground truth's.
    pub views_groundtruth: Option<MapLayers>,
}

/// Writes a run's results into `a.out` (staged, then published whole); fails without
/// writing anything when no frame could be read.
pub fn write_run(
    a: &RunArgs,
    config: &Config,
    seq: &Sequence,
    out: PipelineOutput,
) -> Result<RunSummary> {
    let (output, map) = (out.run, out.map);
    if output
        .frames
        .iter()
        .all(|f| f.status == FrameStatus::Skipped)
    {
        let first = output.frames.first();
        anyhow::bail!(
            "none of the {} frames could be read, nothing written (frame {}: {})",
            output.frames.len(),
            first.map_or(0, |f| f.index),
            first
                .and_then(|f| f.skip_reason.as_deref())
                .unwrap_or("no frames")
        );
    }
    // The true terrain is in the ground truth's world: the map is scored against it only
    // when the run's world is that one.
    let in_gt_world = output.world.source == WorldSource::Reference && a.world_from_groundtruth;
    let truth_file = Some(a.dataset.join("terrain.npy")).filter(|p| p.is_file() && in_gt_world);
    let terrain = match truth_file {
        Some(p) => Some(read_grid(&p, None).context("reading the true terrain")?),
        None => None,
    };
    let (map_score, map_terrain_json) = match &map {
        Some(m) => terrain_scores(&m.layers.elevation, terrain.as_ref()),
        None => (None, Value::Null),
    };
    // In the ground truth's world, the same views at ground-truth poses: the part of the
    // map's error (and unevenness) that is not the SLAM's.
    let (views_gt, views_groundtruth) = match (&map, seq.groundtruth()) {
        (Some(m), Some(gt)) if in_gt_world => {
            let frames: Vec<usize> = m
                .stats
                .view_frames
                .iter()
                .filter_map(|&p| Some(output.frames.get(p)?.index))
                .collect();
            let map_config = config.map.clone().unwrap_or_default();
            let (layers, _) = views_map(seq, &frames, gt, map_config)?;
            let mut j = terrain_scores(&layers.elevation, terrain.as_ref()).1;
            j["floor"] = json!(floor_fit(
                &layers.elevation,
                stride::known_poses::FLOOR_BAND_M
            ));
            j["cells_observed"] = json!(layers.cells_observed());
            (Some(j), Some(layers))
        }
        _ => (None, None),
    };
    // Everything is written into a staging folder published at the end: a run killed at
    // any moment leaves the previous output or the complete new one.
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let dir = staged.path();
    let traj = output.trajectory()?;
    write_tum_trajectory(&dir.join("trajectory.tum"), &traj)?;
    // The poses as they were known frame by frame, before later corrections: what a
    // consumer of live poses (a mapper, a controller) gets. Only a back end corrects them.
    let live = match &output.backend {
        Some(b) => {
            let live = output.live_trajectory()?;
            write_tum_trajectory(&dir.join("trajectory_live.tum"), &live)?;
            write_tum_trajectory(&dir.join("keyframes.tum"), &b.keyframe_trajectory(&output))?;
            Some(live)
        }
        None => None,
    };
    write_frames_csv(&dir.join("frames.csv"), &output)?;
    if let Some(path) = &a.mcap_out {
        write_foxglove_log(path, &output, &traj, map.as_ref())?;
    }
    let config_toml = config.to_toml()?;
    write_atomic(&dir.join("config.toml"), config_toml.as_bytes())?;
    if let Some(m) = &map {
        crate::cli::map::write_layers(&dir.join("map"), &m.layers)?;
    }

    let ate_opts = stride::pipeline::slam_ate_options();
    let (ate_r, rpe_r) = match seq.groundtruth() {
        Some(gt) => {
            let at = ate(gt, &traj, &ate_opts);
            let rp = rpe(gt, &traj, &RpeOptions::for_preset(Preset::Evo));
            match (at, rp) {
                (Ok(at), Ok(rp)) => (Some(at), Some(rp)),
                (at, rp) => {
                    for e in [at.err(), rp.err()].into_iter().flatten() {
                        tracing::warn!("evaluation against ground truth failed: {e}");
                    }
                    (None, None)
                }
            }
        }
        None => (None, None),
    };
    let ate_live = match (seq.groundtruth(), &live) {
        (Some(gt), Some(live)) => ate(gt, live, &ate_opts).ok(),
        _ => None,
    };
    let mut json = report_json(
        a,
        config,
        seq,
        &output,
        ate_r.as_ref(),
        rpe_r.as_ref(),
        ate_live.as_ref(),
    );
    if let (Some(m), Value::Object(o)) = (&map, &mut json) {
        let mut mj = map_json(m);
        if let (Value::Object(o), Value::Object(scores)) = (&mut mj, map_terrain_json) {
            o.extend(scores);
        }
        mj["same_views_groundtruth_poses"] = json!(views_gt);
        o.insert("map".into(), mj);
    }
    write_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    let page = RunPage {
        args: a,
        json: &json,
        out: &output,
        map: map.as_ref(),
        terrain: terrain.as_ref(),
        ate: ate_r.as_ref(),
        rpe: rpe_r.as_ref(),
        config_toml: &config_toml,
    };
    super::run_report::write_html(dir, &page)?;
    staged
        .publish()
        .with_context(|| format!("publishing {}", a.out.display()))?;
    Ok(RunSummary {
        json,
        ate: ate_r,
        rpe: rpe_r,
        output,
        map,
        map_score,
        views_groundtruth,
    })
}

/// A map's heights `elevation` (m) scored against the true terrain, when there is one: the
/// score over every cell both know, and report.json's object of it and of the split near
/// and away from steps (`against_true_terrain`, `..._near_and_away_from_steps`).
fn terrain_scores(elevation: &Grid<f32>, terrain: Option<&Grid<f32>>) -> (Option<MapScore>, Value) {
    let score = terrain.and_then(|t| compare(elevation, t));
    let by_steps = terrain.and_then(|t| score_near_and_away_from_steps(elevation, t));
    let j = json!({
        "against_true_terrain": score,
        "against_true_terrain_near_and_away_from_steps": by_steps,
    });
    (score, j)
}

/// The report.json object of the elevation map (its scores against the true terrain apart).
fn map_json(m: &MapOutput) -> Value {
    let s = &m.stats;
    let floor = floor_fit(&m.layers.elevation, stride::known_poses::FLOOR_BAND_M);
    json!({
        "folder": "map",
        "cells_observed": m.layers.cells_observed(),
        "views": s.view_frames.len(),
        "views_mapped": s.views_mapped,
        "views_settled": s.views_settled,
        "views_unmapped": s.views_unmapped,
        "views_left_out": s.views_left_out,
        "rebuilds": s.rebuilds,
        "update_ms": ms_json(s.update_s.iter().map(|t| t * 1e3)),
        "rebuild_ms": ms_json(s.rebuild_s.iter().map(|t| t * 1e3)),
        "wall_s": m.wall_s,
        "queue_wait_s": s.queue_wait_s,
        "points_used": s.points_used,
        "points_overflow": s.points_overflow,
        "rejected": serde_json::to_value(s.rejected).unwrap_or(Value::Null),
        "alignment": {
            "aligned": s.aligned.len(),
            "too_few_points": s.align_too_few_points,
            "too_large": s.align_too_large,
            "shift_mm_abs": ms_json(s.aligned.iter().map(|a| a.0.abs() * 1e3)),
            "tilt_deg": ms_json(s.aligned.iter().map(|a| a.1.to_degrees())),
        },
        // Each pass of the final alignment: views aligned and kept, the change it made
        // (rad, m) and its wall time (s).
        "final_alignment": serde_json::to_value(&s.final_alignment).unwrap_or(Value::Null),
        "archive_dropped_cells": s.archive_dropped_cells,
        "floor": floor.and_then(|f| serde_json::to_value(f).ok()),
    })
}

/// `{"median": .., "p95": ..}` of some values.
fn ms_json(values: impl Iterator<Item = f64>) -> Value {
    let (median, p95) = median_p95(values);
    json!({"median": median, "p95": p95})
}

fn write_frames_csv(path: &Path, out: &RunOutput) -> Result<()> {
    // `piece`: 0 for the frames placed in the world's piece by the end, another number for
    // each piece placed relative to it only by a guess (RunOutput::frame_pieces);
    // `live_in_world`: 1 when the frame's live pose was already in that piece.
    let mut s = String::from("index,t,status,keyframe,keyframe_id,tracked,inliers,decode_ms,detect_ms,track_ms,ransac_ms,refine_ms,recover_ms,total_ms,wait_ms,piece,live_in_world\n");
    for (f, piece) in out.frames.iter().zip(out.frame_pieces()) {
        let t = &f.timing;
        let _ = writeln!(
            s,
            "{},{:.6},{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{piece},{}",
            f.index,
            f.t_s,
            f.status.as_str(),
            u8::from(f.keyframe),
            f.keyframe_id,
            f.tracked,
            f.inliers,
            f.decode_s * 1e3,
            t.detect_s * 1e3,
            t.track_s * 1e3,
            t.ransac_s * 1e3,
            t.refine_s * 1e3,
            t.recover_s * 1e3,
            t.total_s * 1e3,
            f.wait_s * 1e3,
            u8::from(f.live_in_world)
        );
    }
    write_atomic(path, s.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

fn report_json(
    a: &RunArgs,
    config: &Config,
    seq: &Sequence,
    out: &RunOutput,
    at: Option<&AteResult>,
    rp: Option<&RpeResult>,
    at_live: Option<&AteResult>,
) -> Value {
    let processed: Vec<_> = out
        .frames
        .iter()
        .filter(|f| f.status != FrameStatus::Skipped)
        .collect();
    let count = |s: FrameStatus| out.frames.iter().filter(|f| f.status == s).count();
    let stage = |f: fn(&stride::pipeline::FrameRecord) -> f64| {
        let (m, p) = median_p95(processed.iter().map(|r| f(r) * 1e3));
        json!({"median": m, "p95": p})
    };
    let mut timing = Map::new();
    timing.insert("decode".into(), stage(|r| r.decode_s));
    timing.insert("detect".into(), stage(|r| r.timing.detect_s));
    timing.insert("track".into(), stage(|r| r.timing.track_s));
    timing.insert("ransac".into(), stage(|r| r.timing.ransac_s));
    timing.insert("refine".into(), stage(|r| r.timing.refine_s));
    timing.insert("recover".into(), stage(|r| r.timing.recover_s));
    timing.insert("total".into(), stage(|r| r.timing.total_s));
    let rate = |s: f64| {
        if s > 0.0 {
            processed.len() as f64 / s
        } else {
            f64::NAN
        }
    };
    let mut m = Map::new();
    m.insert("frames".into(), json!(out.frames.len()));
    // Each status's count, both flat (frames_tracked, ...) and in frames_by_status.
    let mut by_status = Map::new();
    for s in [
        FrameStatus::Tracked,
        FrameStatus::Recovered,
        FrameStatus::Relocalized,
        FrameStatus::DepthAligned,
        FrameStatus::Lost,
        FrameStatus::Skipped,
    ] {
        m.insert(format!("frames_{}", s.as_str()), json!(count(s)));
        by_status.insert(s.as_str().into(), json!(count(s)));
    }
    m.insert("frames_by_status".into(), Value::Object(by_status));
    m.insert(
        "keyframes".into(),
        json!(out.frames.iter().filter(|f| f.keyframe).count()),
    );
    m.insert("fps".into(), json!(rate(out.wall_s)));
    m.insert("odometry_fps".into(), json!(rate(out.vo_wall_s)));
    let waits: Vec<f64> = out
        .frames
        .iter()
        .map(|f| f.wait_s)
        .filter(|w| *w > 0.0)
        .collect();
    m.insert(
        "frontend_waits".into(),
        json!({"frames": waits.len(), "total_ms": waits.iter().sum::<f64>() * 1e3}),
    );
    m.insert("timing_ms".into(), Value::Object(timing));
    m.insert(
        "backend".into(),
        json!(config.backend.as_ref().map_or("none", |b| b.mode.as_str())),
    );
    let (roll_deg, pitch_deg, height_m) = out.world.first_camera_attitude();
    m.insert(
        "world_frame".into(),
        json!({
            "source": match out.world.source {
                WorldSource::Floor { .. } => "floor",
                WorldSource::Accelerometer { .. } => "accelerometer",
                WorldSource::Mounting => "mounting",
                WorldSource::Reference => "reference trajectory",
                WorldSource::FirstCamera => "first camera",
                WorldSource::SavedMap { .. } => "saved map",
            },
            "gravity_aligned": out.world.is_gravity_aligned(),
            "description": out.world.describe(),
            "first_camera_height_m": height_m,
            "first_camera_pitch_deg": pitch_deg,
            "first_camera_roll_deg": roll_deg,
        }),
    );
    if let Some(b) = &out.backend {
        let (med, p95) = median_p95(b.keyframes.iter().map(|k| k.time_s * 1e3));
        m.insert(
            "ba_ms".into(),
            json!({"median": med, "p95": p95, "count": b.keyframes.len(),
                   "final": b.final_solve.as_ref().map(|s| s.time_s * 1e3)}),
        );
        let (med, p95) = median_p95(b.keyframes.iter().map(|k| k.optimize_s * 1e3));
        m.insert(
            "optimize_ms".into(),
            json!({"median": med, "p95": p95, "count": b.keyframes.len()}),
        );
        m.insert("map_points".into(), json!(b.map_points));
        m.insert("map_keyframes".into(), json!(b.map_keyframes));
        m.insert("culled_keyframes".into(), json!(b.culled_keyframes));
        // Each loop closed: the two keyframes, the inliers and how far it moved the new one.
        let loops: Vec<Value> = b
            .keyframes
            .iter()
            .filter_map(|k| {
                let l = k.loop_closure.as_ref()?;
                Some(
                    json!({"keyframe": k.keyframe_id, "matched": l.matched, "matches": l.matches,
                            "inliers": l.inliers, "correction_mm": l.correction_m * 1e3,
                            "correction_deg": l.correction_rad.to_degrees(),
                            "moved_keyframes": l.moved_keyframes, "fused": l.fused}),
                )
            })
            .collect();
        m.insert("loop_closures".into(), json!(loops.len()));
        m.insert("loops".into(), Value::Array(loops));
        let sum = |f: fn(&stride_backend::KeyframeReport) -> usize| -> usize {
            b.keyframes.iter().map(f).sum()
        };
        m.insert(
            "associations".into(),
            json!({"by_track": sum(|k| k.by_track), "by_orb": sum(|k| k.by_orb), "fused": sum(|k| k.fused),
                   "new_points": sum(|k| k.new_points), "outliers": sum(|k| k.outliers),
                   "odometry_edges": sum(|k| usize::from(k.odometry_edge)),
                   "depth_edges": sum(|k| k.depth_edges),
                   "revisit_edges": sum(|k| usize::from(k.revisit_edge))}),
        );
        m.insert(
            "schedule".into(),
            json!(if config.schedule.free_running {
                "free"
            } else {
                "fixed"
            }),
        );
    }
    m.insert("seed".into(), json!(config.odometry.seed));
    // Every stage's parameters, as config.toml beside this report holds them.
    m.insert(
        "config".into(),
        serde_json::to_value(config).unwrap_or(Value::Null),
    );
    m.insert("dataset".into(), json!(a.dataset.display().to_string()));
    // The saved maps read and written (null when none), and how often the run placed
    // itself in one.
    let path = |p: &Option<std::path::PathBuf>| p.as_ref().map(|p| p.display().to_string());
    m.insert("load_map".into(), json!(path(&a.load_map)));
    m.insert("save_map".into(), json!(path(&a.save_map)));
    m.insert(
        "relocalizations".into(),
        json!(count(FrameStatus::Relocalized)),
    );
    let segments = out.segments();
    m.insert("segments".into(), json!(segments.len()));
    m.insert("segment_frames".into(), json!(segments));
    // In a saved map: the frames placed in its world (the others are in a piece the run
    // started by a guess, when its first frame was not found in the map, that no loop
    // joined to it).
    let in_map = a.load_map.as_ref().map(|_| out.frames_in_world_piece());
    m.insert("frames_in_saved_map".into(), json!(in_map));
    let g = out.gyroscope_frames;
    m.insert(
        "gyroscope_frames".into(),
        json!({"used": g.readout, "not_covered": g.readout_not_covered,
               "predicted": g.predicted, "prediction_not_covered": g.prediction_not_covered,
               "keyframes_deferred": g.keyframes_deferred,
               "estimates_rejected": g.estimates_rejected}),
    );
    let acc = out.accelerometer_frames;
    m.insert(
        "accelerometer_frames".into(),
        json!({"used": acc.readout, "not_covered": acc.readout_not_covered}),
    );
    m.insert("recoveries_refused".into(), json!(out.recoveries_refused));
    m.insert("camera".into(), json!(seq.camera_source()));
    if let Some(at) = at {
        m.insert("ate".into(), at.to_json());
    }
    if let Some(at) = at_live {
        m.insert("ate_live".into(), at.to_json());
    }
    if let Some(rp) = rp {
        m.insert("rpe".into(), rp.to_json());
    }
    let skipped: Vec<Value> = out
        .frames
        .iter()
        .filter_map(|f| {
            f.skip_reason
                .as_ref()
                .map(|r| json!({"index": f.index, "reason": r}))
        })
        .collect();
    if !skipped.is_empty() {
        m.insert("skipped".into(), Value::Array(skipped));
    }
    Value::Object(m)
}

/// The run as an MCAP log for Foxglove (`--mcap-out`): camera transforms, the path, the
/// keyframes, the feature map's points and the elevation map, in the world frame.
fn write_foxglove_log(
    path: &std::path::Path,
    output: &RunOutput,
    traj: &stride_core::trajectory::Trajectory,
    map: Option<&stride::pipeline::MapOutput>,
) -> Result<()> {
    use stride_datasets::mcap::foxglove::{write_run_log, RunLog};
    let pairs = |t: &stride_core::trajectory::Trajectory| -> Vec<_> {
        t.iter().map(|(s, p)| (s, *p)).collect()
    };
    let poses = pairs(traj);
    let keyframes = output
        .backend
        .as_ref()
        .map_or_else(Vec::new, |b| pairs(&b.keyframe_trajectory(output)));
    let points = output
        .backend
        .as_ref()
        .map_or(&[][..], |b| b.points_world.as_slice());
    let log = RunLog {
        poses: &poses,
        keyframes: &keyframes,
        points_world: points,
        elevation: map.map(|m| (&m.layers.elevation, &m.layers.variance)),
    };
    write_run_log(path, &log).with_context(|| format!("--mcap-out {}", path.display()))
}
