//! The SLAM over a sequence, one frame at a time: the visual odometry on the caller's
//! thread, the back end in a thread of its own ([`coupling`]), a record per frame
//! ([`output`]).
//!
//! Per frame, in order:
//! 1. take the back end's answers that are due (the correction of live poses);
//! 2. track the frame with the odometry (pose relative to its keyframe);
//! 3. hand a new keyframe to the back end;
//! 4. record the frame: its live pose (odometry moved by the latest correction), its pose
//!    relative to its keyframe, timings.
//!
//! At the end the back end runs its full optimization, and every frame's final pose comes
//! from its keyframes' final poses ([`RunOutput::final_poses`]).
//!
//! The odometry and the back end work in the frame of the first camera; the outputs are
//! in the gravity-aligned world ([`world`]), found from the floor in the first frames (or
//! a given mounting).

mod coupling;
mod output;
mod stats;
pub mod world;

pub use coupling::Schedule;
pub use output::{BackendSummary, FrameRecord, FrameStatus, RunOutput};
pub use stats::{median_p95, slam_ate_options};

use anyhow::{Context, Result};
use coupling::{finish_backend, Coupling};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;
use std::collections::VecDeque;
use std::time::Instant;
use stride_backend::{Backend, BackendConfig, BackendThread, KeyframeInput};
use stride_core::frame::RgbdFrame;
use stride_core::plane::Plane;
use stride_datasets::camera_config::CameraConfig;
use stride_datasets::stream::StreamError;
use stride_datasets::tum::TumSequence;
use stride_frontend::{StageTimes, TrackingStatus, VisualOdometry, VoConfig};
use world::{floor_in_camera, WorldFrame, WorldPlan};

/// The SLAM, fed one frame at a time.
pub struct Slam {
    vo: VisualOdometry,
    coupling: Option<Coupling>,
    /// The world frame when it is given (a mounting); otherwise made at the end from
    /// `floors`.
    world: Option<WorldFrame>,
    /// Floors seen (camera coordinates) and their inlier counts, by frame position: the
    /// world frame is made of them at the end, with the frames' final poses.
    floors: Vec<(usize, Plane, usize)>,
    frames: Vec<FrameRecord>,
    /// Wall time in the odometry (s).
    vo_wall_s: f64,
    /// Wall time in [`Slam::process`], [`Slam::skip`] and [`Slam::finish`] (s).
    wall_s: f64,
}

impl Slam {
    /// The odometry for `camera` (its rolling-shutter readout time replaces the one in
    /// `config`), and the back end beside it when `backend` is given.
    pub fn new(
        camera: &CameraConfig,
        config: VoConfig,
        backend: Option<(BackendConfig, Schedule)>,
    ) -> Result<Self> {
        let config = VoConfig {
            rolling_shutter_s: camera.rolling_shutter_s,
            ..config
        };
        let camera = camera.camera;
        let vo = VisualOdometry::new(camera, config).context("creating the visual odometry")?;
        let coupling = match backend {
            Some((config, schedule)) => Some(Coupling {
                thread: BackendThread::spawn(Backend::new(camera, config.clone())?)?,
                config,
                schedule,
                queue: VecDeque::new(),
                correction: Isometry3::identity(),
                reports: Vec::new(),
            }),
            None => None,
        };
        Ok(Self {
            vo,
            coupling,
            world: None,
            floors: Vec::new(),
            frames: Vec::new(),
            vo_wall_s: 0.0,
            wall_s: 0.0,
        })
    }

    /// The same SLAM finding its world frame by `plan` (the floor by default).
    pub fn with_world(mut self, plan: WorldPlan) -> Self {
        self.world = match plan {
            WorldPlan::Floor => None,
            WorldPlan::Mounting {
                pitch_deg,
                height_m,
            } => Some(WorldFrame::from_mounting(pitch_deg, height_m)),
        };
        self
    }

    /// Looks for the floor in the depth of the first frames and of keyframes, unless the
    /// world frame is given.
    fn look_for_floor(&mut self, frame: &RgbdFrame, keyframe: bool) {
        let position = self.frames.len();
        if self.world.is_none() && (keyframe || position < world::FLOOR_SEARCH_FRAMES) {
            if let Some((plane, inliers)) = floor_in_camera(&frame.depth_m, self.vo.camera()) {
                self.floors.push((position, plane, inliers));
            }
        }
    }

    /// Answers due before the next frame: waits under the fixed schedule. Returns the
    /// time waited (s) and the live correction.
    fn take_due(&mut self) -> Result<(f64, Isometry3<f64>)> {
        let position = self.frames.len();
        match self.coupling.as_mut() {
            Some(c) => Ok((c.take_due(position)?, c.correction)),
            None => Ok((0.0, Isometry3::identity())),
        }
    }

    /// Processes the next frame; `decode_s` is the time its decoding took elsewhere (s).
    pub fn process(&mut self, frame: &RgbdFrame, decode_s: f64) -> Result<&FrameRecord> {
        let start = Instant::now();
        let (wait_s, correction) = self.take_due()?;
        let t0 = Instant::now();
        let mut r = self.vo.process(frame)?;
        self.vo_wall_s += t0.elapsed().as_secs_f64();
        if r.status == TrackingStatus::Lost {
            tracing::warn!(
                "frame {} ({:.6} s): tracking failed ({} tracked, {} inliers); pose predicted by constant velocity",
                r.index, r.t_s, r.tracked, r.inliers
            );
        }
        if r.status != TrackingStatus::Lost {
            self.look_for_floor(frame, r.keyframe);
        }
        let position = self.frames.len();
        if let (Some(c), Some(info)) = (self.coupling.as_mut(), r.new_keyframe.take()) {
            c.queue.push_back((info.id, position, r.world_from_camera));
            c.thread.send(KeyframeInput {
                frame_index: r.index,
                t_s: r.t_s,
                world_from_camera: r.world_from_camera,
                info,
            })?;
        }
        self.frames.push(FrameRecord {
            index: r.index,
            t_s: r.t_s,
            live_world_from_camera: correction * r.world_from_camera,
            odometry_world_from_camera: r.world_from_camera,
            keyframe_id: r.keyframe_id,
            status: if r.status == TrackingStatus::Lost {
                FrameStatus::Lost
            } else {
                FrameStatus::Tracked
            },
            keyframe: r.keyframe,
            tracked: r.tracked,
            inliers: r.inliers,
            decode_s,
            timing: r.timing,
            wait_s,
            skip_reason: None,
        });
        self.wall_s += start.elapsed().as_secs_f64();
        self.frames.last().context("the frame was just recorded")
    }

    /// Records a frame that could not be loaded: its pose is predicted by the odometry's
    /// constant-velocity model, and the reason is kept (and counted in reports).
    pub fn skip(&mut self, index: usize, t_s: f64, reason: String) -> Result<&FrameRecord> {
        let start = Instant::now();
        let (wait_s, correction) = self.take_due()?;
        tracing::warn!("frame {index} skipped: {reason}");
        let pose = self.vo.predict(t_s);
        let kf_id = self.vo.current_keyframe().map_or(0, |(id, _)| id);
        self.frames.push(FrameRecord {
            index,
            t_s,
            live_world_from_camera: correction * pose,
            odometry_world_from_camera: pose,
            keyframe_id: kf_id,
            status: FrameStatus::Skipped,
            keyframe: false,
            tracked: 0,
            inliers: 0,
            decode_s: f64::NAN,
            timing: StageTimes::default(),
            wait_s,
            skip_reason: Some(reason),
        });
        self.wall_s += start.elapsed().as_secs_f64();
        self.frames.last().context("the frame was just recorded")
    }

    /// Waits for the back end, runs its final optimization, and returns everything in the
    /// world frame.
    pub fn finish(self) -> Result<RunOutput> {
        let start = Instant::now();
        let backend = self.coupling.map(finish_backend).transpose()?;
        let mut out = RunOutput {
            frames: self.frames,
            vo_wall_s: self.vo_wall_s,
            wall_s: 0.0,
            backend,
            world: WorldFrame::first_camera(),
        };
        let world = self.world.or_else(|| {
            let poses = out.final_poses();
            let floors: Vec<_> = self
                .floors
                .iter()
                .filter_map(|&(i, plane, n)| Some((*poses.get(i)?, plane, n)))
                .collect();
            WorldFrame::from_floors(&floors)
        });
        out.world = world.unwrap_or_else(|| {
            tracing::warn!(
                "no floor seen in the first {} frames nor in keyframes, and no mounting given: \
                 poses are in the first camera's frame (y down), not gravity-aligned",
                world::FLOOR_SEARCH_FRAMES
            );
            WorldFrame::first_camera()
        });
        tracing::info!("world frame: {}", out.world.describe());
        out.move_to_world();
        out.wall_s = self.wall_s + start.elapsed().as_secs_f64();
        Ok(out)
    }
}

/// A progress bar on stderr labelled `what` (hidden when `show` is false): the one style of
/// every long command.
pub fn progress_bar(total: usize, what: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({per_sec}, eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(what.to_owned());
    pb
}

/// Runs the SLAM over the first `max_frames` frames of a sequence (all when `None`), frames
/// decoded ahead on a background thread: the odometry alone when `backend` is `None`; the
/// outputs in the world frame `world` finds.
pub fn run_slam(
    seq: &TumSequence,
    config: VoConfig,
    backend: Option<(BackendConfig, Schedule)>,
    world: WorldPlan,
    max_frames: Option<usize>,
    progress: bool,
) -> Result<RunOutput> {
    let mut slam = Slam::new(&seq.camera, config, backend)?.with_world(world);
    let stream = seq.stream(max_frames, 4);
    let pb = progress_bar(stream.len(), "tracking", progress);
    for item in stream {
        match item {
            Ok(d) => {
                slam.process(&d.frame, d.decode_s).with_context(|| {
                    format!(
                        "frame {} ({})",
                        d.frame.index,
                        seq.frames
                            .get(d.frame.index)
                            .map(|e| e.rgb_path.display().to_string())
                            .unwrap_or_default()
                    )
                })?;
            }
            Err(StreamError::Frame(failure)) => {
                let t_s = seq
                    .frames
                    .get(failure.index)
                    .map_or(f64::NAN, |e| e.t_rgb_s);
                slam.skip(failure.index, t_s, failure.error.to_string())?;
            }
            Err(StreamError::Stopped(e)) => return Err(e.into()),
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    slam.finish()
}
