//! Paper 004's study of gait-dependent motion blur (sections 4-6): how fast a walking
//! robot may go before its camera's blur breaks the SLAM, per gait.
//!
//! One run: the synthetic lab renders a square walk (with motion blur, a rolling shutter and
//! the gait's shake) at a fraction of the 0.15 m/s maximum speed of paper 004's Messor II,
//! the frames go through the [`Pipeline`] as they are rendered (no files), and the run is
//! scored: ATE and RPE against the lab's ground truth, frames tracked and lost, and the blur
//! of each frame, measured from the image alone (variance of the Laplacian) and from the
//! ground truth (the largest image motion of scene points during the exposure).
//!
//! The real side ([`real`]): a recorded sequence blurred along each pixel's image motion at
//! increasing lengths, scored the same way.

pub mod real;

use crate::pipeline::{slam_ate_options, FrameStatus, Pipeline, PipelineConfig, PipelineError};
use stride_core::trajectory::Trajectory;
use stride_datasets::synth::motion::{Gait, PathKind};
use stride_datasets::synth::{Synth, SynthConfig, SynthError};
use stride_eval::blur::{correlation, laplacian_variance};
use stride_eval::{ate, rpe, Align, AteOptions, EvalError, Preset, RpeOptions};

/// Paper 004's full speed (m/s): the study's speeds are fractions of it.
pub const MAX_SPEED_M_S: f64 = 0.15;

/// A run's trajectory scored against its ground truth, evo's definitions.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TrajectoryScores {
    /// ATE RMSE after SE(3) alignment (m).
    pub ate_m: f64,
    /// ATE RMSE after Sim(3) alignment (m): what is left once the trajectory's scale is
    /// taken out (never more than `ate_m`, which the same fit with the scale held at 1
    /// gives).
    pub ate_sim3_m: f64,
    /// The scale the Sim(3) alignment applies to the estimate (above 1: the trajectory
    /// came out short). An RGB-D SLAM takes its scale from the depth, so a depth
    /// sensor's calibration shows here.
    pub sim3_scale: f64,
    /// RPE RMSE over one frame (m).
    pub rpe_m: f64,
    /// RPE RMSE over one frame (degrees).
    pub rpe_deg: f64,
}

/// Scores `traj` against `gt`: ATE (SE(3) and Sim(3)) and RPE over one frame.
pub fn score_trajectory(gt: &Trajectory, traj: &Trajectory) -> Result<TrajectoryScores, EvalError> {
    let se3 = ate(gt, traj, &slam_ate_options())?;
    let sim3_options = AteOptions {
        align: Align::Sim3,
        ..slam_ate_options()
    };
    let sim3 = ate(gt, traj, &sim3_options)?;
    let rp = rpe(gt, traj, &RpeOptions::for_preset(Preset::Evo))?;
    Ok(TrajectoryScores {
        ate_m: se3.trans_m.rmse,
        ate_sim3_m: sim3.trans_m.rmse,
        sim3_scale: sim3.alignment.scale,
        rpe_m: rp.trans_m.rmse,
        rpe_deg: rp.rot_deg.rmse,
    })
}

/// Why a study run failed.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The synthetic sequence could not be built.
    #[error(
        "synthetic sequence ({gait:?}, {speed_fraction} of full speed, seed {seed}): {source}"
    )]
    Synth {
        /// The gait.
        gait: Gait,
        /// The speed as a fraction of [`MAX_SPEED_M_S`].
        speed_fraction: f64,
        /// The seed.
        seed: u64,
        /// The error.
        source: SynthError,
    },
    /// The pipeline failed.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// The evaluation against ground truth failed.
    #[error("evaluation: {0}")]
    Eval(#[from] EvalError),
    /// The real side's sequence has no ground truth to blur and score with.
    #[error("{dataset}: the blur study needs a ground truth (groundtruth.txt)")]
    NoGroundTruth {
        /// The sequence.
        dataset: String,
    },
    /// A frame could not be made: a rendered frame's ground-truth pose could not join the
    /// trajectory (a time out of order), or a recorded frame could not be blurred.
    #[error("frame {frame}: {message}")]
    Frame {
        /// Frame index.
        frame: usize,
        /// What was wrong.
        message: String,
    },
}

/// Frames a run at `speed_fraction` of [`MAX_SPEED_M_S`] takes to walk `distance_m` (m) at
/// `fps` (Hz), rounded. Every speed walks the same path, as paper 004's runs walked the same
/// rectangle, so a slower run has more frames and the error of each speed is measured over
/// the same distance.
pub fn frames_for_distance(distance_m: f64, speed_fraction: f64, fps: f64) -> usize {
    (distance_m / (speed_fraction * MAX_SPEED_M_S) * fps).round() as usize
}

/// One run of the study: a gait at a speed with a seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunSpec {
    /// The gait.
    pub gait: Gait,
    /// Speed as a fraction of [`MAX_SPEED_M_S`].
    pub speed_fraction: f64,
    /// Seed of the lab's random choices (terrain, shake, noise) and of the SLAM's RANSAC.
    pub seed: u64,
    /// Frames rendered (at the lab's 30 Hz).
    pub frames: usize,
}

/// One frame's blur.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FrameBlur {
    /// Time since the first frame (s).
    pub t_s: f64,
    /// Gait phase in `[0, 1)`.
    pub gait_phase: f64,
    /// Legs in stance.
    pub stance_legs: u8,
    /// Largest true image motion of scene points during the exposure (px).
    pub image_motion_px: f64,
    /// Variance of the Laplacian of the grey image (grey levels²): falls as blur rises.
    pub sharpness: f64,
    /// Whether the odometry estimated the frame (tracked, recovered, relocalized or placed by
    /// depth).
    pub tracked: bool,
}

/// What one run measured.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RunResult {
    /// The gait, as named on the command line.
    pub gait: &'static str,
    /// Speed as a fraction of [`MAX_SPEED_M_S`].
    pub speed_fraction: f64,
    /// The seed.
    pub seed: u64,
    /// Frames.
    pub frames: usize,
    /// Frames the odometry estimated (tracked, recovered, relocalized or placed by depth).
    pub tracked: usize,
    /// Frames it could not estimate (predicted by constant velocity).
    pub lost: usize,
    /// Whether the blur mitigations were on (see [`with_mitigation`]).
    pub mitigation: bool,
    /// Frames placed by depth alignment (counted in `tracked`).
    pub depth_aligned: usize,
    /// The trajectory's ATE (SE(3) and Sim(3)), scale and RPE.
    #[serde(flatten)]
    pub scores: TrajectoryScores,
    /// Mean and 95th percentile of the true image motion during the exposure (px).
    pub image_motion_px_mean: f64,
    /// See `image_motion_px_mean`.
    pub image_motion_px_p95: f64,
    /// Median sharpness (variance of the Laplacian).
    pub sharpness_median: f64,
    /// Correlation between a frame's sharpness and its true image motion (negative: the
    /// image-only measure sees the blur).
    pub sharpness_motion_correlation: Option<f64>,
    /// Every frame's blur.
    pub per_frame: Vec<FrameBlur>,
}

/// The name of a gait on the command line.
pub fn gait_name(g: Gait) -> &'static str {
    match g {
        Gait::Tripod => "tripod",
        Gait::Crawl => "crawl",
    }
}

/// `config` with the blur mitigations as configured (`on`) or all off: frames the
/// features lose placed by their depth (odometry key `depth_alignment`), each colour row's
/// rotation integrated from the gyroscope over the readout and averaged over the exposure
/// (`readout_gyroscope`), its translation integrated from the accelerometer
/// (`readout_accelerometer`), the rotation from frame to frame predicted by the gyroscope
/// (`predict_gyroscope`), and keyframes that wait out a jolt the gyroscope shows
/// (`keyframe_jolt_ratio`; the real side has neither inertial sensor).
pub fn with_mitigation(config: &PipelineConfig, on: bool) -> PipelineConfig {
    let mut c = config.clone();
    if !on {
        c.odometry.depth_alignment = false;
        c.odometry.readout_gyroscope = false;
        c.odometry.readout_accelerometer = false;
        c.odometry.predict_gyroscope = false;
        c.odometry.keyframe_jolt_ratio = 0.0;
    }
    c
}

/// The lab's sequence for a run: a square walk with blur (0.75 m sides, as paper 004's
/// rectangles; a run longer than a side reaches the first turn on the spot), on `base`'s
/// camera and terrain.
pub fn synth_config(spec: &RunSpec, base: &SynthConfig) -> SynthConfig {
    let mut c = base.clone();
    c.motion.gait = spec.gait;
    c.motion.speed_m_s = spec.speed_fraction * MAX_SPEED_M_S;
    c.motion.path = PathKind::Square;
    c.motion.square_side_m = 0.75;
    c.frames = spec.frames;
    c.seed = spec.seed;
    c.blur = true;
    c
}

/// Renders the run's frames, feeds them to a pipeline built from `config` (its RANSAC seed
/// replaced by the run's), and scores the result.
pub fn run(
    spec: &RunSpec,
    base: &SynthConfig,
    config: &PipelineConfig,
    mut on_frame: impl FnMut(),
) -> Result<RunResult, StudyError> {
    let sc = synth_config(spec, base);
    let synth = Synth::new(sc.clone()).map_err(|source| StudyError::Synth {
        gait: spec.gait,
        speed_fraction: spec.speed_fraction,
        seed: spec.seed,
        source,
    })?;
    let mut config = config.clone();
    config.odometry.seed = spec.seed;
    // On when turning the mitigations off would change the configuration.
    let mitigation = config.odometry != with_mitigation(&config, false).odometry;
    let mut pipeline = Pipeline::new(&synth.camera_config(), config)?;
    pipeline.add_gyroscope(&synth.gyroscope());
    pipeline.add_accelerometer(&synth.accelerometer());
    let renderer = synth.renderer();
    let (mut gt, mut per_frame) = (Trajectory::new(), Vec::with_capacity(spec.frames));
    let (mut t0, mut depth_aligned) = (None, 0usize);
    for index in 0..spec.frames {
        let f = synth.render_frame(&renderer, index);
        let (frame, info) = f.into_rgbd(sc.camera.depth_scale);
        let sharpness = laplacian_variance(&frame.rgb.to_gray());
        let record = pipeline.process(&frame, 0.0)?;
        depth_aligned += usize::from(record.status == FrameStatus::DepthAligned);
        gt.push(info.t_s, info.world_from_camera)
            .map_err(|e| StudyError::Frame {
                frame: index,
                message: e.to_string(),
            })?;
        let t0 = *t0.get_or_insert(info.t_s);
        per_frame.push(FrameBlur {
            t_s: info.t_s - t0,
            gait_phase: info.gait_phase,
            stance_legs: info.stance_legs,
            image_motion_px: info.image_motion_px,
            sharpness,
            tracked: record.status.estimated(),
        });
        on_frame();
    }
    let out = pipeline.finish()?;
    let traj = out.run.trajectory()?;
    let scores = score_trajectory(&gt, &traj)?;
    let tracked = per_frame.iter().filter(|f| f.tracked).count();
    let motion: Vec<f64> = per_frame.iter().map(|f| f.image_motion_px).collect();
    let sharp: Vec<f64> = per_frame.iter().map(|f| f.sharpness).collect();
    let (_, motion_p95) = crate::pipeline::median_p95(motion.iter().copied());
    Ok(RunResult {
        gait: gait_name(spec.gait),
        speed_fraction: spec.speed_fraction,
        seed: spec.seed,
        frames: spec.frames,
        tracked,
        lost: spec.frames - tracked,
        mitigation,
        depth_aligned,
        scores,
        image_motion_px_mean: motion.iter().sum::<f64>() / motion.len().max(1) as f64,
        image_motion_px_p95: motion_p95,
        sharpness_median: crate::pipeline::median_p95(sharp.iter().copied()).0,
        sharpness_motion_correlation: correlation(&sharp, &motion),
        per_frame,
    })
}
