//! Inertial samples in the TUM layout, one `timestamp x y z` per line: `accelerometer.txt`
//! (s, m/s²) and `gyroscope.txt` (s, rad/s).
//!
//! Frame and sign: both in the camera frame (x right, y down, z forward). The accelerometer
//! reads the specific force, so that a camera at rest reads the reaction to gravity,
//! pointing up: a level camera reads about `(0, -9.81, 0)`. TUM's Kinect recordings read
//! this way; stride's synthetic lab writes it. The gyroscope reads the camera's angular
//! velocity `omega` in its own frame: `world_from_camera(t + s) = world_from_camera(t) *
//! exp(omega s)` for small `s`. The synthetic lab writes one; TUM's recordings have none.

use crate::error::DatasetError;
use crate::text::{data_lines, parse_finite, read_text};
use nalgebra::Vector3;
use std::fmt::Write as _;
use std::path::Path;
use stride_output::fs::write_atomic;

/// One sample: time (s) and specific force in the camera frame (m/s²).
pub type AccelSample = (f64, Vector3<f64>);
/// One sample: time (s) and angular velocity in the camera frame (rad/s).
pub type GyroSample = (f64, Vector3<f64>);

/// Reads an accelerometer file; errors name the file and line (a line without four numbers,
/// samples out of time order).
pub fn read_accelerometer(path: &Path) -> Result<Vec<AccelSample>, DatasetError> {
    parse_accelerometer(&read_text(path)?, path)
}

/// Parses the text of an accelerometer file; `path` is only used in messages.
pub fn parse_accelerometer(text: &str, path: &Path) -> Result<Vec<AccelSample>, DatasetError> {
    parse_samples(text, path, ["ax", "ay", "az"])
}

/// Reads a gyroscope file; errors as [`read_accelerometer`]'s.
pub fn read_gyroscope(path: &Path) -> Result<Vec<GyroSample>, DatasetError> {
    parse_samples(&read_text(path)?, path, ["wx", "wy", "wz"])
}

/// Time-sorted three-axis samples; `axes` names the columns in messages.
fn parse_samples(
    text: &str,
    path: &Path,
    axes: [&str; 3],
) -> Result<Vec<(f64, Vector3<f64>)>, DatasetError> {
    let [a0, a1, a2] = axes;
    let mut out: Vec<(f64, Vector3<f64>)> = Vec::new();
    for dl in data_lines(text) {
        let [t, ax, ay, az] = dl.exact_fields::<4>().map_err(|n| {
            DatasetError::parse(
                path,
                dl.line,
                format!("expected 4 fields (timestamp {a0} {a1} {a2}), found {n}"),
            )
        })?;
        let t = parse_finite(path, dl.line, "timestamp", t)?;
        let f = Vector3::new(
            parse_finite(path, dl.line, a0, ax)?,
            parse_finite(path, dl.line, a1, ay)?,
            parse_finite(path, dl.line, a2, az)?,
        );
        if out.last().is_some_and(|(prev, _)| t <= *prev) {
            return Err(DatasetError::parse(
                path,
                dl.line,
                format!("timestamp {t:.6} is not after the previous sample's: samples must be sorted by time"),
            ));
        }
        out.push((t, f));
    }
    Ok(out)
}

/// Writes samples as `accelerometer.txt` (atomically).
pub fn write_accelerometer(path: &Path, samples: &[AccelSample]) -> Result<(), DatasetError> {
    write_samples(
        path,
        "# accelerometer: timestamp ax ay az (m/s^2, specific force in the camera frame: x right, y down, z forward)",
        samples,
        5,
    )
}

/// Writes samples as `gyroscope.txt` (atomically).
pub fn write_gyroscope(path: &Path, samples: &[GyroSample]) -> Result<(), DatasetError> {
    write_samples(
        path,
        "# gyroscope: timestamp wx wy wz (rad/s, angular velocity in the camera frame: x right, y down, z forward)",
        samples,
        6,
    )
}

/// Writes a header line and one `timestamp x y z` line per sample (`decimals` after the
/// point), atomically.
fn write_samples(
    path: &Path,
    header: &str,
    samples: &[(f64, Vector3<f64>)],
    decimals: usize,
) -> Result<(), DatasetError> {
    let mut s = format!("{header}\n");
    for (t, v) in samples {
        let _ = writeln!(
            s,
            "{t:.6} {:.*} {:.*} {:.*}",
            decimals, v.x, decimals, v.y, decimals, v.z
        );
    }
    write_atomic(path, s.as_bytes()).map_err(|e| DatasetError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_samples_and_names_bad_lines() {
        let p = Path::new("accelerometer.txt");
        let s = parse_accelerometer("# c\n1.0 0 -9.8 0.1\n1.01 0.1 -9.7 0\n", p).unwrap();
        assert_eq!(s.len(), 2);
        assert_eq!(s[1].1, Vector3::new(0.1, -9.7, 0.0));
        let err = parse_accelerometer("1.0 0 -9.8\n", p)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("accelerometer.txt:1:") && err.contains("4 fields"),
            "{err}"
        );
        let err = parse_accelerometer("1.0 0 -9.8 0\n0.5 0 -9.8 0\n", p)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("accelerometer.txt:2:") && err.contains("sorted"),
            "{err}"
        );
        let dir = std::env::temp_dir().join(format!("stride-gyro-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let g = dir.join("gyroscope.txt");
        write_gyroscope(&g, &[(1.0, Vector3::new(0.1, -0.2, 0.3))]).unwrap();
        let back = read_gyroscope(&g).unwrap();
        assert_eq!(back, vec![(1.0, Vector3::new(0.1, -0.2, 0.3))]);
        std::fs::write(&g, "1.0 0 0\n").unwrap();
        let err = read_gyroscope(&g).unwrap_err().to_string();
        assert!(
            err.contains("gyroscope.txt:1:") && err.contains("wx wy wz"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
