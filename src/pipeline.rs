//! Running the visual odometry over a sequence: frames decoded ahead on a background thread,
//! odometry on this thread, per-frame results and timings collected.

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;
use stride_core::trajectory::Trajectory;
use stride_datasets::tum::TumSequence;
use stride_frontend::{FrameResult, TrackingStatus, VisualOdometry, VoConfig};

/// What happened to one frame of the sequence.
#[derive(Debug, Clone)]
pub struct FrameRecord {
    /// Frame index in the sequence.
    pub index: usize,
    /// Timestamp (s).
    pub t_s: f64,
    /// `world_from_camera`.
    pub world_from_camera: Isometry3<f64>,
    /// "initialized", "tracked", "lost" or "skipped".
    pub status: &'static str,
    /// Whether it became a keyframe.
    pub keyframe: bool,
    /// Keypoints tracked into it.
    pub tracked: usize,
    /// RANSAC inliers.
    pub inliers: usize,
    /// Decoding time on the decoder thread (s); NaN for skipped frames.
    pub decode_s: f64,
    /// Odometry stage times (s).
    pub timing: stride_frontend::StageTimes,
    /// Why it was skipped, when it was.
    pub skip_reason: Option<String>,
}

/// The outcome of a run.
pub struct RunOutput {
    /// Every frame, in order.
    pub frames: Vec<FrameRecord>,
    /// Wall time of odometry processing only (s), decoding excluded.
    pub vo_wall_s: f64,
}

impl RunOutput {
    /// The estimated trajectory (every frame).
    pub fn trajectory(&self) -> Result<Trajectory> {
        let mut t = Trajectory::new();
        for f in &self.frames {
            t.push(f.t_s, f.world_from_camera)
                .with_context(|| format!("frame {} at {:.6} s", f.index, f.t_s))?;
        }
        Ok(t)
    }
}

/// Runs the odometry over the first `max_frames` frames (all when `None`).
pub fn run_vo(
    seq: &TumSequence,
    config: VoConfig,
    max_frames: Option<usize>,
    progress: bool,
) -> Result<RunOutput> {
    let mut vo =
        VisualOdometry::new(seq.camera.camera, config).context("creating the visual odometry")?;
    let stream = seq.stream(max_frames, 4);
    let total = stream.len();
    let pb = if progress {
        let pb = ProgressBar::new(total as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "tracking [{bar:30}] {pos}/{len} ({per_sec}, eta {eta}) {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        pb
    } else {
        ProgressBar::hidden()
    };
    let mut frames = Vec::with_capacity(total);
    let mut vo_wall_s = 0.0;
    for item in stream {
        match item {
            Ok(decoded) => {
                let t0 = std::time::Instant::now();
                let r: FrameResult = vo.process(&decoded.frame).with_context(|| {
                    format!(
                        "frame {} ({})",
                        decoded.frame.index,
                        seq.frames
                            .get(decoded.frame.index)
                            .map(|e| e.rgb_path.display().to_string())
                            .unwrap_or_default()
                    )
                })?;
                vo_wall_s += t0.elapsed().as_secs_f64();
                if r.status == TrackingStatus::Lost {
                    tracing::warn!("frame {} ({:.6} s): tracking failed ({} tracked, {} inliers); pose predicted by constant velocity", r.index, r.t_s, r.tracked, r.inliers);
                }
                frames.push(FrameRecord {
                    index: r.index,
                    t_s: r.t_s,
                    world_from_camera: r.world_from_camera,
                    status: r.status.as_str(),
                    keyframe: r.keyframe,
                    tracked: r.tracked,
                    inliers: r.inliers,
                    decode_s: decoded.decode_s,
                    timing: r.timing,
                    skip_reason: None,
                });
            }
            Err(failure) => {
                let t_s = seq
                    .frames
                    .get(failure.index)
                    .map_or(f64::NAN, |e| e.t_rgb_s);
                tracing::warn!("frame {} skipped: {}", failure.index, failure.error);
                frames.push(FrameRecord {
                    index: failure.index,
                    t_s,
                    world_from_camera: vo.predict(t_s),
                    status: "skipped",
                    keyframe: false,
                    tracked: 0,
                    inliers: 0,
                    decode_s: f64::NAN,
                    timing: Default::default(),
                    skip_reason: Some(failure.error.to_string()),
                });
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    Ok(RunOutput { frames, vo_wall_s })
}

/// Median and 95th percentile of a series (NaNs ignored); `(NaN, NaN)` when empty.
pub fn median_p95(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| {
        v.get(((v.len() - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    let n = v.len();
    let median = if n % 2 == 1 {
        at(0.5)
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    };
    (median, at(0.95))
}
