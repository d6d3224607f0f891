//! The SLAM over a sequence, one frame at a time: the visual odometry on the caller's
//! thread, the back end in a thread of its own (`pipeline::coupling`), a record per frame
//! ([`super::FrameRecord`]).
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
//! in the gravity-aligned world ([`super::world`]), found from the floor in the first
//! frames (or a given mounting).

use super::coupling::{finish_backend, Coupling, Schedule};
use super::output::{FrameRecord, FrameStatus, RunOutput};
use super::world::{self, floor_in_camera, WorldFrame, WorldPlan};
use super::PipelineError;
use nalgebra::Isometry3;
use std::collections::VecDeque;
use std::time::Instant;
use stride_backend::{Backend, BackendConfig, BackendThread, KeyframeInput, SavedMap};
use stride_core::frame::RgbdFrame;
use stride_core::plane::Plane;
use stride_datasets::camera_config::CameraConfig;
use stride_frontend::{StageTimes, TrackingStatus, VisualOdometry, VoConfig};

/// The SLAM, fed one frame at a time.
pub struct Slam {
    vo: VisualOdometry,
    coupling: Option<Coupling>,
    /// The world frame when it is given (a mounting); otherwise made at the end from
    /// `floors`.
    world: Option<WorldFrame>,
    /// The reference trajectory that gives the world, when one does.
    reference: Option<stride_core::trajectory::Trajectory>,
    /// The accelerometer's samples that give the world's z axis, when they do.
    accelerometer: Option<Vec<stride_datasets::accelerometer::AccelSample>>,
    /// Floors seen (camera coordinates) and their inlier counts, by frame position: the
    /// world frame is made of them at the end, with the frames' final poses.
    floors: Vec<(usize, Plane, usize)>,
    frames: Vec<FrameRecord>,
    /// Wall time in the odometry (s).
    vo_wall_s: f64,
    /// Wall time in [`Slam::process`], [`Slam::skip`] and [`Slam::finish`] (s).
    wall_s: f64,
    /// The run's pieces as known live (each frame's `live_in_world`).
    pieces: super::pieces::Pieces,
    /// Back-end reports already read into `pieces`.
    reports_seen: usize,
}

impl Slam {
    /// The odometry for `camera` (its rolling-shutter readout and exposure times replace
    /// the ones in `config`), and the back end beside it when `backend` is given. With a
    /// `saved` map, the first frame is relocalized in it and the back end extends it.
    pub fn new(
        camera: &CameraConfig,
        config: VoConfig,
        backend: Option<(BackendConfig, Schedule)>,
        saved: Option<SavedMap>,
    ) -> Result<Self, PipelineError> {
        // The keyframes' place features go to the back end for its loop closure (which also
        // writes them into a saved map); relocalization detects its own when it needs them.
        let loops = backend.as_ref().is_some_and(|(b, _)| {
            b.loop_closure.enabled && b.mode == stride_backend::BackendMode::BundleAdjustment
        });
        let config = VoConfig {
            rolling_shutter_s: camera.rolling_shutter_s,
            exposure_s: camera.exposure_s,
            place_features: config.place_features && loops,
            ..config
        };
        let camera = camera.camera;
        let mut vo = VisualOdometry::new(camera, config).map_err(PipelineError::Odometry)?;
        let prior = saved.map(|s| {
            vo.start_in_map(s.anchors(), s.next_keyframe_id());
            (s.map, s.place_features)
        });
        let coupling = match backend {
            Some((config, schedule)) => Some(Coupling {
                thread: BackendThread::spawn(match prior {
                    Some((map, places)) => Backend::with_map(camera, config.clone(), map, &places)?,
                    None => Backend::new(camera, config.clone())?,
                })?,
                config,
                schedule,
                queue: VecDeque::new(),
                correction: Isometry3::identity(),
                reports: Vec::new(),
                answers: Vec::new(),
            }),
            None => None,
        };
        Ok(Self {
            vo,
            coupling,
            world: None,
            reference: None,
            accelerometer: None,
            floors: Vec::new(),
            frames: Vec::new(),
            vo_wall_s: 0.0,
            wall_s: 0.0,
            pieces: super::pieces::Pieces::new(),
            reports_seen: 0,
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
            WorldPlan::Reference(trajectory) => {
                self.reference = Some(trajectory);
                None
            }
            WorldPlan::Accelerometer(samples) => {
                self.accelerometer = Some(samples);
                None
            }
            WorldPlan::Given(world) => Some(world),
        };
        self
    }

    /// Adds gyroscope samples for the rolling-shutter correction
    /// ([`stride_frontend::VisualOdometry::add_gyroscope`]).
    pub fn add_gyroscope(&mut self, samples: &[stride_datasets::accelerometer::GyroSample]) {
        self.vo.add_gyroscope(samples);
    }

    /// Adds accelerometer samples for the rolling-shutter correction
    /// ([`stride_frontend::VisualOdometry::add_accelerometer`]).
    pub fn add_accelerometer(&mut self, samples: &[stride_datasets::accelerometer::AccelSample]) {
        self.vo.add_accelerometer(samples);
    }

    /// Looks for the floor in the depth of the first frames and of keyframes, unless the
    /// world frame is given.
    fn look_for_floor(&mut self, frame: &RgbdFrame, keyframe: bool) {
        let position = self.frames.len();
        if self.world.is_none()
            && self.reference.is_none()
            && (keyframe || position < world::FLOOR_SEARCH_FRAMES)
        {
            if let Some((plane, inliers)) = floor_in_camera(&frame.depth_m, self.vo.camera()) {
                self.floors.push((position, plane, inliers));
            }
        }
    }

    /// Answers due before the next frame: waits under the fixed schedule. Returns the
    /// time waited (s) and the live correction.
    fn take_due(&mut self) -> Result<(f64, Isometry3<f64>), PipelineError> {
        let position = self.frames.len();
        match self.coupling.as_mut() {
            Some(c) => Ok((c.take_due(position)?, c.correction)),
            None => Ok((0.0, Isometry3::identity())),
        }
    }

    /// Processes the next frame; `decode_s` is the time its decoding took elsewhere (s).
    pub fn process(
        &mut self,
        frame: &RgbdFrame,
        decode_s: f64,
    ) -> Result<FrameRecord, PipelineError> {
        let start = Instant::now();
        let (wait_s, correction) = self.take_due()?;
        let t0 = Instant::now();
        let mut r = self
            .vo
            .process(frame)
            .map_err(|source| PipelineError::Frontend {
                index: frame.index,
                t_s: frame.t_s,
                source,
            })?;
        self.vo_wall_s += t0.elapsed().as_secs_f64();
        // (A first frame lost was not found in a saved map: the odometry said so.)
        if r.status == TrackingStatus::Lost
            && !self.frames.iter().all(|f| f.status == FrameStatus::Skipped)
        {
            tracing::warn!(
                "frame {} ({:.6} s): tracking failed ({} tracked, {} inliers); pose predicted by constant velocity",
                r.index, r.t_s, r.tracked, r.inliers
            );
        }
        if r.status == TrackingStatus::Relocalized {
            tracing::info!(
                "frame {} ({:.6} s): relocalized by appearance among the remembered keyframes ({} inliers of {} matches)",
                r.index,
                r.t_s,
                r.inliers,
                r.correspondences
            );
        }
        if r.status == TrackingStatus::Recovered {
            tracing::info!(
                "frame {} ({:.6} s): recovered by ORB matching against recent keyframes ({} inliers of {} matches)",
                r.index, r.t_s, r.inliers, r.correspondences
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
                depth_m: c.config.revisit.enabled.then(|| frame.depth_m.clone()),
            })?;
        }
        let record = FrameRecord {
            index: r.index,
            t_s: r.t_s,
            live_world_from_camera: correction * r.world_from_camera,
            odometry_world_from_camera: r.world_from_camera,
            keyframe_id: r.keyframe_id,
            matched_keyframe: r.matched_keyframe,
            status: match r.status {
                TrackingStatus::Lost => FrameStatus::Lost,
                TrackingStatus::Recovered => FrameStatus::Recovered,
                TrackingStatus::Relocalized => FrameStatus::Relocalized,
                TrackingStatus::DepthAligned => FrameStatus::DepthAligned,
                TrackingStatus::Initialized | TrackingStatus::Tracked => FrameStatus::Tracked,
            },
            keyframe: r.keyframe,
            tracked: r.tracked,
            inliers: r.inliers,
            decode_s,
            timing: r.timing,
            wait_s,
            skip_reason: None,
            live_in_world: false,
        };
        self.wall_s += start.elapsed().as_secs_f64();
        Ok(self.record(record))
    }

    /// Records a frame that could not be loaded: its pose is predicted by the odometry's
    /// constant-velocity model, and the reason is kept (and counted in reports).
    pub fn skip(
        &mut self,
        index: usize,
        t_s: f64,
        reason: String,
    ) -> Result<FrameRecord, PipelineError> {
        let start = Instant::now();
        let (wait_s, correction) = self.take_due()?;
        let skipped_before = self
            .frames
            .iter()
            .filter(|f| f.status == FrameStatus::Skipped)
            .count();
        super::warn_skipped(skipped_before, index, &reason);
        let pose = self.vo.predict(t_s);
        let kf_id = self.vo.current_keyframe().map_or(0, |(id, _)| id);
        let record = FrameRecord {
            index,
            t_s,
            live_world_from_camera: correction * pose,
            odometry_world_from_camera: pose,
            keyframe_id: kf_id,
            status: FrameStatus::Skipped,
            matched_keyframe: None,
            keyframe: false,
            tracked: 0,
            inliers: 0,
            decode_s: f64::NAN,
            timing: StageTimes::default(),
            wait_s,
            skip_reason: Some(reason),
            live_in_world: false,
        };
        self.wall_s += start.elapsed().as_secs_f64();
        Ok(self.record(record))
    }

    /// The poses the back end answered since the last call (`world_from_camera` of
    /// keyframes, in the SLAM's frame, latest last); empty without a back end.
    pub fn take_answers(&mut self) -> Vec<(u64, Isometry3<f64>)> {
        self.coupling
            .as_mut()
            .map_or_else(Vec::new, Coupling::take_answers)
    }

    /// Whether a back end runs beside the odometry.
    pub fn has_backend(&self) -> bool {
        self.coupling.is_some()
    }

    /// The world frame as far as it is known now: the given mounting, or, once the first
    /// frames have been searched for the floor, the floors seen so far at their live
    /// poses. `None` while it is not known. [`Slam::finish`] refines it with every floor
    /// seen and the final poses.
    pub fn provisional_world(&self) -> Option<WorldFrame> {
        if self.world.is_some() {
            return self.world;
        }
        if let Some(r) = &self.reference {
            let frames = self
                .frames
                .iter()
                .filter(|f| f.status != FrameStatus::Skipped);
            return WorldFrame::from_reference(
                r,
                frames.map(|f| (f.t_s, f.live_world_from_camera)),
            );
        }
        // Nothing to make a world of yet: skip gathering every frame's pose.
        let no_source = self.floors.is_empty() && self.accelerometer.is_none();
        if self.frames.len() < world::FLOOR_SEARCH_FRAMES || no_source {
            return None;
        }
        let poses: Vec<_> = self
            .frames
            .iter()
            .map(|f| f.live_world_from_camera)
            .collect();
        self.world_at(&self.frames, &poses)
    }

    /// The world frame from the floors and the accelerometer (when there is one) with the
    /// `frames`' poses `poses` (SLAM frame, one per frame).
    fn world_at(&self, frames: &[FrameRecord], poses: &[Isometry3<f64>]) -> Option<WorldFrame> {
        let floors: Vec<_> = self
            .floors
            .iter()
            .filter_map(|&(i, plane, n)| Some((*poses.get(i)?, plane, n)))
            .collect();
        match &self.accelerometer {
            Some(samples) => {
                let frames: Vec<(f64, Isometry3<f64>)> = frames
                    .iter()
                    .zip(poses)
                    .filter(|(f, _)| f.status != FrameStatus::Skipped)
                    .map(|(f, p)| (f.t_s, *p))
                    .collect();
                WorldFrame::from_accelerometer(samples, &frames, &floors)
            }
            None => WorldFrame::from_floors(&floors),
        }
    }

    /// Keeps `record` as the next frame's and returns a copy for the caller.
    fn record(&mut self, mut record: FrameRecord) -> FrameRecord {
        // The loops the back end closed since the last frame join their pieces.
        if let Some(c) = &self.coupling {
            for k in c.reports.get(self.reports_seen..).unwrap_or_default() {
                if let Some(l) = &k.loop_closure {
                    self.pieces.tie(k.keyframe_id, l.matched);
                }
            }
            self.reports_seen = c.reports.len();
        }
        let keyframe = record.keyframe.then_some(record.keyframe_id);
        let piece = (self.pieces).frame(record.status, record.matched_keyframe, keyframe);
        record.live_in_world = self.pieces.root(piece) == 0;
        self.frames.push(record.clone());
        record
    }

    /// Waits for the back end, runs its final optimization, and returns everything in the
    /// world frame.
    pub fn finish(mut self) -> Result<RunOutput, PipelineError> {
        let start = Instant::now();
        let backend = self.coupling.take().map(finish_backend).transpose()?;
        let mut out = RunOutput {
            frames: std::mem::take(&mut self.frames),
            vo_wall_s: self.vo_wall_s,
            wall_s: 0.0,
            backend,
            world: WorldFrame::first_camera(),
            gyroscope_frames: self.vo.gyroscope_frames(),
            accelerometer_frames: self.vo.accelerometer_frames(),
            recoveries_refused: self.vo.recoveries_refused(),
        };
        let world = self.world.or_else(|| {
            let poses = out.final_poses();
            if let Some(r) = &self.reference {
                let frames = out.frames.iter().zip(&poses);
                let known = frames.filter(|(f, _)| f.status != FrameStatus::Skipped);
                return WorldFrame::from_reference(r, known.map(|(f, p)| (f.t_s, *p)));
            }
            self.world_at(&out.frames, &poses)
        });
        // With no frame read there is nothing to say about the world: the caller reports
        // the unread frames.
        let any_read = out.read_any_frame();
        out.world = world.unwrap_or_else(|| {
            if !any_read {
                return WorldFrame::first_camera();
            }
            tracing::warn!(
                "{}: poses are in the first camera's frame (y down), not gravity-aligned",
                if self.reference.is_some() {
                    "the reference trajectory covers no frame".to_owned()
                } else {
                    format!(
                        "no floor seen in the first {} frames nor in keyframes, and no mounting given",
                        world::FLOOR_SEARCH_FRAMES
                    )
                }
            );
            WorldFrame::first_camera()
        });
        tracing::info!("world frame: {}", out.world.describe());
        out.move_to_world();
        out.wall_s = self.wall_s + start.elapsed().as_secs_f64();
        Ok(out)
    }
}
