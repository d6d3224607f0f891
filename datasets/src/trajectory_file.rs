//! TUM trajectory files: one pose per line, `t tx ty tz qx qy qz qw`.
//!
//! `t` is in seconds, `tx ty tz` is the position of the body (camera) in the world in metres
//! and `qx qy qz qw` its orientation, so each line is the pose `world_from_camera`.
//!
//! Reading is strict, because a silently misread trajectory corrupts every number computed
//! from it. Each rule below fails with an error naming the file and line:
//!
//! * a data line must have exactly 8 fields (spaces, tabs or commas separate them);
//! * every field must be a finite number (NaN and inf are refused: a lost frame should be
//!   left out of the file, not written as NaN);
//! * the quaternion must not be zero (the TUM tools and evo silently read it as identity);
//! * timestamps must not go back in time: a step back is an error naming both lines (sort
//!   the file, e.g. `sort -n`).
//! * a duplicated timestamp is accepted, as evo and the TUM scripts accept it, with a
//!   warning naming the file, both lines and the count. Both poses are kept: evo's
//!   nearest-stamp association (the `evo` preset) then picks one by its own rule (the later
//!   line for a stamp at or after the duplicate, the earlier one for a stamp before it), and
//!   the `tum` preset keeps the last line, as the TUM scripts' dictionary does. Interpolation
//!   at that time uses the later pose.
//! * a file without any pose is an error.
//!
//! A quaternion whose norm differs from 1 is normalised, as the TUM tools and evo do; when it
//! differs by more than [`QUATERNION_NORM_WARN_TOLERANCE`] (more than rounding to a few
//! decimals explains) a warning names the first such line and the count.

use crate::error::DatasetError;
use crate::text::{data_lines, parse_finite, read_text};
use std::fmt::Write as _;
use std::path::Path;
use stride_core::pose::{pose_from_translation_quaternion, pose_to_translation_quaternion};
use stride_core::trajectory::Trajectory;
use stride_output::fs::write_atomic;

/// Deviation of a quaternion's norm from 1 above which reading warns (it still normalises).
pub const QUATERNION_NORM_WARN_TOLERANCE: f64 = 1e-3;

const FIELD_NAMES: [&str; 8] = ["t", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];

/// Reads a TUM trajectory file. See the module documentation for the rules.
pub fn read_tum_trajectory(path: &Path) -> Result<Trajectory, DatasetError> {
    let text = read_text(path)?;
    parse_tum_trajectory(&text, path)
}

/// Parses the text of a TUM trajectory file; `path` is only used in messages.
pub fn parse_tum_trajectory(text: &str, path: &Path) -> Result<Trajectory, DatasetError> {
    let mut traj = Trajectory::new();
    let mut last_line = 0usize;
    let mut far_from_unit: Option<(usize, f64)> = None;
    let mut far_count = 0usize;
    let mut duplicates = 0usize;
    let mut first_duplicate: Option<(usize, usize, f64)> = None;
    for dl in data_lines(text) {
        let fields = dl.exact_fields::<8>().map_err(|n| {
            DatasetError::parse(
                path,
                dl.line,
                format!("expected 8 fields (t tx ty tz qx qy qz qw), found {n}"),
            )
        })?;
        let mut v = [0.0f64; 8];
        for ((slot, field), name) in v.iter_mut().zip(fields).zip(FIELD_NAMES) {
            *slot = parse_finite(path, dl.line, name, field)?;
        }
        let [t, tx, ty, tz, qx, qy, qz, qw] = v;
        let (pose, norm) = pose_from_translation_quaternion([tx, ty, tz], [qx, qy, qz, qw])
            .map_err(|e| DatasetError::parse(path, dl.line, e.to_string()))?;
        if (norm - 1.0).abs() > QUATERNION_NORM_WARN_TOLERANCE {
            far_count += 1;
            far_from_unit.get_or_insert((dl.line, norm));
        }
        if let Some(&previous) = traj.stamps_s().last() {
            if t == previous {
                duplicates += 1;
                first_duplicate.get_or_insert((last_line, dl.line, t));
            }
            if t < previous {
                return Err(DatasetError::parse(
                    path,
                    dl.line,
                    format!(
                        "timestamp {t:.6} is earlier than {previous:.6} on line {last_line}: \
                         poses must be sorted by time (e.g. `sort -n`)"
                    ),
                ));
            }
        }
        traj.push(t, pose)
            .map_err(|e| DatasetError::parse(path, dl.line, e.to_string()))?;
        last_line = dl.line;
    }
    if traj.is_empty() {
        return Err(DatasetError::invalid(
            path,
            "no poses: the file is empty or holds only comments",
        ));
    }
    if let Some((a, b, t)) = first_duplicate {
        tracing::warn!(
            "{}: lines {a} and {b} have the same timestamp {t:.6}; both kept, as evo and the \
             TUM scripts do ({duplicates} duplicated timestamp(s) in the file)",
            path.display()
        );
    }
    if let Some((line, norm)) = far_from_unit {
        tracing::warn!(
            "{}:{line}: quaternion norm is {norm:.6}, not 1; normalised \
             ({far_count} such line(s) in the file)",
            path.display()
        );
    }
    Ok(traj)
}

/// Formats a trajectory in TUM format: time with 6 decimals (microseconds, the precision of
/// an f64 epoch time), position and quaternion with 9, `qw >= 0`.
pub fn format_tum_trajectory(traj: &Trajectory) -> String {
    let mut out = String::with_capacity(traj.len() * 96 + 32);
    out.push_str("# timestamp tx ty tz qx qy qz qw\n");
    for (t, pose) in traj.iter() {
        let ([x, y, z], [qx, qy, qz, qw]) = pose_to_translation_quaternion(pose);
        // Writing into a String cannot fail.
        let _ = writeln!(
            out,
            "{t:.6} {x:.9} {y:.9} {z:.9} {qx:.9} {qy:.9} {qz:.9} {qw:.9}"
        );
    }
    out
}

/// Writes a trajectory in TUM format, atomically (temporary file, then rename).
pub fn write_tum_trajectory(path: &Path, traj: &Trajectory) -> Result<(), DatasetError> {
    write_atomic(path, format_tum_trajectory(traj).as_bytes())
        .map_err(|e| DatasetError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn parse(text: &str) -> Result<Trajectory, String> {
        parse_tum_trajectory(text, Path::new("traj.txt")).map_err(|e| e.to_string())
    }

    #[test]
    fn reads_comments_blank_lines_and_separators() {
        let t =
            parse("# header\n\n1.0 1 2 3 0 0 0 1\n2.0,1,2,3,0,0,0,1\n3.0\t1\t2\t3\t0\t0\t0\t2\n")
                .unwrap();
        assert_eq!(t.len(), 3);
        assert_eq!(t.stamps_s(), &[1.0, 2.0, 3.0]);
        assert_relative_eq!(t.poses()[2].rotation.angle(), 0.0);
    }

    #[test]
    fn bad_lines_are_named() {
        assert_eq!(
            parse("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n").unwrap_err(),
            "traj.txt:2: expected 8 fields (t tx ty tz qx qy qz qw), found 7"
        );
        assert_eq!(
            parse("1 0 0 x 0 0 0 1\n").unwrap_err(),
            "traj.txt:1: tz 'x' is not a number"
        );
        assert!(parse("1 0 0 0 0 0 0 nan\n")
            .unwrap_err()
            .starts_with("traj.txt:1: qw is nan"));
        assert!(parse("1 inf 0 0 0 0 0 1\n")
            .unwrap_err()
            .starts_with("traj.txt:1: tx is inf"));
        assert!(parse("# c\n1 0 0 0 0 0 0 0\n")
            .unwrap_err()
            .starts_with("traj.txt:2: quaternion (qx qy qz qw) has norm 0"));
        // A duplicated timestamp is kept (evo and the TUM scripts accept it).
        assert_eq!(
            parse("1 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n").unwrap().len(),
            2
        );
        assert!(parse("2 0 0 0 0 0 0 1\n\n1 0 0 0 0 0 0 1\n")
            .unwrap_err()
            .starts_with("traj.txt:3: timestamp 1.000000 is earlier than 2.000000 on line 1"));
        assert_eq!(
            parse("# only a comment\n\n").unwrap_err(),
            "traj.txt: no poses: the file is empty or holds only comments"
        );
        assert_eq!(
            parse("").unwrap_err(),
            "traj.txt: no poses: the file is empty or holds only comments"
        );
    }

    #[test]
    fn write_then_read_round_trips() {
        let t = parse(
            "1305031102.160407 1.344379 0.627206 1.661754 0.658249 0.611043 -0.294444 -0.326553\n",
        )
        .unwrap();
        let back = parse(&format_tum_trajectory(&t)).unwrap();
        assert_eq!(back.stamps_s(), t.stamps_s());
        assert_relative_eq!(back.poses()[0], t.poses()[0], epsilon = 1e-9);
    }

    #[test]
    fn missing_file_is_named() {
        let e = read_tum_trajectory(Path::new("/nonexistent/x.txt")).unwrap_err();
        assert!(e.to_string().starts_with("/nonexistent/x.txt: "), "{e}");
    }
}
