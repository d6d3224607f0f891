//! `stride synth`: synthetic legged-robot RGB-D sequences with ground truth.

use crate::cli::map_figures::elevation_chart;
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::grid_file::read_grid;
use stride_datasets::png_io::read_rgb;
use stride_datasets::synth::motion::{Gait, MotionConfig, PathKind};
use stride_datasets::synth::{generate, SynthConfig, SynthError, SynthSummary, TerrainSource};
use stride_eval::blur::{correlation, dominant_frequency_hz, laplacian_variance};
use stride_eval::plot::{render, Chart, Series, Style, PALETTE};
use stride_eval::report::Report;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum GaitArg {
    /// Two alternating tripods: fast and shaky.
    Tripod,
    /// Wave gait, five legs down: slow and smooth.
    Crawl,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum PathArg {
    /// Straight ahead.
    Straight,
    /// A square loop with turns on the spot.
    Square,
    /// Turning on the spot.
    Turn,
}

#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Output folder (TUM layout); must not exist or be empty unless --overwrite.
    #[arg(long)]
    out: PathBuf,
    /// Terrain from a grey-level PNG (e.g. ../shared/data/terrain/terrain.png).
    #[arg(long, value_name = "IMAGE", conflicts_with = "procedural")]
    terrain: Option<PathBuf>,
    /// Height of white in the terrain image (m).
    #[arg(
        long,
        value_name = "M",
        default_value_t = 0.2,
        requires = "terrain",
        allow_negative_numbers = true
    )]
    height_scale: f64,
    /// Ground size of one terrain-image pixel (m); 0.03 for the grid_map demo image.
    #[arg(
        long,
        value_name = "M",
        default_value_t = 0.03,
        requires = "terrain",
        allow_negative_numbers = true
    )]
    terrain_resolution: f64,
    /// Procedural terrain: mixed, steps, ramps, boxes, rubble, slopes [default: mixed].
    #[arg(long, value_name = "NAME")]
    procedural: Option<String>,
    /// Gait.
    #[arg(long, value_enum, default_value = "tripod")]
    gait: GaitArg,
    /// Walking speed (m/s).
    #[arg(
        long,
        value_name = "M_PER_S",
        default_value_t = 0.1,
        allow_negative_numbers = true
    )]
    speed: f64,
    /// Path shape.
    #[arg(long, value_enum, default_value = "straight")]
    path: PathArg,
    /// Side of the square path (m).
    #[arg(
        long,
        value_name = "M",
        default_value_t = 1.5,
        allow_negative_numbers = true
    )]
    square_side: f64,
    /// Number of frames.
    #[arg(long, value_name = "N", default_value_t = 150)]
    frames: usize,
    /// Frame rate (Hz).
    #[arg(
        long,
        value_name = "HZ",
        default_value_t = 30.0,
        allow_negative_numbers = true
    )]
    fps: f64,
    /// Seed of every random choice.
    #[arg(long, value_name = "S", default_value_t = 1)]
    seed: u64,
    /// Do not render motion blur.
    #[arg(long)]
    no_blur: bool,
    /// Exposure time (ms).
    #[arg(
        long,
        value_name = "MS",
        default_value_t = 20.0,
        allow_negative_numbers = true
    )]
    exposure_ms: f64,
    /// Rolling-shutter readout time of the colour image, first row to last (ms; 0: global
    /// shutter). Depth stays global-shutter, as on a Kinect.
    #[arg(
        long,
        value_name = "MS",
        default_value_t = 20.0,
        allow_negative_numbers = true
    )]
    rolling_shutter_ms: f64,
    /// Scale of the gait-induced shaking (1 = Messor II-like).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    shake: f64,
    /// Fraction of depth-edge pixels that become flying pixels (spurious returns).
    #[arg(
        long,
        value_name = "P",
        default_value_t = 0.1,
        allow_negative_numbers = true
    )]
    flying_pixels: f64,
    /// Scale of the depth's smooth gain field (a PrimeSense camera's depth distortion: up
    /// to 0.4 % at the corners plus a ±0.3 % field at 1): 0 renders depth without it.
    #[arg(
        long,
        value_name = "SCALE",
        default_value_t = 1.0,
        allow_negative_numbers = true
    )]
    depth_bias_scale: f64,
    /// Replace an existing output folder.
    #[arg(long)]
    overwrite: bool,
}

impl SynthArgs {
    /// The generator configuration these arguments describe.
    pub fn config(&self) -> Result<SynthConfig> {
        if !(0.0..=1.0).contains(&self.flying_pixels) {
            bail!(
                "--flying-pixels {} must be a fraction in [0, 1]",
                self.flying_pixels
            );
        }
        if !(self.depth_bias_scale.is_finite() && self.depth_bias_scale >= 0.0) {
            bail!(
                "--depth-bias-scale {} must be finite and 0 or more",
                self.depth_bias_scale
            );
        }
        let defaults = SynthConfig::default();
        let terrain = match (&self.terrain, &self.procedural) {
            (Some(p), _) => TerrainSource::Image {
                path: p.clone(),
                height_scale_m: self.height_scale,
                resolution_m: self.terrain_resolution,
            },
            (None, name) => TerrainSource::Procedural {
                name: name.clone().unwrap_or_else(|| "mixed".into()),
                resolution_m: 0.01,
            },
        };
        let motion = MotionConfig {
            gait: match self.gait {
                GaitArg::Tripod => Gait::Tripod,
                GaitArg::Crawl => Gait::Crawl,
            },
            speed_m_s: self.speed,
            path: match self.path {
                PathArg::Straight => PathKind::Straight,
                PathArg::Square => PathKind::Square,
                PathArg::Turn => PathKind::Turn,
            },
            square_side_m: self.square_side,
            shake: self.shake,
            ..MotionConfig::default()
        };
        let mut depth_noise = defaults.depth_noise;
        depth_noise.flying_pixels = self.flying_pixels;
        depth_noise.edge_dropout = depth_noise.edge_dropout.min(1.0 - self.flying_pixels);
        depth_noise.bias_radial *= self.depth_bias_scale;
        depth_noise.bias_field *= self.depth_bias_scale;
        let c = SynthConfig {
            terrain,
            motion,
            frames: self.frames,
            fps: self.fps,
            seed: self.seed,
            blur: !self.no_blur,
            exposure_s: self.exposure_ms / 1000.0,
            camera: CameraConfig {
                rolling_shutter_s: self.rolling_shutter_ms / 1000.0,
                ..defaults.camera
            },
            depth_noise,
            ..defaults
        };
        c.validate()?;
        Ok(c)
    }
}

/// Generates a sequence with a progress bar; returns its summary.
pub fn synthesize(config: &SynthConfig, out: &Path, overwrite: bool) -> Result<SynthSummary> {
    let pb = crate::cli::progress_bar(config.frames, "rendering", true);
    let summary = match generate(config, out, overwrite, &mut |done, _| {
        pb.set_position(done as u64)
    }) {
        Err(SynthError::NotEmpty(p)) => bail!(
            "{} exists and is not empty (pass --overwrite to replace it)",
            p.display()
        ),
        other => other
            .with_context(|| format!("generating the synthetic sequence in {}", out.display()))?,
    };
    pb.finish_and_clear();
    Ok(summary)
}

pub fn run(a: SynthArgs) -> Result<()> {
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    let config = a.config()?;
    let summary = synthesize(&config, &a.out, a.overwrite)?;
    let median = stride::pipeline::median_p95(summary.render_s.iter().copied()).0;
    crate::outln!(
        "{} frames in {:.1} s: rendering {:.1} ms/frame median ({:.1} frames/s{}), gait cycle {:.2} Hz, steps {:.2} Hz",
        summary.frames.len(),
        summary.total_s,
        median * 1e3,
        1.0 / median,
        if config.blur { ", with blur" } else { "" },
        summary.cycle_hz,
        summary.step_hz
    )?;
    let blur = blur_report(&summary, config.fps)?;
    crate::outln!("{blur}")?;
    crate::outln!("written to {}", a.out.display())?;
    Ok(())
}

/// The sharpness's dominant frequency is looked for from this frequency up (Hz): a walking
/// robot steps faster, and the slower changes are its path's (the demo's lap turns every
/// 7.5 s, 0.13 Hz, which was the strongest frequency of its sharpness).
const GAIT_MIN_HZ: f64 = 0.5;

/// Sharpness of every frame, its dominant frequency (from [`GAIT_MIN_HZ`] up) and its
/// correlation with the true image motion; writes `blur.svg` and `report.html`/`report.md`
/// into the sequence folder.
pub fn blur_report(summary: &SynthSummary, fps: f64) -> Result<String> {
    let dir = &summary.out_dir;
    let mut sharp = Vec::with_capacity(summary.frames.len());
    for f in &summary.frames {
        let p = dir.join("rgb").join(format!("{:.6}.png", f.t_s));
        sharp.push(laplacian_variance(&read_rgb(&p)?.to_gray()));
    }
    let motion: Vec<f64> = summary.frames.iter().map(|f| f.image_motion_px).collect();
    let t0 = summary.frames.first().map_or(0.0, |f| f.t_s);
    let t: Vec<f64> = summary.frames.iter().map(|f| f.t_s - t0).collect();
    let dom = dominant_frequency_hz(&sharp, fps, GAIT_MIN_HZ);
    let corr = correlation(&sharp, &motion);
    let charts = [
        Chart {
            title: "Sharpness (variance of the Laplacian)".into(),
            x_label: "time (s)".into(),
            y_label: "grey levels²".into(),
            series: vec![Series::line(
                "sharpness",
                PALETTE[0],
                t.iter().copied().zip(sharp.iter().copied()).collect(),
            )],
            y_from_zero: true,
            ..Chart::default()
        },
        Chart {
            title: "True image motion during the exposure".into(),
            x_label: "time (s)".into(),
            y_label: "pixels".into(),
            series: vec![
                Series::line(
                    "image motion",
                    PALETTE[1],
                    t.iter().copied().zip(motion.iter().copied()).collect(),
                ),
                Series::line(
                    "stance legs / 2",
                    PALETTE[2],
                    summary
                        .frames
                        .iter()
                        .map(|f| (f.t_s - t0, f64::from(f.stance_legs) / 2.0))
                        .collect(),
                )
                .with_style(Style::Dashed),
            ],
            y_from_zero: true,
            ..Chart::default()
        },
    ];
    let svg = render(&charts, 2, 560.0, 360.0);
    let text = format!(
        "sharpness median {:.1}; dominant frequency {} (of those from {GAIT_MIN_HZ} Hz; gait steps at {:.2} Hz); correlation with image motion {}",
        stride::pipeline::median_p95(sharp.iter().copied()).0,
        dom.map_or("-".into(), |f| format!("{f:.2} Hz")),
        summary.step_hz,
        corr.map_or("-".into(), |c| format!("{c:.2}"))
    );
    let mut rep = Report::new("stride synth: synthetic legged-robot sequence");
    rep.paragraph(format!(
        "{} frames at {fps} Hz in {}.",
        summary.frames.len(),
        dir.display()
    ));
    let truth = read_grid(&dir.join("terrain.npy"), None).context("reading the terrain back")?;
    let path: Vec<(f64, f64)> = summary
        .groundtruth
        .positions()
        .iter()
        .map(|p| (p.x, p.y))
        .collect();
    rep.figure(
        "terrain",
        render(
            &[elevation_chart("True terrain", &truth, &path)?],
            1,
            540.0,
            470.0,
        ),
        "The ground-truth terrain as a colour relief (height on the colour bar), with the camera's path; objects are left out of it (grey).",
    );
    rep.heading("Motion blur over the gait");
    rep.paragraph(text.clone());
    rep.figure("blur", svg, "Left: sharpness of each frame. Right: true image motion during the exposure and legs in stance.");
    rep.write(dir)
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    Ok(text)
}
