//! Running the SLAM over a sequence: frames decoded ahead on a background thread, the
//! visual odometry on this thread, the back end in a thread of its own, per-frame results
//! and timings collected.
//!
//! Each frame's pose is kept relative to its keyframe, so the written trajectory carries
//! every correction the back end made to the keyframes, up to the final optimization.

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;
use std::collections::VecDeque;
use std::time::Instant;
use stride_backend::{
    Backend, BackendConfig, BackendThread, KeyframeInput, KeyframeReport, KeyframeUpdate,
};
use stride_core::trajectory::Trajectory;
use stride_datasets::tum::TumSequence;
use stride_frontend::{FrameResult, StageTimes, TrackingStatus, VisualOdometry, VoConfig};

/// How a frame's pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameStatus {
    /// Estimated by the odometry (or the first frame).
    Tracked,
    /// The odometry could not estimate it: predicted by constant velocity.
    Lost,
    /// The frame could not be loaded: predicted by constant velocity.
    Skipped,
}

impl FrameStatus {
    /// A short lowercase name for reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            FrameStatus::Tracked => "tracked",
            FrameStatus::Lost => "lost",
            FrameStatus::Skipped => "skipped",
        }
    }
}

/// What happened to one frame of the sequence.
#[derive(Debug, Clone)]
pub struct FrameRecord {
    /// Frame index in the sequence.
    pub index: usize,
    /// Timestamp (s).
    pub t_s: f64,
    /// `world_from_camera` as it was known at the frame's time (live): the odometry's
    /// pose moved by the back end's latest correction.
    pub live_world_from_camera: Isometry3<f64>,
    /// `world_from_camera` in the odometry's own world (never corrected).
    pub odometry_world_from_camera: Isometry3<f64>,
    /// The keyframe the pose is kept relative to, and the pose relative to it.
    pub keyframe_id: u64,
    /// `keyframe_from_camera`.
    pub keyframe_from_camera: Isometry3<f64>,
    /// How the pose was obtained.
    pub status: FrameStatus,
    /// Whether it became a keyframe.
    pub keyframe: bool,
    /// Keypoints tracked into it.
    pub tracked: usize,
    /// RANSAC inliers.
    pub inliers: usize,
    /// Decoding time on the decoder thread (s); NaN for skipped frames.
    pub decode_s: f64,
    /// Odometry stage times (s).
    pub timing: StageTimes,
    /// Time the odometry waited for the back end before this frame (s).
    pub wait_s: f64,
    /// Why it was skipped, when it was.
    pub skip_reason: Option<String>,
}

/// When the odometry applies the back end's corrections.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Schedule {
    /// The correction for a keyframe is applied exactly `lag_frames` frames after it was
    /// made, waiting for it if the back end is late: the same work in the same order on
    /// every run, so runs are bit-identical.
    Fixed {
        /// Frames between a keyframe and the application of its correction.
        lag_frames: usize,
    },
    /// Corrections are applied as soon as they are ready; the odometry never waits.
    /// Results depend on thread timing.
    Free,
}

/// The back end's part of a run.
pub struct BackendSummary {
    /// The configuration used.
    pub config: BackendConfig,
    /// One report per keyframe, in order.
    pub keyframes: Vec<KeyframeReport>,
    /// The final optimization.
    pub final_solve: Option<stride_backend::ba::SolveReport>,
    /// Keyframes and points in the final map.
    pub map_keyframes: usize,
    /// See `map_keyframes`.
    pub map_points: usize,
    /// Keyframes culled over the run.
    pub culled_keyframes: usize,
    /// The final map's points (world frame, m), for plots.
    pub points_world: Vec<nalgebra::Point3<f64>>,
    /// Final `world_from_camera` of every keyframe ever made, by identifier.
    pub keyframe_poses: Vec<(u64, Isometry3<f64>)>,
}

impl BackendSummary {
    /// The final poses of the keyframes, at their frames' times.
    pub fn keyframe_trajectory(&self, out: &RunOutput) -> Trajectory {
        let mut t = Trajectory::new();
        for f in out.frames.iter().filter(|f| f.keyframe) {
            if let Ok(i) = self
                .keyframe_poses
                .binary_search_by_key(&f.keyframe_id, |(k, _)| *k)
            {
                if let Some((_, pose)) = self.keyframe_poses.get(i) {
                    // Frames are in time order and keyframes among them: pushing cannot fail.
                    let _ = t.push(f.t_s, *pose);
                }
            }
        }
        t
    }
}

/// The outcome of a run.
pub struct RunOutput {
    /// Every frame, in order.
    pub frames: Vec<FrameRecord>,
    /// Wall time of the odometry only (s): decoding and waits for the back end excluded.
    pub vo_wall_s: f64,
    /// Wall time of the whole run on this thread, decoding excluded (s): odometry, waits,
    /// and the final optimization.
    pub wall_s: f64,
    /// The back end's part, when there was one.
    pub backend: Option<BackendSummary>,
}

impl RunOutput {
    /// The final `world_from_camera` of every frame (the live poses without a back end).
    ///
    /// A frame between keyframes `A` and `B` has two estimates, each keyframe's final pose
    /// times the frame's odometry pose relative to it; the frame takes their average,
    /// weighted by its time between the two (all of `A`'s at `A`). A keyframe the odometry
    /// placed poorly then spoils only half of its neighbours' poses instead of all of them.
    pub fn final_poses(&self) -> Vec<Isometry3<f64>> {
        let Some(b) = &self.backend else {
            return self
                .frames
                .iter()
                .map(|f| f.live_world_from_camera)
                .collect();
        };
        let pose_of = |id: u64| {
            b.keyframe_poses
                .binary_search_by_key(&id, |(k, _)| *k)
                .ok()
                .and_then(|i| b.keyframe_poses.get(i))
                .map(|(_, p)| *p)
        };
        // Each keyframe's record, and for each frame the next keyframe's record.
        let mut next_kf: Vec<Option<&FrameRecord>> = vec![None; self.frames.len()];
        let mut next = None;
        for (i, f) in self.frames.iter().enumerate().rev() {
            next_kf[i] = next;
            if f.keyframe {
                next = Some(f);
            }
        }
        let kf_record: std::collections::HashMap<u64, &FrameRecord> = self
            .frames
            .iter()
            .filter(|f| f.keyframe)
            .map(|f| (f.keyframe_id, f))
            .collect();
        self.frames
            .iter()
            .zip(next_kf)
            .map(|(f, nk)| {
                let Some(world_from_a) = pose_of(f.keyframe_id) else {
                    return f.live_world_from_camera;
                };
                let from_a = world_from_a * f.keyframe_from_camera;
                let (Some(kb), Some(ka)) = (nk, kf_record.get(&f.keyframe_id)) else {
                    return from_a;
                };
                let Some(world_from_b) = pose_of(kb.keyframe_id) else {
                    return from_a;
                };
                let b_from_f =
                    kb.odometry_world_from_camera.inverse() * f.odometry_world_from_camera;
                let from_b = world_from_b * b_from_f;
                let span = kb.t_s - ka.t_s;
                let alpha = if span > 0.0 {
                    ((f.t_s - ka.t_s) / span).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                from_a.lerp_slerp(&from_b, alpha)
            })
            .collect()
    }

    /// The final `world_from_camera` of one frame (see [`RunOutput::final_poses`]).
    pub fn final_pose(&self, f: &FrameRecord) -> Isometry3<f64> {
        self.frames
            .iter()
            .position(|g| std::ptr::eq(g, f))
            .and_then(|i| self.final_poses().get(i).copied())
            .unwrap_or(f.live_world_from_camera)
    }

    /// The estimated trajectory (every frame, final poses).
    pub fn trajectory(&self) -> Result<Trajectory> {
        let poses = self.final_poses();
        let mut t = Trajectory::new();
        for (f, p) in self.frames.iter().zip(poses) {
            t.push(f.t_s, p)
                .with_context(|| format!("frame {} at {:.6} s", f.index, f.t_s))?;
        }
        Ok(t)
    }

    /// The trajectory as it was known frame by frame (live poses).
    pub fn live_trajectory(&self) -> Result<Trajectory> {
        self.trajectory_with(|f| f.live_world_from_camera)
    }

    fn trajectory_with(&self, pose: impl Fn(&FrameRecord) -> Isometry3<f64>) -> Result<Trajectory> {
        let mut t = Trajectory::new();
        for f in &self.frames {
            t.push(f.t_s, pose(f))
                .with_context(|| format!("frame {} at {:.6} s", f.index, f.t_s))?;
        }
        Ok(t)
    }
}

fn progress_bar(total: usize, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template(
            "tracking [{bar:30}] {pos}/{len} ({per_sec}, eta {eta}) {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb
}

/// The back end beside the odometry, and the keyframes whose corrections are due.
struct Coupling {
    thread: BackendThread,
    schedule: Schedule,
    /// Keyframes sent and not yet answered: identifier, frame position, odometry pose.
    queue: VecDeque<(u64, usize, Isometry3<f64>)>,
    /// `optimized_from_odometry` implied by the latest answer.
    correction: Isometry3<f64>,
    reports: Vec<KeyframeReport>,
}

impl Coupling {
    /// Takes the back end's answer for the oldest keyframe sent.
    fn absorb(&mut self, u: KeyframeUpdate) -> Result<()> {
        let Some((id, _, odometry_pose)) = self.queue.pop_front() else {
            anyhow::bail!(
                "the back end answered keyframe {} that was never sent",
                u.keyframe_id
            );
        };
        anyhow::ensure!(
            id == u.keyframe_id,
            "the back end answered keyframe {} where {id} was due",
            u.keyframe_id
        );
        self.correction = u.correction(&odometry_pose);
        self.reports.push(u.report);
        Ok(())
    }

    /// Takes the answers due before the frame at `position` (waiting for them under the
    /// fixed schedule). Returns the time waited (s).
    fn take_due(&mut self, position: usize) -> Result<f64> {
        let mut waited = 0.0;
        match self.schedule {
            Schedule::Fixed { lag_frames } => {
                while self
                    .queue
                    .front()
                    .is_some_and(|&(_, made, _)| made + lag_frames <= position)
                {
                    let t = Instant::now();
                    let u = self.thread.recv()?;
                    waited += t.elapsed().as_secs_f64();
                    self.absorb(u)?;
                }
            }
            Schedule::Free => {
                while let Some(u) = self.thread.try_recv()? {
                    self.absorb(u)?;
                }
            }
        }
        Ok(waited)
    }
}

/// Runs the SLAM over the first `max_frames` frames (all when `None`): the odometry alone
/// when `backend` is `None`.
pub fn run_slam(
    seq: &TumSequence,
    config: VoConfig,
    backend: Option<(BackendConfig, Schedule)>,
    max_frames: Option<usize>,
    progress: bool,
) -> Result<RunOutput> {
    let camera = seq.camera.camera;
    let mut vo = VisualOdometry::new(camera, config).context("creating the visual odometry")?;
    let mut coupling = match &backend {
        Some((cfg, schedule)) => Some(Coupling {
            thread: BackendThread::spawn(Backend::new(camera, cfg.clone())?)?,
            schedule: *schedule,
            queue: VecDeque::new(),
            correction: Isometry3::identity(),
            reports: Vec::new(),
        }),
        None => None,
    };
    let stream = seq.stream(max_frames, 4);
    let pb = progress_bar(stream.len(), progress);
    let mut frames = Vec::with_capacity(stream.len());
    let (mut vo_wall_s, start) = (0.0, Instant::now());
    for (position, item) in stream.enumerate() {
        let wait_s = match coupling.as_mut() {
            Some(c) => c.take_due(position)?,
            None => 0.0,
        };
        let correction = coupling
            .as_ref()
            .map_or(Isometry3::identity(), |c| c.correction);
        let decoded = match item {
            Ok(d) => d,
            Err(failure) => {
                let t_s = seq
                    .frames
                    .get(failure.index)
                    .map_or(f64::NAN, |e| e.t_rgb_s);
                tracing::warn!("frame {} skipped: {}", failure.index, failure.error);
                let pose = vo.predict(t_s);
                let (kf_id, world_from_kf) =
                    vo.current_keyframe().unwrap_or((0, Isometry3::identity()));
                frames.push(FrameRecord {
                    index: failure.index,
                    t_s,
                    live_world_from_camera: correction * pose,
                    odometry_world_from_camera: pose,
                    keyframe_id: kf_id,
                    keyframe_from_camera: world_from_kf.inverse() * pose,
                    status: FrameStatus::Skipped,
                    keyframe: false,
                    tracked: 0,
                    inliers: 0,
                    decode_s: f64::NAN,
                    timing: StageTimes::default(),
                    wait_s,
                    skip_reason: Some(failure.error.to_string()),
                });
                pb.inc(1);
                continue;
            }
        };
        let t0 = Instant::now();
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
        if let (Some(c), Some(info)) = (coupling.as_mut(), r.new_keyframe.clone()) {
            c.queue.push_back((info.id, position, r.world_from_camera));
            c.thread.send(KeyframeInput {
                frame_index: r.index,
                t_s: r.t_s,
                world_from_camera: r.world_from_camera,
                info,
            })?;
        }
        frames.push(FrameRecord {
            index: r.index,
            t_s: r.t_s,
            live_world_from_camera: correction * r.world_from_camera,
            odometry_world_from_camera: r.world_from_camera,
            keyframe_id: r.keyframe_id,
            keyframe_from_camera: r.keyframe_from_camera,
            status: if r.status == TrackingStatus::Lost {
                FrameStatus::Lost
            } else {
                FrameStatus::Tracked
            },
            keyframe: r.keyframe,
            tracked: r.tracked,
            inliers: r.inliers,
            decode_s: decoded.decode_s,
            timing: r.timing,
            wait_s,
            skip_reason: None,
        });
        pb.inc(1);
    }
    pb.finish_and_clear();
    let backend = match (coupling, backend) {
        (Some(c), Some((config, _))) => Some(finish_backend(c, config)?),
        _ => None,
    };
    Ok(RunOutput {
        frames,
        vo_wall_s,
        wall_s: start.elapsed().as_secs_f64(),
        backend,
    })
}

/// Waits for the back end, runs its final optimization and collects its results.
fn finish_backend(c: Coupling, config: BackendConfig) -> Result<BackendSummary> {
    let mut reports = c.reports;
    let finished = c.thread.finish().context("finishing the back end")?;
    reports.extend(finished.late_updates.into_iter().map(|u| u.report));
    let map = finished.backend.map();
    let ids = map.keyframes().keys().chain(map.culled().keys());
    let mut keyframe_poses: Vec<(u64, Isometry3<f64>)> =
        ids.filter_map(|&k| Some((k, map.pose_of(k)?))).collect();
    keyframe_poses.sort_by_key(|(k, _)| *k);
    Ok(BackendSummary {
        config,
        keyframes: reports,
        final_solve: finished.final_solve,
        map_keyframes: map.keyframes().len(),
        map_points: map.points().len(),
        culled_keyframes: map.culled().len(),
        points_world: map.points().values().map(|p| p.p_world).collect(),
        keyframe_poses,
    })
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
