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
pub mod patch_hit;
pub mod raster;
pub mod render;
pub mod scanner;
pub mod scene;
pub mod sensor;
pub mod stripe;
pub mod terrain;
pub mod texture;
pub mod texture_batch;

mod config;
mod output;
mod pool;

pub use config::{SynthConfig, SynthError, TerrainSource};
pub use output::{generate, SynthSummary};

use motion::{Motion, TrunkState};

/// Standard gravity (m/s²).
pub const GRAVITY_M_S2: f64 = 9.80665;
/// Accelerometer samples per second written by the lab: 400 Hz, as its gyroscope (the
/// rolling-shutter correction integrates them over a 20 ms readout; a foot's impact
/// changes the acceleration within a few milliseconds).
pub const ACCELEROMETER_HZ: f64 = 400.0;
/// Standard deviation of the accelerometer's noise (m/s², per axis and sample): twice a
/// MEMS accelerometer's 175 ug/sqrt(Hz) (a BMI088's datasheet figure, 0.024 m/s² over the
/// 200 Hz of bandwidth of 400 Hz samples).
pub const ACCELEROMETER_NOISE_M_S2: f64 = 0.05;
/// Gyroscope samples per second written by the lab: 400 Hz, a common output rate of the
/// IMUs on legged robots and RGB-D cameras (a RealSense D435i offers 200 or 400 Hz).
pub const GYROSCOPE_HZ: f64 = 400.0;
/// Standard deviation of the gyroscope's white noise (rad/s, per axis and sample): a MEMS
/// gyroscope's 3e-4 rad/s/sqrt(Hz) (0.017 deg/s/sqrt(Hz), a BMI088's datasheet figure)
/// over the 200 Hz of bandwidth of 400 Hz samples. No bias: the lab's runs are seconds
/// long, where a bias stays constant and the robot's calibration at rest removes it.
pub const GYROSCOPE_NOISE_RAD_S: f64 = 0.004;
use crate::camera_config::CameraConfig;
use nalgebra::Isometry3;
use render::{Renderer, Visibility};
use scene::Scene;
use sensor::{depth_sensor, rgb_sensor, SensorFields};
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::grid::{Grid, GridGeometry};
use stride_core::image::{Image, RgbImage};
use terrain::HeightField;

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
    /// Rays of the depth pass whose terrain hit was marched (see
    /// [`render::Geometry::marched_rays`]).
    pub marched_rays: usize,
}

impl SynthFrame {
    /// The frame as the odometry takes it (colour and depth at the frame's time, depth in
    /// m from the raw units at `depth_scale` per m), and what is known about it.
    pub fn into_rgbd(self, depth_scale: f64) -> (stride_core::frame::RgbdFrame, FrameInfo) {
        let info = self.info;
        let frame = stride_core::frame::RgbdFrame {
            index: info.index,
            t_s: info.t_s,
            t_depth_s: info.t_s,
            depth_m: crate::png_io::depth_from_raw(&self.depth_raw, depth_scale),
            rgb: self.rgb,
        };
        (frame, info)
    }
}

/// A synthetic world ready to render frames.
pub struct Synth {
    config: SynthConfig,
    scene: Scene,
    motion: Motion,
    camera: PinholeCamera,
    sensor_fields: SensorFields,
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
        let camera = config.camera.camera.without_distortion();
        let sensor_fields = SensorFields::new(&camera, &config.depth_noise, config.seed);
        Ok(Self {
            config,
            scene,
            motion,
            camera,
            sensor_fields,
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

    /// The camera as the lab describes it to a SLAM (camera.json): the rendering camera,
    /// its depth scale and readout, and the exposure when the frames are blurred over it
    /// (0 without blur: each frame is then one instant).
    pub fn camera_config(&self) -> CameraConfig {
        let cfg = &self.config;
        CameraConfig {
            camera: self.camera,
            exposure_s: if cfg.blur { cfg.exposure_s } else { 0.0 },
            ..cfg.camera
        }
    }

    /// The robot's state at `t` seconds after the first frame.
    pub fn state(&self, t: f64) -> TrunkState {
        let hf = &self.scene.terrain;
        self.motion.state(t, &|x, y| hf.height(x, y))
    }

    /// What an accelerometer on the camera reads `t` seconds after the first frame: the
    /// specific force (the camera's acceleration minus gravity, m/s²) in the camera frame
    /// (x right, y down, z forward), from the second difference of the motion over one
    /// sample period either side: the acceleration averaged with triangular weights over
    /// those two periods, as a MEMS accelerometer low-passes before it delivers samples.
    pub fn specific_force(&self, t: f64) -> nalgebra::Vector3<f64> {
        const H_S: f64 = 1.0 / ACCELEROMETER_HZ;
        let at = |t: f64| self.state(t).world_from_camera;
        let (a, b, c) = (at(t - H_S), at(t), at(t + H_S));
        let acceleration = (a.translation.vector - 2.0 * b.translation.vector
            + c.translation.vector)
            / (H_S * H_S);
        let f_world = acceleration + nalgebra::Vector3::new(0.0, 0.0, GRAVITY_M_S2);
        b.rotation.inverse() * f_world
    }

    /// What a gyroscope on the camera reads `t` seconds after the first frame: the
    /// camera's mean angular velocity in its own frame (rad/s) over the sample period
    /// around `t` (the rotation from `t - 1/(2 GYROSCOPE_HZ)` to `t + 1/(2 GYROSCOPE_HZ)`
    /// over that time). A MEMS gyroscope low-passes its rate before it delivers samples;
    /// the rate at one instant would alias the gait's impact vibration into the samples.
    pub fn angular_velocity(&self, t: f64) -> nalgebra::Vector3<f64> {
        let h_s = 0.5 / GYROSCOPE_HZ;
        let (a, b) = (
            self.state(t - h_s).world_from_camera,
            self.state(t + h_s).world_from_camera,
        );
        (a.rotation.inverse() * b.rotation).scaled_axis() / (2.0 * h_s)
    }

    /// The accelerometer's samples over the sequence: [`Self::specific_force`] at
    /// [`ACCELEROMETER_HZ`] with seeded Gaussian noise ([`ACCELEROMETER_NOISE_M_S2`]), on
    /// the frames' clock (s), from 50 ms before the first frame to 50 ms past the last.
    pub fn accelerometer(&self) -> Vec<crate::accelerometer::AccelSample> {
        self.inertial(
            ACCELEROMETER_HZ,
            ACCELEROMETER_NOISE_M_S2,
            [0xACCE_1E21, 0xACCE_1E20],
            |t| self.specific_force(t),
        )
    }

    /// The gyroscope's samples over the sequence: [`Self::angular_velocity`] at
    /// [`GYROSCOPE_HZ`] with seeded Gaussian noise ([`GYROSCOPE_NOISE_RAD_S`]), on the
    /// frames' clock (s), from 50 ms before the first frame to 50 ms past the last.
    pub fn gyroscope(&self) -> Vec<crate::accelerometer::GyroSample> {
        self.inertial(
            GYROSCOPE_HZ,
            GYROSCOPE_NOISE_RAD_S,
            [0x6E20_5C0F, 0x6E20_5C0E],
            |t| self.angular_velocity(t),
        )
    }

    /// Samples of `read` (seconds after the first frame) at `hz` with Gaussian noise of
    /// `sigma`, 50 ms past the last frame, so that its readout lies between samples, and
    /// 50 ms before the first, as a robot's inertial sensor runs before its camera starts
    /// (the first frame's readout, centred on its time, starts 10 ms before it). The
    /// samples before the first frame draw their noise from a generator of their own
    /// (`salts[0]`), so those from the first frame on are the same as without them.
    fn inertial(
        &self,
        hz: f64,
        sigma: f64,
        salts: [u64; 2],
        read: impl Fn(f64) -> nalgebra::Vector3<f64>,
    ) -> Vec<(f64, nalgebra::Vector3<f64>)> {
        let n = ((self.duration_s() + 0.05) * hz).ceil() as usize + 1;
        let lead = (0.05 * hz).ceil() as usize;
        let shift_s = lead as f64 / hz;
        let mut samples = self.noisy_samples(lead, hz, sigma, salts[0], |t| read(t - shift_s));
        for s in &mut samples {
            s.0 -= shift_s;
        }
        samples.extend(self.noisy_samples(n, hz, sigma, salts[1], read));
        samples
    }

    /// Time from the first frame to the last (s).
    fn duration_s(&self) -> f64 {
        self.config.frames.saturating_sub(1) as f64 / self.config.fps
    }

    /// `n` samples of `read(t)` at `hz` from the first frame on, each with Gaussian noise
    /// of standard deviation `sigma` per axis (seeded by the run's seed and `salt`), time
    /// stamped on the frames' clock (s).
    fn noisy_samples(
        &self,
        n: usize,
        hz: f64,
        sigma: f64,
        salt: u64,
        read: impl Fn(f64) -> nalgebra::Vector3<f64>,
    ) -> Vec<(f64, nalgebra::Vector3<f64>)> {
        let mut rng = stride_core::rng::SplitMix64::new(self.config.seed ^ salt);
        (0..n)
            .map(|k| {
                let t = k as f64 / hz;
                let noise =
                    nalgebra::Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sigma;
                (self.config.start_time_s + t, read(t) + noise)
            })
            .collect()
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
        self.render_frame_with(renderer, index, Visibility::Rasterized)
    }

    /// [`Self::render_frame`] with a choice of how the terrain is found (the marched
    /// reference, for comparisons and benchmarks).
    pub fn render_frame_with(
        &self,
        renderer: &Renderer<'_>,
        index: usize,
        visibility: Visibility,
    ) -> SynthFrame {
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
        let rs = cfg.camera.rolling_shutter_s;
        let rows = self.camera.height().max(2) as usize;
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
        let mut geom = renderer.render_with(&pose, rs <= 0.0, visibility);
        let mut color = if rs > 0.0 {
            renderer.color_buffer()
        } else {
            std::mem::take(&mut geom.color)
        };
        for k in 0..n {
            if k == n / 2 && rs <= 0.0 {
                continue; // the global-shutter centre sub-frame came with the depth
            }
            let tk = t - e / 2.0 + (k as f64 + 0.5) * e / n as f64;
            renderer.accumulate_color(&row_poses(tk), pad, &mut color, visibility);
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
            &self.sensor_fields,
            cfg.read_noise_dn,
            cfg.seed,
            index as u64,
        );
        let depth_raw = depth_sensor(
            &geom,
            &self.sensor_fields,
            &cfg.depth_noise,
            cfg.camera.depth_scale,
            cfg.seed,
            index as u64,
        );
        renderer.recycle_color(color);
        let depth_true_m = std::mem::take(&mut geom.depth_z);
        let marched_rays = geom.marched_rays;
        renderer.recycle(geom);
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
            marched_rays,
            depth_true_m,
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
