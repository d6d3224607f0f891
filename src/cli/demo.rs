//! `stride demo`: the whole pipeline on the embedded synthetic sequence. It renders a walking
//! robot's RGB-D sequence with ground-truth poses and terrain, tracks it with the SLAM
//! (odometry and bundle adjustment), maps the terrain with ground-truth poses (our mapper and
//! the Fankhauser baseline) and with the SLAM's poses, and writes one report.

use crate::cli::map::{self, MapArgs, MapperArg};
use crate::cli::run::{self, RunArgs};
use crate::cli::synth::{blur_report, synthesize};
use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::{json, Value};
use std::path::PathBuf;
use stride_core::trajectory::Trajectory;
use stride_datasets::synth::SynthConfig;
use stride_datasets::trajectory_file::write_tum_trajectory;
use stride_eval::plot::{render, Chart, Series, PALETTE};
use stride_eval::report::Report;
use stride_output::fs::write_atomic;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Output folder; its `sequence`, `slam`, `map_groundtruth` and `map_slam`
    /// subfolders are replaced.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Frames of the synthetic sequence (30 per second of walking).
    #[arg(long, default_value_t = 90)]
    pub frames: usize,
    /// Seed of the sequence and of RANSAC.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Render without motion blur (about three times faster).
    #[arg(long)]
    pub no_blur: bool,
}

/// The SLAM trajectory (in the frame of its first camera) expressed in the world
/// frame of the ground truth by the ground-truth pose of the first frame, as a robot would
/// start its map from the attitude its IMU gives. Every later pose is the SLAM's own.
fn anchored(vo: &Trajectory, gt: &Trajectory) -> Result<Trajectory> {
    let (Some((t0, vo0)), true) = (vo.iter().next(), !gt.is_empty()) else {
        bail!("empty trajectory");
    };
    let world_from_cam0 = gt
        .interpolate(t0)
        .context("the ground truth does not cover the first frame")?;
    let world_from_vo = world_from_cam0 * vo0.inverse();
    let mut out = Trajectory::new();
    for (t, p) in vo.iter() {
        out.push(t, world_from_vo * p)?;
    }
    Ok(out)
}

fn map_args(a: &DemoArgs, poses: String, out: PathBuf, mapper: MapperArg) -> MapArgs {
    MapArgs {
        dataset: a.out.join("sequence"),
        poses,
        out,
        camera: None,
        mapper,
        resolution: 0.01,
        size: 4.0,
        gt_terrain: None,
        drift: 0.0,
        seed: a.seed,
        max_frames: None,
        no_visibility: false,
        no_see_through: false,
        no_edge_filter: false,
        no_median_filter: false,
    }
}

fn f(v: &Value, path: &[&str]) -> f64 {
    path.iter()
        .fold(v, |v, k| v.get(*k).unwrap_or(&Value::Null))
        .as_f64()
        .unwrap_or(f64::NAN)
}

/// What the demo's stages produced, for the report.
struct Stages {
    config: SynthConfig,
    synth: stride_datasets::synth::SynthSummary,
    blur: String,
    slam: run::RunSummary,
    slam_world: Trajectory,
    map_gt: Value,
    map_slam: Value,
}

/// The demo, stage by stage: render, SLAM, maps, report.
pub fn run(a: DemoArgs) -> Result<()> {
    let started = std::time::Instant::now();
    prepare_out(&a)?;
    let (config, synth, blur) = render_sequence(&a)?;
    let (slam, slam_world) = run_slam(&a, &synth.groundtruth)?;
    let (map_gt, map_slam) = make_maps(&a)?;
    let st = Stages {
        config,
        synth,
        blur,
        slam,
        slam_world,
        map_gt,
        map_slam,
    };
    let summary = summary_json(&a, &st, started);
    write_report(&a, &st, &summary, started)?;
    let s = &summary;
    crate::outln!(
        "SLAM: {} of {} frames tracked, ATE {:.2} cm; map MSE ours {:.2e} m² vs baseline {:.2e} m² (SLAM poses: {:.2e} m²), phantoms {} vs {}",
        st.slam.json["frames_tracked"],
        a.frames,
        100.0 * f(s, &["slam", "ate_rmse_m"]),
        f(s, &["map_groundtruth_poses", "stack", "mse"]),
        f(s, &["map_groundtruth_poses", "fankhauser", "mse"]),
        f(s, &["map_slam_poses", "stack", "mse"]),
        st.map_gt["stack"]["phantoms"]["phantoms"],
        st.map_gt["fankhauser"]["phantoms"]["phantoms"]
    )?;
    crate::outln!("report: {}", a.out.join("report.html").display())?;
    Ok(())
}

/// Checks the output folder and removes the subfolders the demo replaces.
fn prepare_out(a: &DemoArgs) -> Result<()> {
    crate::cli::check_out_dir("--out", &a.out)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    for sub in ["sequence", "slam", "map_groundtruth", "map_slam"] {
        let p = a.out.join(sub);
        if p.exists() {
            std::fs::remove_dir_all(&p).with_context(|| format!("replacing {}", p.display()))?;
        }
    }
    Ok(())
}

/// Stage 1, the sequence: a tripod gait over mixed terrain, and its blur report.
fn render_sequence(
    a: &DemoArgs,
) -> Result<(SynthConfig, stride_datasets::synth::SynthSummary, String)> {
    let config = SynthConfig {
        frames: a.frames,
        seed: a.seed,
        blur: !a.no_blur,
        ..SynthConfig::default()
    };
    config.validate()?;
    tracing::info!(
        "rendering {} frames of a tripod gait over mixed terrain{}",
        a.frames,
        if config.blur { " with motion blur" } else { "" }
    );
    let synth = synthesize(&config, &a.out.join("sequence"), false)?;
    let blur = blur_report(&synth, config.fps)?;
    Ok((config, synth, blur))
}

/// Stage 2, SLAM: the odometry with the back end's bundle adjustment; its trajectory
/// anchored in the ground truth's world frame and written for the mapper.
fn run_slam(a: &DemoArgs, groundtruth: &Trajectory) -> Result<(run::RunSummary, Trajectory)> {
    tracing::info!("SLAM");
    let slam = run::execute(&RunArgs {
        dataset: a.out.join("sequence"),
        camera: None,
        out: a.out.join("slam"),
        backend: run::BackendArg::Ba,
        vo_only: false,
        free_running: false,
        seed: a.seed,
        max_frames: None,
        deterministic: true,
        camera_pitch_deg: None,
        camera_height_m: None,
    })?;
    let world = anchored(&slam.output.trajectory()?, groundtruth)?;
    write_tum_trajectory(&a.out.join(SLAM_WORLD), &world)?;
    Ok((slam, world))
}

/// Where the SLAM's trajectory in the world frame is written, inside the output folder.
const SLAM_WORLD: &str = "slam/trajectory_world.tum";

/// Stage 3, maps: ground-truth poses (ours and the baseline), then the SLAM's poses (ours).
fn make_maps(a: &DemoArgs) -> Result<(Value, Value)> {
    tracing::info!("elevation maps");
    let (gt, _, _) = map::execute(&map_args(
        a,
        "groundtruth".into(),
        a.out.join("map_groundtruth"),
        MapperArg::Both,
    ))?;
    let (slam, _, _) = map::execute(&map_args(
        a,
        a.out.join(SLAM_WORLD).display().to_string(),
        a.out.join("map_slam"),
        MapperArg::Stack,
    ))?;
    Ok((gt, slam))
}

/// The demo's report.json: the numbers of every stage.
fn summary_json(a: &DemoArgs, st: &Stages, started: std::time::Instant) -> Value {
    let j = &st.slam.json;
    json!({
        "frames": a.frames,
        "seed": a.seed,
        "blur": st.config.blur,
        "slam": {
            "frames_tracked": j["frames_tracked"],
            "frames_lost": j["frames_lost"],
            "ate_rmse_m": st.slam.ate.as_ref().map(|r| r.trans_m.rmse),
            "rpe_rmse_m_per_frame": st.slam.rpe.as_ref().map(|r| r.trans_m.rmse),
            "rpe_rmse_deg_per_frame": st.slam.rpe.as_ref().map(|r| r.rot_deg.rmse),
            "fps": j["fps"],
        },
        "map_groundtruth_poses": {
            "stack": {"mse": st.map_gt["stack"]["mse"], "mean_abs_m": st.map_gt["stack"]["mean_abs"], "p95_abs_m": st.map_gt["stack"]["p95_abs"], "coverage": st.map_gt["stack"]["coverage"], "phantoms": st.map_gt["stack"]["phantoms"]["phantoms"], "update_ms_median": st.map_gt["stack"]["update_ms"]["median"]},
            "fankhauser": {"mse": st.map_gt["fankhauser"]["mse"], "mean_abs_m": st.map_gt["fankhauser"]["mean_abs"], "p95_abs_m": st.map_gt["fankhauser"]["p95_abs"], "coverage": st.map_gt["fankhauser"]["coverage"], "phantoms": st.map_gt["fankhauser"]["phantoms"]["phantoms"], "update_ms_median": st.map_gt["fankhauser"]["update_ms"]["median"]},
            "performance_index": st.map_gt["performance_index_stack_vs_fankhauser"],
        },
        "map_slam_poses": {"stack": {"mse": st.map_slam["mse"], "mean_abs_m": st.map_slam["mean_abs"], "p95_abs_m": st.map_slam["p95_abs"], "coverage": st.map_slam["coverage"], "phantoms": st.map_slam["phantoms"]["phantoms"]}},
        "wall_s": started.elapsed().as_secs_f64(),
    })
}

/// Stage 4, the report: a results table, the trajectory, the terrain and the blur study.
fn write_report(
    a: &DemoArgs,
    st: &Stages,
    summary: &Value,
    started: std::time::Instant,
) -> Result<()> {
    let mut rep = Report::new("stride demo: a walking robot's pose and terrain");
    rep.paragraph(format!(
        "A hexapod walks a tripod gait at {:.2} m/s over the procedural 'mixed' terrain (steps, ramps, rubble, boxes) with a Kinect-like RGB-D camera 0.4 m up, tilted down; {} frames at {} Hz{}, seed {}. Everything below is computed from the rendered images; the ground truth is used only to score (and to anchor the SLAM's first pose, as a robot's IMU would).",
        st.config.motion.speed_m_s,
        a.frames,
        st.config.fps,
        if st.config.blur { ", 20 ms exposure with motion blur, rolling shutter" } else { ", no motion blur" },
        a.seed
    ));
    rep.heading("Results");
    rep.table(&["what", "value", "see"], results_rows(st, summary));
    rep.paragraph("The MSE is dominated by a few cells at the sides of objects and steps, where a 1 cm cell honestly holds either height; the mean and 95th percentile say more about the rest.");
    rep.paragraph("Map update times here are measured while PNG decoding runs beside the mapper on the same two cores; `stride bench map` times them on frames decoded up front.");
    let top = |t: &Trajectory| t.positions().iter().map(|p| (p.x, p.y)).collect::<Vec<_>>();
    let side = |t: &Trajectory| {
        let t0 = t.stamps_s().first().copied().unwrap_or(0.0);
        t.iter()
            .map(|(s, p)| (s - t0, p.translation.z))
            .collect::<Vec<_>>()
    };
    let charts = [
        Chart {
            title: "Trajectory from above".into(),
            x_label: "x (m)".into(),
            y_label: "y (m)".into(),
            series: vec![
                Series::line("ground truth", PALETTE[6], top(&st.synth.groundtruth)),
                Series::line("SLAM", PALETTE[1], top(&st.slam_world)),
            ],
            equal_aspect: true,
            ..Chart::default()
        },
        Chart {
            title: "Camera height: the gait's bobbing".into(),
            x_label: "time (s)".into(),
            y_label: "z (m)".into(),
            series: vec![
                Series::line("ground truth", PALETTE[6], side(&st.synth.groundtruth)),
                Series::line("SLAM", PALETTE[1], side(&st.slam_world)),
            ],
            ..Chart::default()
        },
    ];
    rep.figure(
        "trajectory",
        render(&charts, 2, 520.0, 380.0),
        "The SLAM trajectory (anchored at the first ground-truth pose) against ground truth.",
    );
    rep.heading("Terrain");
    rep.image("sequence/terrain.png", "Ground-truth terrain (colour relief, +y up); objects are left out of the ground truth (NaN).");
    rep.image(
        "map_groundtruth/stack/elevation.png",
        "Our map (paper 000's voxel stacks), ground-truth poses.",
    );
    rep.image(
        "map_groundtruth/fankhauser/elevation.png",
        "The Fankhauser et al. 2014 baseline on the same frames and poses.",
    );
    rep.image(
        "map_slam/elevation.png",
        "Our map with the SLAM's poses: what a robot without ground truth gets.",
    );
    rep.heading("Motion blur");
    rep.paragraph(st.blur.as_str());
    rep.image(
        "sequence/blur.svg",
        "Image sharpness over time against the true image motion.",
    );
    rep.paragraph(format!(
        "Whole demo: {:.0} s of wall time.",
        started.elapsed().as_secs_f64()
    ));
    rep.write(&a.out)
        .with_context(|| format!("writing the report into {}", a.out.display()))?;
    write_atomic(
        &a.out.join("report.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;

    Ok(())
}

/// The rows of the demo report's results table: what, value, where to look.
fn results_rows(st: &Stages, s: &Value) -> Vec<Vec<String>> {
    let cm = |path: &[&str]| format!("{:.2} cm", 100.0 * f(s, path));
    let mse = |path: &[&str]| format!("{:.2e} m²", f(s, path));
    let ms = |path: &[&str]| format!("{:.2} ms", f(s, path));
    let pair = |x: String, y: String| format!("{x} / {y}");
    let (j, gt) = (&st.slam.json, "map_groundtruth_poses");
    let (slam, map_gt, map_slam) = (
        "slam/report.html",
        "map_groundtruth/report.html",
        "map_slam/report.html",
    );
    let rows = [
        (
            "frames tracked / lost",
            pair(
                j["frames_tracked"].to_string(),
                j["frames_lost"].to_string(),
            ),
            slam,
        ),
        (
            "SLAM ATE rmse (SE(3) aligned)",
            cm(&["slam", "ate_rmse_m"]),
            slam,
        ),
        (
            "SLAM RPE rmse per frame",
            format!(
                "{} / {:.3} deg",
                cm(&["slam", "rpe_rmse_m_per_frame"]),
                f(s, &["slam", "rpe_rmse_deg_per_frame"])
            ),
            slam,
        ),
        (
            "SLAM speed (decoding excluded)",
            format!("{:.0} frames/s", f(s, &["slam", "fps"])),
            slam,
        ),
        (
            "map MSE, ours, ground-truth poses",
            mse(&[gt, "stack", "mse"]),
            map_gt,
        ),
        (
            "map MSE, Fankhauser baseline, same poses",
            mse(&[gt, "fankhauser", "mse"]),
            map_gt,
        ),
        (
            "map error mean / 95th percentile: ours",
            pair(
                cm(&[gt, "stack", "mean_abs_m"]),
                cm(&[gt, "stack", "p95_abs_m"]),
            ),
            map_gt,
        ),
        (
            "map error mean / 95th percentile: baseline",
            pair(
                cm(&[gt, "fankhauser", "mean_abs_m"]),
                cm(&[gt, "fankhauser", "p95_abs_m"]),
            ),
            map_gt,
        ),
        (
            "map coverage of the ground truth: ours / baseline",
            format!(
                "{:.2} / {:.2}",
                f(s, &[gt, "stack", "coverage"]),
                f(s, &[gt, "fankhauser", "coverage"])
            ),
            map_gt,
        ),
        (
            "performance index (ours / baseline, eq. 13)",
            format!("{:.3}", f(s, &[gt, "performance_index"])),
            map_gt,
        ),
        (
            "map MSE, ours, SLAM poses",
            mse(&["map_slam_poses", "stack", "mse"]),
            map_slam,
        ),
        (
            "map error mean / 95th percentile: ours, SLAM poses",
            pair(
                cm(&["map_slam_poses", "stack", "mean_abs_m"]),
                cm(&["map_slam_poses", "stack", "p95_abs_m"]),
            ),
            map_slam,
        ),
        (
            "phantom cells > 2 cm over flat ground: ours / baseline",
            pair(
                st.map_gt["stack"]["phantoms"]["phantoms"].to_string(),
                st.map_gt["fankhauser"]["phantoms"]["phantoms"].to_string(),
            ),
            map_gt,
        ),
        (
            "map update per 640x480 frame, median: ours / baseline",
            pair(
                ms(&[gt, "stack", "update_ms_median"]),
                ms(&[gt, "fankhauser", "update_ms_median"]),
            ),
            "stride bench map",
        ),
    ];
    rows.into_iter()
        .map(|(what, value, see)| vec![what.to_string(), value, see.to_string()])
        .collect()
}
