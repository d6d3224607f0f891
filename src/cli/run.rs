//! `stride run`: the SLAM pipeline on a sequence: visual odometry, and beside it the back end
//! (feature map and bundle adjustment, or a pose graph).

use super::run_files::RunSummary;
use anyhow::{Context, Result};
use clap::Args;
use serde_json::Value;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;
use stride::config::Config;
use stride::pipeline::run_sequence;
use stride::pipeline::world::WorldPlan;
use stride_backend::{BackendMode, SavedMap};
use stride_datasets::mcap::McapTopics;
use stride_datasets::sequence::Sequence;
use stride_datasets::tum::AssociationOptions;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Sequence folder in TUM layout (rgb.txt, depth.txt, optional groundtruth.txt), or an
    /// MCAP log of ROS 2 messages (a file ending in .mcap; topics below).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Topics of an MCAP --dataset.
    #[command(flatten)]
    pub topics: TopicArgs,
    /// Camera: fr1, fr2, fr3 or a camera file [default: the folder's camera.json, else the
    /// TUM camera its name implies].
    #[arg(long)]
    pub camera: Option<String>,
    /// Output folder (created if missing; an existing non-empty one only with --overwrite).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the output folder's contents.
    #[arg(long)]
    pub overwrite: bool,
    /// Poses only: no elevation map.
    #[arg(long)]
    pub no_map: bool,
    /// Every stage's parameters as a TOML file (`stride config --print-defaults` prints
    /// them all); the flags below override it.
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<PathBuf>,
    /// The back end: `ba` (feature map and bundle adjustment of poses and points), `pose-graph`
    /// (keyframe poses tied by relative motions, RGB-D SLAM v2 style) or `none` (the visual
    /// odometry alone) [default: the configuration's, `ba`].
    #[arg(long, value_enum)]
    pub backend: Option<BackendArg>,
    /// The visual odometry alone: the same as `--backend none`.
    #[arg(long)]
    pub vo_only: bool,
    /// Apply the back end's corrections as soon as they are ready, never waiting for them.
    /// Faster on a loaded machine, but results then depend on thread timing. By default a
    /// correction is applied a fixed number of frames after its keyframe, so that reruns are
    /// bit-identical.
    #[arg(long)]
    pub free_running: bool,
    /// Seed of RANSAC [default: the configuration's, 1].
    #[arg(long)]
    pub seed: Option<u64>,
    /// Process at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Repeatable bit for bit (the default schedule already is; this also pins OpenCV to one
    /// thread, which does not change results). Conflicts with --free-running.
    #[arg(long, conflicts_with = "free_running")]
    pub deterministic: bool,
    /// The camera's downward pitch (degrees) on the robot, with --camera-height-m: sets the
    /// gravity-aligned world frame instead of the floor seen in the first frames.
    #[arg(
        long,
        value_name = "DEG",
        requires = "camera_height_m",
        allow_negative_numbers = true
    )]
    pub camera_pitch_deg: Option<f64>,
    /// The camera's height above the ground (m), with --camera-pitch-deg.
    #[arg(long, value_name = "M", requires = "camera_pitch_deg")]
    pub camera_height_m: Option<f64>,
    /// Take the world frame from the ground truth (its pose of the first frame it covers)
    /// instead of the floor: the outputs are then in the ground truth's world, and the map is scored against the
    /// folder's true terrain (terrain.npy) when it has one.
    #[arg(long, conflicts_with = "camera_pitch_deg")]
    pub world_from_groundtruth: bool,
    /// Find the world's z axis from the floor alone, even when the folder has an
    /// accelerometer.txt (by default its mean reading gives the z axis, the floor the
    /// height).
    #[arg(long)]
    pub ignore_accelerometer: bool,
    /// Save the final map (keyframes, points, descriptors, covisibility, the world frame)
    /// to this file for a later `--load-map` (format: docs/map-format.md). Needs a back end.
    #[arg(long, value_name = "FILE.json")]
    pub save_map: Option<PathBuf>,
    /// Also write the run as an MCAP log that Foxglove shows in 3-D: the camera's transforms,
    /// path and keyframes, the feature map's points and the elevation map (Foxglove's
    /// schemas, JSON encoding; world frame, z up).
    #[arg(long, value_name = "FILE.mcap")]
    pub mcap_out: Option<PathBuf>,
    /// Start in a map saved by `--save-map`: the first frame is relocalized in it (an error
    /// when it cannot be), poses come out in that map's world, and the back end extends the
    /// map. Made with the same camera.
    #[arg(long, value_name = "FILE.json", conflicts_with_all = ["camera_pitch_deg", "world_from_groundtruth"])]
    pub load_map: Option<PathBuf>,
}

/// The topics of an MCAP log (`stride info FILE.mcap` lists them).
#[derive(Debug, Args, Clone)]
pub struct TopicArgs {
    /// Colour images (sensor_msgs/Image or CompressedImage) of an MCAP --dataset.
    #[arg(long, value_name = "TOPIC", default_value = stride_datasets::mcap::DEFAULT_RGB_TOPIC)]
    pub rgb_topic: String,
    /// Depth images registered to the colour camera (16UC1, 32FC1 or 16-bit PNG).
    #[arg(long, value_name = "TOPIC", default_value = stride_datasets::mcap::DEFAULT_DEPTH_TOPIC)]
    pub depth_topic: String,
    /// The colour camera's sensor_msgs/CameraInfo [default: /camera/rgb/camera_info when
    /// present; --camera wins over it].
    #[arg(long, value_name = "TOPIC")]
    pub camera_info_topic: Option<String>,
    /// A sensor_msgs/Imu whose linear acceleration is in the colour camera's optical frame,
    /// for the gravity-aligned world [default: /imu when it is in the images' frame].
    #[arg(long, value_name = "TOPIC")]
    pub imu_topic: Option<String>,
    /// Ground truth: transforms from PARENT to CHILD (world_from_camera) on any
    /// tf2_msgs/TFMessage topic [default: world:groundtruth when present].
    #[arg(long, value_name = "PARENT:CHILD")]
    pub gt_tf: Option<String>,
    /// Units per metre of 16-bit depth [default: the depth channel's depth_units_per_m
    /// metadata, else 1000 (REP 118: millimetres)].
    #[arg(long, value_name = "UNITS")]
    pub depth_units_per_m: Option<f64>,
}

impl Default for TopicArgs {
    /// The defaults of the flags: the topics `stride convert` writes.
    fn default() -> Self {
        Self {
            rgb_topic: stride_datasets::mcap::DEFAULT_RGB_TOPIC.into(),
            depth_topic: stride_datasets::mcap::DEFAULT_DEPTH_TOPIC.into(),
            camera_info_topic: None,
            imu_topic: None,
            gt_tf: None,
            depth_units_per_m: None,
        }
    }
}

impl TopicArgs {
    /// The topics as the datasets crate takes them.
    pub fn topics(&self) -> Result<McapTopics> {
        let groundtruth_tf = match &self.gt_tf {
            None => None,
            Some(s) => {
                let (p, c) = s
                    .split_once(':')
                    .filter(|(p, c)| !p.is_empty() && !c.is_empty())
                    .with_context(|| format!("--gt-tf {s}: expected PARENT:CHILD"))?;
                Some((p.to_owned(), c.to_owned()))
            }
        };
        Ok(McapTopics {
            rgb: self.rgb_topic.clone(),
            depth: self.depth_topic.clone(),
            camera_info: self.camera_info_topic.clone(),
            imu: self.imu_topic.clone(),
            groundtruth_tf,
            depth_units_per_m: self.depth_units_per_m,
        })
    }

    /// Opens `dataset` (a TUM folder or an MCAP log) with these topics.
    pub fn open(&self, dataset: &std::path::Path, camera: Option<&str>) -> Result<Sequence> {
        Sequence::open(
            dataset,
            camera,
            AssociationOptions::default(),
            &self.topics()?,
        )
        .context("opening the dataset")
    }
}

/// The back end to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendArg {
    /// Bundle adjustment of keyframe poses and 3-D points.
    Ba,
    /// A pose graph over keyframes.
    PoseGraph,
    /// None: the visual odometry alone.
    None,
}

impl BackendArg {
    /// The back end's mode; `None` for the odometry alone.
    pub fn mode(self) -> Option<BackendMode> {
        match self {
            BackendArg::Ba => Some(BackendMode::BundleAdjustment),
            BackendArg::PoseGraph => Some(BackendMode::PoseGraph),
            BackendArg::None => None,
        }
    }
}

impl RunArgs {
    /// How the run finds its gravity-aligned world frame: the ground truth when asked, the
    /// given mounting, else the accelerometer when the folder has one, else the floor.
    pub fn world_plan(&self, seq: &Sequence) -> Result<WorldPlan> {
        if self.world_from_groundtruth {
            let gt = seq.groundtruth().with_context(|| {
                format!(
                    "--world-from-groundtruth: {} has no ground truth",
                    self.dataset.display()
                )
            })?;
            return Ok(WorldPlan::Reference(gt.clone()));
        }
        match (self.camera_pitch_deg, self.camera_height_m) {
            (Some(pitch_deg), Some(height_m)) => {
                if !((-90.0..=90.0).contains(&pitch_deg) && (0.0..=10.0).contains(&height_m)) {
                    anyhow::bail!(
                        "--camera-pitch-deg {pitch_deg} must be within [-90, 90] and \
                         --camera-height-m {height_m} within [0, 10]"
                    );
                }
                Ok(WorldPlan::Mounting {
                    pitch_deg,
                    height_m,
                })
            }
            _ => Ok(match seq.accelerometer() {
                Some(samples) if !self.ignore_accelerometer => {
                    WorldPlan::Accelerometer(samples.to_vec())
                }
                _ => WorldPlan::Floor,
            }),
        }
    }

    /// Every stage's parameters: the --config file (or the defaults), then the flags.
    /// The defaults are those of the back end chosen (by the flags, else by the file; see
    /// [`Config::defaults_for`]): the keys a file leaves out take them.
    pub fn config(&self) -> Result<Config> {
        let no_backend = self.vo_only || self.backend == Some(BackendArg::None);
        let flag_mode = if no_backend {
            Some(None)
        } else {
            self.backend.and_then(BackendArg::mode).map(Some)
        };
        let (mut c, mode) = match &self.config {
            Some(path) => Config::load_for(path, flag_mode)?,
            None => {
                let mode = flag_mode.unwrap_or(Some(BackendMode::BundleAdjustment));
                (Config::defaults_for(mode), mode)
            }
        };
        if no_backend {
            c.backend = None;
        } else if let Some(mode) = mode {
            c.backend = Some(c.backend_in(mode));
        }
        if let Some(seed) = self.seed {
            c.odometry.seed = seed;
        }
        if self.free_running {
            c.schedule.free_running = true;
        }
        if self.no_map {
            c.map = None;
        }
        c.validate()?;
        Ok(c)
    }
}

/// Writes the run's final map to `path`, in the run's world (described as `world_origin`
/// when the run started in a saved map). The keyframes of pieces placed only by a guess
/// relative to the world's origin ([`stride::pipeline::RunOutput::keyframes_outside_world_piece`])
/// are left out, with their own points: the map's frame would hold them where the guess put
/// them.
fn save_map(
    path: &std::path::Path,
    out: &mut stride::pipeline::RunOutput,
    camera: stride_core::camera::PinholeCamera,
    world_origin: Option<String>,
) -> Result<()> {
    let outside = out.keyframes_outside_world_piece();
    let world = out.world;
    let Some(b) = out.backend.as_mut() else {
        anyhow::bail!("--save-map needs a back end (the odometry alone keeps no map)");
    };
    let mut map = std::mem::take(&mut b.map);
    let mut place_features = std::mem::take(&mut b.place_features);
    if !outside.is_empty() {
        let points = map.remove_keyframes(&outside);
        place_features.retain(|k, _| !outside.contains(k));
        tracing::warn!(
            "{}: {} keyframes and {points} points left out, placed only by a guess relative to the map (a piece after a lost frame, or a start not found in the saved map, that no loop joined)",
            path.display(),
            outside.len()
        );
    }
    let saved = SavedMap {
        camera,
        map,
        world_from_map: world.world_from_slam,
        world: world_origin.unwrap_or_else(|| world.describe()),
        gravity_aligned: world.is_gravity_aligned(),
        place_features,
    };
    saved.save(path)?;
    tracing::info!(
        "map saved to {}: {} keyframes, {} points",
        path.display(),
        saved.map.keyframes().len(),
        saved.map.points().len()
    );
    Ok(())
}

pub fn run(a: RunArgs) -> Result<()> {
    let summary = execute(&a)?;
    let j = &summary.json;
    let f = |k: &str| j.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let mut line = format!(
        "{} frames, {} tracked, {} recovered, {} relocalized, {} lost, {} skipped; {} frames/s (back end: {}), odometry median {:.2} ms/frame (decoding excluded)",
        j["frames"], j["frames_tracked"], j["frames_recovered"], j["frames_relocalized"], j["frames_lost"], j["frames_skipped"], format_args!("{:.1}", f("fps")), j["backend"].as_str().unwrap_or("?"), j["timing_ms"]["total"]["median"].as_f64().unwrap_or(f64::NAN)
    );
    if let Some(n) = j.get("segments").and_then(Value::as_u64).filter(|&n| n > 1) {
        let _ = write!(
            line,
            "\n{n} segments: pieces of the trajectory placed relative to each other by a guess (lost frames no loop joined again)"
        );
    }
    if let (Some(n), Some(all)) = (
        j.get("frames_in_saved_map").and_then(Value::as_u64),
        j.get("frames").and_then(Value::as_u64),
    ) {
        let _ = write!(
            line,
            "\n{n} of {all} frames placed in the saved map's world"
        );
        if n < all {
            let _ = write!(
                line,
                " (the others in a piece started by a guess that no loop joined to the map)"
            );
        }
    }
    // Map points and local optimizations exist only with a back end.
    if let (Some(kf), Some(_)) = (
        j.get("keyframes").and_then(Value::as_u64),
        j.get("map_points"),
    ) {
        let _ = write!(
            line,
            "\n{kf} keyframes, {} map points, {} loops closed; back end per keyframe median {:.2} ms, of it local optimization {:.2} ms",
            j["map_points"],
            j["loop_closures"],
            j["ba_ms"]["median"].as_f64().unwrap_or(f64::NAN),
            j["optimize_ms"]["median"].as_f64().unwrap_or(f64::NAN)
        );
    }
    if let (Some(at), Some(rp)) = (&summary.ate, &summary.rpe) {
        let _ = write!(
            line,
            "\nATE rmse {:.4} m over {} poses (evo, SE(3)); RPE rmse {:.4} m, {:.3} deg per frame",
            at.trans_m.rmse, at.trans_m.count, rp.trans_m.rmse, rp.rot_deg.rmse
        );
    }
    if let Some(m) = &summary.map {
        let _ = write!(
            line,
            "\nelevation map: {} cells from {} views ({} rebuilds){}",
            m.layers.cells_observed(),
            m.stats.view_frames.len(),
            m.stats.rebuilds,
            summary
                .map_score
                .as_ref()
                .map_or(String::new(), |s| format!(
                    "; against the true terrain RMSE {:.1} mm, coverage {:.2}",
                    s.rmse * 1e3,
                    s.coverage
                ))
        );
        if m.stats.views_left_out > 0 {
            let _ = write!(
                line,
                "; {} views left out (the start the saved map never placed)",
                m.stats.views_left_out
            );
        }
    }
    crate::outln!("{line}")?;
    crate::outln!("written to {}", a.out.display())?;
    Ok(())
}

/// Runs and writes everything into `a.out`; returns the summary.
pub fn execute(a: &RunArgs) -> Result<RunSummary> {
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    if let Some(path) = a.mcap_out.as_ref().filter(|p| p.exists() && !a.overwrite) {
        anyhow::bail!(
            "--mcap-out {}: the file exists; pass --overwrite to replace it",
            path.display()
        );
    }
    let config = a.config()?;
    let seq = a.topics.open(&a.dataset, a.camera.as_deref())?;
    tracing::info!(
        "{} frames from {}, camera {}",
        seq.len(),
        a.dataset.display(),
        seq.camera_source()
    );
    stride_frontend::set_opencv_threads(if a.deterministic { 1 } else { 2 })?;
    if a.save_map.is_some() && config.backend.is_none() {
        anyhow::bail!("--save-map needs a back end (the odometry alone keeps no map)");
    }
    let mut pipeline = config.pipeline(a.world_plan(&seq)?);
    // Where the world came from: a map saved again keeps its original description.
    let mut world_origin = None;
    if let Some(path) = &a.load_map {
        let t = Instant::now();
        let saved = SavedMap::load(path, &seq.camera().camera)?;
        tracing::info!(
            "loaded {}: {} keyframes, {} points in {:.0} ms; world from {}",
            path.display(),
            saved.map.keyframes().len(),
            saved.map.points().len(),
            t.elapsed().as_secs_f64() * 1e3,
            saved.world
        );
        world_origin = Some(saved.world.clone());
        pipeline.saved_map = Some(saved);
    }
    let total = a.max_frames.map_or(seq.len(), |m| m.min(seq.len()));
    let pb = crate::cli::progress_bar(total, "tracking", true);
    let out = run_sequence(&seq, pipeline, a.max_frames, |_| pb.inc(1))?;
    pb.finish_and_clear();
    let mut summary = super::run_files::write_run(a, &config, &seq, out)?;
    if let Some(path) = &a.save_map {
        save_map(path, &mut summary.output, seq.camera().camera, world_origin)?;
    }
    Ok(summary)
}
