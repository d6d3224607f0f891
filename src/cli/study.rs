//! `stride study blur`: paper 004's study of gait-dependent motion blur on the synthetic lab.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use stride::pipeline::world::WorldPlan;
use stride::study::{RunResult, RunSpec, MAX_SPEED_M_S};
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::synth::motion::Gait;
use stride_datasets::synth::SynthConfig;
use stride_eval::plot::{render, Chart, Series, Style, PALETTE};
use stride_eval::report::Report;
use stride_output::fs::{write_atomic, StagedDir};

use super::synth::GaitArg;

#[derive(Debug, Subcommand)]
pub enum StudyCommand {
    /// Gait-dependent motion blur (paper 004): square walks at several speeds per gait,
    /// the SLAM on each, ATE, RPE, tracked frames and blur against speed and gait.
    Blur(BlurStudyArgs),
}

#[derive(Debug, Args)]
pub struct BlurStudyArgs {
    /// Output folder: study.json, report.html, report.md.
    #[arg(long)]
    out: PathBuf,
    /// Replace the output folder's contents.
    #[arg(long)]
    overwrite: bool,
    /// Gaits.
    #[arg(long, value_enum, value_delimiter = ',', default_values = ["tripod", "crawl"])]
    gaits: Vec<GaitArg>,
    /// Speeds as fractions of paper 004's full speed, 0.15 m/s.
    #[arg(long, value_delimiter = ',', default_values_t = [0.3, 0.45, 0.6, 0.8, 0.95])]
    speeds: Vec<f64>,
    /// Seeds per gait and speed (1, 2, ...).
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Frames per run (30 Hz).
    #[arg(long, default_value_t = 150)]
    frames: usize,
    /// A quick study for CI: 320x240 images, 45 frames, one seed, the slowest and fastest
    /// speeds (unless given).
    #[arg(long)]
    quick: bool,
    /// Every stage's parameters as a TOML file (`stride config --print-defaults`); the map
    /// is not built.
    #[arg(long, value_name = "FILE.toml")]
    config: Option<PathBuf>,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

pub fn run(c: StudyCommand) -> Result<()> {
    match c {
        StudyCommand::Blur(a) => blur(a),
    }
}

fn blur(mut a: BlurStudyArgs) -> Result<()> {
    super::check_out_dir("--out", &a.out, a.overwrite)?;
    let mut base = SynthConfig::default();
    if a.quick {
        let full = [0.3, 0.45, 0.6, 0.8, 0.95];
        if a.speeds == full {
            a.speeds = vec![0.3, 0.95];
        }
        a.seeds = 1;
        a.frames = a.frames.min(45);
        base.camera = CameraConfig {
            camera: stride_core::camera::PinholeCamera::new(
                258.65, 258.23, 159.3, 127.6, 320, 240,
            )?,
            ..base.camera
        };
    }
    if a.speeds
        .iter()
        .any(|s| !(s.is_finite() && *s > 0.0 && *s <= 1.0))
    {
        bail!("--speeds: each must be in (0, 1] (a fraction of {MAX_SPEED_M_S} m/s)");
    }
    if a.seeds == 0 || a.frames < 10 {
        bail!("--seeds must be at least 1 and --frames at least 10");
    }
    let mut config = match &a.config {
        Some(p) => stride::config::Config::load(p)?.pipeline(WorldPlan::Floor),
        None => stride::PipelineConfig::default(),
    };
    config.map = None;
    let specs: Vec<RunSpec> = a
        .gaits
        .iter()
        .flat_map(|g| {
            let gait = match g {
                GaitArg::Tripod => Gait::Tripod,
                GaitArg::Crawl => Gait::Crawl,
            };
            let frames = a.frames;
            a.speeds.iter().flat_map(move |&speed_fraction| {
                (1..=a.seeds).map(move |seed| RunSpec {
                    gait,
                    speed_fraction,
                    seed,
                    frames,
                })
            })
        })
        .collect();
    let bar = super::progress_bar(specs.len() * a.frames, "frames", !a.quiet);
    let mut runs = Vec::with_capacity(specs.len());
    for spec in &specs {
        let r = stride::study::run(spec, &base, &config, || bar.inc(1))?;
        tracing::info!(
            "{} at {:.2} of full speed, seed {}: ATE {:.2} mm, {} of {} frames tracked, image motion {:.1} px",
            r.gait,
            r.speed_fraction,
            r.seed,
            r.ate_m * 1e3,
            r.tracked,
            r.frames,
            r.image_motion_px_mean
        );
        runs.push(r);
    }
    bar.finish_and_clear();
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let json = serde_json::json!({
        "max_speed_m_s": MAX_SPEED_M_S,
        "frames": a.frames,
        "image_size": [base.camera.camera.width(), base.camera.camera.height()],
        "runs": runs,
    });
    write_atomic(
        &staged.path().join("study.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    let rows = table(&runs, &a.speeds);
    report(&runs, &rows, a.frames)
        .write(staged.path())
        .context("writing the report")?;
    staged
        .publish()
        .with_context(|| format!("publishing {}", a.out.display()))?;
    crate::outln!(
        "gait    speed  ATE mm (mean, worst)  RPE mm  tracked  lost  motion px  sharpness"
    )?;
    for r in &rows {
        crate::outln!("{}", r.join("  "))?;
    }
    crate::outln!("written to {}", a.out.display())?;
    Ok(())
}

/// Paper 004's Table 1 for our runs: per gait and speed, over the seeds.
fn table(runs: &[RunResult], speeds: &[f64]) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    for gait in ["tripod", "crawl"] {
        for &s in speeds {
            let set: Vec<&RunResult> = runs
                .iter()
                .filter(|r| r.gait == gait && r.speed_fraction == s)
                .collect();
            if set.is_empty() {
                continue;
            }
            let n = set.len() as f64;
            let mean = |f: &dyn Fn(&RunResult) -> f64| set.iter().map(|r| f(r)).sum::<f64>() / n;
            let worst_ate = set.iter().map(|r| r.ate_m).fold(0.0, f64::max);
            let frames: usize = set.iter().map(|r| r.frames).sum();
            let tracked: usize = set.iter().map(|r| r.tracked).sum();
            rows.push(vec![
                gait.to_owned(),
                format!("{s:.2} ({:.3} m/s)", s * MAX_SPEED_M_S),
                format!("{:.2}, {:.2}", mean(&|r| r.ate_m) * 1e3, worst_ate * 1e3),
                format!("{:.2}", mean(&|r| r.rpe_m) * 1e3),
                format!("{:.1} %", 100.0 * tracked as f64 / frames.max(1) as f64),
                format!("{}", frames - tracked),
                format!("{:.1}", mean(&|r| r.image_motion_px_mean)),
                format!("{:.0}", mean(&|r| r.sharpness_median)),
            ]);
        }
    }
    rows
}

/// The gait phase (x 5) over time, the line broken where the phase wraps to 0.
fn phase_line(pf: &[stride::study::FrameBlur]) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(pf.len() + 8);
    for (i, f) in pf.iter().enumerate() {
        if i > 0 && pf.get(i - 1).is_some_and(|p| p.gait_phase > f.gait_phase) {
            out.push((f64::NAN, f64::NAN));
        }
        out.push((f.t_s, 5.0 * f.gait_phase));
    }
    out
}

/// The HTML/Markdown report: the table and the plots.
fn report(runs: &[RunResult], rows: &[Vec<String>], frames: usize) -> Report {
    let per_gait = |f: &dyn Fn(&RunResult) -> (f64, f64), style: Style| -> Vec<Series> {
        ["tripod", "crawl"]
            .iter()
            .enumerate()
            .filter_map(|(i, g)| {
                let mut pts: Vec<(f64, f64)> =
                    runs.iter().filter(|r| r.gait == *g).map(f).collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                (!pts.is_empty()).then(|| Series::line(*g, PALETTE[i], pts).with_style(style))
            })
            .collect()
    };
    let ate = Chart {
        title: "ATE against speed (every seed)".into(),
        x_label: "speed (fraction of 0.15 m/s)".into(),
        y_label: "ATE RMSE (mm)".into(),
        series: per_gait(&|r| (r.speed_fraction, r.ate_m * 1e3), Style::Markers),
        y_from_zero: true,
        ..Chart::default()
    };
    let tracked = Chart {
        title: "Tracked frames against blur".into(),
        x_label: "mean true image motion in the exposure (px)".into(),
        y_label: "frames tracked (%)".into(),
        series: per_gait(
            &|r| {
                let pct = 100.0 * r.tracked as f64 / r.frames.max(1) as f64;
                (r.image_motion_px_mean, pct)
            },
            Style::Markers,
        ),
        y_from_zero: true,
        ..Chart::default()
    };
    let mut charts = vec![ate, tracked];
    // Blur over time in the fastest tripod run (else the fastest run).
    let fastest_of = |gait: Option<&str>| {
        runs.iter()
            .filter(|r| gait.is_none_or(|g| r.gait == g))
            .max_by(|a, b| a.speed_fraction.total_cmp(&b.speed_fraction))
    };
    let fastest = fastest_of(Some("tripod")).or_else(|| fastest_of(None));
    if let Some(r) = fastest {
        let pf = &r.per_frame;
        charts.push(Chart {
            title: format!(
                "Blur over time: {} at {:.2} of full speed, seed {}",
                r.gait, r.speed_fraction, r.seed
            ),
            x_label: "time (s)".into(),
            y_label: "px; legs".into(),
            series: vec![
                Series::line(
                    "true image motion (px)",
                    PALETTE[1],
                    pf.iter().map(|f| (f.t_s, f.image_motion_px)).collect(),
                ),
                Series::line(
                    "legs in stance",
                    PALETTE[2],
                    pf.iter()
                        .map(|f| (f.t_s, f64::from(f.stance_legs)))
                        .collect(),
                )
                .with_style(Style::Dashed),
                Series::line("gait phase x 5", PALETTE[3], phase_line(pf))
                    .with_style(Style::Dashed),
            ],
            y_from_zero: true,
            ..Chart::default()
        });
        charts.push(Chart {
            title: "Sharpness from the image alone, same run".into(),
            x_label: "time (s)".into(),
            y_label: "variance of the Laplacian (grey levels²)".into(),
            series: vec![Series::line(
                "sharpness",
                PALETTE[0],
                pf.iter().map(|f| (f.t_s, f.sharpness)).collect(),
            )],
            y_from_zero: true,
            ..Chart::default()
        });
    }
    let mut rep = Report::new("stride study blur: gait-dependent motion blur (paper 004)");
    rep.paragraph(format!(
        "{} run{} of {frames} frames at 30 Hz: square walks (0.75 m sides) in the synthetic lab \
         with motion blur, a 20 ms rolling shutter and the gait's shake; the SLAM (odometry \
         with bundle adjustment) on each as the frames are rendered. ATE: RMSE after SE(3) \
         alignment, RPE: over one frame (evo's definitions). A frame is tracked when the \
         odometry estimated it (tracked or recovered); lost frames were predicted.",
        runs.len(),
        if runs.len() == 1 { "" } else { "s" }
    ));
    rep.heading("Per gait and speed, over the seeds (as paper 004's Table 1)");
    rep.table(
        &[
            "gait",
            "speed",
            "ATE mm (mean, worst)",
            "RPE mm",
            "tracked",
            "lost",
            "image motion px",
            "sharpness",
        ],
        rows.to_vec(),
    );
    let corr: Vec<String> = runs
        .iter()
        .map(|r| {
            format!(
                "{} {:.2} s{}: {}",
                r.gait,
                r.speed_fraction,
                r.seed,
                r.sharpness_motion_correlation
                    .map_or("-".into(), |c| format!("{c:.2}"))
            )
        })
        .collect();
    rep.heading("Plots");
    rep.figure(
        "study",
        render(&charts, 2, 560.0, 360.0),
        "Top: ATE against speed and tracked frames against blur, per gait. Bottom: the blur of \
         the fastest tripod run over time with its gait, and the sharpness measured from the \
         images alone.",
    );
    rep.heading("Sharpness against true image motion");
    rep.paragraph(format!(
        "Correlation, per run, between a frame's variance of the Laplacian and its true image \
         motion during the exposure (negative: the image-only measure sees the blur): {}.",
        corr.join("; ")
    ));
    rep
}
