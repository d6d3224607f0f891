//! `stride run`: the SLAM pipeline on a sequence: visual odometry, and beside it the back end
//! (feature map and bundle adjustment, or a pose graph).

use crate::pipeline::world::{WorldPlan, WorldSource};
use crate::pipeline::{median_p95, run_slam, FrameStatus, RunOutput, Schedule};
use anyhow::{Context, Result};
use clap::Args;
use serde_json::{json, Map, Value};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stride_backend::{BackendConfig, BackendMode};
use stride_datasets::trajectory_file::write_tum_trajectory;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_eval::{ate, rpe, AteResult, Preset, RpeOptions, RpeResult};
use stride_frontend::VoConfig;
use stride_output::fs::{write_atomic, StagedDir};

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Sequence folder in TUM layout (rgb.txt, depth.txt, optional groundtruth.txt).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Camera: fr1, fr2, fr3 or a camera file [default: the folder's camera.json, else the
    /// TUM camera its name implies].
    #[arg(long)]
    pub camera: Option<String>,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// The back end: `ba` (feature map and bundle adjustment of poses and points), `pose-graph`
    /// (keyframe poses tied by relative motions, RGB-D SLAM v2 style) or `none` (the visual
    /// odometry alone).
    #[arg(long, value_enum, default_value = "ba")]
    pub backend: BackendArg,
    /// The visual odometry alone: the same as `--backend none`.
    #[arg(long)]
    pub vo_only: bool,
    /// Apply the back end's corrections as soon as they are ready, never waiting for them.
    /// Faster on a loaded machine, but results then depend on thread timing. By default a
    /// correction is applied a fixed number of frames after its keyframe, so that reruns are
    /// bit-identical.
    #[arg(long)]
    pub free_running: bool,
    /// Seed of RANSAC.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Repeatable bit for bit (the default schedule already is; this also pins OpenCV to one
    /// thread, which does not change results). Conflicts with --free-running.
    #[arg(long, conflicts_with = "free_running")]
    pub deterministic: bool,
    /// The camera's downward pitch (degrees) on the robot, with --camera-height-m: sets the
    /// gravity-aligned world frame instead of the floor seen in the first frames.
    #[arg(
        long,
        value_name = "DEG",
        requires = "camera_height_m",
        allow_negative_numbers = true
    )]
    pub camera_pitch_deg: Option<f64>,
    /// The camera's height above the ground (m), with --camera-pitch-deg.
    #[arg(long, value_name = "M", requires = "camera_pitch_deg")]
    pub camera_height_m: Option<f64>,
}

/// The back end to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendArg {
    /// Bundle adjustment of keyframe poses and 3-D points.
    Ba,
    /// A pose graph over keyframes.
    PoseGraph,
    /// None: the visual odometry alone.
    None,
}

impl BackendArg {
    /// The back end's mode; `None` for the odometry alone.
    pub fn mode(self) -> Option<BackendMode> {
        match self {
            BackendArg::Ba => Some(BackendMode::BundleAdjustment),
            BackendArg::PoseGraph => Some(BackendMode::PoseGraph),
            BackendArg::None => None,
        }
    }
}

/// Frames between a keyframe and the application of its correction under the fixed
/// schedule: time for the local optimization while the odometry goes on.
pub const SYNC_LAG_FRAMES: usize = 3;

impl RunArgs {
    /// How the run finds its gravity-aligned world frame: the given mounting, else the
    /// floor.
    pub fn world_plan(&self) -> Result<WorldPlan> {
        match (self.camera_pitch_deg, self.camera_height_m) {
            (Some(pitch_deg), Some(height_m)) => {
                if !((-90.0..=90.0).contains(&pitch_deg) && (0.0..=10.0).contains(&height_m)) {
                    anyhow::bail!(
                        "--camera-pitch-deg {pitch_deg} must be within [-90, 90] and \
                         --camera-height-m {height_m} within [0, 10]"
                    );
                }
                Ok(WorldPlan::Mounting {
                    pitch_deg,
                    height_m,
                })
            }
            _ => Ok(WorldPlan::Floor),
        }
    }

    /// The back end's configuration and schedule, `None` for the odometry alone.
    pub fn backend(&self) -> Option<(BackendConfig, Schedule)> {
        if self.vo_only {
            return None;
        }
        let mode = self.backend.mode()?;
        let schedule = if self.free_running {
            Schedule::Free
        } else {
            Schedule::Fixed {
                lag_frames: SYNC_LAG_FRAMES,
            }
        };
        let c = BackendConfig {
            mode,
            ..BackendConfig::default()
        };
        Some((c, schedule))
    }

    /// The name of the back end for reports.
    fn backend_name(&self) -> &'static str {
        self.backend().map_or("none", |(c, _)| c.mode.as_str())
    }
}

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
}

pub fn run(a: RunArgs) -> Result<()> {
    let summary = execute(&a)?;
    let j = &summary.json;
    let f = |k: &str| j.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let mut line = format!(
        "{} frames, {} tracked, {} lost, {} skipped; {} frames/s with the back end ({}), odometry median {:.2} ms/frame (decoding excluded)",
        j["frames"], j["frames_tracked"], j["frames_lost"], j["frames_skipped"], format_args!("{:.1}", f("fps")), j["backend"].as_str().unwrap_or("?"), j["timing_ms"]["total"]["median"].as_f64().unwrap_or(f64::NAN)
    );
    if let Some(kf) = j.get("keyframes").and_then(Value::as_u64) {
        let _ = write!(
            line,
            "\n{kf} keyframes, {} map points; local optimization median {:.2} ms",
            j["map_points"],
            j["ba_ms"]["median"].as_f64().unwrap_or(f64::NAN)
        );
    }
    if let (Some(at), Some(rp)) = (&summary.ate, &summary.rpe) {
        let _ = write!(
            line,
            "\nATE rmse {:.4} m over {} poses (evo, SE(3)); RPE rmse {:.4} m, {:.3} deg per frame",
            at.trans_m.rmse, at.trans_m.count, rp.trans_m.rmse, rp.rot_deg.rmse
        );
    }
    crate::outln!("{line}")?;
    crate::outln!("written to {}", a.out.display())?;
    Ok(())
}

/// Runs and writes everything into `a.out`; returns the summary.
pub fn execute(a: &RunArgs) -> Result<RunSummary> {
    crate::cli::check_out_dir("--out", &a.out)?;
    let seq = TumSequence::open(
        &a.dataset,
        a.camera.as_deref(),
        AssociationOptions::default(),
    )
    .context("opening the dataset")?;
    tracing::info!(
        "{} frames from {}, camera {}",
        seq.len(),
        a.dataset.display(),
        seq.camera_source
    );
    stride_frontend::set_opencv_threads(if a.deterministic { 1 } else { 2 })?;
    let base = if a.backend().is_some() {
        VoConfig::default()
    } else {
        VoConfig::odometry_only()
    };
    let config = VoConfig {
        seed: a.seed,
        ..base
    };
    let output = run_slam(
        &seq,
        config,
        a.backend(),
        a.world_plan()?,
        a.max_frames,
        true,
    )?;
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

    let ate_opts = crate::pipeline::slam_ate_options();
    let (ate_r, rpe_r) = match &seq.groundtruth {
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
    let ate_live = match (&seq.groundtruth, &live) {
        (Some(gt), Some(live)) => ate(gt, live, &ate_opts).ok(),
        _ => None,
    };
    let json = report_json(
        a,
        &seq,
        &output,
        ate_r.as_ref(),
        rpe_r.as_ref(),
        ate_live.as_ref(),
    );
    write_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    super::run_report::write_html(dir, a, &json, &output, ate_r.as_ref(), rpe_r.as_ref())?;
    staged
        .publish()
        .with_context(|| format!("publishing {}", a.out.display()))?;
    Ok(RunSummary {
        json,
        ate: ate_r,
        rpe: rpe_r,
        output,
    })
}

fn write_frames_csv(path: &Path, out: &RunOutput) -> Result<()> {
    let mut s = String::from("index,t,status,keyframe,keyframe_id,tracked,inliers,decode_ms,detect_ms,track_ms,ransac_ms,refine_ms,total_ms,wait_ms\n");
    for f in &out.frames {
        let t = &f.timing;
        let _ = writeln!(
            s,
            "{},{:.6},{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}",
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
            t.total_s * 1e3,
            f.wait_s * 1e3
        );
    }
    write_atomic(path, s.as_bytes()).with_context(|| format!("writing {}", path.display()))
}

fn report_json(
    a: &RunArgs,
    seq: &TumSequence,
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
    let stage = |f: fn(&crate::pipeline::FrameRecord) -> f64| {
        let (m, p) = median_p95(processed.iter().map(|r| f(r) * 1e3));
        json!({"median": m, "p95": p})
    };
    let mut timing = Map::new();
    timing.insert("decode".into(), stage(|r| r.decode_s));
    timing.insert("detect".into(), stage(|r| r.timing.detect_s));
    timing.insert("track".into(), stage(|r| r.timing.track_s));
    timing.insert("ransac".into(), stage(|r| r.timing.ransac_s));
    timing.insert("refine".into(), stage(|r| r.timing.refine_s));
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
    m.insert("frames_tracked".into(), json!(count(FrameStatus::Tracked)));
    m.insert("frames_lost".into(), json!(count(FrameStatus::Lost)));
    m.insert("frames_skipped".into(), json!(count(FrameStatus::Skipped)));
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
    m.insert("backend".into(), json!(a.backend_name()));
    let (roll_deg, pitch_deg, height_m) = out.world.first_camera_attitude();
    m.insert(
        "world_frame".into(),
        json!({
            "source": match out.world.source {
                WorldSource::Floor { .. } => "floor",
                WorldSource::Mounting => "mounting",
                WorldSource::FirstCamera => "first camera",
            },
            "gravity_aligned": out.world.source != WorldSource::FirstCamera,
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
        m.insert("map_points".into(), json!(b.map_points));
        m.insert("map_keyframes".into(), json!(b.map_keyframes));
        m.insert("culled_keyframes".into(), json!(b.culled_keyframes));
        let sum = |f: fn(&stride_backend::KeyframeReport) -> usize| -> usize {
            b.keyframes.iter().map(f).sum()
        };
        m.insert(
            "associations".into(),
            json!({"by_track": sum(|k| k.by_track), "by_orb": sum(|k| k.by_orb), "fused": sum(|k| k.fused),
                   "new_points": sum(|k| k.new_points), "outliers": sum(|k| k.outliers),
                   "odometry_edges": sum(|k| usize::from(k.odometry_edge))}),
        );
        m.insert(
            "schedule".into(),
            json!(if a.free_running { "free" } else { "fixed" }),
        );
        let c = &b.config;
        m.insert(
            "backend_config".into(),
            json!({
                "window_keyframes": c.window_keyframes,
                "max_fixed_keyframes": c.max_fixed_keyframes,
                "local_iterations": c.local_iterations,
                "final_iterations": c.final_iterations,
                "min_reobserved": c.min_reobserved,
                "model_noise_m": c.model_noise_m,
                "depth_noise_scale": c.depth_noise_scale,
                "huber_chi2": c.huber_chi2,
                "outlier_chi2": c.outlier_chi2,
                "match_max_hamming": c.matching.max_hamming,
                "match_ratio": c.matching.ratio,
                "match_chi2_gate": c.matching.chi2_gate,
                "sync_lag_frames": SYNC_LAG_FRAMES,
            }),
        );
    }
    m.insert("seed".into(), json!(a.seed));
    m.insert("dataset".into(), json!(a.dataset.display().to_string()));
    m.insert("camera".into(), json!(seq.camera_source.to_string()));
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
