//! Synthetic legged-robot RGB-D sequences with ground truth: terrain, gait, sensor noise and
//! motion blur.
//!
//! The generator renders what a Kinect-class camera on a walking hexapod sees: a textured
//! terrain (from an image or procedural), objects and walls around it, a trunk shaken by its
//! gait, Kinect-like depth noise and physically averaged motion blur. It writes a TUM-layout
//! folder that [`crate::tum::TumSequence`] opens unchanged:
//!
//! ```text
//! rgb/, depth/          PNGs (depth: 16-bit, 5000 units per metre)
//! rgb.txt, depth.txt    timestamp filename
//! groundtruth.txt       world_from_camera at each frame time (TUM format)
//! camera.json           intrinsics, size, depth scale
//! terrain.npy/.json     true elevation (highest surface, world z up), grid format
//! terrain.png           colour-relief preview of it
//! frames.csv            per frame: gait phase, stance legs, true speeds, image motion
//! synth.json            the configuration (no timings: the folder is deterministic)
//! ```
//!
//! The world frame is z up, with its origin where the robot starts and x along its initial
//! heading. Output is deterministic for a seed, whatever the thread count.

pub mod motion;
pub mod render;
pub mod scene;
pub mod terrain;
pub mod texture;

use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use crate::grid_file::{relief_png, write_header, write_layer};
use crate::png_io::{encode_depth_u16, encode_rgb};
use motion::{Gait, Motion, MotionConfig, PathKind, TrunkState};
use nalgebra::Isometry3;
use render::{depth_sensor, rgb_sensor, DepthNoise, Renderer};
use scene::Scene;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::fsutil::write_atomic;
use stride_core::grid::{Grid, GridGeometry};
use stride_core::image::{Image, RgbImage};
use stride_core::trajectory::Trajectory;
use terrain::HeightField;

/// Where the terrain comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum TerrainSource {
    /// A grey-level image: 0..255 maps to `0..height_scale_m`, `resolution_m` per pixel.
    Image {
        /// PNG file.
        path: PathBuf,
        /// Height of white (m).
        height_scale_m: f64,
        /// Size of a pixel on the ground (m).
        resolution_m: f64,
    },
    /// A procedural terrain (see [`terrain::PROCEDURAL_NAMES`]) at `resolution_m`.
    Procedural {
        /// Its name.
        name: String,
        /// Cell size (m).
        resolution_m: f64,
    },
}

/// Everything that defines a synthetic sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    /// The terrain.
    pub terrain: TerrainSource,
    /// Gait, speed, path and camera mount.
    pub motion: MotionConfig,
    /// Number of frames.
    pub frames: usize,
    /// Frame rate (Hz).
    pub fps: f64,
    /// Seed of every random choice.
    pub seed: u64,
    /// Render motion blur (sub-frames over the exposure).
    pub blur: bool,
    /// Exposure time (s), at most one frame period.
    pub exposure_s: f64,
    /// The camera (rendered as an ideal pinhole; distortion is not simulated).
    pub camera: CameraConfig,
    /// Depth sensor model.
    pub depth_noise: DepthNoise,
    /// Colour read noise (standard deviation, 8-bit levels).
    pub read_noise_dn: f64,
    /// Time of the first frame (s, written in the TUM files).
    pub start_time_s: f64,
    /// Number of objects (boxes) placed around the path.
    pub objects: usize,
    /// Rolling-shutter readout time of the colour camera (s): top to bottom row. 0 for a
    /// global shutter.
    pub rolling_shutter_s: f64,
    /// Relative amplitude of the frame-to-frame exposure (gain) variation of an
    /// auto-exposing camera.
    pub exposure_flicker: f64,
}

impl Default for SynthConfig {
    /// Procedural `mixed` terrain, tripod gait at 0.1 m/s, straight, 150 frames at 30 Hz,
    /// 20 ms exposure with blur, fr1-like intrinsics without distortion.
    fn default() -> Self {
        let mut camera = CameraConfig::preset("fr1").unwrap_or(CameraConfig {
            camera: PinholeCamera {
                fx: 517.3,
                fy: 516.5,
                cx: 318.6,
                cy: 255.3,
                width: 640,
                height: 480,
                distortion: None,
            },
            depth_scale: 5000.0,
        });
        camera.camera.distortion = None;
        Self {
            terrain: TerrainSource::Procedural {
                name: "mixed".into(),
                resolution_m: 0.01,
            },
            motion: MotionConfig::default(),
            frames: 150,
            fps: 30.0,
            seed: 1,
            blur: true,
            exposure_s: 0.02,
            camera,
            depth_noise: DepthNoise::default(),
            read_noise_dn: 1.5,
            start_time_s: 1_700_000_000.0,
            objects: 14,
            rolling_shutter_s: 0.02,
            exposure_flicker: 0.03,
        }
    }
}

/// Why a synthetic sequence could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// A parameter is out of its valid range.
    #[error("invalid synthetic sequence parameter: {0}")]
    Invalid(String),
    /// Reading the terrain or writing the output failed.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
}

impl SynthConfig {
    /// Checks every parameter, with a message saying what is wrong and what is allowed.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |m: String| Err(SynthError::Invalid(m));
        let m = &self.motion;
        if !(m.speed_m_s.is_finite() && m.speed_m_s >= 0.0) {
            return bad(format!(
                "speed {} m/s: must be a non-negative number",
                m.speed_m_s
            ));
        }
        if m.speed_m_s > 1.0 {
            return bad(format!("speed {} m/s: a small legged robot walks at most about 0.3 m/s; the generator accepts up to 1 m/s", m.speed_m_s));
        }
        if self.frames == 0 {
            return bad("frames must be at least 1".into());
        }
        if self.frames > 100_000 {
            return bad(format!("{} frames: at most 100000", self.frames));
        }
        if !(self.fps.is_finite() && (1.0..=120.0).contains(&self.fps)) {
            return bad(format!("fps {}: must be between 1 and 120 Hz", self.fps));
        }
        if !(self.exposure_s.is_finite()
            && self.exposure_s > 0.0
            && self.exposure_s <= 1.0 / self.fps + 1e-12)
        {
            return bad(format!(
                "exposure {} s: must be positive and at most one frame period ({:.4} s)",
                self.exposure_s,
                1.0 / self.fps
            ));
        }
        if !(m.square_side_m.is_finite() && m.square_side_m > 0.1) {
            return bad(format!(
                "square side {} m: must be more than 0.1 m",
                m.square_side_m
            ));
        }
        if !(m.camera_height_m.is_finite() && (0.15..=2.0).contains(&m.camera_height_m)) {
            return bad(format!(
                "camera height {} m: must be between 0.15 and 2 m",
                m.camera_height_m
            ));
        }
        if !(m.camera_tilt_deg.is_finite() && (0.0..=80.0).contains(&m.camera_tilt_deg)) {
            return bad(format!(
                "camera tilt {} deg: must be between 0 and 80",
                m.camera_tilt_deg
            ));
        }
        if !(m.shake.is_finite() && (0.0..=10.0).contains(&m.shake)) {
            return bad(format!("shake {}: must be between 0 and 10", m.shake));
        }
        match &self.terrain {
            TerrainSource::Image {
                height_scale_m,
                resolution_m,
                ..
            } => {
                if !(height_scale_m.is_finite() && *height_scale_m > 0.0 && *height_scale_m <= 3.0)
                {
                    return bad(format!(
                        "height scale {height_scale_m} m: must be in (0, 3]"
                    ));
                }
                if !(resolution_m.is_finite() && (0.002..=0.5).contains(resolution_m)) {
                    return bad(format!(
                        "terrain resolution {resolution_m} m: must be between 0.002 and 0.5"
                    ));
                }
            }
            TerrainSource::Procedural { name, resolution_m } => {
                if !terrain::PROCEDURAL_NAMES.contains(&name.as_str()) {
                    return bad(format!(
                        "unknown procedural terrain '{name}' (expected one of: {})",
                        terrain::PROCEDURAL_NAMES.join(", ")
                    ));
                }
                if !(resolution_m.is_finite() && (0.005..=0.1).contains(resolution_m)) {
                    return bad(format!(
                        "terrain resolution {resolution_m} m: must be between 0.005 and 0.1"
                    ));
                }
            }
        }
        if !(self.rolling_shutter_s.is_finite() && (0.0..=0.1).contains(&self.rolling_shutter_s)) {
            return bad(format!(
                "rolling shutter readout {} s: must be between 0 and 0.1",
                self.rolling_shutter_s
            ));
        }
        if !(self.exposure_flicker.is_finite() && (0.0..=0.5).contains(&self.exposure_flicker)) {
            return bad(format!(
                "exposure flicker {}: must be between 0 and 0.5",
                self.exposure_flicker
            ));
        }
        if !(self.read_noise_dn.is_finite() && self.read_noise_dn >= 0.0) {
            return bad(format!(
                "read noise {}: must be non-negative",
                self.read_noise_dn
            ));
        }
        Ok(())
    }

    /// Duration covered by the frames (s).
    pub fn duration_s(&self) -> f64 {
        self.frames as f64 / self.fps
    }
}

/// What is known about one rendered frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameInfo {
    /// Zero-based frame index.
    pub index: usize,
    /// Timestamp (s).
    pub t_s: f64,
    /// Gait phase in `[0, 1)`.
    pub gait_phase: f64,
    /// Legs in stance.
    pub stance_legs: u8,
    /// True camera speed (m/s).
    pub speed_m_s: f64,
    /// True camera angular speed (rad/s).
    pub angular_speed_rad_s: f64,
    /// Largest image motion of scene points during the exposure (px).
    pub image_motion_px: f64,
    /// Sub-frames averaged for the blur (1 without blur).
    pub subframes: usize,
    /// `world_from_camera` at the frame time (mid-exposure).
    pub world_from_camera: Isometry3<f64>,
}

/// A rendered frame in memory.
pub struct SynthFrame {
    /// Colour image.
    pub rgb: RgbImage,
    /// Raw depth (units of `1 / depth_scale` m; 0 = no return).
    pub depth_raw: Image<u16>,
    /// Noise-free z-depth (m; 0 = nothing hit), for tests.
    pub depth_true_m: Vec<f32>,
    /// Facts about the frame.
    pub info: FrameInfo,
    /// Rendering time (s), sensor models included, PNG encoding excluded.
    pub render_s: f64,
}

/// A synthetic world ready to render frames.
pub struct Synth {
    config: SynthConfig,
    scene: Scene,
    motion: Motion,
    camera: PinholeCamera,
}

impl Synth {
    /// Builds the terrain, the scene and the motion. Errors on invalid parameters and
    /// unreadable terrain images (naming the file).
    pub fn new(config: SynthConfig) -> Result<Self, SynthError> {
        config.validate()?;
        let motion = Motion::with_seed(config.motion, config.seed);
        let path = motion.path_samples(config.duration_s(), 400);
        let grid = match &config.terrain {
            TerrainSource::Image {
                path: p,
                height_scale_m,
                resolution_m,
            } => terrain::from_image(p, *height_scale_m, *resolution_m)?,
            TerrainSource::Procedural { name, resolution_m } => {
                let (mut x0, mut y0, mut x1, mut y1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                for &(x, y) in &path {
                    x0 = x0.min(x);
                    y0 = y0.min(y);
                    x1 = x1.max(x);
                    y1 = y1.max(y);
                }
                let margin = 3.2;
                let g = GridGeometry::covering(
                    x0 - margin,
                    y0 - margin,
                    x1 + margin,
                    y1 + margin,
                    *resolution_m,
                );
                terrain::procedural(name, g, config.seed).map_err(SynthError::Invalid)?
            }
        };
        let scene = Scene::build(
            HeightField::new(grid),
            &path,
            2.5,
            config.objects,
            1.0,
            config.seed,
        );
        let mut camera = config.camera.camera;
        camera.distortion = None;
        Ok(Self {
            config,
            scene,
            motion,
            camera,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SynthConfig {
        &self.config
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The motion model.
    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// The rendering camera (ideal pinhole).
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// The robot's state at `t` seconds after the first frame.
    pub fn state(&self, t: f64) -> TrunkState {
        let hf = &self.scene.terrain;
        self.motion.state(t, &|x, y| hf.height(x, y))
    }

    /// A renderer for this scene.
    pub fn renderer(&self) -> Renderer<'_> {
        Renderer::new(&self.scene, self.camera)
    }

    /// The true elevation (highest surface), world z up.
    pub fn ground_truth_elevation(&self) -> Grid<f32> {
        self.scene.ground_truth_elevation()
    }

    /// Renders frame `index` (time `index / fps` after the start).
    pub fn render_frame(&self, renderer: &Renderer<'_>, index: usize) -> SynthFrame {
        let start = Instant::now();
        let cfg = &self.config;
        let t = index as f64 / cfg.fps;
        let state = self.state(t);
        let pose = state.world_from_camera;
        let e = cfg.exposure_s;
        let probes = renderer.probe_points(&pose);
        let a = self.state(t - e / 2.0).world_from_camera;
        let b = self.state(t + e / 2.0).world_from_camera;
        let motion_px = renderer.image_motion_px(&probes, &a, &b);
        // One sub-frame per pixel of image motion, odd so that the middle one is at t.
        let mut n = if cfg.blur {
            (motion_px.ceil() as usize).clamp(1, 31)
        } else {
            1
        };
        if n % 2 == 0 {
            n += 1;
        }
        // Rolling shutter: row r of a sub-frame centred at tc is exposed at
        // tc - readout / 2 + readout * r / (rows - 1). Depth stays global-shutter, so during
        // motion colour and depth disagree slightly, as on a real sensor.
        let rs = cfg.rolling_shutter_s;
        let rows = self.camera.height.max(2) as usize;
        let row_poses = |tc: f64| -> Vec<Isometry3<f64>> {
            if rs <= 0.0 {
                vec![self.state(tc).world_from_camera]
            } else {
                (0..rows)
                    .map(|r| {
                        self.state(tc - rs / 2.0 + rs * r as f64 / (rows - 1) as f64)
                            .world_from_camera
                    })
                    .collect()
            }
        };
        let pad = if rs > 0.0 {
            let a = self.state(t - (e + rs) / 2.0).world_from_camera;
            let b = self.state(t + (e + rs) / 2.0).world_from_camera;
            renderer.image_motion_px(&probes, &a, &b) + 2.0
        } else {
            motion_px + 2.0
        };
        let geom = renderer.render(&pose, rs <= 0.0);
        let mut color = if rs > 0.0 {
            vec![[0.0f32; 3]; geom.color.len()]
        } else {
            geom.color.clone()
        };
        for k in 0..n {
            if k == n / 2 && rs <= 0.0 {
                continue; // the global-shutter centre sub-frame came with the depth
            }
            let tk = t - e / 2.0 + (k as f64 + 0.5) * e / n as f64;
            renderer.accumulate_color(&row_poses(tk), pad, &mut color);
        }
        let gain = 1.0
            + cfg.exposure_flicker
                * (std::f64::consts::TAU * 0.37 * t + (cfg.seed % 628) as f64 / 100.0).sin()
            + 0.25
                * cfg.exposure_flicker
                * stride_core::rng::hash_normal(stride_core::rng::key(&[
                    cfg.seed,
                    index as u64,
                    0x6A17,
                ]));
        let scale = (gain / n as f64) as f32;
        for c in &mut color {
            c[0] *= scale;
            c[1] *= scale;
            c[2] *= scale;
        }
        let rgb = rgb_sensor(
            &color,
            &self.camera,
            cfg.read_noise_dn,
            cfg.seed,
            index as u64,
        );
        let depth_raw = depth_sensor(
            &geom,
            self.camera.width as usize,
            &cfg.depth_noise,
            cfg.camera.depth_scale,
            cfg.seed,
            index as u64,
        );
        // True speeds by central differences over 1 ms.
        let h = 1e-3;
        let (pa, pb) = (
            self.state(t - h).world_from_camera,
            self.state(t + h).world_from_camera,
        );
        let speed = (pb.translation.vector - pa.translation.vector).norm() / (2.0 * h);
        let ang = (pa.rotation.inverse() * pb.rotation).angle() / (2.0 * h);
        SynthFrame {
            rgb,
            depth_raw,
            depth_true_m: geom.depth_z,
            info: FrameInfo {
                index,
                t_s: cfg.start_time_s + t,
                gait_phase: state.gait_phase,
                stance_legs: state.stance_legs,
                speed_m_s: speed,
                angular_speed_rad_s: ang,
                image_motion_px: motion_px,
                subframes: n,
                world_from_camera: pose,
            },
            render_s: start.elapsed().as_secs_f64(),
        }
    }
}

/// What [`generate`] produced.
#[derive(Debug, Clone)]
pub struct SynthSummary {
    /// The output folder.
    pub out_dir: PathBuf,
    /// Per-frame facts.
    pub frames: Vec<FrameInfo>,
    /// Rendering time per frame (s), PNG encoding and writing excluded.
    pub render_s: Vec<f64>,
    /// Wall time of the whole generation (s).
    pub total_s: f64,
    /// Gait cycle frequency (Hz).
    pub cycle_hz: f64,
    /// Touchdown frequency (Hz).
    pub step_hz: f64,
    /// Ground-truth trajectory (`world_from_camera`).
    pub groundtruth: Trajectory,
}

fn gait_name(g: Gait) -> &'static str {
    match g {
        Gait::Tripod => "tripod",
        Gait::Crawl => "crawl",
    }
}

fn path_name(p: PathKind) -> &'static str {
    match p {
        PathKind::Straight => "straight",
        PathKind::Square => "square",
        PathKind::Turn => "turn",
    }
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    write_atomic(path, bytes).map_err(|e| DatasetError::io(path, e))
}

/// Renders the sequence and writes it into `out` (see the module documentation). The folder
/// is assembled under a temporary name beside `out` and renamed at the end, so `out` is
/// either complete or absent. An existing non-empty `out` is an error unless `overwrite`.
/// `progress(done, total)` is called after each frame.
pub fn generate(
    config: &SynthConfig,
    out: &Path,
    overwrite: bool,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SynthSummary, SynthError> {
    let start = Instant::now();
    config.validate()?;
    if out.exists()
        && !overwrite
        && std::fs::read_dir(out)
            .map(|mut d| d.next().is_some())
            .unwrap_or(true)
    {
        return Err(SynthError::Dataset(DatasetError::invalid(
            out,
            "exists and is not empty (pass --overwrite to replace it)",
        )));
    }
    let synth = Synth::new(config.clone())?;
    let tmp = stride_core::fsutil::temp_path_for(out);
    let _ = std::fs::remove_dir_all(&tmp);
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(tmp.join(sub)).map_err(|e| DatasetError::io(tmp.join(sub), e))?;
    }
    let result = generate_into(&synth, &tmp, progress);
    let mut summary = match result {
        Ok(s) => s,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    if out.exists() {
        std::fs::remove_dir_all(out).map_err(|e| DatasetError::io(out, e))?;
    }
    std::fs::rename(&tmp, out).map_err(|e| DatasetError::io(out, e))?;
    summary.out_dir = out.to_path_buf();
    summary.total_s = start.elapsed().as_secs_f64();
    Ok(summary)
}

fn generate_into(
    synth: &Synth,
    dir: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SynthSummary, SynthError> {
    let cfg = synth.config();
    let renderer = synth.renderer();
    let total = cfg.frames;
    let (tx, rx) = std::sync::mpsc::sync_channel::<(String, RgbImage, Image<u16>)>(2);
    let writer_dir = dir.to_path_buf();
    // PNG encoding and writing run beside rendering.
    let writer = std::thread::spawn(move || -> Result<(), DatasetError> {
        for (stamp, rgb, depth) in rx {
            let rgb_path = writer_dir.join("rgb").join(format!("{stamp}.png"));
            let depth_path = writer_dir.join("depth").join(format!("{stamp}.png"));
            let rgb_png = encode_rgb(&rgb).map_err(|m| DatasetError::Image {
                path: rgb_path.clone(),
                message: m,
            })?;
            let depth_png = encode_depth_u16(&depth).map_err(|m| DatasetError::Image {
                path: depth_path.clone(),
                message: m,
            })?;
            std::fs::write(&rgb_path, rgb_png).map_err(|e| DatasetError::io(&rgb_path, e))?;
            std::fs::write(&depth_path, depth_png).map_err(|e| DatasetError::io(&depth_path, e))?;
        }
        Ok(())
    });
    let mut infos = Vec::with_capacity(total);
    let mut render_s = Vec::with_capacity(total);
    let mut send_failed = false;
    for i in 0..total {
        let f = synth.render_frame(&renderer, i);
        let stamp = format!("{:.6}", f.info.t_s);
        infos.push(f.info);
        render_s.push(f.render_s);
        if tx.send((stamp, f.rgb, f.depth_raw)).is_err() {
            send_failed = true;
            break;
        }
        progress(i + 1, total);
    }
    drop(tx);
    match writer.join() {
        Ok(r) => r?,
        Err(_) => return Err(SynthError::Invalid("the PNG writer thread panicked".into())),
    }
    if send_failed {
        return Err(SynthError::Invalid("the PNG writer stopped early".into()));
    }

    let mut rgb_txt = String::from("# color images\n# timestamp filename\n");
    let mut depth_txt = String::from("# depth maps\n# timestamp filename\n");
    let mut csv = String::from(
        "index,t,gait_phase,stance_legs,speed_m_s,angular_speed_rad_s,image_motion_px,subframes\n",
    );
    let mut gt = Trajectory::new();
    for f in &infos {
        let stamp = format!("{:.6}", f.t_s);
        let _ = writeln!(rgb_txt, "{stamp} rgb/{stamp}.png");
        let _ = writeln!(depth_txt, "{stamp} depth/{stamp}.png");
        let _ = writeln!(
            csv,
            "{},{stamp},{:.4},{},{:.5},{:.5},{:.3},{}",
            f.index,
            f.gait_phase,
            f.stance_legs,
            f.speed_m_s,
            f.angular_speed_rad_s,
            f.image_motion_px,
            f.subframes
        );
        let t: f64 = stamp.parse().unwrap_or(f.t_s);
        gt.push(t, f.world_from_camera)
            .map_err(|e| SynthError::Invalid(e.to_string()))?;
    }
    write(&dir.join("rgb.txt"), rgb_txt.as_bytes())?;
    write(&dir.join("depth.txt"), depth_txt.as_bytes())?;
    write(&dir.join("frames.csv"), csv.as_bytes())?;
    crate::trajectory_file::write_tum_trajectory(&dir.join("groundtruth.txt"), &gt)?;
    write(
        &dir.join("camera.json"),
        CameraConfig {
            camera: *synth.camera(),
            depth_scale: cfg.camera.depth_scale,
        }
        .to_json()
        .as_bytes(),
    )?;
    let elevation = synth.ground_truth_elevation();
    write_layer(&dir.join("terrain.npy"), &elevation)?;
    write_header(&dir.join("terrain.json"), &elevation.geometry)?;
    let preview = relief_png(&elevation, 1000).map_err(|m| DatasetError::Image {
        path: dir.join("terrain.png"),
        message: m,
    })?;
    write(&dir.join("terrain.png"), &preview)?;

    let terrain_desc = match &cfg.terrain {
        TerrainSource::Image {
            path,
            height_scale_m,
            resolution_m,
        } => {
            serde_json::json!({"image": path.display().to_string(), "height_scale_m": height_scale_m, "resolution_m": resolution_m})
        }
        TerrainSource::Procedural { name, resolution_m } => {
            serde_json::json!({"procedural": name, "resolution_m": resolution_m})
        }
    };
    let meta = serde_json::json!({
        "generator": "stride synth",
        "terrain": terrain_desc,
        "gait": gait_name(cfg.motion.gait),
        "path": path_name(cfg.motion.path),
        "speed_m_s": cfg.motion.speed_m_s,
        "square_side_m": cfg.motion.square_side_m,
        "camera_height_m": cfg.motion.camera_height_m,
        "camera_tilt_deg": cfg.motion.camera_tilt_deg,
        "shake": cfg.motion.shake,
        "frames": cfg.frames,
        "fps": cfg.fps,
        "seed": cfg.seed,
        "blur": cfg.blur,
        "exposure_s": cfg.exposure_s,
        "objects": cfg.objects,
        "depth_noise": cfg.depth_noise,
        "read_noise_dn": cfg.read_noise_dn,
        "rolling_shutter_s": cfg.rolling_shutter_s,
        "exposure_flicker": cfg.exposure_flicker,
        "gait_cycle_hz": synth.motion().cycle_hz(),
        "gait_step_hz": synth.motion().step_hz(),
        "world_frame": "z up; origin at the robot's start, x along its initial heading",
    });
    write(
        &dir.join("synth.json"),
        serde_json::to_string_pretty(&meta)
            .unwrap_or_default()
            .as_bytes(),
    )?;
    Ok(SynthSummary {
        out_dir: dir.to_path_buf(),
        frames: infos,
        render_s,
        total_s: 0.0,
        cycle_hz: synth.motion().cycle_hz(),
        step_hz: synth.motion().step_hz(),
        groundtruth: gt,
    })
}
