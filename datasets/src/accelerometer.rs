//! Accelerometer samples in the TUM layout: `accelerometer.txt`, one `timestamp ax ay az`
//! per line (s, m/s²).
//!
//! Frame and sign: the specific force in the camera frame (x right, y down, z forward), so
//! that a camera at rest reads the reaction to gravity, pointing up: a level camera reads
//! about `(0, -9.81, 0)`. TUM's Kinect recordings read this way; stride's synthetic lab
//! writes it.

use crate::error::DatasetError;
use crate::text::{data_lines, parse_finite, read_text};
use nalgebra::Vector3;
use std::fmt::Write as _;
use std::path::Path;
use stride_output::fs::write_atomic;

/// One sample: time (s) and specific force in the camera frame (m/s²).
pub type AccelSample = (f64, Vector3<f64>);

/// Reads an accelerometer file; errors name the file and line (a line without four numbers,
/// samples out of time order).
pub fn read_accelerometer(path: &Path) -> Result<Vec<AccelSample>, DatasetError> {
    parse_accelerometer(&read_text(path)?, path)
}

/// Parses the text of an accelerometer file; `path` is only used in messages.
pub fn parse_accelerometer(text: &str, path: &Path) -> Result<Vec<AccelSample>, DatasetError> {
    let mut out: Vec<AccelSample> = Vec::new();
    for dl in data_lines(text) {
        let [t, ax, ay, az] = dl.exact_fields::<4>().map_err(|n| {
            DatasetError::parse(
                path,
                dl.line,
                format!("expected 4 fields (timestamp ax ay az), found {n}"),
            )
        })?;
        let t = parse_finite(path, dl.line, "timestamp", t)?;
        let f = Vector3::new(
            parse_finite(path, dl.line, "ax", ax)?,
            parse_finite(path, dl.line, "ay", ay)?,
            parse_finite(path, dl.line, "az", az)?,
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
    let mut s = String::from("# accelerometer: timestamp ax ay az (m/s^2, specific force in the camera frame: x right, y down, z forward)\n");
    for (t, f) in samples {
        let _ = writeln!(s, "{t:.6} {:.5} {:.5} {:.5}", f.x, f.y, f.z);
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
    }
}
