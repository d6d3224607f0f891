//! Scan logs: 2-D range scans with their poses as plain text, one scan per line:
//!
//! `t tx ty tz qx qy qz qw angle_min angle_increment n r_0 ... r_(n-1)`
//!
//! `t` in seconds; the pose `world_from_sensor` (world z up, m, unit quaternion); the
//! sensor frame as ROS's `LaserScan` (beams in its x-y plane, angle from +x towards +y,
//! rad); ranges in metres, `0` or `nan` for no return. `#` starts a comment line. Scans
//! must come in time order.

use crate::error::DatasetError;
use crate::text::{data_lines, parse_finite, read_text};
use std::fmt::Write as _;
use std::path::Path;
use stride_core::pose::{pose_from_translation_quaternion, pose_to_translation_quaternion};
use stride_core::scan::Scan;
use stride_output::fs::write_atomic;

/// Reads a scan log; errors name the file and line.
pub fn read_scan_log(path: &Path) -> Result<Vec<Scan>, DatasetError> {
    parse_scan_log(&read_text(path)?, path)
}

/// Parses the text of a scan log; `path` is only used in messages.
pub fn parse_scan_log(text: &str, path: &Path) -> Result<Vec<Scan>, DatasetError> {
    let mut out: Vec<Scan> = Vec::new();
    for dl in data_lines(text) {
        let fields: Vec<&str> = dl.fields().collect();
        let err = |m: String| DatasetError::parse(path, dl.line, m);
        if fields.len() < 11 {
            return Err(err(format!(
                "expected t tx ty tz qx qy qz qw angle_min angle_increment n and n ranges, \
                 found {} fields",
                fields.len()
            )));
        }
        let num = |k: usize, name: &str| parse_finite(path, dl.line, name, fields[k]);
        let t = num(0, "t")?;
        let tr = [num(1, "tx")?, num(2, "ty")?, num(3, "tz")?];
        let q = [num(4, "qx")?, num(5, "qy")?, num(6, "qz")?, num(7, "qw")?];
        let (pose, _) = pose_from_translation_quaternion(tr, q).map_err(|e| err(e.to_string()))?;
        let angle_min = num(8, "angle_min")?;
        let increment = num(9, "angle_increment")?;
        let n: usize = fields[10]
            .parse()
            .map_err(|_| err(format!("n = '{}' is not a count of ranges", fields[10])))?;
        if n.checked_add(11) != Some(fields.len()) {
            return Err(err(format!(
                "n = {n} ranges announced, {} given",
                fields.len() - 11
            )));
        }
        let mut ranges = Vec::with_capacity(n);
        for (k, f) in fields[11..].iter().enumerate() {
            let r: f64 = f
                .parse()
                .map_err(|_| err(format!("range {k} = '{f}' is not a number")))?;
            if r < 0.0 || r.is_infinite() {
                return Err(err(format!(
                    "range {k} = {r}: ranges are >= 0 (0 or nan: no return)"
                )));
            }
            ranges.push(if r == 0.0 { f64::NAN } else { r });
        }
        if let Some(prev) = out.last() {
            if t < prev.t_s {
                return Err(err(format!(
                    "time {t} is earlier than the previous scan's {}: scans must be in time order",
                    prev.t_s
                )));
            }
        }
        out.push(Scan {
            t_s: t,
            world_from_sensor: pose,
            angle_min_rad: angle_min,
            angle_increment_rad: increment,
            ranges,
        });
    }
    if out.is_empty() {
        return Err(DatasetError::invalid(path, "no scan in the file"));
    }
    Ok(out)
}

/// The text of a scan log (ranges to 0.1 mm, `nan` for no return).
pub fn format_scan_log(scans: &[Scan]) -> String {
    let mut s = String::from(
        "# t tx ty tz qx qy qz qw angle_min angle_increment n r_0 ... r_(n-1)\n\
         # world_from_sensor (world z up, m); beams in the sensor's x-y plane from +x to +y (rad); ranges (m), nan: no return\n",
    );
    for scan in scans {
        let (t, q) = pose_to_translation_quaternion(&scan.world_from_sensor);
        let _ = write!(
            s,
            "{:.6} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {}",
            scan.t_s,
            t[0],
            t[1],
            t[2],
            q[0],
            q[1],
            q[2],
            q[3],
            scan.angle_min_rad,
            scan.angle_increment_rad,
            scan.ranges.len()
        );
        for r in &scan.ranges {
            if r.is_finite() && *r > 0.0 {
                let _ = write!(s, " {r:.4}");
            } else {
                s.push_str(" nan");
            }
        }
        s.push('\n');
    }
    s
}

/// Writes a scan log atomically.
pub fn write_scan_log(path: &Path, scans: &[Scan]) -> Result<(), DatasetError> {
    write_atomic(path, format_scan_log(scans).as_bytes()).map_err(|e| DatasetError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors_name_the_line() {
        let text = "# header\n1.5 0 0 0.26 0 0.3007058 0 0.9537170 -1.0 0.5 3 0.5 0 nan\n\
                    1.6 0.01 0 0.26 0 0 0 1 -1.0 0.5 2 0.52 0.61\n";
        let p = Path::new("scans.txt");
        let scans = parse_scan_log(text, p).unwrap();
        assert_eq!(scans.len(), 2);
        assert_eq!(scans[0].ranges.len(), 3);
        assert!(scans[0].valid(0) && !scans[0].valid(1) && !scans[0].valid(2));
        let back = parse_scan_log(&format_scan_log(&scans), p).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[1].ranges, vec![0.52, 0.61]);
        for (bad, why) in [
            (
                "1 0 0 0 0 0 0 1 0 0.1 3 1 2\n",
                "scans.txt:1: n = 3 ranges announced, 2 given",
            ),
            ("1 0 0 0 0 0 0 1 0 0.1\n", "scans.txt:1: expected t tx"),
            ("1 0 0 0 0 0 0 0 0 0.1 1 1\n", "scans.txt:1:"),
            ("1 0 0 0 0 0 0 1 0 0.1 1 -2\n", "range 0 = -2"),
            (
                "2 0 0 0 0 0 0 1 0 0.1 1 1\n1 0 0 0 0 0 0 1 0 0.1 1 1\n",
                "scans.txt:2: time 1 is earlier",
            ),
            ("# nothing\n", "no scan"),
        ] {
            let e = parse_scan_log(bad, p).unwrap_err().to_string();
            assert!(e.contains(why), "{e} (wanted {why})");
        }
    }
}
