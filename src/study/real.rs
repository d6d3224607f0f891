//! The real side of the blur study: a recorded sequence with ground truth (TUM's
//! fr3/teddy, say) played with its colour frames blurred along each pixel's image motion
//! ([`stride_datasets::motion_blur`]) at increasing lengths, the SLAM run on each with
//! several RANSAC seeds, and each run scored as the synthetic runs are. Length 0 is the
//! sequence as recorded, the reference the others are compared with.
//!
//! Each frame is decoded once, blurred once per length and handed to one pipeline per
//! seed, so the blur's cost does not grow with the seeds.

use super::StudyError;
use crate::pipeline::{FrameStatus, Pipeline, PipelineConfig};
use stride_core::frame::RgbdFrame;
use stride_datasets::motion_blur::{blur_frame, MotionBlur};
use stride_datasets::sequence::Sequence;
use stride_datasets::stream::StreamError;
use stride_eval::blur::laplacian_variance;

/// Frames decoded ahead of the blur.
const DECODE_AHEAD: usize = 4;

/// One run of the real side: a blur length with a seed.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RealRun {
    /// The frames' median blur length (px); 0 for the sequence as recorded.
    pub length_px: f64,
    /// The SLAM's RANSAC seed.
    pub seed: u64,
    /// Frames fed to the SLAM.
    pub frames: usize,
    /// Frames the odometry estimated (tracked, recovered, relocalized or placed by depth).
    pub tracked: usize,
    /// Frames it could not estimate (predicted), unreadable frames included.
    pub lost: usize,
    /// Frames that could not be read (skipped, counted in `lost`).
    pub unreadable: usize,
    /// Whether the blur mitigations were on (see [`super::with_mitigation`]).
    pub mitigation: bool,
    /// Frames placed by depth alignment (counted in `tracked`).
    pub depth_aligned: usize,
    /// The trajectory's ATE (SE(3) and Sim(3)), scale and RPE.
    #[serde(flatten)]
    pub scores: super::TrajectoryScores,
    /// Median sharpness of the blurred frames (variance of the Laplacian, grey levels²).
    pub sharpness_median: f64,
}

/// Runs the SLAM (built from `config`, its RANSAC seed and depth alignment replaced by each
/// of `variants`' `(seed, mitigation)`) on the
/// first `max_frames` frames of `seq` (all when `None`) blurred as `blur` says; `on_frame`
/// sees each blurred frame (`None` for an unreadable one) before the SLAM does, and can
/// fail the study (when it writes the frame out, say). `seq` needs a ground truth.
pub fn run_blurred(
    seq: &Sequence,
    blur: &MotionBlur,
    variants: &[(u64, bool)],
    config: &PipelineConfig,
    max_frames: Option<usize>,
    mut on_frame: impl FnMut(Option<&RgbdFrame>) -> Result<(), String>,
) -> Result<Vec<RealRun>, StudyError> {
    let gt = seq.groundtruth().ok_or_else(|| StudyError::NoGroundTruth {
        dataset: seq.path().display().to_string(),
    })?;
    let camera = &seq.camera().camera;
    let mut pipelines = variants
        .iter()
        .map(|&(seed, mitigation)| {
            let mut c = super::with_mitigation(config, mitigation);
            c.odometry.seed = seed;
            Pipeline::new(seq.camera(), c)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut tracked = vec![(0usize, 0usize); variants.len()];
    let (mut frames, mut unreadable, mut sharpness) = (0usize, 0usize, Vec::new());
    for item in seq.stream(max_frames, DECODE_AHEAD) {
        frames += 1;
        match item {
            Ok(d) => {
                let (f, decode_s) = (d.frame, d.decode_s);
                let blurred =
                    blur_frame(&f.rgb, &f.depth_m, camera, gt, f.t_s, blur).map_err(|e| {
                        StudyError::Frame {
                            frame: f.index,
                            message: e.to_string(),
                        }
                    })?;
                sharpness.push(laplacian_variance(&blurred.rgb.to_gray()));
                let frame = RgbdFrame {
                    rgb: blurred.rgb,
                    ..f
                };
                on_frame(Some(&frame)).map_err(|message| StudyError::Frame {
                    frame: frame.index,
                    message,
                })?;
                for (p, n) in pipelines.iter_mut().zip(tracked.iter_mut()) {
                    let r = p.process(&frame, decode_s)?;
                    n.0 += usize::from(r.status.estimated());
                    n.1 += usize::from(r.status == FrameStatus::DepthAligned);
                }
            }
            Err(StreamError::Frame(failure)) => {
                unreadable += 1;
                on_frame(None).map_err(|message| StudyError::Frame {
                    frame: failure.index,
                    message,
                })?;
                let t_s = seq.frame_time_s(failure.index).unwrap_or(f64::NAN);
                for p in &mut pipelines {
                    p.skip(failure.index, t_s, failure.error.to_string())?;
                }
            }
            Err(StreamError::Stopped(e)) => {
                return Err(crate::pipeline::PipelineError::from(e).into())
            }
        }
    }
    let sharpness_median = crate::pipeline::median_p95(sharpness.into_iter()).0;
    let mut runs = Vec::with_capacity(variants.len());
    for ((p, &(seed, mitigation)), (tracked, depth_aligned)) in
        pipelines.into_iter().zip(variants).zip(tracked)
    {
        let traj = p.finish()?.run.trajectory()?;
        let scores = super::score_trajectory(gt, &traj)?;
        runs.push(RealRun {
            length_px: blur.length_px,
            seed,
            frames,
            tracked,
            lost: frames - tracked,
            unreadable,
            mitigation,
            depth_aligned,
            scores,
            sharpness_median,
        });
    }
    Ok(runs)
}
