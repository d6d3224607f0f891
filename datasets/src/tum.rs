//! TUM RGB-D sequence folders.
//!
//! A folder holds `rgb/` and `depth/` PNGs listed with their timestamps in `rgb.txt` and
//! `depth.txt` (`timestamp filename` per line), optionally `accelerometer.txt` (see
//! [`crate::accelerometer`]), and optionally `groundtruth.txt` (a TUM
//! trajectory) and `camera.json` (a camera file, see [`crate::camera_config`]).
//!
//! Colour and depth images are associated as TUM's `associate.py` does (greedy, one-to-one,
//! smallest time difference first, `|dt| < 0.02 s` by default, optional offset added to the
//! depth stamps). The camera is, in order of preference: the one asked for, the folder's
//! `camera.json`, or the TUM preset named by the folder (`..._freiburg1_...` is `fr1`).

use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use crate::png_io::{decode_depth, decode_rgb};
use crate::stream::{DecodedFrame, FrameFailure, FrameStream};
use crate::text::{data_lines, parse_finite, read_text};
use crate::trajectory_file::read_tum_trajectory;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_core::frame::RgbdFrame;
use stride_core::time::associate_greedy;
use stride_core::trajectory::Trajectory;

/// How colour and depth stamps are paired.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AssociationOptions {
    /// Largest accepted `|t_rgb - (t_depth + offset)|` in seconds (exclusive, as the TUM tool).
    pub max_diff_s: f64,
    /// Added to depth stamps before comparing (seconds).
    pub offset_s: f64,
}

impl Default for AssociationOptions {
    /// TUM's defaults: 0.02 s window, no offset.
    fn default() -> Self {
        Self {
            max_diff_s: 0.02,
            offset_s: 0.0,
        }
    }
}

/// One associated colour/depth pair.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEntry {
    /// Colour image time (s).
    pub t_rgb_s: f64,
    /// Colour image file.
    pub rgb_path: PathBuf,
    /// Depth image time (s).
    pub t_depth_s: f64,
    /// Depth image file.
    pub depth_path: PathBuf,
}

/// Where the sequence's camera came from.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraSource {
    /// Given by the caller (a preset name or a file path).
    Requested(String),
    /// The folder's own `camera.json`.
    SequenceFile(PathBuf),
    /// A TUM preset named by the folder (`freiburg1` is `fr1`, ...).
    FolderName(&'static str),
}

impl std::fmt::Display for CameraSource {
    /// For logs and reports: `fr3 (requested)`, `camera.json in the folder`, `fr3 (from
    /// the folder name)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CameraSource::Requested(spec) => write!(f, "{spec} (requested)"),
            CameraSource::SequenceFile(p) => write!(f, "{} (the folder's)", p.display()),
            CameraSource::FolderName(name) => write!(f, "{name} (from the folder name)"),
        }
    }
}

/// An opened TUM RGB-D sequence: its associated frames, camera and ground truth.
#[derive(Debug, Clone)]
pub struct TumSequence {
    /// The sequence folder.
    pub dir: PathBuf,
    /// Intrinsics and depth scale used to decode the frames.
    pub camera: CameraConfig,
    /// Where [`Self::camera`] came from.
    pub camera_source: CameraSource,
    /// Associated colour/depth pairs, in time order.
    pub frames: Vec<FrameEntry>,
    /// `groundtruth.txt` (poses `world_from_camera`), when the folder has one.
    pub groundtruth: Option<Trajectory>,
    /// `accelerometer.txt` (specific force in the camera frame, see
    /// [`crate::accelerometer`]), when the folder has one.
    pub accelerometer: Option<Vec<crate::accelerometer::AccelSample>>,
    /// `gyroscope.txt` (angular velocity in the camera frame, see
    /// [`crate::accelerometer`]), when the folder has one.
    pub gyroscope: Option<Vec<crate::accelerometer::GyroSample>>,
    /// Colour images left without a depth partner.
    pub unmatched_rgb: usize,
}

/// Reads `rgb.txt`/`depth.txt`: `timestamp filename` lines in time order. A step back in
/// time is an error naming both lines; a repeated timestamp keeps the later line, as the
/// TUM scripts (which read the list into a dictionary) do, with a warning naming the file,
/// both lines and the count.
pub fn read_image_list(path: &Path) -> Result<Vec<(f64, String)>, DatasetError> {
    parse_image_list(&read_text(path)?, path)
}

/// Parses the text of an image list; `path` is only used in messages. See
/// [`read_image_list`].
pub fn parse_image_list(text: &str, path: &Path) -> Result<Vec<(f64, String)>, DatasetError> {
    let mut out: Vec<(f64, String)> = Vec::new();
    let mut last_line = 0;
    let mut duplicates = 0usize;
    let mut first_duplicate = None;
    for dl in data_lines(text) {
        let [stamp, file] = dl.exact_fields::<2>().map_err(|n| {
            DatasetError::parse(
                path,
                dl.line,
                format!("expected 2 fields (timestamp filename), found {n}"),
            )
        })?;
        let t = parse_finite(path, dl.line, "timestamp", stamp)?;
        if let Some((prev, _)) = out.last() {
            if t < *prev {
                return Err(DatasetError::parse(
                    path,
                    dl.line,
                    format!(
                        "timestamp {t:.6} is earlier than {prev:.6} on line {last_line}: \
                         entries must be sorted by time"
                    ),
                ));
            }
            if t == *prev {
                duplicates += 1;
                first_duplicate.get_or_insert((last_line, dl.line, t));
                out.pop();
            }
        }
        out.push((t, file.to_owned()));
        last_line = dl.line;
    }
    if let Some((a, b, t)) = first_duplicate {
        tracing::warn!(
            "{}: lines {a} and {b} have the same timestamp {t:.6}; the later line is used, as \
             the TUM scripts do ({duplicates} duplicated timestamp(s) in the file)",
            path.display()
        );
    }
    Ok(out)
}

fn preset_from_folder_name(dir: &Path) -> Option<&'static str> {
    let name = dir
        .canonicalize()
        .ok()?
        .file_name()?
        .to_string_lossy()
        .into_owned();
    ["freiburg1", "freiburg2", "freiburg3"]
        .iter()
        .zip(["fr1", "fr2", "fr3"])
        .find(|(key, _)| name.contains(*key))
        .map(|(_, preset)| preset)
}

impl TumSequence {
    /// Opens a sequence folder, associates its images and loads its ground truth.
    ///
    /// `camera` is a preset name (`fr1`, `fr2`, `fr3`) or a camera file; `None` means the
    /// folder's `camera.json`, else the preset its name implies, else an error.
    pub fn open(
        dir: &Path,
        camera: Option<&str>,
        assoc: AssociationOptions,
    ) -> Result<Self, DatasetError> {
        if !dir.is_dir() {
            return Err(DatasetError::invalid(
                dir,
                "not a folder (expected a TUM RGB-D sequence)",
            ));
        }
        let (camera, camera_source) = match camera {
            Some(spec) => (
                CameraConfig::resolve(spec)?,
                CameraSource::Requested(spec.to_owned()),
            ),
            None => {
                let file = dir.join("camera.json");
                if file.is_file() {
                    (
                        CameraConfig::from_file(&file)?,
                        CameraSource::SequenceFile(file),
                    )
                } else if let Some(preset) = preset_from_folder_name(dir) {
                    let config = CameraConfig::preset(preset)
                        .ok_or_else(|| DatasetError::invalid(dir, "unknown camera preset"))?;
                    (config, CameraSource::FolderName(preset))
                } else {
                    return Err(DatasetError::invalid(
                        dir,
                        "no camera given, no camera.json in the folder, and the folder name \
                         names no TUM camera: pass --camera fr1|fr2|fr3|FILE",
                    ));
                }
            }
        };
        let rgb = read_image_list(&dir.join("rgb.txt"))?;
        let depth = read_image_list(&dir.join("depth.txt"))?;
        let t_rgb: Vec<f64> = rgb.iter().map(|(t, _)| *t).collect();
        let t_depth: Vec<f64> = depth.iter().map(|(t, _)| *t).collect();
        let pairs = associate_greedy(&t_rgb, &t_depth, assoc.offset_s, assoc.max_diff_s);
        let frames: Vec<FrameEntry> = pairs
            .iter()
            .filter_map(|&(i, j)| {
                let (tr, fr) = rgb.get(i)?;
                let (td, fd) = depth.get(j)?;
                Some(FrameEntry {
                    t_rgb_s: *tr,
                    rgb_path: dir.join(fr),
                    t_depth_s: *td,
                    depth_path: dir.join(fd),
                })
            })
            .collect();
        if frames.is_empty() {
            return Err(DatasetError::invalid(
                dir,
                format!(
                    "no colour image has a depth image within {} s ({} rgb, {} depth entries)",
                    assoc.max_diff_s,
                    rgb.len(),
                    depth.len()
                ),
            ));
        }
        let gt_path = dir.join("groundtruth.txt");
        let groundtruth = if gt_path.is_file() {
            Some(read_tum_trajectory(&gt_path)?)
        } else {
            None
        };
        let accel_path = dir.join("accelerometer.txt");
        let accelerometer = if accel_path.is_file() {
            Some(crate::accelerometer::read_accelerometer(&accel_path)?)
        } else {
            None
        };
        let gyro_path = dir.join("gyroscope.txt");
        let gyroscope = if gyro_path.is_file() {
            Some(crate::accelerometer::read_gyroscope(&gyro_path)?)
        } else {
            None
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            camera,
            camera_source,
            unmatched_rgb: rgb.len() - frames.len(),
            frames,
            groundtruth,
            accelerometer,
            gyroscope,
        })
    }

    /// Number of associated frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when the sequence has no frame (never, for a successfully opened sequence).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Reads and decodes frame `index`, checking that both images match the camera's size.
    pub fn load_frame(&self, index: usize) -> Result<RgbdFrame, DatasetError> {
        let entry = self
            .frames
            .get(index)
            .ok_or_else(|| DatasetError::invalid(&self.dir, format!("no frame #{index}")))?;
        load_entry(index, entry, &self.camera)
    }

    /// Decodes frames `0..max_frames` (all when `None`) on a background thread, keeping up
    /// to `prefetch` decoded frames ready. A frame that fails to load is reported in place and
    /// the stream continues with the next one; a decoder thread that cannot start or dies
    /// ends the stream with [`crate::stream::StreamError::Stopped`].
    pub fn stream(&self, max_frames: Option<usize>, prefetch: usize) -> FrameStream {
        let n = max_frames.map_or(self.frames.len(), |m| m.min(self.frames.len()));
        self.stream_frames((0..n).collect(), prefetch)
    }

    /// As [`Self::stream`], for the frames `indices` only (ascending); each frame keeps its
    /// index in the sequence.
    pub fn stream_frames(&self, indices: Vec<usize>, prefetch: usize) -> FrameStream {
        let entries: Vec<(usize, FrameEntry)> = indices
            .iter()
            .filter_map(|&i| Some((i, self.frames.get(i)?.clone())))
            .collect();
        let camera = self.camera;
        FrameStream::spawn(&self.dir, entries.len(), prefetch, move |tx| {
            for (index, entry) in entries.iter().map(|(i, e)| (*i, e)) {
                let start = Instant::now();
                let item = load_entry(index, entry, &camera)
                    .map(|frame| DecodedFrame {
                        frame,
                        decode_s: start.elapsed().as_secs_f64(),
                    })
                    .map_err(|error| FrameFailure { index, error });
                if tx.send(item).is_err() {
                    break; // the consumer hung up
                }
            }
        })
    }
}

fn load_entry(
    index: usize,
    entry: &FrameEntry,
    camera: &CameraConfig,
) -> Result<RgbdFrame, DatasetError> {
    let rgb_bytes =
        std::fs::read(&entry.rgb_path).map_err(|e| DatasetError::io(&entry.rgb_path, e))?;
    let depth_bytes =
        std::fs::read(&entry.depth_path).map_err(|e| DatasetError::io(&entry.depth_path, e))?;
    let rgb = decode_rgb(&rgb_bytes, &entry.rgb_path)?;
    let depth_m = decode_depth(&depth_bytes, &entry.depth_path, camera.depth_scale)?;
    let (w, h) = (camera.camera.width(), camera.camera.height());
    for (path, iw, ih) in [
        (&entry.rgb_path, rgb.width(), rgb.height()),
        (&entry.depth_path, depth_m.width(), depth_m.height()),
    ] {
        if (iw, ih) != (w, h) {
            return Err(DatasetError::Image {
                path: path.clone(),
                message: format!("image is {iw}x{ih} but the camera is {w}x{h}"),
            });
        }
    }
    Ok(RgbdFrame {
        index,
        t_s: entry.t_rgb_s,
        t_depth_s: entry.t_depth_s,
        rgb,
        depth_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_lists_must_be_sorted_and_two_fields() {
        let dir = std::env::temp_dir().join(format!("stride-tum-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("rgb.txt");
        std::fs::write(&p, "# c\n1.0 rgb/1.png\n2.0 rgb/2.png\n").unwrap();
        assert_eq!(read_image_list(&p).unwrap().len(), 2);
        std::fs::write(&p, "1.0 rgb/1.png\n1.0 rgb/2.png\n2.0 rgb/3.png\n").unwrap();
        assert_eq!(
            read_image_list(&p).unwrap(),
            vec![(1.0, "rgb/2.png".to_owned()), (2.0, "rgb/3.png".to_owned())],
            "a repeated timestamp keeps the later line"
        );
        std::fs::write(&p, "2.0 rgb/1.png\n1.0 rgb/2.png\n").unwrap();
        let e = read_image_list(&p).unwrap_err().to_string();
        assert!(
            e.contains("rgb.txt:2: timestamp 1.000000 is earlier than 2.000000 on line 1"),
            "{e}"
        );
        std::fs::write(&p, "1.0 rgb/1.png extra\n").unwrap();
        let e = read_image_list(&p).unwrap_err().to_string();
        assert!(e.contains("rgb.txt:1: expected 2 fields"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
