//! The generator's parameters, their defaults and their validation.

use super::motion::MotionConfig;
use super::sensor::DepthNoise;
use super::terrain;
use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use std::path::PathBuf;
use stride_core::camera::PinholeCamera;

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
    /// The camera (rendered as an ideal pinhole; distortion is not simulated). Its
    /// `exposure_s` is not read: the lab's exposure is the field above.
    pub camera: CameraConfig,
    /// Depth sensor model.
    pub depth_noise: DepthNoise,
    /// Colour read noise (standard deviation, 8-bit levels).
    pub read_noise_dn: f64,
    /// Time of the first frame (s, written in the TUM files).
    pub start_time_s: f64,
    /// Number of objects (boxes) placed around the path.
    pub objects: usize,
    /// Relative amplitude of the frame-to-frame exposure (gain) variation of an
    /// auto-exposing camera.
    pub exposure_flicker: f64,
}

impl Default for SynthConfig {
    /// Procedural `mixed` terrain, tripod gait at 0.1 m/s, straight, 150 frames at 30 Hz,
    /// 20 ms exposure with blur, fr1-like intrinsics without distortion, a 20 ms
    /// rolling-shutter readout.
    fn default() -> Self {
        // fr1's intrinsics without its distortion; the fallback is never taken (fr1 is a
        // built-in preset) but keeps this infallible.
        let camera = CameraConfig::preset("fr1").unwrap_or(CameraConfig {
            camera: PinholeCamera::KINECT_DEFAULT,
            depth_scale: 5000.0,
            rolling_shutter_s: 0.0,
            exposure_s: 0.0,
        });
        // A 20 ms rolling-shutter readout, as on PrimeSense/Kinect colour cameras.
        let camera = CameraConfig {
            camera: camera.camera.without_distortion(),
            rolling_shutter_s: 0.02,
            ..camera
        };
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
    /// The output folder holds files and replacing it was not asked for.
    #[error("{} exists and is not empty; it is replaced only when overwriting is asked for", .0.display())]
    NotEmpty(std::path::PathBuf),
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
        if !(self.camera.rolling_shutter_s.is_finite()
            && (0.0..=0.1).contains(&self.camera.rolling_shutter_s))
        {
            return bad(format!(
                "rolling shutter readout {} s: must be between 0 and 0.1",
                self.camera.rolling_shutter_s
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
