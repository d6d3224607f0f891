//! Camera presets and camera files.
//!
//! A camera file is JSON, TOML or YAML (chosen by extension: `.json`, `.toml`, `.yaml` or
//! `.yml`) with the keys `fx, fy, cx, cy` (pixels), `width, height` (pixels), `depth_scale`
//! (raw depth units per metre: 5000 for TUM's 16-bit PNGs) and optionally
//! `distortion: [k1, k2, p1, p2, k3]` (OpenCV's order; four values mean k3 = 0) and
//! `rolling_shutter_s` (the colour camera's readout time, top row to bottom row, in seconds;
//! 0 or absent for a global shutter) and `exposure_s` (the colour camera's exposure time per
//! row, in seconds; 0 or absent when unknown). Unknown keys are ignored, so a file can carry
//! notes or extra calibration.
//!
//! A `.yaml`/`.yml` file in ORB-SLAM2 or ORB-SLAM3 settings format (`%YAML:1.0`,
//! `Camera.fx` or `Camera1.fx`, `DepthMapFactor`) is read too; see
//! [`crate::orbslam_settings`] for the keys.

use crate::error::DatasetError;
use serde::{Deserialize, Serialize};
use std::path::Path;
use stride_core::camera::{BrownConrady, PinholeCamera};

/// A depth camera registered to a colour camera: intrinsics plus the depth PNG scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraConfig {
    /// Intrinsics, image size and distortion of the colour camera (depth is registered).
    pub camera: PinholeCamera,
    /// Raw depth units per metre in the depth PNGs (TUM: 5000, i.e. 0.2 mm per unit).
    pub depth_scale: f64,
    /// Rolling-shutter readout time of the colour camera, top row to bottom row (s), the
    /// frame's timestamp being the middle row's time; 0 for a global shutter (and for every
    /// preset: the TUM benchmark does not publish it).
    pub rolling_shutter_s: f64,
    /// Exposure time of each colour row (s): a moving camera's keypoint sits where the
    /// scene was on average over it. 0 when unknown (and for every preset).
    pub exposure_s: f64,
}

/// TUM's depth scale: 16-bit depth PNGs hold 5000 units per metre.
pub const TUM_DEPTH_SCALE: f64 = 5000.0;

/// The depth scale of the `fr2` preset (units per metre): the Freiburg 2 sequences' depth
/// reads about 4 % long at TUM's nominal 5000, and ORB-SLAM2/ORB-SLAM3's TUM2 settings (and
/// the peers' harness, `../shared/tools/peers`) read it at 5208. The same value here keeps
/// `--camera fr2` runs at the scale the ground truth has and comparable with those peers; a
/// camera file's `depth_scale` overrides it.
pub const TUM_FR2_DEPTH_SCALE: f64 = 5208.0;

/// The serialised form of a camera file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CameraFile {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: u32,
    height: u32,
    depth_scale: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    distortion: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "is_zero")]
    rolling_shutter_s: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    exposure_s: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// Names accepted by [`CameraConfig::preset`].
pub const PRESET_NAMES: [&str; 3] = ["fr1", "fr2", "fr3"];

impl CameraConfig {
    /// The TUM RGB-D benchmark's calibrated cameras (Freiburg 1, 2 and 3; 640x480). fr1 and
    /// fr2 carry the published distortion; fr3 images are already undistorted. Depth scale
    /// 5000 units per metre, except fr2: [`TUM_FR2_DEPTH_SCALE`]. `None` for an unknown
    /// name.
    pub fn preset(name: &str) -> Option<Self> {
        let (intr, dist, depth_scale) = match name {
            "fr1" => (
                (517.306408, 516.469215, 318.643040, 255.313989),
                Some([0.262383, -0.953104, -0.005358, 0.002628, 1.163314]),
                TUM_DEPTH_SCALE,
            ),
            "fr2" => (
                (520.908620, 521.007327, 325.141442, 249.701764),
                Some([0.231222, -0.784899, -0.003257, -0.000105, 0.917205]),
                TUM_FR2_DEPTH_SCALE,
            ),
            "fr3" => ((535.4, 539.2, 320.1, 247.6), None, TUM_DEPTH_SCALE),
            _ => return None,
        };
        let camera = PinholeCamera::new(intr.0, intr.1, intr.2, intr.3, 640, 480).ok()?;
        let camera = match dist {
            Some(d) => camera.with_distortion(BrownConrady::from_array(d)).ok()?,
            None => camera,
        };
        Some(Self {
            camera,
            depth_scale,
            rolling_shutter_s: 0.0,
            exposure_s: 0.0,
        })
    }

    /// A preset name (`fr1`, `fr2`, `fr3`) or the path of a camera file.
    pub fn resolve(spec: &str) -> Result<Self, DatasetError> {
        match Self::preset(spec) {
            Some(c) => Ok(c),
            None => Self::from_file(Path::new(spec)),
        }
    }

    /// Reads a camera file (format by extension; see the module documentation).
    pub fn from_file(path: &Path) -> Result<Self, DatasetError> {
        camera_file_extension(path)?;
        let text = crate::text::read_text(path)?;
        Self::from_text(&text, path)
    }

    /// Parses the text of a camera file, in the format its `path`'s extension names (the
    /// path is otherwise only used in messages).
    pub fn from_text(text: &str, path: &Path) -> Result<Self, DatasetError> {
        let ext = camera_file_extension(path)?;
        if matches!(ext.as_str(), "yaml" | "yml")
            && crate::orbslam_settings::is_orbslam_settings(text)
        {
            return Self::from_orbslam(text, path);
        }
        let file: CameraFile = match ext.as_str() {
            "json" => serde_json::from_str(text).map_err(|e| {
                DatasetError::parse(path, e.line(), format!("invalid camera JSON: {e}"))
            })?,
            "toml" => toml::from_str(text)
                .map_err(|e| DatasetError::invalid(path, format!("invalid camera TOML: {e}")))?,
            _ => serde_yaml_ng::from_str(text).map_err(|e| match e.location() {
                Some(loc) => {
                    DatasetError::parse(path, loc.line(), format!("invalid camera YAML: {e}"))
                }
                None => DatasetError::invalid(path, format!("invalid camera YAML: {e}")),
            })?,
        };
        file.into_config()
            .map_err(|message| DatasetError::invalid(path, message))
    }

    /// An ORB-SLAM2/3 settings file's camera.
    fn from_orbslam(text: &str, path: &Path) -> Result<Self, DatasetError> {
        let c = crate::orbslam_settings::parse(text).map_err(|(line, message)| match line {
            0 => DatasetError::invalid(path, format!("ORB-SLAM settings: {message}")),
            l => DatasetError::parse(path, l, format!("ORB-SLAM settings: {message}")),
        })?;
        let (width, height) = c.size.unwrap_or_else(|| {
            tracing::warn!(
                "{}: no Camera.width/height (ORB-SLAM2 files have none): assuming 640x480; \
                 a frame of another size is an error",
                path.display()
            );
            (640, 480)
        });
        let [fx, fy, cx, cy] = c.intrinsics;
        let distortion = (c.distortion != [0.0; 5]).then(|| c.distortion.to_vec());
        CameraFile {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            depth_scale: c.depth_scale,
            distortion,
            rolling_shutter_s: 0.0,
            exposure_s: 0.0,
        }
        .into_config()
        .map_err(|message| DatasetError::invalid(path, message))
    }

    /// The camera file form of this configuration, as pretty JSON.
    pub fn to_json(&self) -> String {
        let c = &self.camera;
        let file = CameraFile {
            fx: c.fx(),
            fy: c.fy(),
            cx: c.cx(),
            cy: c.cy(),
            width: c.width(),
            height: c.height(),
            depth_scale: self.depth_scale,
            distortion: c.distortion().map(|d| d.to_array().to_vec()),
            rolling_shutter_s: self.rolling_shutter_s,
            exposure_s: self.exposure_s,
        };
        // Serialising plain numbers cannot fail.
        serde_json::to_string_pretty(&file).unwrap_or_default()
    }
}

/// The lower-case extension of a camera file, or an error when it names no known format.
fn camera_file_extension(path: &Path) -> Result<String, DatasetError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if !matches!(ext.as_str(), "json" | "toml" | "yaml" | "yml") {
        return Err(DatasetError::invalid(
            path,
            format!(
                "not a camera preset ({}) nor a camera file ending in .json, .toml, .yaml or .yml",
                PRESET_NAMES.join(", ")
            ),
        ));
    }
    Ok(ext)
}

impl CameraFile {
    fn into_config(self) -> Result<CameraConfig, String> {
        let camera =
            PinholeCamera::new(self.fx, self.fy, self.cx, self.cy, self.width, self.height)
                .map_err(|e| e.to_string())?;
        let camera = match self.distortion {
            None => camera,
            Some(d) => {
                let coeffs = match d.as_slice() {
                    [k1, k2, p1, p2] => [*k1, *k2, *p1, *p2, 0.0],
                    [k1, k2, p1, p2, k3] => [*k1, *k2, *p1, *p2, *k3],
                    other => {
                        return Err(format!(
                            "distortion must hold 4 or 5 numbers [k1, k2, p1, p2(, k3)], found {}",
                            other.len()
                        ))
                    }
                };
                camera
                    .with_distortion(BrownConrady::from_array(coeffs))
                    .map_err(|e| e.to_string())?
            }
        };
        if !(self.depth_scale.is_finite() && self.depth_scale > 0.0) {
            return Err(format!(
                "depth_scale = {} is invalid: must be a positive number of raw units per metre",
                self.depth_scale
            ));
        }
        if !(self.rolling_shutter_s.is_finite() && (0.0..=0.1).contains(&self.rolling_shutter_s)) {
            return Err(format!(
                "rolling_shutter_s = {} is invalid: must be a readout time from 0 to 0.1 s",
                self.rolling_shutter_s
            ));
        }
        if !(self.exposure_s.is_finite() && (0.0..=0.5).contains(&self.exposure_s)) {
            return Err(format!(
                "exposure_s = {} is invalid: must be an exposure time from 0 to 0.5 s",
                self.exposure_s
            ));
        }
        Ok(CameraConfig {
            camera,
            depth_scale: self.depth_scale,
            rolling_shutter_s: self.rolling_shutter_s,
            exposure_s: self.exposure_s,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes `text` to `name` in `dir` (each test's own temporary folder, removed when the
    /// test ends).
    fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn presets_hold_the_published_values() {
        let fr1 = CameraConfig::preset("fr1").unwrap();
        assert_eq!(fr1.camera.fx(), 517.306408);
        assert_eq!(fr1.camera.distortion().unwrap().k3, 1.163314);
        let fr3 = CameraConfig::resolve("fr3").unwrap();
        assert_eq!((fr3.camera.cx(), fr3.camera.cy()), (320.1, 247.6));
        assert!(fr3.camera.distortion().is_none());
        assert_eq!(fr3.depth_scale, 5000.0);
        assert_eq!(fr1.depth_scale, 5000.0);
        // Freiburg 2's depth reads about 4 % long at 5000 (ORB-SLAM's TUM2 settings).
        let fr2 = CameraConfig::preset("fr2").unwrap();
        assert_eq!(fr2.depth_scale, 5208.0);
        assert_eq!(fr2.camera.fx(), 520.908620);
        assert!(CameraConfig::preset("fr4").is_none());
    }

    #[test]
    fn reads_json_toml_and_yaml_ignoring_unknown_keys() {
        let dir = tempfile::tempdir().unwrap();
        let json = write(
            &dir,
            "c.json",
            r#"{"fx": 500, "fy": 501, "cx": 320, "cy": 240, "width": 640, "height": 480,
               "depth_scale": 1000, "distortion": [0.1, 0.01, 0, 0], "note": "ignored"}"#,
        );
        let c = CameraConfig::from_file(&json).unwrap();
        assert_eq!(c.camera.fy(), 501.0);
        assert_eq!(c.depth_scale, 1000.0);
        assert_eq!(c.camera.distortion().unwrap().k3, 0.0);
        let toml = write(
            &dir,
            "c.toml",
            "fx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nwidth = 640\nheight = 480\ndepth_scale = 5000.0\nmodel = \"x\"\n",
        );
        assert!(CameraConfig::from_file(&toml)
            .unwrap()
            .camera
            .distortion()
            .is_none());
        let yaml = write(
            &dir,
            "c.yaml",
            "fx: 500\nfy: 500\ncx: 320\ncy: 240\nwidth: 640\nheight: 480\ndepth_scale: 5000\ndistortion: [0.1, 0, 0, 0, 0.2]\n",
        );
        assert_eq!(
            CameraConfig::from_file(&yaml)
                .unwrap()
                .camera
                .distortion()
                .unwrap()
                .k3,
            0.2
        );
        // Round trip through the JSON writer.
        let back = write(&dir, "back.json", &c.to_json());
        assert_eq!(CameraConfig::from_file(&back).unwrap(), c);
    }

    #[test]
    fn the_rolling_shutter_readout_and_the_exposure_are_read_written_and_checked() {
        let text = |rs: &str| {
            format!(
                r#"{{"fx": 500, "fy": 500, "cx": 320, "cy": 240, "width": 640, "height": 480,
                    "depth_scale": 5000{rs}}}"#
            )
        };
        let path = Path::new("c.json");
        let global = CameraConfig::from_text(&text(""), path).unwrap();
        assert_eq!(global.rolling_shutter_s, 0.0);
        assert!(!global.to_json().contains("rolling_shutter_s"));
        let rolling = CameraConfig::from_text(&text(r#", "rolling_shutter_s": 0.03"#), path);
        let rolling = rolling.unwrap();
        assert_eq!(rolling.rolling_shutter_s, 0.03);
        assert_eq!(
            CameraConfig::from_text(&rolling.to_json(), path).unwrap(),
            rolling
        );
        let err = CameraConfig::from_text(&text(r#", "rolling_shutter_s": -1"#), path);
        assert!(err
            .unwrap_err()
            .to_string()
            .contains("rolling_shutter_s = -1"));
        // The exposure, the same way: absent is 0 (unknown), written back when known.
        assert_eq!(global.exposure_s, 0.0);
        assert!(!global.to_json().contains("exposure_s"));
        let exposed = CameraConfig::from_text(&text(r#", "exposure_s": 0.02"#), path).unwrap();
        assert_eq!(exposed.exposure_s, 0.02);
        assert_eq!(
            CameraConfig::from_text(&exposed.to_json(), path).unwrap(),
            exposed
        );
        let err = CameraConfig::from_text(&text(r#", "exposure_s": 2"#), path).unwrap_err();
        assert!(err.to_string().contains("exposure_s = 2"), "{err}");
    }

    #[test]
    fn orbslam_settings_give_the_same_camera_as_the_presets() {
        let dir = tempfile::tempdir().unwrap();
        // ORB-SLAM2's TUM3.yaml (no image size, no distortion) and an ORB-SLAM3 1.0 file.
        let orb2 = write(
            &dir,
            "TUM3.yaml",
            "%YAML:1.0\n# c\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n\
             Camera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\nDepthMapFactor: 5000.0\n",
        );
        assert_eq!(
            CameraConfig::from_file(&orb2).unwrap(),
            CameraConfig::preset("fr3").unwrap()
        );
        let orb3 = write(
            &dir,
            "TUM1.yaml",
            "%YAML:1.0\nFile.version: \"1.0\"\nCamera.type: \"PinHole\"\nCamera1.fx: 517.306408\n\
             Camera1.fy: 516.469215\nCamera1.cx: 318.643040\nCamera1.cy: 255.313989\n\
             Camera1.k1: 0.262383\nCamera1.k2: -0.953104\nCamera1.p1: -0.005358\n\
             Camera1.p2: 0.002628\nCamera1.k3: 1.163314\nCamera.width: 640\nCamera.height: 480\n\
             RGBD.DepthMapFactor: 5000.0\n",
        );
        assert_eq!(
            CameraConfig::from_file(&orb3).unwrap(),
            CameraConfig::preset("fr1").unwrap()
        );
        let bad = write(
            &dir,
            "bad.yaml",
            "%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: x\n",
        );
        let e = CameraConfig::from_file(&bad).unwrap_err().to_string();
        assert!(
            e.contains("bad.yaml:3: ORB-SLAM settings: Camera.fy: 'x' is not a finite number"),
            "{e}"
        );
    }

    #[test]
    fn bad_camera_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let missing_key = write(
            &dir,
            "m.json",
            r#"{"fx": 500, "fy": 500, "cx": 1, "cy": 1, "width": 640, "height": 480}"#,
        );
        let e = CameraConfig::from_file(&missing_key)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("m.json:1: invalid camera JSON: missing field `depth_scale`"),
            "{e}"
        );
        let negative = write(
            &dir,
            "n.yaml",
            "fx: -1\nfy: 500\ncx: 1\ncy: 1\nwidth: 640\nheight: 480\ndepth_scale: 5000\n",
        );
        let e = CameraConfig::from_file(&negative).unwrap_err().to_string();
        assert!(
            e.contains("n.yaml: camera parameter fx = -1 is invalid: must be positive"),
            "{e}"
        );
        let bad_dist = write(&dir, "d.toml", "fx = 1.0\nfy = 1.0\ncx = 1.0\ncy = 1.0\nwidth = 4\nheight = 4\ndepth_scale = 1.0\ndistortion = [1.0]\n");
        assert!(CameraConfig::from_file(&bad_dist)
            .unwrap_err()
            .to_string()
            .contains("4 or 5 numbers"));
        let e = CameraConfig::resolve("camera.txt").unwrap_err().to_string();
        assert!(e.contains("not a camera preset"), "{e}");
    }
}
