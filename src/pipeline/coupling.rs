//! The back end beside the odometry: keyframes out, corrections in, on a fixed or free
//! schedule.

use super::output::BackendSummary;
use super::PipelineError;
use nalgebra::Isometry3;
use std::collections::VecDeque;
use std::time::Instant;
use stride_backend::{BackendConfig, BackendThread, KeyframeReport, KeyframeUpdate};

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

impl Schedule {
    /// Frames between a keyframe and the application of its correction under the default
    /// fixed schedule: time for the local optimization while the odometry goes on.
    pub const DEFAULT_LAG_FRAMES: usize = 3;
}

/// The back end beside the odometry, and the keyframes whose corrections are due.
pub(crate) struct Coupling {
    /// The back end's configuration, for the report.
    pub(crate) config: BackendConfig,
    pub(crate) thread: BackendThread,
    pub(crate) schedule: Schedule,
    /// Keyframes sent and not yet answered: identifier, frame position, odometry pose.
    pub(crate) queue: VecDeque<(u64, usize, Isometry3<f64>)>,
    /// `optimized_from_odometry` implied by the latest answer.
    pub(crate) correction: Isometry3<f64>,
    pub(crate) reports: Vec<KeyframeReport>,
    /// Poses answered since the caller last took them ([`Coupling::take_answers`]):
    /// each answer's window of keyframes, `world_from_camera` in the SLAM's frame.
    pub(crate) answers: Vec<(u64, Isometry3<f64>)>,
}

impl Coupling {
    /// Takes the back end's answer for the oldest keyframe sent.
    fn absorb(&mut self, u: KeyframeUpdate) -> Result<(), PipelineError> {
        let due = self.queue.pop_front();
        let Some((id, _, odometry_pose)) = due.filter(|d| d.0 == u.keyframe_id) else {
            return Err(PipelineError::BackendOrder {
                answered: u.keyframe_id,
                expected: due.map(|d| d.0),
            });
        };
        self.correction = u.correction(&odometry_pose);
        self.answers.push((id, u.world_from_keyframe));
        self.answers.extend(u.window_poses);
        self.reports.push(u.report);
        Ok(())
    }

    /// The poses answered since the last call, in the order they were answered (a later
    /// one of the same keyframe supersedes an earlier one).
    pub(crate) fn take_answers(&mut self) -> Vec<(u64, Isometry3<f64>)> {
        std::mem::take(&mut self.answers)
    }

    /// Takes the answers due before the frame at `position` (waiting for them under the
    /// fixed schedule). Returns the time waited (s).
    pub(crate) fn take_due(&mut self, position: usize) -> Result<f64, PipelineError> {
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

/// Waits for the back end, runs its final optimization and collects its results.
pub(crate) fn finish_backend(c: Coupling) -> Result<BackendSummary, PipelineError> {
    let config = c.config;
    let mut reports = c.reports;
    let finished = c.thread.finish()?;
    reports.extend(finished.late_updates.into_iter().map(|u| u.report));
    let place_features = finished.backend.place_features();
    let map = finished.backend.into_map();
    let ids = map.keyframes().keys().chain(map.culled().keys());
    let mut keyframe_poses: Vec<(u64, Isometry3<f64>)> =
        ids.filter_map(|&k| Some((k, map.pose_of(k)?))).collect();
    keyframe_poses.sort_by_key(|k| k.0);
    Ok(BackendSummary {
        config,
        keyframes: reports,
        final_solve: finished.final_solve,
        map_keyframes: map.keyframes().len(),
        map_points: map.points().len(),
        culled_keyframes: map.culled().len(),
        points_world: map.points().values().map(|p| p.p_world).collect(),
        keyframe_poses,
        map,
        place_features,
    })
}
