//! The pipeline from RGB-D frames to pose and terrain, one frame at a time.
//!
//! Per frame, in order:
//! 1. the SLAM ([`slam::Slam`]) takes the back end's answers that are due, tracks the frame
//!    with the odometry and hands a new keyframe to the back end (its own thread);
//! 2. the elevation map ([`terrain::Terrain`], in its own thread) keeps the frame's depth
//!    as a view tied to its keyframe (every few frames), moves the keyframes the back end
//!    answered for, and maps the views whose pose is known, once the gravity-aligned world
//!    is ([`world`]: a reference trajectory, a given mounting, the accelerometer, or the
//!    floor in the first frames).
//!
//! At the end ([`Pipeline::finish`]) the back end runs its full optimization, the world
//! frame is refined with the final poses (every floor seen, every accelerometer sample),
//! and the map is rebuilt at the final poses.
//!
//! Frames (SLAM, odometry, back end) are named as in the rest of stride: every output pose
//! is `world_from_camera` in the world (z up, gravity-aligned, metres), cameras looking
//! along +z with x right and y down.

mod coupling;
mod error;
mod output;
mod pieces;
mod sequence;
pub mod slam;
mod stats;
pub mod terrain;
mod terrain_thread;
pub mod world;

pub use coupling::Schedule;
pub use error::PipelineError;
pub(crate) use output::warn_skipped;
pub use output::{BackendSummary, FrameRecord, FrameStatus, RunOutput};
pub use sequence::run_sequence;
pub use stats::{median_p95, slam_ate_options};

use slam::Slam;
use std::time::Instant;
use stride_backend::{BackendConfig, SavedMap};
use stride_core::frame::RgbdFrame;
use stride_datasets::camera_config::CameraConfig;
use stride_frontend::VoConfig;
use stride_mapping::MapLayers;
use terrain::{Terrain, TerrainConfig, TerrainStats};
use terrain_thread::TerrainThread;
use world::{WorldFrame, WorldPlan, WorldSource};

/// Every stage's parameters.
#[derive(Debug, Clone)]
pub struct PipelineConfig {
    /// The visual odometry (the frontend). Its rolling-shutter readout is replaced by the
    /// camera's.
    pub odometry: VoConfig,
    /// The back end beside the odometry and when its corrections apply; `None` for the
    /// odometry alone.
    pub backend: Option<(BackendConfig, Schedule)>,
    /// Where the gravity-aligned world frame comes from.
    pub world: WorldPlan,
    /// The elevation map; `None` for poses only.
    pub map: Option<TerrainConfig>,
    /// A saved map to start in: the first frame is relocalized in it (or, when it cannot
    /// be, put at the newest saved keyframe's pose by a guess, in a piece that loop closure
    /// joins to the map later: [`RunOutput::frames_in_world_piece`]), the back end extends
    /// it, and its world replaces `world`. `None` starts a new map at the first frame.
    pub saved_map: Option<SavedMap>,
}

impl Default for PipelineConfig {
    /// The SLAM with bundle adjustment on the fixed (repeatable) schedule, the world from
    /// the floor, and the elevation map: [`crate::config::Config::default`]'s settings.
    fn default() -> Self {
        crate::config::Config::default().pipeline(WorldPlan::Floor)
    }
}

/// The elevation map at the end of a run.
pub struct MapOutput {
    /// Its layers in the world frame (z up, m), NaN where unknown.
    pub layers: MapLayers,
    /// What the map did.
    pub stats: TerrainStats,
    /// Wall time the caller's thread spent on the map (s): handing data over, waiting for
    /// the map's thread at the end, and the final rebuild.
    pub wall_s: f64,
}

/// What a run produced.
pub struct PipelineOutput {
    /// Poses, per-frame records and the back end's summary.
    pub run: RunOutput,
    /// The elevation map, when one was asked for and the world frame is gravity-aligned.
    pub map: Option<MapOutput>,
}

/// The pipeline: the SLAM and the elevation map on its poses, fed one frame at a time.
///
/// ```no_run
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// use stride::pipeline::{Pipeline, PipelineConfig};
/// let seq = stride_datasets::tum::TumSequence::open(
///     std::path::Path::new("rgbd_dataset_freiburg3_teddy"),
///     None,
///     Default::default(),
/// )?;
/// let mut pipeline = Pipeline::new(&seq.camera, PipelineConfig::default())?;
/// for decoded in seq.stream(None, 4) {
///     let decoded = decoded?;
///     let record = pipeline.process(&decoded.frame, decoded.decode_s)?;
///     println!("{} {:?}", record.t_s, record.live_world_from_camera.translation);
/// }
/// let out = pipeline.finish()?;
/// println!("{} cells mapped", out.map.map_or(0, |m| m.layers.cells_observed()));
/// # Ok(()) }
/// ```
pub struct Pipeline {
    slam: Slam,
    terrain: Option<TerrainThread>,
    /// The current keyframe's identifier and odometry pose, to tie views to it.
    keyframe: Option<(u64, nalgebra::Isometry3<f64>)>,
    /// Frames seen so far.
    frames: usize,
    /// Wall time the frame path spent handing data to the map (s).
    map_wall_s: f64,
}

impl Pipeline {
    /// A pipeline for `camera` (its rolling-shutter readout replaces the odometry's).
    pub fn new(camera: &CameraConfig, config: PipelineConfig) -> Result<Self, PipelineError> {
        let terrain = config
            .map
            .map(|c| TerrainThread::spawn(Terrain::new(&camera.camera, c)?))
            .transpose()?;
        let world = match &config.saved_map {
            Some(s) => WorldPlan::Given(WorldFrame {
                world_from_slam: s.world_from_map,
                source: WorldSource::SavedMap {
                    gravity_aligned: s.gravity_aligned,
                },
            }),
            None => config.world,
        };
        let slam =
            Slam::new(camera, config.odometry, config.backend, config.saved_map)?.with_world(world);
        Ok(Self {
            slam,
            terrain,
            keyframe: None,
            frames: 0,
            map_wall_s: 0.0,
        })
    }

    /// Adds gyroscope samples: time (s, the frames' clock) and the camera's angular
    /// velocity in its own frame (rad/s), in time order, all at once or as they arrive.
    /// With a rolling shutter, each frame's correction then takes each row's rotation,
    /// integrated from the samples over the readout (odometry key `readout_gyroscope`), and
    /// the rotation predicted from frame to frame comes from them (`predict_gyroscope`);
    /// report.json counts the frames that did and those the samples did not cover.
    pub fn add_gyroscope(&mut self, samples: &[stride_datasets::accelerometer::GyroSample]) {
        self.slam.add_gyroscope(samples);
    }

    /// Adds accelerometer samples: time (s, the frames' clock) and the specific force in
    /// the camera frame (m/s²), in time order, all at once or as they arrive. With a
    /// rolling shutter and samples of 200 Hz or more, each frame's correction then takes
    /// each row's translation, integrated from them (odometry key
    /// `readout_accelerometer`); report.json counts the frames that did and those the
    /// samples did not cover. The world frame's use of an accelerometer is separate
    /// ([`WorldPlan::Accelerometer`]).
    pub fn add_accelerometer(&mut self, samples: &[stride_datasets::accelerometer::AccelSample]) {
        self.slam.add_accelerometer(samples);
    }

    /// Processes the next frame; `decode_s` is the time its decoding took elsewhere (s),
    /// for the report. Returns its record: pose (live), status, keyframe, timings.
    pub fn process(
        &mut self,
        frame: &RgbdFrame,
        decode_s: f64,
    ) -> Result<FrameRecord, PipelineError> {
        let record = self.slam.process(frame, decode_s)?;
        let position = self.frames;
        self.frames += 1;
        if record.keyframe {
            self.keyframe = Some((record.keyframe_id, record.odometry_world_from_camera));
        }
        if let Some(t) = self.terrain.as_mut() {
            let start = Instant::now();
            let tracked = record.status.estimated();
            if let Some((id, odometry_pose)) = self.keyframe.filter(|_| tracked) {
                if t.wants(position, record.keyframe) {
                    let keyframe_from_camera =
                        odometry_pose.inverse() * record.odometry_world_from_camera;
                    t.view(
                        position,
                        frame.t_s,
                        &frame.depth_m,
                        id,
                        keyframe_from_camera,
                    )?;
                }
                if record.keyframe && !self.slam.has_backend() {
                    t.poses(vec![(id, record.live_world_from_camera)])?;
                }
            }
            self.map_wall_s += start.elapsed().as_secs_f64();
        }
        self.update_map()?;
        Ok(record)
    }

    /// Records a frame that could not be loaded (its pose predicted, the reason kept and
    /// counted).
    pub fn skip(
        &mut self,
        index: usize,
        t_s: f64,
        reason: String,
    ) -> Result<FrameRecord, PipelineError> {
        let record = self.slam.skip(index, t_s, reason)?;
        self.frames += 1;
        self.update_map()?;
        Ok(record)
    }

    /// Hands the back end's answers and the world frame (once known) to the map. The
    /// answers are taken even without a map, so that they never pile up.
    fn update_map(&mut self) -> Result<(), PipelineError> {
        let answers = self.slam.take_answers();
        let Some(t) = self.terrain.as_mut() else {
            return Ok(());
        };
        let start = Instant::now();
        t.poses(answers)?;
        if !t.has_world() {
            if let Some(w) = self.slam.provisional_world() {
                t.world(w.world_from_slam)?;
            }
        }
        self.map_wall_s += start.elapsed().as_secs_f64();
        Ok(())
    }

    /// The elevation map as it is now (world frame, z up; the map's own thread catches up
    /// first), when there is one.
    pub fn map(&mut self) -> Option<Result<MapLayers, PipelineError>> {
        self.terrain.as_mut().map(TerrainThread::layers)
    }

    /// Waits for the back end, runs its final optimization, and rebuilds the map at the
    /// final poses; everything in the final world frame.
    pub fn finish(self) -> Result<PipelineOutput, PipelineError> {
        let run = self.slam.finish()?;
        let map = match self.terrain {
            Some(_) if !run.world.is_gravity_aligned() => {
                if run.read_any_frame() {
                    tracing::warn!(
                        "no elevation map: the world frame is not gravity-aligned (no floor seen, no mounting given)"
                    );
                }
                None
            }
            Some(t) => {
                let start = Instant::now();
                // Not the views of a start in a saved map that nothing joined to it: their
                // terrain would lie where a guess at a saved keyframe's pose put it.
                let (layers, stats) = t.finish(&run.final_poses(), &run.in_guessed_start())?;
                Some(MapOutput {
                    layers,
                    stats,
                    wall_s: self.map_wall_s + start.elapsed().as_secs_f64(),
                })
            }
            None => None,
        };
        Ok(PipelineOutput { run, map })
    }
}
