//! Camera settings files of ORB-SLAM2 and ORB-SLAM3 (OpenCV `FileStorage` YAML, starting
//! with `%YAML:1.0`), the calibration most RGB-D SLAM users already have.
//!
//! Read keys (everything else is ignored):
//!
//! * intrinsics: `Camera.fx fy cx cy` (ORB-SLAM2 and ORB-SLAM3 before its settings version
//!   1.0) or `Camera1.fx fy cx cy` (ORB-SLAM3 `File.version: "1.0"`), in pixels;
//! * distortion: `k1 k2 p1 p2` and optionally `k3` under the same prefix (all zero when
//!   absent); a `Camera.type` other than `PinHole` (e.g. `KannalaBrandt8`) is an error;
//! * image size: `Camera.width`, `Camera.height` (or `Camera1.`); ORB-SLAM2's TUM files
//!   have none, so 640x480 is assumed then, with a warning (a frame of another size is then
//!   an error naming the frame);
//! * depth: `DepthMapFactor` (ORB-SLAM2) or `RGBD.DepthMapFactor` (ORB-SLAM3 1.0): raw depth
//!   units per metre, stride's `depth_scale`. Required: without it the file is not an RGB-D
//!   calibration.

use std::collections::HashMap;

/// Whether `text` looks like an ORB-SLAM settings file rather than a plain YAML camera file.
pub fn is_orbslam_settings(text: &str) -> bool {
    text.trim_start().starts_with("%YAML:1.0")
        || text
            .lines()
            .any(|l| l.starts_with("Camera.fx:") || l.starts_with("Camera1.fx:"))
}

/// The top-level `key: value` pairs of an OpenCV YAML file with their line numbers
/// (indented lines, comments, directives and `---` are skipped; quotes are removed).
fn top_level(text: &str) -> HashMap<&str, (usize, &str)> {
    let mut out = HashMap::new();
    for (i, line) in text.lines().enumerate() {
        if line.starts_with([' ', '\t', '#', '%', '-']) {
            continue;
        }
        let line = line.split_once(" #").map_or(line, |(a, _)| a);
        let Some((key, value)) = line.split_once(':') else {
            continue;
        };
        let value = value.trim().trim_matches('"').trim_matches('\'');
        out.insert(key.trim(), (i + 1, value));
    }
    out
}

/// Camera parameters read from an ORB-SLAM settings file.
#[derive(Debug, Clone, PartialEq)]
pub struct OrbSlamCamera {
    /// `fx, fy, cx, cy` (px).
    pub intrinsics: [f64; 4],
    /// `k1, k2, p1, p2, k3` (OpenCV's order).
    pub distortion: [f64; 5],
    /// Image size (px); `None` when the file does not say.
    pub size: Option<(u32, u32)>,
    /// Raw depth units per metre.
    pub depth_scale: f64,
}

/// Parses an ORB-SLAM2/3 settings file. Errors are `(line, message)`; line 0 when the
/// problem is a missing key.
pub fn parse(text: &str) -> Result<OrbSlamCamera, (usize, String)> {
    let keys = top_level(text);
    if let Some(&(line, t)) = keys.get("Camera.type") {
        if !t.eq_ignore_ascii_case("PinHole") {
            return Err((
                line,
                format!("Camera.type '{t}' is not supported: stride models pinhole cameras with Brown-Conrady distortion"),
            ));
        }
    }
    let prefix = if keys.contains_key("Camera1.fx") {
        "Camera1."
    } else {
        "Camera."
    };
    let number = |name: &str| -> Result<Option<f64>, (usize, String)> {
        match keys.get(name) {
            None => Ok(None),
            Some(&(line, v)) => v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| (line, format!("{name}: '{v}' is not a finite number"))),
        }
    };
    let required = |name: String| -> Result<f64, (usize, String)> {
        number(&name)?.ok_or_else(|| (0, format!("missing {name}")))
    };
    let intrinsics = [
        required(format!("{prefix}fx"))?,
        required(format!("{prefix}fy"))?,
        required(format!("{prefix}cx"))?,
        required(format!("{prefix}cy"))?,
    ];
    let mut distortion = [0.0; 5];
    for (slot, k) in distortion.iter_mut().zip(["k1", "k2", "p1", "p2", "k3"]) {
        *slot = number(&format!("{prefix}{k}"))?.unwrap_or(0.0);
    }
    let dim = |k: &str| -> Result<Option<u32>, (usize, String)> {
        let name = ["Camera.", "Camera1."]
            .iter()
            .map(|p| format!("{p}{k}"))
            .find(|n| keys.contains_key(n.as_str()));
        let Some(name) = name else { return Ok(None) };
        let v = number(&name)?.unwrap_or(0.0);
        if v >= 1.0 && v.fract() == 0.0 && v <= f64::from(u16::MAX) {
            Ok(Some(v as u32))
        } else {
            let line = keys.get(name.as_str()).map_or(0, |e| e.0);
            Err((line, format!("{name}: {v} is not an image size in pixels")))
        }
    };
    let size = match (dim("width")?, dim("height")?) {
        (Some(w), Some(h)) => Some((w, h)),
        _ => None,
    };
    let depth_scale = match number("DepthMapFactor")? {
        Some(d) => d,
        None => number("RGBD.DepthMapFactor")?.ok_or_else(|| {
            (
                0,
                "missing DepthMapFactor (or RGBD.DepthMapFactor): not an RGB-D calibration".into(),
            )
        })?,
    };
    Ok(OrbSlamCamera {
        intrinsics,
        distortion,
        size,
        depth_scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ORBSLAM2_TUM3: &str = "%YAML:1.0

#--------------------------------------------------------------------------------------------
# Camera Parameters. Adjust them!
#--------------------------------------------------------------------------------------------

# Camera calibration and distortion parameters (OpenCV)
Camera.fx: 535.4
Camera.fy: 539.2
Camera.cx: 320.1
Camera.cy: 247.6

Camera.k1: 0.0
Camera.k2: 0.0
Camera.p1: 0.0
Camera.p2: 0.0

Camera.fps: 30.0
Camera.bf: 40.0
Camera.RGB: 1
ThDepth: 40.0

# Deptmap values factor
DepthMapFactor: 5000.0

ORBextractor.nFeatures: 1000
Viewer.KeyFrameSize: 0.05
";

    const ORBSLAM3_V1: &str = "%YAML:1.0
File.version: \"1.0\"
Camera.type: \"PinHole\"
Camera1.fx: 517.306408
Camera1.fy: 516.469215
Camera1.cx: 318.643040
Camera1.cy: 255.313989
Camera1.k1: 0.262383
Camera1.k2: -0.953104
Camera1.p1: -0.005358
Camera1.p2: 0.002628
Camera1.k3: 1.163314
Camera.width: 640
Camera.height: 480
Camera.fps: 30
Camera.RGB: 1
Stereo.ThDepth: 40.0
Stereo.b: 0.07732
RGBD.DepthMapFactor: 5000.0
Tlr: !!opencv-matrix
   rows: 3
   cols: 4
   dt: f
   data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]
";

    #[test]
    fn reads_orbslam2_and_orbslam3_settings() {
        assert!(is_orbslam_settings(ORBSLAM2_TUM3) && is_orbslam_settings(ORBSLAM3_V1));
        assert!(!is_orbslam_settings("fx: 1\nfy: 1\n"));
        let c = parse(ORBSLAM2_TUM3).unwrap();
        assert_eq!(c.intrinsics, [535.4, 539.2, 320.1, 247.6]);
        assert_eq!(c.distortion, [0.0; 5]);
        assert_eq!(c.size, None);
        assert_eq!(c.depth_scale, 5000.0);
        let c = parse(ORBSLAM3_V1).unwrap();
        assert_eq!(c.intrinsics[0], 517.306408);
        assert_eq!(c.distortion[4], 1.163314);
        assert_eq!(c.size, Some((640, 480)));
    }

    #[test]
    fn bad_settings_name_the_key_and_line() {
        let e = parse(&ORBSLAM2_TUM3.replace("Camera.fy: 539.2", "Camera.fy: abc")).unwrap_err();
        assert_eq!(e, (9, "Camera.fy: 'abc' is not a finite number".to_owned()));
        let e = parse(&ORBSLAM2_TUM3.replace("DepthMapFactor: 5000.0", "")).unwrap_err();
        assert!(e.1.starts_with("missing DepthMapFactor"), "{e:?}");
        let e = parse(&ORBSLAM3_V1.replace("PinHole", "KannalaBrandt8")).unwrap_err();
        assert_eq!(e.0, 3);
        assert!(e.1.contains("KannalaBrandt8"), "{e:?}");
        let e = parse(&ORBSLAM3_V1.replace("Camera.width: 640", "Camera.width: 64.5")).unwrap_err();
        assert!(e.1.contains("not an image size"), "{e:?}");
        let e = parse(&ORBSLAM3_V1.replace("Camera1.cx: 318.643040\n", "")).unwrap_err();
        assert_eq!(e, (0, "missing Camera1.cx".to_owned()));
    }
}
