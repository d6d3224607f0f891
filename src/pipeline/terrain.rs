//! The elevation map inside the pipeline: each keyframe's depth at its optimized pose, and
//! the recent part of the map rebuilt when the back end moves keyframes.
//!
//! The map takes a *view* every `every_frames` frames (and at every keyframe): a decimated
//! copy of its depth, tied to the frame's keyframe by the odometry's relative pose, so that
//! it moves with its keyframe. Views are mapped in order once their keyframe's pose is
//! settled enough to use (the back end's answer, or at once for the odometry alone) and the
//! world frame is known (the map's z axis must point up). When the back end moves the
//! keyframe of a mapped view by more than a threshold, the map of the kept views (`live`)
//! is rebuilt from their copies at their new poses, so that a correction moves the terrain
//! with the poses instead of smearing it. Memory stays bounded: only the newest
//! `max_stored_views` keep their copy; an older view is *settled*: integrated once into a
//! second map (`settled`) that is never rebuilt, and its copy dropped. The map a caller
//! sees is the live map laid over the settled one.
//!
//! Before a view is integrated it is laid onto the live map ([`TerrainConfig::align`],
//! [`stride_mapping::align`]): its height and tilt are corrected so that its points meet the
//! established cells. Errors of a few tenths of a degree in the SLAM's orientation would
//! otherwise make a flat floor rough far from the camera; x, y and yaw stay the SLAM's.

use super::PipelineError;
use nalgebra::Isometry3;
use std::collections::{HashMap, VecDeque};
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;
use stride_mapping::align::{AlignConfig, AlignOutcome};
use stride_mapping::input::{Rejections, SensorFrame};
use stride_mapping::stack::{StackConfig, StackMapper};
use stride_mapping::{ElevationMapper, MapLayers, MappingError};

/// The elevation map's place in the pipeline: which pixels it takes and when it rebuilds.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TerrainConfig {
    /// The voxel-stack mapper's parameters (paper 000): resolution, window, checks.
    pub stack: StackConfig,
    /// A view is taken every this many frames (1: every frame), and at every keyframe.
    pub every_frames: usize,
    /// A view's depth keeps every `decimation`-th pixel of every `decimation`-th row
    /// (1: all). At 2 m a 640 x 480 Kinect pixel spans 4 mm, so with 2 every 1 cm cell
    /// still gets several points, for a quarter of the memory and of the update time.
    pub decimation: u32,
    /// A mapped view whose keyframe the back end moves by more than this (m) ...
    pub rebuild_translation_m: f64,
    /// ... or turns by more than this (rad; 0.005 rad moves a point 2 m away by 1 cm)
    /// makes the live map be rebuilt.
    pub rebuild_rotation_rad: f64,
    /// Views whose decimated depth is kept for rebuilds (the newest ones); older views
    /// are settled. Each costs 4 bytes per kept pixel (300 kB at 640 x 480 with
    /// decimation 2).
    pub max_stored_views: usize,
    /// Each view's height and tilt laid onto the live map before it is integrated; `None`
    /// integrates views at the SLAM's poses as they are.
    #[serde(with = "stride_core::serde_opt")]
    pub align: Option<AlignConfig>,
    /// At the end of a run, the kept views are aligned again this many times, each time
    /// against the map of all of them ([`Terrain::finish`], `terrain_realign`); 0: never.
    /// Needs `align`.
    pub final_alignment_passes: usize,
    /// The fraction of a view's height and tilt offset from the map of all views that the
    /// final alignment applies, relative to the SLAM's pose (0 to 1): below 1 the SLAM's
    /// pose keeps a pull, so that what the views cannot tell apart (a slow bend of the
    /// whole map) stays where the SLAM put it.
    pub final_alignment_gain: f64,
}

impl Default for TerrainConfig {
    fn default() -> Self {
        Self {
            stack: StackConfig::default(),
            every_frames: 2,
            decimation: 2,
            rebuild_translation_m: 0.005,
            rebuild_rotation_rad: 0.005,
            max_stored_views: 120,
            align: Some(AlignConfig::default()),
            final_alignment_passes: 8,
            final_alignment_gain: 0.9,
        }
    }
}

impl TerrainConfig {
    /// Checks every value (the stack mapper's included); the error names the key.
    pub fn validate(&self) -> Result<(), PipelineError> {
        let bad = |key: &str, value: String, allowed| {
            Err(PipelineError::Config {
                key: key.to_owned(),
                value,
                allowed,
            })
        };
        if !(1..=8).contains(&self.decimation) {
            return bad("map.decimation", self.decimation.to_string(), "1 to 8");
        }
        if !(self.rebuild_translation_m.is_finite() && self.rebuild_translation_m > 0.0) {
            return bad(
                "map.rebuild_translation_m",
                self.rebuild_translation_m.to_string(),
                "positive (m)",
            );
        }
        if !(self.rebuild_rotation_rad.is_finite() && self.rebuild_rotation_rad > 0.0) {
            return bad(
                "map.rebuild_rotation_rad",
                self.rebuild_rotation_rad.to_string(),
                "positive (rad)",
            );
        }
        if self.max_stored_views == 0 {
            return bad("map.max_stored_views", "0".into(), "at least 1");
        }
        if !(1..=1000).contains(&self.every_frames) {
            return bad(
                "map.every_frames",
                self.every_frames.to_string(),
                "1 to 1000",
            );
        }
        if self.final_alignment_passes > 50 {
            return bad(
                "map.final_alignment_passes",
                self.final_alignment_passes.to_string(),
                "0 to 50",
            );
        }
        if !(0.0..=1.0).contains(&self.final_alignment_gain) {
            return bad(
                "map.final_alignment_gain",
                self.final_alignment_gain.to_string(),
                "0 to 1",
            );
        }
        match self.align.as_ref().map(AlignConfig::validate) {
            Some(Err(MappingError::Parameter {
                name,
                value,
                reason,
            })) => return bad(&format!("map.align.{name}"), value.to_string(), reason),
            Some(Err(e)) => return Err(e.into()),
            _ => {}
        }
        match self.stack.validate() {
            Ok(_) => Ok(()),
            Err(MappingError::Parameter {
                name,
                value,
                reason,
            }) => bad(&format!("map.stack.{name}"), value.to_string(), reason),
            Err(e) => Err(e.into()),
        }
    }
}

/// What the map did over a run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TerrainStats {
    /// Frame positions (0, 1, ...) of every view taken, in order.
    pub view_frames: Vec<usize>,
    /// Views integrated (each once, rebuilds not counted).
    pub views_mapped: usize,
    /// Time of each of those integrations (s).
    pub update_s: Vec<f64>,
    /// Rebuilds of the live map, the final one included.
    pub rebuilds: usize,
    /// Time of each rebuild (s).
    pub rebuild_s: Vec<f64>,
    /// Views settled (their depth copy dropped).
    pub views_settled: usize,
    /// Views dropped before they could be mapped (no pose or no world frame by the time
    /// they had to leave the store).
    pub views_unmapped: usize,
    /// Views of the store left out of the final map: those of a start in a saved map that
    /// the map never placed and nothing joined to it
    /// ([`crate::pipeline::RunOutput::in_guessed_start`]).
    pub views_left_out: usize,
    /// Depth measurements integrated into the live map, rebuilds included.
    pub points_used: usize,
    /// Measurements dropped because their column had too many distinct voxels in one frame
    /// (counted the same way; [`stride_mapping::UpdateStats::points_overflow`]).
    pub points_overflow: usize,
    /// Measurements dropped, by reason (counted the same way).
    pub rejected: Rejections,
    /// Time the frame path waited for room in the map thread's queue (s): 0 when the map
    /// kept up.
    pub queue_wait_s: f64,
    /// Views aligned to the map when first mapped ([`TerrainConfig::align`]; rebuilds
    /// re-align but are not counted): the vertical shift at the camera (m) and the tilt
    /// (rad) of each correction applied.
    pub aligned: Vec<(f64, f64)>,
    /// Views first mapped unaligned because the map had too few established cells under
    /// them (the first views, a view of new ground) or the points could not fix a tilt.
    pub align_too_few_points: usize,
    /// Views first mapped unaligned because the correction found exceeded its limits.
    pub align_too_large: usize,
    /// The final alignment's passes, in order ([`TerrainConfig::final_alignment_passes`]).
    pub final_alignment: Vec<RealignPass>,
    /// Columns dropped from the maps' archives to keep `map.stack.archive_max_cells`
    /// (the farthest first): 0 unless the walk covered more ground than the cap.
    pub archive_dropped_cells: usize,
}

/// A view: a frame's decimated depth and where it is.
struct Stored {
    /// The frame's position in the run (0, 1, ...).
    frame: usize,
    t_s: f64,
    depth_m: DepthImage,
    /// Its keyframe, and its pose relative to it (`keyframe_from_camera`, the odometry's).
    keyframe: u64,
    keyframe_from_camera: Isometry3<f64>,
    /// The SLAM's `world_from_camera` (gravity-aligned world) when it was integrated ...
    mapped_at: Option<Isometry3<f64>>,
    /// ... and the pose it was integrated at: that one, aligned to the map.
    integrated_at: Option<Isometry3<f64>>,
}

/// The elevation map fed by keyframes.
pub struct Terrain {
    config: TerrainConfig,
    /// The camera of the decimated depth images.
    camera: PinholeCamera,
    live: StackMapper,
    settled: StackMapper,
    /// Views kept, oldest first.
    stored: VecDeque<Stored>,
    /// Keyframes' `world_from_camera` in the SLAM's frame, as far as known.
    keyframe_poses: HashMap<u64, Isometry3<f64>>,
    world_from_slam: Option<Isometry3<f64>>,
    stats: TerrainStats,
    /// Archive columns dropped by live maps that rebuilds have since replaced.
    dropped_by_replaced: usize,
}

impl Terrain {
    /// An empty map for depth images of `camera`.
    pub fn new(camera: &PinholeCamera, config: TerrainConfig) -> Result<Self, PipelineError> {
        config.validate()?;
        let d = f64::from(config.decimation);
        // Pixel (u, v) of the decimated image is pixel (d u, d v) of the full one.
        let small = PinholeCamera::new(
            camera.fx() / d,
            camera.fy() / d,
            camera.cx() / d,
            camera.cy() / d,
            camera.width().div_ceil(config.decimation),
            camera.height().div_ceil(config.decimation),
        )
        .map_err(|e| PipelineError::Config {
            key: "map.decimation".into(),
            value: format!("{} ({e})", config.decimation),
            allowed: "small enough to leave an image",
        })?;
        let small = match camera.distortion() {
            Some(&dist) => small
                .with_distortion(dist)
                .map_err(|e| PipelineError::Config {
                    key: "camera.distortion".into(),
                    value: e.to_string(),
                    allowed: "finite coefficients",
                })?,
            None => small,
        };
        Ok(Self {
            live: StackMapper::new(config.stack.clone())?,
            settled: StackMapper::new(config.stack.clone())?,
            camera: small,
            config,
            stored: VecDeque::new(),
            keyframe_poses: HashMap::new(),
            world_from_slam: None,
            stats: TerrainStats::default(),
            dropped_by_replaced: 0,
        })
    }

    /// Its configuration.
    pub fn config(&self) -> &TerrainConfig {
        &self.config
    }

    /// Keeps the depth of the frame at position `frame` (seen at `t_s`, s) as a view tied to
    /// `keyframe` by `keyframe_from_camera`, to be mapped once that keyframe's pose is known.
    pub fn add_view(
        &mut self,
        frame: usize,
        t_s: f64,
        depth_m: &DepthImage,
        keyframe: u64,
        keyframe_from_camera: Isometry3<f64>,
    ) {
        let d = self.config.decimation;
        let (w, h) = (self.camera.width(), self.camera.height());
        let mut small = DepthImage::filled(w, h, 0.0);
        for v in 0..h {
            for u in 0..w {
                if let (Some(z), Some(slot)) = (depth_m.get(u * d, v * d), small.get_mut(u, v)) {
                    *slot = z;
                }
            }
        }
        self.stats.view_frames.push(frame);
        self.stored.push_back(Stored {
            frame,
            t_s,
            depth_m: small,
            keyframe,
            keyframe_from_camera,
            mapped_at: None,
            integrated_at: None,
        });
    }

    /// Sets keyframes' `world_from_camera` in the SLAM's frame (later entries win).
    /// Keyframes no kept view needs are forgotten.
    pub fn set_poses(&mut self, poses: &[(u64, Isometry3<f64>)]) {
        self.keyframe_poses.extend(poses.iter().copied());
        let oldest = self.stored.front().map_or(u64::MAX, |s| s.keyframe);
        self.keyframe_poses.retain(|&k, _| k >= oldest);
    }

    /// Sets the world frame (once; later calls are ignored until [`Terrain::finish`]).
    pub fn set_world(&mut self, world_from_slam: Isometry3<f64>) {
        self.world_from_slam.get_or_insert(world_from_slam);
    }

    /// Brings the map up to date: rebuilds it when a mapped keyframe moved too far, maps
    /// the keyframes whose pose became known, settles the oldest beyond the store's size.
    pub fn update(&mut self) -> Result<(), PipelineError> {
        let Some(world_from_slam) = self.world_from_slam else {
            return self.settle_excess();
        };
        let poses = &self.keyframe_poses;
        let world_pose = |s: &Stored| {
            poses
                .get(&s.keyframe)
                .map(|k| world_from_slam * k * s.keyframe_from_camera)
        };
        let moved = self
            .stored
            .iter()
            .any(|s| match (s.mapped_at, world_pose(s)) {
                (Some(at), Some(now)) => self.moved(&at, &now),
                _ => false,
            });
        // The poses now, before the store is touched.
        let now: Vec<Option<Isometry3<f64>>> = self.stored.iter().map(world_pose).collect();
        if moved {
            self.rebuild(&now)?;
        }
        // Keyframes are answered in order: map the known prefix.
        for (i, pose) in now.iter().enumerate() {
            let Some(s) = self.stored.get(i) else { break };
            if s.mapped_at.is_some() {
                continue;
            }
            let Some(pose) = *pose else { break };
            let start = Instant::now();
            let outcome = self.integrate_stored(i, pose)?;
            self.count_alignment(outcome);
            self.stats.views_mapped += 1;
            self.stats.update_s.push(start.elapsed().as_secs_f64());
        }
        let settled = self.settle_excess();
        self.count_archive_drops();
        settled
    }

    /// Brings [`TerrainStats::archive_dropped_cells`] up to date.
    fn count_archive_drops(&mut self) {
        self.stats.archive_dropped_cells =
            self.dropped_by_replaced + self.live.archive_cells().1 + self.settled.archive_cells().1;
    }

    /// Whether a keyframe placed at `a` and now at `b` moved enough to rebuild.
    fn moved(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        let delta = a.inverse() * b;
        delta.translation.vector.norm() > self.config.rebuild_translation_m
            || delta.rotation.angle() > self.config.rebuild_rotation_rad
    }

    /// Records how a view's first integration was aligned (rebuilds are not counted, so
    /// that the counts add up to the views mapped).
    fn count_alignment(&mut self, outcome: Option<AlignOutcome>) {
        match outcome {
            Some(AlignOutcome::Aligned(a)) => self.stats.aligned.push((a.shift_m, a.tilt_rad)),
            Some(AlignOutcome::TooFewPoints(_) | AlignOutcome::Degenerate) => {
                self.stats.align_too_few_points += 1;
            }
            Some(AlignOutcome::TooLarge(_)) => self.stats.align_too_large += 1,
            None => {}
        }
    }

    /// Integrates stored view `i` into the live map at `world_from_camera` (the SLAM's),
    /// aligned to the map first when [`TerrainConfig::align`] asks for it; returns what the
    /// alignment found (`None` without alignment or without such a view).
    fn integrate_stored(
        &mut self,
        i: usize,
        world_from_camera: Isometry3<f64>,
    ) -> Result<Option<AlignOutcome>, PipelineError> {
        let Some(s) = self.stored.get_mut(i) else {
            return Ok(None);
        };
        let mut frame = SensorFrame::depth(&s.depth_m, &self.camera, world_from_camera, s.t_s)?;
        let outcome = self
            .config
            .align
            .as_ref()
            .map(|c| self.live.align(&frame, c));
        let at = match outcome {
            Some(AlignOutcome::Aligned(a)) => {
                tracing::trace!(
                    "frame {}: aligned to the map by {:.1} mm, {:.3} deg ({} points, rms {:.1} -> {:.1} mm)",
                    s.frame,
                    a.shift_m * 1e3,
                    a.tilt_rad.to_degrees(),
                    a.points,
                    a.rms_before_m * 1e3,
                    a.rms_after_m * 1e3
                );
                a.correction * world_from_camera
            }
            Some(AlignOutcome::TooLarge(a)) => {
                tracing::debug!(
                    "frame {}: alignment to the map refused ({:.1} mm, {:.2} deg)",
                    s.frame,
                    a.shift_m * 1e3,
                    a.tilt_rad.to_degrees()
                );
                world_from_camera
            }
            _ => world_from_camera,
        };
        frame.map_from_sensor = at;
        let u = self.live.integrate(&frame);
        self.stats.points_used += u.points_used;
        self.stats.points_overflow += u.points_overflow;
        self.stats.rejected.add(&u.rejected);
        s.mapped_at = Some(world_from_camera);
        s.integrated_at = Some(at);
        Ok(outcome)
    }

    /// A new live map from every kept view with a pose (`poses`, one per view), in order.
    fn rebuild(&mut self, poses: &[Option<Isometry3<f64>>]) -> Result<(), PipelineError> {
        let start = Instant::now();
        self.clear_live()?;
        for (i, pose) in poses.iter().enumerate() {
            match *pose {
                Some(p) => {
                    self.integrate_stored(i, p)?;
                }
                None => {
                    if let Some(s) = self.stored.get_mut(i) {
                        s.mapped_at = None;
                        s.integrated_at = None;
                    }
                }
            }
        }
        self.stats.rebuilds += 1;
        self.stats.rebuild_s.push(start.elapsed().as_secs_f64());
        Ok(())
    }

    /// Replaces the live map with an empty one, counting the archive columns it dropped.
    fn clear_live(&mut self) -> Result<(), PipelineError> {
        self.dropped_by_replaced += self.live.archive_cells().1;
        self.live = StackMapper::new(self.config.stack.clone())?;
        Ok(())
    }

    /// Moves the oldest keyframes beyond the store's size into the settled map.
    fn settle_excess(&mut self) -> Result<(), PipelineError> {
        while self.stored.len() > self.config.max_stored_views {
            let Some(s) = self.stored.pop_front() else {
                break;
            };
            match s.integrated_at {
                Some(pose) => {
                    let frame = SensorFrame::depth(&s.depth_m, &self.camera, pose, s.t_s)?;
                    self.settled.integrate(&frame);
                    self.stats.views_settled += 1;
                }
                None => {
                    tracing::warn!(
                        "frame {} left the map's store before it could be mapped (no pose or no world frame yet)",
                        s.frame
                    );
                    self.stats.views_unmapped += 1;
                }
            }
        }
        Ok(())
    }

    /// The map now: the live map (median-filtered, as paper 000 delivers it) laid over the
    /// settled one, in the world frame (z up, m).
    pub fn layers(&self) -> Result<MapLayers, PipelineError> {
        let (live, _) = self.live.finished();
        if self.stats.views_settled == 0 {
            return Ok(live);
        }
        let (settled, _) = self.settled.finished();
        Ok(settled.overlaid(&live)?)
    }

    /// The final map: the kept views at their frames' final `world_from_camera` in the
    /// final world (`final_pose` of a frame position; where a frame has none its view stays
    /// where it was mapped), without the views whose frames are `left_out`, rebuilt if any
    /// moved beyond the thresholds or left, then aligned again against the map of all of them
    /// ([`TerrainConfig::final_alignment_passes`]). The settled part stays where it was
    /// mapped.
    pub fn finish(
        mut self,
        final_pose: impl Fn(usize) -> Option<Isometry3<f64>>,
        left_out: impl Fn(usize) -> bool,
    ) -> Result<(MapLayers, TerrainStats), PipelineError> {
        // A view without a final pose stays where it was mapped; one left out leaves.
        let now: Vec<_> = self
            .stored
            .iter()
            .map(|s| (!left_out(s.frame)).then(|| final_pose(s.frame).or(s.mapped_at))?)
            .collect();
        let moved = self
            .stored
            .iter()
            .zip(&now)
            .any(|(s, now)| match (s.mapped_at, now) {
                (Some(at), Some(now)) => self.moved(&at, now),
                (None, Some(_)) | (Some(_), None) => true,
                _ => false,
            });
        self.stats.views_left_out = now.iter().filter(|p| p.is_none()).count();
        if moved {
            self.rebuild(&now)?;
        }
        for _ in 0..self.config.final_alignment_passes {
            self.realign()?;
        }
        self.count_archive_drops();
        let layers = self.layers()?;
        Ok((layers, self.stats))
    }

    /// What the map did so far.
    pub fn stats(&self) -> &TerrainStats {
        &self.stats
    }
}

#[path = "terrain_realign.rs"]
mod realign;
pub use realign::RealignPass;

#[cfg(test)]
#[path = "terrain_tests.rs"]
mod tests;
