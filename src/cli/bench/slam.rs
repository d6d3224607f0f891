//! `stride bench vo`: the SLAM's speed and accuracy on frames decoded up front: the full
//! SLAM (odometry with the back end beside it) against the odometry alone, taking turns
//! run by run, and ORB-SLAM3 on the same frames in the same session.

use super::{median, orbslam3_summary};
use crate::cli::run::BackendArg;
use anyhow::{bail, Result};
use clap::Args;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::time::Instant;
use stride::config::Config;
use stride::pipeline::world::WorldPlan;
use stride::pipeline::{median_p95, Schedule};
use stride::{Pipeline, PipelineConfig};
use stride_backend::BackendConfig;
use stride_core::frame::RgbdFrame;
use stride_datasets::tum::{AssociationOptions, CameraSource, TumSequence};
use stride_eval::ate;
use stride_frontend::VoConfig;

#[derive(Debug, Args)]
pub struct VoBenchArgs {
    /// Sequence folder (TUM layout).
    #[arg(long)]
    dataset: PathBuf,
    /// Camera preset or file [default: from the folder].
    #[arg(long)]
    camera: Option<String>,
    /// The SLAM's odometry and back-end settings from a TOML configuration (`stride config
    /// --print-defaults`); `--backend` overrides its mode. The odometry alone keeps its own
    /// defaults.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Runs of each configuration (medians are reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// OpenCV threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// The back end of the full SLAM.
    #[arg(long, value_enum, default_value = "ba")]
    backend: BackendArg,
    /// Python of a throwaway venv with pyorbslam3 and evo: also run ORB-SLAM3 on the same
    /// frames in this session through ../shared/tools/peers/orbslam3_tum.py (never a
    /// project dependency) and report both.
    #[arg(long, value_name = "PYTHON")]
    orbslam3: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// One run's figures.
struct RunFigures {
    fps: f64,
    frame_ms: f64,
    wait_ms: f64,
    waits: usize,
    ate_m: f64,
    trajectory: Vec<(f64, [f64; 7])>,
}

fn run_once(
    seq: &TumSequence,
    frames: &[(RgbdFrame, f64)],
    vo: VoConfig,
    backend: Option<(BackendConfig, Schedule)>,
) -> Result<RunFigures> {
    // Poses only: the same work as the peer's.
    let config = PipelineConfig {
        odometry: vo,
        backend,
        world: WorldPlan::Floor,
        map: None,
        saved_map: None,
    };
    let mut slam = Pipeline::new(&seq.camera, config)?;
    let t0 = Instant::now();
    for (f, decode_s) in frames {
        slam.process(f, *decode_s)?;
    }
    let out = slam.finish()?.run;
    let wall = t0.elapsed().as_secs_f64();
    let traj = out.trajectory()?;
    let ate_m = match &seq.groundtruth {
        Some(gt) => {
            ate(gt, &traj, &stride::pipeline::slam_ate_options())?
                .trans_m
                .rmse
        }
        None => f64::NAN,
    };
    Ok(RunFigures {
        fps: frames.len() as f64 / wall,
        frame_ms: median_p95(out.frames.iter().map(|f| f.timing.total_s * 1e3)).0,
        wait_ms: out.frames.iter().map(|f| f.wait_s).sum::<f64>() * 1e3,
        waits: out.frames.iter().filter(|f| f.wait_s > 0.0).count(),
        ate_m,
        trajectory: traj
            .iter()
            .map(|(t, p)| {
                let (tr, q) = stride_core::pose::pose_to_translation_quaternion(p);
                (t, [tr[0], tr[1], tr[2], q[0], q[1], q[2], q[3]])
            })
            .collect(),
    })
}

fn summary(runs: &[RunFigures]) -> Value {
    let col = |f: fn(&RunFigures) -> f64| runs.iter().map(f).collect::<Vec<f64>>();
    let range = |v: &[f64]| {
        (
            v.iter().copied().fold(f64::INFINITY, f64::min),
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let (fps, ate_m) = (col(|r| r.fps), col(|r| r.ate_m));
    let repeatable = runs.windows(2).all(|w| w[0].trajectory == w[1].trajectory);
    json!({
        "fps_median": median(fps.clone()), "fps_range": range(&fps),
        "frame_ms_median": median(col(|r| r.frame_ms)),
        "ate_rmse_median": median(ate_m.clone()), "ate_rmse_range": range(&ate_m),
        "wait_ms_median": median(col(|r| r.wait_ms)),
        "frames_waited_max": runs.iter().map(|r| r.waits).max(),
        "repeatable": repeatable,
    })
}

pub fn bench_vo(a: VoBenchArgs) -> Result<()> {
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let seq = TumSequence::open(
        &a.dataset,
        a.camera.as_deref(),
        AssociationOptions::default(),
    )?;
    stride_frontend::set_opencv_threads(a.threads)?;
    let mut frames = Vec::with_capacity(seq.len());
    for i in 0..seq.len() {
        let t = Instant::now();
        let f = seq.load_frame(i)?;
        frames.push((f, t.elapsed().as_secs_f64()));
    }
    let decode_ms = median(frames.iter().map(|(_, d)| d * 1e3).collect());
    let mode = a.backend.mode();
    let config = match &a.config {
        Some(path) => Config::load_for(path, Some(mode))?.0,
        None => Config::defaults_for(mode),
    };
    let with = |schedule| mode.map(|mode| (config.backend_in(mode), schedule));
    let fixed = with(Schedule::Fixed {
        lag_frames: config.schedule.lag_frames,
    });
    let free = with(Schedule::Free);
    // The configurations take turns run by run, so that all see the same machine state:
    // the SLAM with the default (fixed) schedule and free-running, the same odometry
    // without the back end (its frame time shows what the back end costs it), and the
    // odometry alone with its own defaults.
    let mut runs: [Vec<RunFigures>; 4] = Default::default();
    for _ in 0..a.runs {
        let vo = || config.odometry.clone();
        runs[0].push(run_once(&seq, &frames, vo(), fixed.clone())?);
        runs[1].push(run_once(&seq, &frames, vo(), free.clone())?);
        runs[2].push(run_once(&seq, &frames, vo(), None)?);
        runs[3].push(run_once(&seq, &frames, VoConfig::odometry_only(), None)?);
    }
    let [s, sf, sv, v] = runs.each_ref().map(|r| summary(r));
    let orb = match &a.orbslam3 {
        Some(py) => {
            let camera = match (&a.camera, &seq.camera_source) {
                (Some(c), _) => c.clone(),
                (None, CameraSource::FolderName(p)) => (*p).to_owned(),
                _ => bail!("--orbslam3 needs --camera fr1|fr2|fr3 for this folder"),
            };
            Some(orbslam3_summary(py, &a.dataset, &camera, a.runs)?)
        }
        None => None,
    };
    let f = |j: &Value, k: &str| j.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let o = |k: &str, s: &str| {
        orb.as_ref()
            .and_then(|j| j.get(k))
            .and_then(|x| x.get(s))
            .and_then(Value::as_f64)
            .unwrap_or(f64::NAN)
    };
    let report = json!({
        "frames": frames.len(), "runs": a.runs, "opencv_threads": a.threads,
        "decode_ms_median": decode_ms, "backend": mode.map_or("none", |m| m.as_str()),
        "slam": s, "slam_free_running": sf, "slam_odometry_without_back_end": sv,
        "odometry_alone": v, "orbslam3": orb,
        "slam_over_orbslam3_fps": f(&s, "fps_median") / o("fps_track", "median"),
    });
    if a.json {
        crate::outln!("{report}")?;
        return Ok(());
    }
    crate::outln!(
        "{} frames of {}, {} runs each, {} OpenCV thread(s); PNG decoding (excluded) {decode_ms:.2} ms/frame",
        frames.len(),
        a.dataset.display(),
        a.runs,
        a.threads
    )?;
    crate::outln!(
        "{:<34}{:>22}{:>18}{:>16}",
        "",
        "ATE rmse mm [range]",
        "frames/s [range]",
        "frame ms"
    )?;
    for (name, j) in [
        ("stride SLAM", &s),
        ("stride SLAM, free-running", &sf),
        ("  its odometry, no back end", &sv),
        ("stride odometry alone", &v),
    ] {
        let r = |k: &str, i: usize| j[k][i].as_f64().unwrap_or(f64::NAN);
        crate::outln!(
            "{name:<34}{:>22}{:>18}{:>16.2}",
            format!(
                "{:.2} [{:.2}-{:.2}]",
                f(j, "ate_rmse_median") * 1e3,
                r("ate_rmse_range", 0) * 1e3,
                r("ate_rmse_range", 1) * 1e3
            ),
            format!(
                "{:.1} [{:.0}-{:.0}]",
                f(j, "fps_median"),
                r("fps_range", 0),
                r("fps_range", 1)
            ),
            f(j, "frame_ms_median")
        )?;
    }
    if orb.is_some() {
        crate::outln!(
            "{:<34}{:>22}{:>18}{:>16.2}",
            "ORB-SLAM3 (full SLAM)",
            format!(
                "{:.2} [{:.2}-{:.2}]",
                o("ate_rmse_final", "median") * 1e3,
                o("ate_rmse_final", "min") * 1e3,
                o("ate_rmse_final", "max") * 1e3
            ),
            format!(
                "{:.1} [{:.0}-{:.0}]",
                o("fps_track", "median"),
                o("fps_track", "min"),
                o("fps_track", "max")
            ),
            o("ms_median", "median")
        )?;
        crate::outln!(
            "stride SLAM / ORB-SLAM3 frame rate: {:.2}",
            f(&report, "slam_over_orbslam3_fps")
        )?;
    }
    crate::outln!(
        "the odometry's frame time with the back end beside / without: {:.2} (free-running {:.2}); under the fixed schedule it waited on at most {} frames ({:.1} ms in all, median), free-running on {}; runs identical: {} (free-running: {})",
        f(&s, "frame_ms_median") / f(&sv, "frame_ms_median"),
        f(&sf, "frame_ms_median") / f(&sv, "frame_ms_median"),
        s["frames_waited_max"],
        f(&s, "wait_ms_median"),
        sf["frames_waited_max"],
        s["repeatable"],
        sf["repeatable"]
    )?;
    Ok(())
}
