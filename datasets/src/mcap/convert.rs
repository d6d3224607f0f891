//! TUM RGB-D folders to MCAP logs of ROS 2 messages, and back, timestamps and pixels exact.
//!
//! TUM to MCAP: every line of `rgb.txt` and `depth.txt` becomes an image message stamped
//! with the line's time to the microsecond (TUM's six decimals, digit for digit;
//! `header.stamp` and `log_time`); the camera a
//! `CameraInfo` message on [`DEFAULT_CAMERA_INFO_TOPIC`]; `accelerometer.txt` and
//! `gyroscope.txt` `Imu` messages (linear acceleration only, angular velocity only: the
//! other field's covariance starts with -1, ROS's "not given"; in the camera's frame);
//! `groundtruth.txt`
//! `TFMessage`s from [`GROUNDTRUTH_PARENT`] to [`GROUNDTRUTH_CHILD`] on [`TF_TOPIC`].
//! Depth keeps the folder's raw 16-bit units; the depth channel's metadata
//! ([`DEPTH_UNITS_KEY`]) says how many make a metre. Images are written raw (`rgb8`,
//! `16UC1`) or, with [`ImageFormat::Png`], as the folder's own files in `CompressedImage`s.
//!
//! MCAP to TUM: the colour and depth topics' messages become PNGs named by their stamps,
//! listed in `rgb.txt` and `depth.txt`; the camera becomes `camera.json`, the accelerometer
//! `accelerometer.txt`, the gyroscope `gyroscope.txt`, the ground truth `groundtruth.txt`.
//! The folder is staged and published whole; the MCAP file is written to a temporary
//! sibling and renamed.

use super::images::{self, ImagePayload};
use super::ros2::{
    CameraInfoMsg, CompressedImageMsg, Header, ImageMsg, ImuMsg, TfMessage, Time, TransformStamped,
};
use super::schema::Ros2Type;
use super::writer::{write_log, LogWriter};
use super::{
    McapSequence, DEFAULT_CAMERA_INFO_TOPIC, DEFAULT_DEPTH_TOPIC, DEFAULT_IMU_TOPIC,
    DEFAULT_RGB_TOPIC, DEPTH_UNITS_KEY, GROUNDTRUTH_CHILD, GROUNDTRUTH_PARENT, TF_TOPIC,
};
use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use crate::png_io::{decode_depth_raw, decode_rgb, encode_depth_u16, encode_rgb};
use crate::tum::{read_image_list, TumSequence};
use std::path::Path;
use stride_core::pose::pose_to_translation_quaternion;
use stride_output::fs::StagedDir;

/// How images are stored in a converted log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ImageFormat {
    /// `sensor_msgs/Image`: `rgb8` colour and `16UC1` depth (fastest to read).
    #[default]
    Raw,
    /// `sensor_msgs/CompressedImage`: the folder's PNG (or JPEG) files as they are.
    Png,
}

/// Chunk compression of a written log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Compression {
    /// None (fastest to read and write).
    #[default]
    None,
    /// zstd.
    Zstd,
    /// lz4.
    Lz4,
}

/// What a conversion wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ConvertCounts {
    /// Colour images.
    pub rgb: usize,
    /// Depth images.
    pub depth: usize,
    /// Accelerometer samples.
    pub imu: usize,
    /// Gyroscope samples.
    pub gyroscope: usize,
    /// Ground-truth poses.
    pub groundtruth: usize,
}

/// An `Imu` message carrying one vector: the linear acceleration (`linear`) or the angular
/// velocity; the other field and the orientation are marked not given (-1 first in their
/// covariances, ROS's convention).
fn imu_message(header: Header, v: [f64; 3], linear: bool) -> ImuMsg {
    const NOT_GIVEN: [f64; 9] = [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    let (given, absent) = ((v, [0.0; 9]), ([0.0; 3], NOT_GIVEN));
    let ((linear_acceleration, linear_acceleration_covariance), angular) = if linear {
        (given, absent)
    } else {
        (absent, given)
    };
    ImuMsg {
        header,
        orientation: [0.0, 0.0, 0.0, 1.0],
        orientation_covariance: NOT_GIVEN,
        angular_velocity: angular.0,
        angular_velocity_covariance: angular.1,
        linear_acceleration,
        linear_acceleration_covariance,
    }
}

/// The frame id of the colour camera's optical frame in written messages.
pub const CAMERA_FRAME_ID: &str = "camera_rgb_optical_frame";

/// The `CameraInfo` of a camera (plumb-bob distortion, identity rectification).
pub fn camera_info(camera: &CameraConfig, header: Header) -> CameraInfoMsg {
    let c = &camera.camera;
    let d = c.distortion().map_or([0.0; 5], |d| d.to_array());
    CameraInfoMsg {
        header,
        height: c.height(),
        width: c.width(),
        distortion_model: "plumb_bob".into(),
        d: d.to_vec(),
        k: [c.fx(), 0.0, c.cx(), 0.0, c.fy(), c.cy(), 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            c.fx(),
            0.0,
            c.cx(),
            0.0,
            0.0,
            c.fy(),
            c.cy(),
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
        ],
        binning: [0, 0],
        roi: ([0, 0, 0, 0], 0),
    }
}

/// One message to write: (log time ns, order key, topic index, CDR bytes or a file to encode).
enum Pending {
    Image {
        file: std::path::PathBuf,
        depth: bool,
    },
    Ready(Vec<u8>),
}

/// Writes the TUM folder `dir` (camera: `camera`, else as [`TumSequence::open`] finds it)
/// as an MCAP log at `out`; returns what it wrote.
pub fn tum_to_mcap(
    dir: &Path,
    camera: Option<&str>,
    out: &Path,
    format: ImageFormat,
    compression: Compression,
) -> Result<ConvertCounts, DatasetError> {
    let seq = TumSequence::open(dir, camera, crate::tum::AssociationOptions::default())?;
    // The lists as the TUM reader reads them (a repeated stamp keeps the later line); stamps
    // to the microsecond, which TUM's six decimals are exactly.
    let stamped = |name: &str| -> Result<Vec<(Time, String)>, DatasetError> {
        Ok(read_image_list(&dir.join(name))?
            .into_iter()
            .map(|(t, f)| (Time::from_seconds(t), f))
            .collect())
    };
    let (rgb, depth) = (stamped("rgb.txt")?, stamped("depth.txt")?);
    let options = ::mcap::WriteOptions::new()
        .profile("ros2")
        .compression(match compression {
            Compression::None => None,
            Compression::Zstd => Some(::mcap::Compression::Zstd),
            Compression::Lz4 => Some(::mcap::Compression::Lz4),
        });
    write_log(out, options, |w| fill_log(w, &seq, &rgb, &depth, format))
}

fn fill_log(
    w: &mut LogWriter,
    seq: &TumSequence,
    rgb: &[(Time, String)],
    depth: &[(Time, String)],
    format: ImageFormat,
) -> Result<ConvertCounts, DatasetError> {
    let mut channel =
        |ty: Ros2Type, topic: &str, meta: &[(&str, String)]| w.add_ros2_channel(ty, topic, meta);
    let image_type = match format {
        ImageFormat::Raw => Ros2Type::Image,
        ImageFormat::Png => Ros2Type::CompressedImage,
    };
    let ch_rgb = channel(image_type, DEFAULT_RGB_TOPIC, &[])?;
    let ch_depth = channel(
        image_type,
        DEFAULT_DEPTH_TOPIC,
        &[(DEPTH_UNITS_KEY, format!("{}", seq.camera.depth_scale))],
    )?;
    let ch_info = channel(Ros2Type::CameraInfo, DEFAULT_CAMERA_INFO_TOPIC, &[])?;
    let header = |stamp: Time| Header {
        stamp,
        frame_id: CAMERA_FRAME_ID.into(),
    };
    // Every message, ordered by time (then by kind, for equal stamps).
    let mut all: Vec<(Time, u8, u16, Pending)> = Vec::new();
    for (t, f) in rgb {
        all.push((
            *t,
            1,
            ch_rgb,
            Pending::Image {
                file: seq.dir.join(f),
                depth: false,
            },
        ));
    }
    for (t, f) in depth {
        all.push((
            *t,
            2,
            ch_depth,
            Pending::Image {
                file: seq.dir.join(f),
                depth: true,
            },
        ));
    }
    if let Some(t0) = rgb.first().map(|r| r.0) {
        all.push((
            t0,
            0,
            ch_info,
            Pending::Ready(camera_info(&seq.camera, header(t0)).encode()),
        ));
    }
    let mut counts = ConvertCounts {
        rgb: rgb.len(),
        depth: depth.len(),
        ..ConvertCounts::default()
    };
    // One IMU channel for the accelerometer's and the gyroscope's messages.
    let ch_imu = (seq.accelerometer.is_some() || seq.gyroscope.is_some())
        .then(|| channel(Ros2Type::Imu, DEFAULT_IMU_TOPIC, &[]))
        .transpose()?;
    // Accelerometer-only and gyroscope-only messages (each at its own rate).
    for (samples, linear) in [(&seq.accelerometer, true), (&seq.gyroscope, false)] {
        let (Some(samples), Some(ch)) = (samples, ch_imu) else {
            continue;
        };
        for (t, v) in samples {
            let stamp = Time::from_seconds(*t);
            let m = imu_message(header(stamp), [v.x, v.y, v.z], linear);
            all.push((stamp, 3, ch, Pending::Ready(m.encode())));
        }
        if linear {
            counts.imu = samples.len();
        } else {
            counts.gyroscope = samples.len();
        }
    }
    if let Some(gt) = &seq.groundtruth {
        let ch = channel(Ros2Type::TfMessage, TF_TOPIC, &[])?;
        for (t, pose) in gt.iter() {
            let stamp = Time::from_seconds(t);
            let (translation, rotation) = pose_to_translation_quaternion(pose);
            let m = TfMessage {
                transforms: vec![TransformStamped {
                    header: Header {
                        stamp,
                        frame_id: GROUNDTRUTH_PARENT.into(),
                    },
                    child_frame_id: GROUNDTRUTH_CHILD.into(),
                    translation,
                    rotation,
                }],
            };
            all.push((stamp, 4, ch, Pending::Ready(m.encode())));
        }
        counts.groundtruth = gt.len();
    }
    all.sort_by_key(|(t, kind, _, _)| (*t, *kind));
    for (stamp, _, ch, pending) in all {
        let data = match pending {
            Pending::Ready(d) => d,
            Pending::Image { file, depth } => image_message(&file, depth, format, header(stamp))?,
        };
        w.write(ch, stamp.nanos(), &data)?;
    }
    Ok(counts)
}

/// The CDR message of one image file of a TUM folder.
fn image_message(
    file: &Path,
    depth: bool,
    format: ImageFormat,
    header: Header,
) -> Result<Vec<u8>, DatasetError> {
    let bytes = std::fs::read(file).map_err(|e| DatasetError::io(file, e))?;
    Ok(match (format, depth) {
        (ImageFormat::Png, _) => {
            let is_png = bytes.starts_with(b"\x89PNG");
            if depth && !is_png {
                return Err(DatasetError::invalid(file, "a depth image must be a PNG"));
            }
            CompressedImageMsg {
                header,
                format: if is_png { "png" } else { "jpeg" }.into(),
                data: &bytes,
            }
            .encode()
        }
        (ImageFormat::Raw, false) => {
            let img = decode_rgb(&bytes, file)?;
            let data = images::rgb8_bytes(&img);
            ImageMsg {
                header,
                height: img.height(),
                width: img.width(),
                encoding: "rgb8".into(),
                is_bigendian: 0,
                step: img.width() * 3,
                data: &data,
            }
            .encode()
        }
        (ImageFormat::Raw, true) => {
            let img = decode_depth_raw(&bytes, file)?;
            let data = images::u16_le_bytes(&img);
            ImageMsg {
                header,
                height: img.height(),
                width: img.width(),
                encoding: "16UC1".into(),
                is_bigendian: 0,
                step: img.width() * 2,
                data: &data,
            }
            .encode()
        }
    })
}

/// A stamp as TUM writes it: seconds with six decimals, or more when the stamp needs them.
pub fn format_stamp(t: Time) -> String {
    let mut frac = format!("{:09}", t.nanosec);
    while frac.len() > 6 && frac.ends_with('0') {
        frac.pop();
    }
    format!("{}.{frac}", t.sec)
}

/// Writes the sequence of an MCAP log as a TUM folder at `out` (staged, published whole).
/// Every message of the colour and depth topics is written, paired or not.
pub fn mcap_to_tum(seq: &McapSequence, out: &Path) -> Result<ConvertCounts, DatasetError> {
    let stage = StagedDir::new(out).map_err(|e| DatasetError::io(out, e))?;
    let dir = stage.path().to_path_buf();
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(dir.join(sub)).map_err(|e| DatasetError::io(dir.join(sub), e))?;
    }
    let mut lists = [String::new(), String::new()];
    for (list, what) in lists.iter_mut().zip(["rgb", "depth"]) {
        list.push_str(&format!(
            "# {what} images\n# file: converted by stride from an MCAP log\n# timestamp filename\n"
        ));
    }
    let mut counts = ConvertCounts::default();
    let topics = [seq.topics.rgb.clone(), seq.topics.depth.clone()];
    let mut index = [0usize; 2];
    super::scan::for_each_message(&seq.path, |message| {
        let (topic, data) = (message.channel.topic.as_str(), message.data.as_ref());
        let Some(which) = topics.iter().position(|t| t == topic) else {
            return Ok(true);
        };
        let k = index[which];
        index[which] += 1;
        let bad = |m: String| DatasetError::message(&seq.path, topic, k, m);
        let p = super::payload(data, seq.compressed[which]).map_err(bad)?;
        let stamp = match &p {
            ImagePayload::Raw(m) => m.header.stamp,
            ImagePayload::Compressed(m) => m.header.stamp,
        };
        let name = format!("{}/{}.png", ["rgb", "depth"][which], format_stamp(stamp));
        let png = if which == 0 {
            encode_rgb(&images::rgb_image(&p).map_err(bad)?)
        } else {
            encode_depth_u16(&images::depth_units(&p).map_err(bad)?)
        }
        .map_err(bad)?;
        let file = dir.join(&name);
        std::fs::write(&file, png).map_err(|e| DatasetError::io(&file, e))?;
        lists[which].push_str(&format!("{} {name}\n", format_stamp(stamp)));
        Ok(true)
    })?;
    counts.rgb = index[0];
    counts.depth = index[1];
    for (list, name) in lists.iter().zip(["rgb.txt", "depth.txt"]) {
        let file = dir.join(name);
        std::fs::write(&file, list).map_err(|e| DatasetError::io(&file, e))?;
    }
    let camera_file = dir.join("camera.json");
    std::fs::write(&camera_file, seq.camera.to_json())
        .map_err(|e| DatasetError::io(&camera_file, e))?;
    if let Some(acc) = &seq.accelerometer {
        crate::accelerometer::write_accelerometer(&dir.join("accelerometer.txt"), acc)?;
        counts.imu = acc.len();
    }
    if let Some(gyro) = &seq.gyroscope {
        crate::accelerometer::write_gyroscope(&dir.join("gyroscope.txt"), gyro)?;
        counts.gyroscope = gyro.len();
    }
    if let Some(gt) = &seq.groundtruth {
        crate::trajectory_file::write_tum_trajectory(&dir.join("groundtruth.txt"), gt)?;
        counts.groundtruth = gt.len();
    }
    stage.publish().map_err(|e| DatasetError::io(out, e))?;
    Ok(counts)
}
