//! `stride demo`: the whole pipeline on the embedded synthetic sequence. It renders a walking
//! robot's RGB-D sequence with ground-truth poses and terrain, runs the pipeline on it (the
//! SLAM with bundle adjustment, and the elevation map on its keyframes' optimized poses),
//! maps the same terrain with ground-truth poses (the same keyframes, and every frame with
//! our mapper and the Fankhauser baseline) to score both, and writes one report.

use crate::cli::map::write_layers;
use crate::cli::map_figures::{elevation_chart, error_chart};
use crate::cli::run::{BackendArg, RunArgs};
use crate::cli::run_files::{write_run, RunSummary};
use crate::cli::synth::{blur_report, synthesize};
use anyhow::{Context, Result};
use clap::Args;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use stride::config::Config;
use stride::known_poses::{map_sequence, phantom_score, score_near_and_away_from_steps, MapperRun};
use stride::run_sequence;
use stride_core::grid::Grid;
use stride_core::trajectory::Trajectory;
use stride_datasets::grid_file::read_grid;
use stride_datasets::sequence::Sequence;
use stride_datasets::synth::motion::{MotionConfig, PathKind};
use stride_datasets::synth::SynthConfig;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_eval::plot::{render, Chart, Series, Style, PALETTE};
use stride_eval::report::Report;
use stride_mapping::fankhauser::{FankhauserConfig, FankhauserMapper};
use stride_mapping::metrics::{compare, MapScore, SeenScore};
use stride_mapping::stack::StackMapper;
use stride_mapping::{ElevationMapper, MapLayers};
use stride_output::fs::{write_atomic, StagedDir};

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Output folder (written whole at the end; an existing non-empty one only with
    /// --overwrite).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Replace the output folder's contents.
    #[arg(long)]
    pub overwrite: bool,
    /// Frames of the synthetic sequence (10 per second of walking); the default walks the
    /// square once, back to the start.
    #[arg(long, default_value_t = LAP_FRAMES)]
    pub frames: usize,
    /// Seed of the sequence and of RANSAC.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Render without motion blur (about three times faster).
    #[arg(long)]
    pub no_blur: bool,
    /// Every stage's parameters as a TOML file (see `stride config --print-defaults`).
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<PathBuf>,
}

/// Side of the demo's square walk (m).
const SQUARE_SIDE_M: f64 = 0.75;
/// Walking speed (m/s): paper 004's fastest, 0.15 m/s.
const SPEED_M_S: f64 = 0.15;
/// Frame rate (Hz): a low rate, so that a whole lap fits the demo's time and the odometry
/// has frame-to-frame motion large enough to drift.
const FPS: f64 = 10.0;
/// Frames of one lap of the square: four sides at `SPEED_M_S` and four quarter turns on
/// the spot, at `FPS` (4 x (5 s + 2.6 s) = 30.5 s).
const LAP_FRAMES: usize = 305;

fn f(v: &Value, path: &[&str]) -> f64 {
    path.iter()
        .fold(v, |v, k| v.get(*k).unwrap_or(&Value::Null))
        .as_f64()
        .unwrap_or(f64::NAN)
}

/// A map and its score against the true terrain.
struct Scored {
    layers: MapLayers,
    score: Option<MapScore>,
    /// The same cells split near and away from steps and obstacles' feet.
    by_steps: Option<SeenScore>,
    phantoms: usize,
}

impl Scored {
    fn new(layers: MapLayers, truth: &Grid<f32>) -> Self {
        let score = compare(&layers.elevation, truth);
        let by_steps = score_near_and_away_from_steps(&layers.elevation, truth);
        let phantoms = phantom_score(&layers.elevation, truth).phantoms;
        Self {
            layers,
            score,
            by_steps,
            phantoms,
        }
    }

    fn json(&self) -> Value {
        let s = self.score.as_ref();
        let b = self.by_steps.as_ref();
        json!({
            "rmse_m": s.map(|s| s.rmse),
            "mean_abs_m": s.map(|s| s.mean_abs),
            "p95_abs_m": s.map(|s| s.p95_abs),
            "coverage": s.map(|s| s.coverage),
            "cells_compared": s.map(|s| s.cells_compared),
            "rmse_away_from_steps_m": b.map(|b| b.rmse_away_m),
            "rmse_near_steps_m": b.map(|b| b.rmse_near_steps_m),
            "cells_near_steps": b.map(|b| b.cells_near_steps),
            "phantoms": self.phantoms,
        })
    }
}

/// What the demo's stages produced, for the report.
struct Stages {
    config: SynthConfig,
    synth: stride_datasets::synth::SynthSummary,
    blur: String,
    truth: Grid<f32>,
    slam: RunSummary,
    /// The pipeline's map (SLAM poses), scored.
    map_slam: Scored,
    /// The same views at ground-truth poses.
    map_views_gt: Scored,
    /// Every frame at ground-truth poses: ours, and the baseline.
    map_frames_gt: Vec<(MapperRun, Scored)>,
}

/// The demo, stage by stage: render, pipeline, maps with ground-truth poses, report; all
/// in a staging folder that replaces the output folder at the end.
pub fn run(a: DemoArgs) -> Result<()> {
    let started = std::time::Instant::now();
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let dir = staged.path();
    let (synth_config, synth, blur) = render_sequence(&a, dir)?;
    let seq = TumSequence::open(&dir.join("sequence"), None, AssociationOptions::default())
        .map(Sequence::Tum)
        .context("opening the rendered sequence")?;
    let truth = read_grid(&dir.join("sequence/terrain.npy"), None)?;
    let args = run_args(&a, dir);
    let config = args.config()?;
    let mut slam = run_pipeline(&args, &config, &seq)?;
    let map_config = config
        .map
        .clone()
        .context("the demo needs the map: not `map = false`")?;
    // The run scored both maps for its report; the demo's report adds the phantoms and
    // the split near and away from steps, so it takes the layers and scores them again.
    let map_slam = Scored::new(
        slam.map
            .take()
            .map(|m| m.layers)
            .context("the pipeline made no map")?,
        &truth,
    );
    tracing::info!("maps with ground-truth poses");
    // The run (in the ground truth's world) mapped the same views at ground-truth poses.
    let map_views_gt = Scored::new(
        slam.views_groundtruth
            .take()
            .context("the run made no map of its views at ground-truth poses")?,
        &truth,
    );
    let mappers: Vec<Box<dyn ElevationMapper>> = vec![
        Box::new(StackMapper::new(map_config.stack.clone())?),
        Box::new(FankhauserMapper::new(FankhauserConfig::default())?),
    ];
    let (runs, _) = map_sequence(&seq, &synth.groundtruth, mappers, None, Some(&truth), || {})?;
    let map_frames_gt = runs
        .into_iter()
        .map(|r| {
            let scored = Scored::new(r.layers.clone(), &truth);
            (r, scored)
        })
        .collect();
    let st = Stages {
        config: synth_config,
        synth,
        blur,
        truth,
        slam,
        map_slam,
        map_views_gt,
        map_frames_gt,
    };
    for (r, _) in &st.map_frames_gt {
        write_layers(&dir.join("map_groundtruth").join(r.name), &r.layers)?;
    }
    write_layers(&dir.join("map_views_groundtruth"), &st.map_views_gt.layers)?;
    let summary = summary_json(&a, &st, started);
    write_report(&a, dir, &st, &summary, started)?;
    staged
        .publish()
        .with_context(|| format!("publishing {}", a.out.display()))?;
    let s = &summary;
    crate::outln!(
        "SLAM: {} of {} frames tracked, ATE {:.2} mm; map RMSE with SLAM poses {:.1} mm vs {:.1} mm with ground-truth poses (same views), coverage {:.2} vs {:.2}",
        st.slam.json["frames_tracked"],
        a.frames,
        1e3 * f(s, &["slam", "ate_rmse_m"]),
        1e3 * f(s, &["map", "slam_poses", "rmse_m"]),
        1e3 * f(s, &["map", "groundtruth_poses_views", "rmse_m"]),
        f(s, &["map", "slam_poses", "coverage"]),
        f(s, &["map", "groundtruth_poses_views", "coverage"]),
    )?;
    crate::outln!("report: {}", a.out.join("report.html").display())?;
    Ok(())
}

/// Stage 1, the sequence: a tripod gait over mixed terrain, and its blur report.
fn render_sequence(
    a: &DemoArgs,
    dir: &Path,
) -> Result<(SynthConfig, stride_datasets::synth::SynthSummary, String)> {
    let config = SynthConfig {
        frames: a.frames,
        seed: a.seed,
        blur: !a.no_blur,
        fps: FPS,
        motion: MotionConfig {
            path: PathKind::Square,
            square_side_m: SQUARE_SIDE_M,
            speed_m_s: SPEED_M_S,
            ..MotionConfig::default()
        },
        ..SynthConfig::default()
    };
    config.validate()?;
    tracing::info!(
        "rendering {} frames of a tripod gait around a square over mixed terrain{}",
        a.frames,
        if config.blur { " with motion blur" } else { "" }
    );
    let synth = synthesize(&config, &dir.join("sequence"), false)?;
    let blur = blur_report(&synth, config.fps)?;
    Ok((config, synth, blur))
}

/// The `stride run` arguments of the demo's pipeline: the SLAM with bundle adjustment,
/// the map, the world anchored at the ground truth (as a robot starting at a known pose
/// would be), repeatable.
fn run_args(a: &DemoArgs, dir: &Path) -> RunArgs {
    RunArgs {
        dataset: dir.join("sequence"),
        topics: super::run::TopicArgs::default(),
        camera: None,
        out: dir.join("slam"),
        overwrite: false,
        config: a.config.clone(),
        no_map: false,
        backend: Some(BackendArg::Ba),
        vo_only: false,
        free_running: false,
        seed: Some(a.seed),
        max_frames: None,
        deterministic: true,
        camera_pitch_deg: None,
        camera_height_m: None,
        world_from_groundtruth: true,
        ignore_accelerometer: false,
        save_map: None,
        mcap_out: None,
        load_map: None,
    }
}

/// Stage 2, the pipeline: the SLAM and the elevation map on its poses, written as `stride
/// run` writes it.
fn run_pipeline(args: &RunArgs, config: &Config, seq: &Sequence) -> Result<RunSummary> {
    tracing::info!("pipeline: SLAM and elevation map");
    stride_frontend::set_opencv_threads(1)?;
    let pb = crate::cli::progress_bar(seq.len(), "pipeline", true);
    let out = run_sequence(seq, config.pipeline(args.world_plan(seq)?), None, |_| {
        pb.inc(1)
    })?;
    pb.finish_and_clear();
    write_run(args, config, seq, out)
}

fn summary_json(a: &DemoArgs, st: &Stages, started: std::time::Instant) -> Value {
    let j = &st.slam.json;
    let frames_gt: serde_json::Map<String, Value> = st
        .map_frames_gt
        .iter()
        .map(|(r, s)| {
            let mut v = s.json();
            let (med, _) = stride::pipeline::median_p95(r.update_s.iter().map(|t| t * 1e3));
            v["update_ms_median"] = json!(med);
            (r.name.to_owned(), v)
        })
        .collect();
    json!({
        "frames": a.frames,
        "seed": a.seed,
        "blur": st.config.blur,
        "slam": {
            "frames_tracked": j["frames_tracked"],
            "frames_recovered": j["frames_recovered"],
            "frames_lost": j["frames_lost"],
            "keyframes": j["keyframes"],
            "loop_closures": j["loop_closures"],
            "ate_rmse_m": st.slam.ate.as_ref().map(|r| r.trans_m.rmse),
            "ate_live_rmse_m": j["ate_live"]["rmse"],
            "ate_odometry_rmse_m": odometry_trajectory(&st.slam.output).ok().and_then(|t| {
                stride_eval::ate(&st.synth.groundtruth, &t, &stride::pipeline::slam_ate_options())
                    .ok()
                    .map(|r| r.trans_m.rmse)
            }),
            "rpe_rmse_m_per_frame": st.slam.rpe.as_ref().map(|r| r.trans_m.rmse),
            "rpe_rmse_deg_per_frame": st.slam.rpe.as_ref().map(|r| r.rot_deg.rmse),
            "fps": j["fps"],
        },
        "map": {
            "slam_poses": st.map_slam.json(),
            "groundtruth_poses_views": st.map_views_gt.json(),
            "groundtruth_poses_every_frame": frames_gt,
            "pipeline": j["map"],
        },
        "wall_s": started.elapsed().as_secs_f64(),
    })
}
/// Stage 4, the report: a results table, the trajectory, the terrain and the blur study.
fn write_report(
    a: &DemoArgs,
    dir: &Path,
    st: &Stages,
    summary: &Value,
    started: std::time::Instant,
) -> Result<()> {
    let mut rep = Report::new("stride demo: a walking robot's pose and terrain");
    rep.paragraph(format!(
        "A hexapod walks a tripod gait at {:.2} m/s around a {} m square (turning on the spot at the corners, back to its start after {} frames) over the procedural 'mixed' terrain (steps, ramps, rubble, boxes) with a Kinect-like RGB-D camera 0.4 m up, tilted down; {} frames at {} Hz{}, seed {}. Everything below is computed from the rendered images by the pipeline (`stride::Pipeline`: the SLAM, and the elevation map on its optimized poses); the ground truth is used only to score, and to give the first camera's pose (as a robot starting at a known pose).",
        st.config.motion.speed_m_s,
        st.config.motion.square_side_m,
        LAP_FRAMES,
        a.frames,
        st.config.fps,
        if st.config.blur { ", 20 ms exposure with motion blur, rolling shutter" } else { ", no motion blur" },
        a.seed
    ));
    rep.heading("Results");
    rep.table(&["what", "value"], results_rows(st, summary));
    rep.paragraph("Map errors are over the cells that both the map and the true terrain know; coverage is the fraction of the true terrain's cells the map knows. The largest errors sit at the sides of steps and objects, where a 1 cm cell honestly holds either height.");
    let top = |t: &Trajectory| t.positions().iter().map(|p| (p.x, p.y)).collect::<Vec<_>>();
    let side = |t: &Trajectory| {
        let t0 = t.stamps_s().first().copied().unwrap_or(0.0);
        t.iter()
            .map(|(s, p)| (s - t0, p.translation.z))
            .collect::<Vec<_>>()
    };
    let slam_traj = st.slam.output.trajectory()?;
    let odometry = odometry_trajectory(&st.slam.output)?;
    let charts = [
        Chart {
            title: "Trajectory from above".into(),
            x_label: "world x (m)".into(),
            y_label: "world y (m)".into(),
            series: vec![
                Series::line("ground truth", PALETTE[6], top(&st.synth.groundtruth)),
                Series::line("odometry alone (uncorrected)", PALETTE[4], top(&odometry))
                    .with_style(Style::Dashed),
                Series::line("SLAM (final)", PALETTE[1], top(&slam_traj)),
            ],
            equal_aspect: true,
            ..Chart::default()
        },
        Chart {
            title: "Camera height: the gait's bobbing".into(),
            x_label: "time (s)".into(),
            y_label: "world z (m)".into(),
            series: vec![
                Series::line("ground truth", PALETTE[6], side(&st.synth.groundtruth)),
                Series::line("odometry alone (uncorrected)", PALETTE[4], side(&odometry))
                    .with_style(Style::Dashed),
                Series::line("SLAM (final)", PALETTE[1], side(&slam_traj)),
            ],
            ..Chart::default()
        },
    ];
    rep.figure(
        "trajectory",
        render(&charts, 2, 520.0, 380.0),
        "The SLAM's final trajectory against ground truth, in the world frame, and the odometry's own poses before the back end's corrections: the odometry drifts as it goes round, and the back end (bundle adjustment over the map's points, and loop closure when the robot comes back to its start) pulls the path back onto the ground truth. The table gives both errors.",
    );
    rep.heading("Terrain");
    let gt_path = top(&st.synth.groundtruth);
    rep.figure(
        "terrain",
        render(
            &[elevation_chart("True terrain", &st.truth, &gt_path)?],
            1,
            540.0,
            470.0,
        ),
        "The true terrain as a colour relief (height on the colour bar), with the walked path; objects are left out of it (grey).",
    );
    let path = top(&slam_traj);
    let mut maps = vec![elevation_chart(
        "Pipeline map (SLAM poses)",
        &st.map_slam.layers.elevation,
        &path,
    )?];
    maps.extend(error_chart(
        &st.map_slam.layers.elevation,
        &st.truth,
        &path,
    )?);
    rep.figure(
        "map_slam",
        render(&maps, 2, 540.0, 470.0),
        "Left: the map the pipeline built from its views (every second frame) at their optimized poses, with the walked path. Right: its error against the true terrain. Grey: unknown.",
    );
    let mut gt_maps = vec![elevation_chart(
        "Same views, ground-truth poses",
        &st.map_views_gt.layers.elevation,
        &gt_path,
    )?];
    for (r, _) in &st.map_frames_gt {
        gt_maps.push(elevation_chart(
            &format!("Every frame, ground-truth poses: {}", r.name),
            &r.layers.elevation,
            &gt_path,
        )?);
    }
    rep.figure(
        "maps_groundtruth",
        render(&gt_maps, 2, 540.0, 470.0),
        "Maps from ground-truth poses: the pipeline's views (what the SLAM's map is compared with), and every frame with our voxel-stack mapper (paper 000) and the Fankhauser et al. 2014 baseline.",
    );
    rep.heading("Motion blur");
    rep.paragraph(st.blur.as_str());
    rep.image(
        "sequence/blur.svg",
        "Image sharpness over time against the true image motion.",
    );
    rep.paragraph(format!(
        "Whole demo: {:.0} s of wall time. The SLAM's own report: slam/report.html.",
        started.elapsed().as_secs_f64()
    ));
    rep.write(dir)
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    write_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    Ok(())
}

/// The odometry's own poses (world frame), before any correction by the back end.
fn odometry_trajectory(out: &stride::pipeline::RunOutput) -> Result<Trajectory> {
    let mut t = Trajectory::new();
    for f in &out.frames {
        t.push(f.t_s, f.odometry_world_from_camera)?;
    }
    Ok(t)
}

/// The rows of the demo report's results table: what, value.
fn results_rows(st: &Stages, s: &Value) -> Vec<Vec<String>> {
    let mm = |path: &[&str]| format!("{:.1} mm", 1e3 * f(s, path));
    let j = &st.slam.json;
    let map_row = |label: &str, key: &[&str]| {
        let at = |k: &str| {
            let mut p = key.to_vec();
            p.push(k);
            f(s, &p)
        };
        vec![
            label.to_owned(),
            format!(
                "RMSE {:.1} mm, mean {:.1} mm, p95 {:.1} mm; coverage {:.2}; {} phantom cells",
                1e3 * at("rmse_m"),
                1e3 * at("mean_abs_m"),
                1e3 * at("p95_abs_m"),
                at("coverage"),
                at("phantoms")
            ) + &match at("rmse_away_from_steps_m") {
                away if away.is_finite() => format!(
                    "; away from steps and obstacles' feet RMSE {:.1} mm",
                    1e3 * away
                ),
                _ => String::new(),
            },
        ]
    };
    let mut rows = vec![
        vec![
            "frames tracked / recovered / lost / keyframes / loop closures".to_owned(),
            format!(
                "{} / {} / {} / {} / {}",
                j["frames_tracked"],
                j["frames_recovered"],
                j["frames_lost"],
                j["keyframes"],
                j["loop_closures"]
            ),
        ],
        vec![
            "ATE rmse (SE(3) aligned): SLAM final / live / odometry alone".to_owned(),
            format!(
                "{} / {} / {}",
                mm(&["slam", "ate_rmse_m"]),
                mm(&["slam", "ate_live_rmse_m"]),
                mm(&["slam", "ate_odometry_rmse_m"])
            ),
        ],
        vec![
            "SLAM RPE rmse per frame".to_owned(),
            format!(
                "{} / {:.3} deg",
                mm(&["slam", "rpe_rmse_m_per_frame"]),
                f(s, &["slam", "rpe_rmse_deg_per_frame"])
            ),
        ],
        vec![
            "pipeline speed (decoding excluded)".to_owned(),
            format!("{:.0} frames/s", f(s, &["slam", "fps"])),
        ],
        map_row("map, pipeline (SLAM poses)", &["map", "slam_poses"]),
        map_row(
            "map, same views at ground-truth poses",
            &["map", "groundtruth_poses_views"],
        ),
    ];
    for (r, _) in &st.map_frames_gt {
        rows.push(map_row(
            &format!("map, every frame at ground-truth poses: {}", r.name),
            &["map", "groundtruth_poses_every_frame", r.name],
        ));
    }
    rows.push(vec![
        "map rebuilds when the back end moved keyframes".to_owned(),
        match j["map"]["rebuild_ms"]["median"].as_f64() {
            Some(ms) => format!("{} (median {ms:.0} ms)", j["map"]["rebuilds"]),
            None => j["map"]["rebuilds"].to_string(),
        },
    ]);
    rows
}
