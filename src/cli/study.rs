//! `stride study blur`: paper 004's study of gait-dependent motion blur on the synthetic lab.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use stride::pipeline::world::WorldPlan;
use stride::study::{frames_for_distance, RunResult, RunSpec, MAX_SPEED_M_S};
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::synth::motion::Gait;
use stride_datasets::synth::SynthConfig;
use stride_eval::plot::{render, Chart, Series, Style, PALETTE};
use stride_eval::report::Report;
use stride_output::fs::{write_atomic, StagedDir};

use super::run::TopicArgs;
use super::study_real;
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
    /// Distance every run walks (m), along a square with 0.75 m sides. Paper 004's runs
    /// walked the same rectangle at each speed, so a slower run takes more frames (at 30 Hz:
    /// 0.5 m is 105 frames at 0.95 of full speed, 333 at 0.30) and every speed's error is
    /// measured over the same path. More than 0.75 m reaches the first turn on the spot.
    #[arg(long, default_value_t = 0.5, value_name = "M")]
    distance_m: f64,
    /// A quick study for CI: 320x240 images, walks of at most 0.2 m, one seed, the slowest
    /// and fastest speeds (unless given); on the real side the first 60 frames, unblurred
    /// and at 25 px (unless given).
    #[arg(long)]
    quick: bool,
    /// The real side: a recorded sequence with ground truth (a TUM folder or an MCAP log),
    /// its colour frames blurred along each pixel's image motion at `--lengths`, the SLAM on
    /// each (e.g. ../shared/data/tum/rgbd_dataset_freiburg3_teddy_200).
    #[arg(long, value_name = "DIR|FILE.mcap")]
    real: Option<PathBuf>,
    /// Median blur lengths of the real side (px); 0 is the sequence as recorded.
    #[arg(long, value_delimiter = ',', default_values_t = [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0])]
    lengths: Vec<f64>,
    /// Only the real side (needs --real).
    #[arg(long, requires = "real")]
    real_only: bool,
    /// Camera of the real sequence (as `stride run --camera`).
    #[arg(long)]
    camera: Option<String>,
    /// Python of a throwaway venv with pyorbslam3 and evo: also run ORB-SLAM3 on the real
    /// side's blurred frames, in this session, through ../shared/tools/peers/orbslam3_tum.py
    /// (never a project dependency; a TUM --real folder only).
    #[arg(long, value_name = "PYTHON", requires = "real")]
    orbslam3: Option<PathBuf>,
    /// The blur mitigations: frames whose colour image the features cannot place are
    /// placed by their depth (odometry key `depth_alignment`), each colour row's rotation
    /// comes from the gyroscope, over the readout and the exposure (`readout_gyroscope`),
    /// and its translation from the accelerometer (`readout_accelerometer`), the rotation
    /// predicted from frame to frame comes from the gyroscope (`predict_gyroscope`), and a
    /// keyframe waits out a jolt the gyroscope shows (`keyframe_jolt_ratio`). `on` runs
    /// them as configured (each can be switched off in `--config`), `off` turns them all
    /// off, `both` runs every sequence off and on and tables them side by side.
    #[arg(long, value_enum, default_value_t = Mitigation::On)]
    mitigation: Mitigation,
    #[command(flatten)]
    topics: TopicArgs,
    /// Every stage's parameters as a TOML file (`stride config --print-defaults`); the map
    /// is not built.
    #[arg(long, value_name = "FILE.toml")]
    config: Option<PathBuf>,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

/// Which runs have the blur mitigations on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Mitigation {
    /// Off (the odometry without its blur mitigations).
    Off,
    /// On (as configured).
    On,
    /// Each sequence twice: off, then on.
    Both,
}

impl Mitigation {
    /// The settings to run (see `stride::study::with_mitigation`).
    fn settings(self) -> Vec<bool> {
        match self {
            Mitigation::Off => vec![false],
            Mitigation::On => vec![true],
            Mitigation::Both => vec![false, true],
        }
    }
}

pub fn run(c: StudyCommand) -> Result<()> {
    match c {
        StudyCommand::Blur(a) => blur(a),
    }
}

fn blur(mut a: BlurStudyArgs) -> Result<()> {
    super::check_out_dir("--out", &a.out, a.overwrite)?;
    let mut base = SynthConfig::default();
    let mut real_frames = None;
    if a.quick {
        let full = [0.3, 0.45, 0.6, 0.8, 0.95];
        if a.speeds == full {
            a.speeds = vec![0.3, 0.95];
        }
        if a.lengths == [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0] {
            a.lengths = vec![0.0, 25.0];
        }
        a.seeds = 1;
        a.distance_m = a.distance_m.min(0.2);
        real_frames = Some(60);
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
    if a.lengths.iter().any(|l| !(l.is_finite() && *l >= 0.0)) {
        bail!("--lengths: each must be a blur length of 0 px or more");
    }
    if a.seeds == 0 {
        bail!("--seeds must be at least 1");
    }
    if !(a.distance_m.is_finite() && a.distance_m > 0.0) {
        bail!("--distance-m must be a positive distance (m)");
    }
    let fps = base.fps;
    if let Some(s) = (a.speeds.iter()).find(|&&s| frames_for_distance(a.distance_m, s, fps) < 10) {
        bail!(
            "--distance-m {}: at {s} of full speed that is fewer than 10 frames; walk further",
            a.distance_m
        );
    }
    let mut config = match &a.config {
        Some(p) => stride::config::Config::load(p)?.pipeline(WorldPlan::Floor),
        None => stride::PipelineConfig::default(),
    };
    config.map = None;
    let real = match &a.real {
        Some(p) => Some(
            a.topics
                .open(p, a.camera.as_deref())
                .with_context(|| format!("--real {}", p.display()))?,
        ),
        None => None,
    };
    if let Some(seq) = &real {
        if seq.groundtruth().is_none() {
            bail!(
                "--real {}: it has no ground truth to blur and score with",
                seq.path().display()
            );
        }
    }
    let specs: Vec<RunSpec> = if a.real_only {
        Vec::new()
    } else {
        specs(&a, fps)
    };
    let real_len = real.as_ref().map_or(0, |s| {
        real_frames.map_or(s.len(), |m: usize| m.min(s.len()))
    });
    let mitigations = a.mitigation.settings();
    let bar = super::progress_bar(
        specs.iter().map(|s| s.frames).sum::<usize>() * mitigations.len()
            + real_len * a.lengths.len(),
        "frames",
        !a.quiet,
    );
    let mut runs = Vec::with_capacity(specs.len());
    for (spec, &mitigation) in specs
        .iter()
        .flat_map(|s| mitigations.iter().map(move |m| (s, m)))
    {
        let config = stride::study::with_mitigation(&config, mitigation);
        let r = stride::study::run(spec, &base, &config, || bar.inc(1))?;
        tracing::info!(
            "{} at {:.2} of full speed, seed {}, mitigation {}: ATE {:.2} mm, {} of {} frames tracked ({} by depth), image motion {:.1} px",
            r.gait,
            r.speed_fraction,
            r.seed,
            on_off(mitigation),
            r.scores.ate_m * 1e3,
            r.tracked,
            r.frames,
            r.depth_aligned,
            r.image_motion_px_mean
        );
        runs.push(r);
    }
    let variants: Vec<(u64, bool)> = (1..=a.seeds)
        .flat_map(|s| mitigations.iter().map(move |&m| (s, m)))
        .collect();
    let (real_runs, peer_runs) = match &real {
        Some(seq) => {
            let camera = match &a.orbslam3 {
                Some(_) => Some(study_real::peer_camera(seq, a.camera.as_deref())?),
                None => None,
            };
            let peer = a.orbslam3.as_deref().zip(camera.as_deref());
            study_real::runs(seq, &a.lengths, &variants, &config, real_frames, peer, &bar)?
        }
        None => (Vec::new(), Vec::new()),
    };
    bar.finish_and_clear();
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let real_name = real.as_ref().map(|s| s.path().display().to_string());
    let json = serde_json::json!({
        "max_speed_m_s": MAX_SPEED_M_S,
        "distance_m": a.distance_m,
        "image_size": [base.camera.camera.width(), base.camera.camera.height()],
        "runs": runs,
        "real": real_name.as_ref().map(|d| serde_json::json!({
            "dataset": d,
            "lengths_px": a.lengths,
            "half_window_s": stride_datasets::motion_blur::MotionBlur::default().half_window_s,
            "runs": real_runs,
            "orbslam3": peer_runs.iter().map(|(l, s)| serde_json::json!({"length_px": l, "summary": s})).collect::<Vec<_>>(),
        })),
    });
    write_atomic(
        &staged.path().join("study.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    let rows = table(&runs, &a.speeds, &mitigations);
    let real_section = real_name
        .as_deref()
        .map(|d| (d, a.seeds, &real_runs[..], &peer_runs));
    report(&runs, &rows, a.distance_m, real_section)
        .write(staged.path())
        .context("writing the report")?;
    staged
        .publish()
        .with_context(|| format!("publishing {}", a.out.display()))?;
    if !runs.is_empty() {
        crate::outln!("{}", COLUMNS.join("  "))?;
        for r in &rows {
            crate::outln!("{}", r.join("  "))?;
        }
    }
    if let Some(d) = &real_name {
        crate::outln!("{d}, blurred along its motion:")?;
        crate::outln!("{}", study_real::columns(!peer_runs.is_empty()).join("  "))?;
        for r in study_real::table(&real_runs, &peer_runs) {
            crate::outln!("{}", r.join("  "))?;
        }
    }
    crate::outln!("written to {}", a.out.display())?;
    Ok(())
}

/// The synthetic runs: each gait at each speed with each seed, each walking `a.distance_m`
/// at `fps` (Hz).
fn specs(a: &BlurStudyArgs, fps: f64) -> Vec<RunSpec> {
    a.gaits
        .iter()
        .flat_map(|g| {
            let gait = match g {
                GaitArg::Tripod => Gait::Tripod,
                GaitArg::Crawl => Gait::Crawl,
            };
            a.speeds.iter().flat_map(move |&speed_fraction| {
                let frames = frames_for_distance(a.distance_m, speed_fraction, fps);
                (1..=a.seeds).map(move |seed| RunSpec {
                    gait,
                    speed_fraction,
                    seed,
                    frames,
                })
            })
        })
        .collect()
}

/// "on" or "off".
pub(crate) fn on_off(on: bool) -> &'static str {
    if on {
        "on"
    } else {
        "off"
    }
}

/// Paper 004's Table 1 for our runs: per gait, speed and mitigation, over the seeds.
fn table(runs: &[RunResult], speeds: &[f64], mitigations: &[bool]) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    let cases = ["tripod", "crawl"].into_iter().flat_map(|g| {
        speeds
            .iter()
            .flat_map(move |&s| mitigations.iter().map(move |&m| (g, s, m)))
    });
    for (gait, s, m) in cases {
        let set: Vec<&RunResult> = runs
            .iter()
            .filter(|r| r.gait == gait && r.speed_fraction == s && r.mitigation == m)
            .collect();
        if set.is_empty() {
            continue;
        }
        let n = set.len() as f64;
        let mean = |f: &dyn Fn(&RunResult) -> f64| set.iter().map(|r| f(r)).sum::<f64>() / n;
        let worst_ate = set.iter().map(|r| r.scores.ate_m).fold(0.0, f64::max);
        let frames: usize = set.iter().map(|r| r.frames).sum();
        let tracked: usize = set.iter().map(|r| r.tracked).sum();
        let by_depth: usize = set.iter().map(|r| r.depth_aligned).sum();
        rows.push(vec![
            gait.to_owned(),
            format!("{s:.2} ({:.3} m/s)", s * MAX_SPEED_M_S),
            format!("{}", set.first().map_or(0, |r| r.frames)),
            on_off(m).to_owned(),
            format!(
                "{:.2}, {:.2}",
                mean(&|r| r.scores.ate_m) * 1e3,
                worst_ate * 1e3
            ),
            format!("{:.2}", mean(&|r| r.scores.ate_sim3_m) * 1e3),
            format!("{:.2}", mean(&|r| scale_off_pct(&r.scores))),
            format!("{:.2}", mean(&|r| r.scores.rpe_m) * 1e3),
            format!("{:.1} %", 100.0 * tracked as f64 / frames.max(1) as f64),
            format!("{by_depth}"),
            format!("{}", frames - tracked),
            format!("{:.1}", mean(&|r| r.image_motion_px_mean)),
            format!("{:.0}", mean(&|r| r.sharpness_median)),
        ]);
    }
    rows
}

/// The columns of the synthetic runs' table ([`table`]'s rows).
const COLUMNS: [&str; 13] = [
    "gait",
    "speed",
    "frames per run",
    "mitigation",
    "ATE mm (mean, worst)",
    SIM3_ATE_COLUMN,
    SCALE_OFF_COLUMN,
    "RPE mm",
    "tracked",
    "by depth",
    "lost",
    "image motion px",
    "sharpness",
];

/// The table column of the ATE once the scale is taken out.
pub(super) const SIM3_ATE_COLUMN: &str = "ATE mm, Sim(3)";

/// The table column of [`scale_off_pct`].
pub(super) const SCALE_OFF_COLUMN: &str = "length off % (mean)";

/// How far the trajectory's length is from the truth's (%, unsigned): `|1 / s - 1|` for
/// the Sim(3) alignment's scale `s` (an RGB-D SLAM's scale comes from its depth).
pub(super) fn scale_off_pct(s: &stride::study::TrajectoryScores) -> f64 {
    100.0 * (1.0 / s.sim3_scale - 1.0).abs()
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

/// The HTML/Markdown report: the tables and the plots (the real side's when it ran:
/// dataset, seeds, runs).
fn report(
    runs: &[RunResult],
    rows: &[Vec<String>],
    distance_m: f64,
    real: Option<(
        &str,
        u64,
        &[stride::study::real::RealRun],
        &study_real::PeerRuns,
    )>,
) -> Report {
    // One series per gait, and per mitigation setting when both ran.
    let both = runs.iter().any(|r| r.mitigation) && runs.iter().any(|r| !r.mitigation);
    let settings: &[Option<bool>] = if both {
        &[Some(false), Some(true)]
    } else {
        &[None]
    };
    let per_gait = |f: &dyn Fn(&RunResult) -> (f64, f64), style: Style| -> Vec<Series> {
        ["tripod", "crawl"]
            .iter()
            .flat_map(|g| settings.iter().map(move |m| (g, *m)))
            .enumerate()
            .filter_map(|(i, (g, m))| {
                let mut pts: Vec<(f64, f64)> = runs
                    .iter()
                    .filter(|r| r.gait == *g && m.is_none_or(|m| r.mitigation == m))
                    .map(f)
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                let name = match m {
                    Some(m) => format!("{g}, mitigation {}", on_off(m)),
                    None => (*g).to_owned(),
                };
                let colour = PALETTE.get(i).copied().unwrap_or(PALETTE[0]);
                (!pts.is_empty()).then(|| Series::line(name, colour, pts).with_style(style))
            })
            .collect()
    };
    let ate = Chart {
        title: "ATE against speed (every seed)".into(),
        x_label: "speed (fraction of 0.15 m/s)".into(),
        y_label: "ATE RMSE (mm)".into(),
        series: per_gait(
            &|r| (r.speed_fraction, r.scores.ate_m * 1e3),
            Style::Markers,
        ),
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
    if !runs.is_empty() {
        let fewest = runs.iter().map(|r| r.frames).min().unwrap_or(0);
        let most = runs.iter().map(|r| r.frames).max().unwrap_or(0);
        rep.paragraph(format!(
            "{} run{}, each a walk of {distance_m} m at 30 Hz ({fewest}-{most} frames: the \
             slower, the more, since paper 004's runs walked the same path at each speed) \
             along a square (0.75 m sides) in the synthetic lab with motion blur, a 20 ms \
             rolling shutter and the gait's shake; the SLAM (odometry with bundle \
             adjustment) on each as the frames are rendered. ATE: RMSE \
             after SE(3) alignment, RPE: over one frame (evo's definitions). A frame is tracked \
             when the odometry estimated it (tracked, recovered, relocalized, or placed by its \
             depth: the mitigation, counted apart as 'by depth'); lost frames were predicted. \
             Mitigation: frames the features lose are placed by aligning their depth with the \
             last keyframe's (the colour blurs, the depth does not); each colour row's \
             rotation is integrated from the lab's gyroscope and its translation from its \
             accelerometer over the readout, averaged over the exposure; the rotation from \
             frame to frame is predicted from the gyroscope; and a keyframe that lost tracks \
             ask for waits while it shows a foot's impact. On and off, the tracks are \
             measured again with each estimate of the frame's motion (the rolling shutter's \
             model, `rolling_shutter_passes`).",
            runs.len(),
            if runs.len() == 1 { "" } else { "s" }
        ));
        rep.heading("Per gait and speed, over the seeds (as paper 004's Table 1)");
        rep.table(&COLUMNS, rows.to_vec());
        rep.heading("Plots");
        rep.figure(
            "study",
            render(&charts, 2, 560.0, 360.0),
            "Top: ATE against speed and tracked frames against blur, per gait. Bottom: the \
             blur of the fastest tripod run over time with its gait, and the sharpness measured \
             from the images alone.",
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
        rep.heading("Sharpness against true image motion");
        rep.paragraph(format!(
            "Correlation, per run, between a frame's variance of the Laplacian and its true \
             image motion during the exposure (negative: the image-only measure sees the blur): \
             {}.",
            corr.join("; ")
        ));
    }
    if let Some((dataset, seeds, real_runs, peer)) = real {
        study_real::section(&mut rep, dataset, seeds, real_runs, peer);
        rep.figure(
            "real",
            render(&study_real::charts(real_runs, peer), 2, 560.0, 360.0),
            "ATE and tracked frames against the median blur length, every seed.",
        );
    }
    rep
}
