//! `stride run`: the SLAM pipeline on a sequence (for now its visual odometry).

use crate::pipeline::{median_p95, run_vo, RunOutput};
use anyhow::{Context, Result};
use clap::Args;
use serde_json::{json, Map, Value};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stride_core::fsutil::write_atomic;
use stride_datasets::trajectory_file::write_tum_trajectory;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_eval::plot::{render, Chart, Series, Style, PALETTE};
use stride_eval::report::Report;
use stride_eval::{ate, rpe, Align, AteOptions, AteResult, Preset, RpeOptions, RpeResult};
use stride_frontend::VoConfig;

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
    /// Visual odometry only. The back end (feature map and bundle adjustment) is not built
    /// yet, so every run is visual odometry for now; this flag makes that explicit.
    #[arg(long)]
    pub vo_only: bool,
    /// Seed of RANSAC.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Repeatable bit for bit: one OpenCV thread (results are identical with more threads;
    /// this only pins the schedule).
    #[arg(long)]
    pub deterministic: bool,
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
    #[allow(dead_code)] // used by the demo pipeline
    pub output: RunOutput,
}

pub fn run(a: RunArgs) -> Result<()> {
    let summary = execute(&a)?;
    let j = &summary.json;
    let f = |k: &str| j.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let mut line = format!(
        "{} frames, {} tracked, {} lost, {} skipped; VO {:.1} frames/s (median {:.2} ms/frame, decoding excluded)",
        j["frames"], j["frames_tracked"], j["frames_lost"], j["frames_skipped"], f("fps"), j["timing_ms"]["total"]["median"].as_f64().unwrap_or(f64::NAN)
    );
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
    if !a.vo_only {
        tracing::warn!(
            "the back end (map, bundle adjustment) is not built yet: running visual odometry only"
        );
    }
    let seq = TumSequence::open(
        &a.dataset,
        a.camera.as_deref(),
        AssociationOptions::default(),
    )
    .context("opening the dataset")?;
    tracing::info!(
        "{} frames from {} ({:?})",
        seq.len(),
        a.dataset.display(),
        seq.camera_source
    );
    stride_frontend::set_opencv_threads(if a.deterministic { 1 } else { 2 })?;
    let config = VoConfig {
        seed: a.seed,
        ..VoConfig::default()
    };
    let output = run_vo(&seq, config, a.max_frames, true)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let traj = output.trajectory()?;
    write_tum_trajectory(&a.out.join("trajectory.tum"), &traj)?;
    write_frames_csv(&a.out.join("frames.csv"), &output)?;

    let (ate_r, rpe_r) = match &seq.groundtruth {
        Some(gt) => {
            let at = ate(
                gt,
                &traj,
                &AteOptions {
                    align: Align::Se3,
                    ..AteOptions::for_preset(Preset::Evo)
                },
            );
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
    let json = report_json(a, &seq, &output, ate_r.as_ref(), rpe_r.as_ref());
    write_atomic(
        &a.out.join("report.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    write_html(&a.out, a, &json, &output, ate_r.as_ref(), rpe_r.as_ref())?;
    Ok(RunSummary {
        json,
        ate: ate_r,
        rpe: rpe_r,
        output,
    })
}

fn write_frames_csv(path: &Path, out: &RunOutput) -> Result<()> {
    let mut s = String::from("index,t,status,keyframe,tracked,inliers,decode_ms,detect_ms,track_ms,ransac_ms,refine_ms,total_ms\n");
    for f in &out.frames {
        let t = &f.timing;
        let _ = writeln!(
            s,
            "{},{:.6},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}",
            f.index,
            f.t_s,
            f.status,
            u8::from(f.keyframe),
            f.tracked,
            f.inliers,
            f.decode_s * 1e3,
            t.detect_s * 1e3,
            t.track_s * 1e3,
            t.ransac_s * 1e3,
            t.refine_s * 1e3,
            t.total_s * 1e3
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
) -> Value {
    let processed: Vec<_> = out
        .frames
        .iter()
        .filter(|f| f.status != "skipped")
        .collect();
    let count = |s: &str| out.frames.iter().filter(|f| f.status == s).count();
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
    let mut m = Map::new();
    m.insert("frames".into(), json!(out.frames.len()));
    m.insert(
        "frames_tracked".into(),
        json!(count("tracked") + count("initialized")),
    );
    m.insert("frames_lost".into(), json!(count("lost")));
    m.insert("frames_skipped".into(), json!(count("skipped")));
    m.insert(
        "keyframes".into(),
        json!(out.frames.iter().filter(|f| f.keyframe).count()),
    );
    m.insert(
        "fps".into(),
        json!(if out.vo_wall_s > 0.0 {
            processed.len() as f64 / out.vo_wall_s
        } else {
            f64::NAN
        }),
    );
    m.insert("timing_ms".into(), Value::Object(timing));
    m.insert("mode".into(), json!("vo"));
    m.insert("seed".into(), json!(a.seed));
    m.insert("dataset".into(), json!(a.dataset.display().to_string()));
    m.insert("camera".into(), json!(format!("{:?}", seq.camera_source)));
    m.insert(
        "world_frame".into(),
        json!("the first frame's camera frame (x right, y down, z forward)"),
    );
    if let Some(at) = at {
        m.insert("ate".into(), at.to_json());
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

fn write_html(
    dir: &Path,
    a: &RunArgs,
    j: &Value,
    out: &RunOutput,
    at: Option<&AteResult>,
    rp: Option<&RpeResult>,
) -> Result<()> {
    let mut rep = Report::new("stride run: visual odometry");
    rep.paragraph(format!(
        "Dataset {}; {} frames; seed {}.",
        a.dataset.display(),
        out.frames.len(),
        a.seed
    ));
    let g = |k: &str| j.get(k).cloned().unwrap_or(Value::Null).to_string();
    rep.table(
        &["quantity", "value"],
        vec![
            vec!["frames".into(), g("frames")],
            vec!["tracked".into(), g("frames_tracked")],
            vec![
                "lost (constant-velocity prediction)".into(),
                g("frames_lost"),
            ],
            vec!["skipped (could not load)".into(), g("frames_skipped")],
            vec!["keyframes".into(), g("keyframes")],
            vec![
                "VO frames/s (decoding excluded)".into(),
                format!("{:.1}", j["fps"].as_f64().unwrap_or(f64::NAN)),
            ],
        ],
    );
    let stages = ["decode", "detect", "track", "ransac", "refine", "total"];
    rep.table(
        &["stage", "median (ms)", "p95 (ms)"],
        stages
            .iter()
            .map(|s| {
                let v = &j["timing_ms"][*s];
                vec![
                    (*s).to_owned(),
                    format!("{:.3}", v["median"].as_f64().unwrap_or(f64::NAN)),
                    format!("{:.3}", v["p95"].as_f64().unwrap_or(f64::NAN)),
                ]
            })
            .collect(),
    );
    if let Some(at) = at {
        at.add_to_report(&mut rep, "ate");
    }
    if let Some(rp) = rp {
        rp.add_to_report(&mut rep, "rpe");
    }
    let t0 = out.frames.first().map_or(0.0, |f| f.t_s);
    let per_frame = [
        Chart {
            title: "Tracking".into(),
            x_label: "time (s)".into(),
            y_label: "keypoints".into(),
            series: vec![
                Series::line(
                    "tracked",
                    PALETTE[0],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.tracked as f64))
                        .collect(),
                ),
                Series::line(
                    "inliers",
                    PALETTE[2],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.inliers as f64))
                        .collect(),
                ),
                Series::line(
                    "lost/skipped",
                    PALETTE[1],
                    out.frames
                        .iter()
                        .filter(|f| f.status == "lost" || f.status == "skipped")
                        .map(|f| (f.t_s - t0, 0.0))
                        .collect(),
                )
                .with_style(Style::Markers),
            ],
            y_from_zero: true,
            ..Chart::default()
        },
        Chart {
            title: "Time per frame".into(),
            x_label: "time (s)".into(),
            y_label: "ms".into(),
            series: vec![
                Series::line(
                    "total",
                    PALETTE[0],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.timing.total_s * 1e3))
                        .collect(),
                ),
                Series::line(
                    "track",
                    PALETTE[2],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.timing.track_s * 1e3))
                        .collect(),
                ),
                Series::line(
                    "decode (other thread)",
                    PALETTE[4],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.decode_s * 1e3))
                        .collect(),
                )
                .with_style(Style::Dashed),
            ],
            y_from_zero: true,
            ..Chart::default()
        },
    ];
    rep.figure("tracking", render(&per_frame, 2, 560.0, 360.0), "Left: keypoints tracked and RANSAC inliers per frame, failures marked. Right: processing time per frame.");
    rep.write(dir)
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    Ok(())
}
