//! What a run produced: a record per frame, the back end's summary, and the final poses.

use crate::pipeline::world::WorldFrame;
use crate::pipeline::PipelineError;
use nalgebra::Isometry3;
use stride_backend::{BackendConfig, KeyframeReport};
use stride_core::trajectory::Trajectory;
use stride_frontend::StageTimes;

/// How a frame's pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameStatus {
    /// Estimated by the odometry (or the first frame).
    Tracked,
    /// Lucas-Kanade could not follow it; found by matching ORB features against recent
    /// keyframes (the odometry's wide-baseline recovery).
    Recovered,
    /// Found by appearance among the keyframes the run may come back to: the first frame
    /// of a run in a saved map, or a frame that tracking and recovery lost.
    Relocalized,
    /// Lost by the features, placed by aligning its depth with the last keyframe's (a
    /// colour image too blurred to follow; the odometry's depth alignment).
    DepthAligned,
    /// The odometry could not estimate it: predicted by constant velocity.
    Lost,
    /// The frame could not be loaded: predicted by constant velocity.
    Skipped,
}

impl FrameStatus {
    /// Whether the odometry estimated the pose (tracked, recovered, relocalized or depth
    /// aligned) rather than predicting it (lost, skipped).
    pub fn estimated(&self) -> bool {
        !matches!(self, FrameStatus::Lost | FrameStatus::Skipped)
    }

    /// A short lowercase name for reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            FrameStatus::Tracked => "tracked",
            FrameStatus::Recovered => "recovered",
            FrameStatus::Relocalized => "relocalized",
            FrameStatus::DepthAligned => "depth",
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
    /// The odometry's current keyframe when the frame was tracked.
    pub keyframe_id: u64,
    /// How the pose was obtained.
    pub status: FrameStatus,
    /// The keyframe a recovered or relocalized frame was matched against.
    pub matched_keyframe: Option<u64>,
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
    /// Whether, when the frame was processed, its pose was placed in the world's piece
    /// ([`RunOutput::frame_pieces`]' 0): false after a lost frame, or in a saved map before
    /// its first frame was found there, until a match or the back end's loop closure joins
    /// the frame's piece to it. A live pose with `false` is where a guess put it.
    pub live_in_world: bool,
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
    /// Final `world_from_camera` of every keyframe ever made (a culled one's through the
    /// keyframe it is kept relative to), by identifier.
    pub keyframe_poses: Vec<(u64, Isometry3<f64>)>,
    /// The final map itself, in the SLAM's frame (what `--save-map` writes).
    pub map: stride_backend::map::Map,
    /// The place features of the final map's keyframes (camera frames, m), by keyframe
    /// (none when loop closure was off): `--save-map` writes them too.
    pub place_features: std::collections::BTreeMap<u64, Vec<stride_frontend::PlaceFeature>>,
}

impl BackendSummary {
    /// The final `world_from_camera` of keyframe `id`.
    pub fn keyframe_pose(&self, id: u64) -> Option<Isometry3<f64>> {
        let i = self
            .keyframe_poses
            .binary_search_by_key(&id, |k| k.0)
            .ok()?;
        self.keyframe_poses.get(i).map(|k| k.1)
    }

    /// The final poses of the keyframes, at their frames' times.
    pub fn keyframe_trajectory(&self, out: &RunOutput) -> Trajectory {
        let mut t = Trajectory::new();
        for f in out.frames.iter().filter(|f| f.keyframe) {
            if let Some(pose) = self.keyframe_pose(f.keyframe_id) {
                // Frames are in time order and keyframes among them: pushing cannot fail.
                let _ = t.push(f.t_s, pose);
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
    /// The world frame every pose and point of this output is in.
    pub world: WorldFrame,
    /// What a gyroscope given ([`Pipeline::add_gyroscope`]) was used for: frames whose
    /// rolling-shutter correction and whose predicted rotation took it, and frames it did
    /// not cover.
    ///
    /// [`Pipeline::add_gyroscope`]: crate::Pipeline::add_gyroscope
    pub gyroscope_frames: stride_frontend::GyroscopeFrames,
    /// What an accelerometer given ([`Pipeline::add_accelerometer`]) was used for: frames
    /// whose rolling-shutter correction took its translation, and frames it did not cover.
    ///
    /// [`Pipeline::add_accelerometer`]: crate::Pipeline::add_accelerometer
    pub accelerometer_frames: stride_frontend::AccelerometerFrames,
    /// Poses recovery found and refused as a step no camera makes from the tracked frame
    /// before ([`stride_frontend::VisualOdometry::recoveries_refused`]).
    pub recoveries_refused: usize,
}

impl RunOutput {
    /// Whether any frame could be read (a run of only skipped frames has no world and no
    /// map to speak of).
    pub fn read_any_frame(&self) -> bool {
        self.frames.iter().any(|f| f.status != FrameStatus::Skipped)
    }

    /// Moves every pose and point from the SLAM's frame into the world
    /// (`self.world.world_from_slam`).
    pub(crate) fn move_to_world(&mut self) {
        let w = self.world.world_from_slam;
        for f in &mut self.frames {
            f.live_world_from_camera = w * f.live_world_from_camera;
            f.odometry_world_from_camera = w * f.odometry_world_from_camera;
        }
        if let Some(b) = &mut self.backend {
            for p in &mut b.points_world {
                *p = w * *p;
            }
            for (_, pose) in &mut b.keyframe_poses {
                *pose = w * *pose;
            }
        }
    }

    /// The sizes (frames) of the pieces of the run whose placement relative to one another
    /// rests only on a guess, largest first. A lost frame (its pose predicted by constant
    /// velocity) starts a new piece, and so does a relocalized one (placed against the
    /// keyframe it was found against, not the frames before it); two pieces join when a
    /// frame of the later one is recovered or relocalized against a keyframe of the
    /// earlier one, the back end closes a loop between their keyframes, or two of their
    /// keyframes share as many points in the final map as make a loop candidate connected
    /// ([`stride_backend::LoopParams::connected_points`]). One piece for a run never lost.
    pub fn segments(&self) -> Vec<usize> {
        let mut sizes = vec![0usize; self.frames.len() + 1];
        for p in self.pieces().0 {
            if let Some(n) = sizes.get_mut(p) {
                *n += 1;
            }
        }
        sizes.retain(|&n| n > 0);
        sizes.sort_unstable_by(|a, b| b.cmp(a));
        sizes
    }

    /// The frames in the piece that holds the world's origin: the first frame's or, in a
    /// saved map, the saved map's (its keyframes, numbered before the run's, form that
    /// piece). In a saved map, the frames placed in the map's world; the others sit in a
    /// piece placed by a guess that no loop joined to the map (see [`Self::segments`]).
    pub fn frames_in_world_piece(&self) -> usize {
        self.pieces().0.iter().filter(|&&p| p == 0).count()
    }

    /// The piece of every frame (see [`Self::segments`]): 0 for the one that holds the
    /// world's origin ([`Self::frames_in_world_piece`]), a number of its own for each other
    /// piece.
    pub fn frame_pieces(&self) -> Vec<usize> {
        self.pieces().0
    }

    /// Per frame, whether it is in the piece a run in a saved map started by a guess, at a
    /// saved keyframe's pose (its first frame not found in the map), and that nothing joined
    /// to the map: poses that may be metres off, unlike those of a piece after a lost frame,
    /// which the motion model predicted over the gap. All false otherwise.
    pub fn in_guessed_start(&self) -> Vec<bool> {
        let pieces = self.pieces().0;
        let first = self
            .frames
            .iter()
            .position(|f| f.status != FrameStatus::Skipped);
        let guessed = first
            .filter(|&i| {
                self.frames
                    .get(i)
                    .is_some_and(|f| f.status == FrameStatus::Lost)
            })
            .and_then(|i| pieces.get(i).copied())
            .filter(|&p| p != 0);
        pieces.iter().map(|&p| Some(p) == guessed).collect()
    }

    /// The final map's keyframes outside the piece that holds the world's origin (see
    /// [`Self::frames_in_world_piece`]): placed only by a guess relative to it, they are
    /// left out of a saved map, whose frame would otherwise hold them where the guess put
    /// them. Empty without a back end.
    pub fn keyframes_outside_world_piece(&self) -> std::collections::BTreeSet<u64> {
        self.pieces().1
    }

    /// The piece of every frame now (see [`Self::segments`] and the `pieces` module): 0
    /// holds the first frame or, when the run started in a saved map, the map's keyframes;
    /// and the final map's keyframes outside piece 0.
    fn pieces(&self) -> (Vec<usize>, std::collections::BTreeSet<u64>) {
        let mut pieces = super::pieces::Pieces::new();
        let made: Vec<usize> = self
            .frames
            .iter()
            .map(|f| {
                let keyframe = f.keyframe.then_some(f.keyframe_id);
                pieces.frame(f.status, f.matched_keyframe, keyframe)
            })
            .collect();
        // Loops, and keyframes the final map ties by shared points.
        if let Some(b) = &self.backend {
            for k in &b.keyframes {
                if let Some(l) = &k.loop_closure {
                    pieces.tie(k.keyframe_id, l.matched);
                }
            }
            let min_shared = b.config.loop_closure.connected_points.max(1);
            for (&id, kf) in b.map.keyframes() {
                for (other, _) in kf.covisible(min_shared) {
                    pieces.tie(id, other);
                }
            }
        }
        let outside = self
            .backend
            .iter()
            .flat_map(|b| b.map.keyframes().keys())
            .filter(|&&k| pieces.keyframe_piece(k).is_some_and(|p| p != 0))
            .copied()
            .collect();
        let frames = made.into_iter().map(|p| pieces.root(p)).collect();
        (frames, outside)
    }

    /// The final `world_from_camera` of every frame (the live poses without a back end).
    ///
    /// A frame between keyframes `A` (its own) and `B` (the next) has two estimates, each
    /// keyframe's final pose times the frame's odometry pose relative to it; the frame
    /// takes their average, weighted by its time between the two (all of `A`'s at `A`). A
    /// keyframe the odometry placed poorly then spoils only half of its neighbours' poses
    /// instead of all of them.
    pub fn final_poses(&self) -> Vec<Isometry3<f64>> {
        let Some(b) = &self.backend else {
            return self
                .frames
                .iter()
                .map(|f| f.live_world_from_camera)
                .collect();
        };
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
        // A keyframe's final pose times the frame's odometry pose relative to it.
        let through = |k: &FrameRecord, f: &FrameRecord| {
            b.keyframe_pose(k.keyframe_id).map(|world_from_k| {
                world_from_k * k.odometry_world_from_camera.inverse() * f.odometry_world_from_camera
            })
        };
        self.frames
            .iter()
            .zip(next_kf)
            .map(|(f, kb)| {
                let Some(ka) = kf_record.get(&f.keyframe_id) else {
                    return f.live_world_from_camera;
                };
                let Some(from_a) = through(ka, f) else {
                    return f.live_world_from_camera;
                };
                // A lost next keyframe was placed by a guess: nothing ties the frames
                // before it to it.
                let kb = kb.filter(|kb| kb.status != FrameStatus::Lost);
                let Some((kb, from_b)) = kb.and_then(|kb| Some((kb, through(kb, f)?))) else {
                    return from_a;
                };
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

    /// The estimated trajectory (every frame, final poses).
    pub fn trajectory(&self) -> Result<Trajectory, PipelineError> {
        self.trajectory_of(self.final_poses())
    }

    /// The trajectory as it was known frame by frame (live poses).
    pub fn live_trajectory(&self) -> Result<Trajectory, PipelineError> {
        self.trajectory_of(self.frames.iter().map(|f| f.live_world_from_camera))
    }

    /// The frames' times with `poses`, one per frame in order.
    fn trajectory_of(
        &self,
        poses: impl IntoIterator<Item = Isometry3<f64>>,
    ) -> Result<Trajectory, PipelineError> {
        let mut t = Trajectory::new();
        for (f, p) in self.frames.iter().zip(poses) {
            t.push(f.t_s, p)
                .map_err(|source| PipelineError::Trajectory {
                    index: f.index,
                    t_s: f.t_s,
                    source,
                })?;
        }
        Ok(t)
    }
}

/// Frames that could not be read are logged one by one up to this many; the rest only
/// counted (reports list every one), so that a systematic fault (a camera file of the wrong
/// size) does not bury the error that follows under a line per frame.
pub(crate) const SKIPS_LISTED: usize = 5;

/// Logs frame `index` as skipped for `reason`, given how many were skipped before it: one
/// line each for the first [`SKIPS_LISTED`], then one line saying the rest are counted.
pub(crate) fn warn_skipped(skipped_before: usize, index: usize, reason: &dyn std::fmt::Display) {
    if skipped_before < SKIPS_LISTED {
        tracing::warn!("frame {index} skipped: {reason}");
    } else if skipped_before == SKIPS_LISTED {
        tracing::warn!(
            "frame {index} skipped: {reason}; further skipped frames are counted, not listed"
        );
    }
}
