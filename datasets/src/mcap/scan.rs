//! One streaming pass over an MCAP file: every message in file order, with the checks and
//! bookkeeping that opening a sequence and listing a log need.

use super::ros2::{leading_header, CameraInfoMsg, ImuMsg, TfMessage};
use super::schema::Ros2Type;
use super::{
    image_kind, McapTopics, DEFAULT_CAMERA_INFO_TOPIC, DEFAULT_IMU_TOPIC, DEPTH_UNITS_KEY,
};
use super::{GROUNDTRUTH_CHILD, GROUNDTRUTH_PARENT};
use crate::accelerometer::{AccelSample, GyroSample};
use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::Path;
use stride_core::camera::{BrownConrady, PinholeCamera};
use stride_core::pose::pose_from_translation_quaternion;
use stride_core::time::seconds_from_nanos;
use stride_core::trajectory::Trajectory;

/// Calls `f(message)` for every message of the file in file order (each owning its data),
/// until `f` returns `Ok(false)` or an error. A file that is not MCAP, is truncated or
/// corrupt (bad CRC, a record cut short) is an error naming the file and how many messages
/// were read.
pub(super) fn for_each_message(
    path: &Path,
    mut f: impl FnMut(::mcap::Message<'static>) -> Result<bool, DatasetError>,
) -> Result<(), DatasetError> {
    let file = std::fs::File::open(path).map_err(|e| DatasetError::io(path, e))?;
    // Chunk and data-section CRCs are checked (a flipped bit is an error, not a changed
    // pixel). A record's claimed length is bounded before anything is buffered for it:
    // 100 times the file (records inside compressed chunks can be far larger than the
    // file), at least 64 MiB, at most 1 GiB.
    let file_len = file
        .metadata()
        .map_err(|e| DatasetError::io(path, e))?
        .len();
    let limit = usize::try_from(file_len.saturating_mul(100))
        .unwrap_or(usize::MAX)
        .clamp(64 << 20, 1 << 30);
    let options = ::mcap::sans_io::LinearReaderOptions::default()
        .with_validate_chunk_crcs(true)
        .with_validate_data_section_crc(true)
        .with_record_length_limit(limit);
    let reader = ::mcap::io::MessageReader::new_with_options(
        BufReader::with_capacity(1 << 20, file),
        options,
    );
    for (read, message) in reader.enumerate() {
        let message = message.map_err(|e| {
            DatasetError::invalid(
                path,
                format!("not a readable MCAP file (after {read} messages): {e}"),
            )
        })?;
        if !f(message)? {
            break;
        }
    }
    Ok(())
}

fn schema_name(channel: &::mcap::Channel) -> String {
    channel
        .schema
        .as_ref()
        .map_or_else(|| "(no schema)".to_owned(), |s| s.name.clone())
}

/// One topic of a log.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicSummary {
    /// The topic.
    pub topic: String,
    /// Its schema's name (`sensor_msgs/msg/Image`, ...).
    pub schema: String,
    /// Its message encoding (`cdr` for ROS 2).
    pub encoding: String,
    /// Messages on it.
    pub messages: usize,
    /// First and last `log_time` (s).
    pub span_s: (f64, f64),
}

/// What a log holds, for `stride info`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LogSummary {
    /// Topics, by name.
    pub topics: Vec<TopicSummary>,
    /// Transforms seen on `tf2_msgs/TFMessage` topics: (parent, child, count).
    pub transforms: Vec<(String, String, usize)>,
    /// Messages in all.
    pub messages: usize,
}

/// Lists the topics of a log and the frame pairs of its transforms.
pub fn summarize(path: &Path) -> Result<LogSummary, DatasetError> {
    let mut topics: BTreeMap<String, TopicSummary> = BTreeMap::new();
    let mut transforms: BTreeMap<(String, String), usize> = BTreeMap::new();
    let mut messages = 0usize;
    for_each_message(path, |message| {
        let channel = message.channel.as_ref();
        messages += 1;
        let t = seconds_from_nanos(message.log_time);
        let s = topics
            .entry(channel.topic.clone())
            .or_insert_with(|| TopicSummary {
                topic: channel.topic.clone(),
                schema: schema_name(channel),
                encoding: channel.message_encoding.clone(),
                messages: 0,
                span_s: (t, t),
            });
        s.messages += 1;
        s.span_s = (s.span_s.0.min(t), s.span_s.1.max(t));
        if channel.message_encoding == "cdr"
            && Ros2Type::from_name(&s.schema) == Some(Ros2Type::TfMessage)
        {
            if let Ok(tf) = TfMessage::decode(&message.data) {
                for x in tf.transforms {
                    *transforms
                        .entry((x.header.frame_id, x.child_frame_id))
                        .or_insert(0) += 1;
                }
            }
        }
        Ok(true)
    })?;
    Ok(LogSummary {
        topics: topics.into_values().collect(),
        transforms: transforms
            .into_iter()
            .map(|((p, c), n)| (p, c, n))
            .collect(),
        messages,
    })
}

/// What opening a sequence reads from a log.
pub(super) struct Scanned {
    pub topics: McapTopics,
    /// (stamp s, index among the topic's messages), sorted by stamp.
    pub rgb: Vec<(f64, usize)>,
    pub depth: Vec<(f64, usize)>,
    pub rgb_compressed: bool,
    pub depth_compressed: bool,
    pub depth_units_per_m: Option<f64>,
    pub camera: Option<(CameraConfig, String)>,
    pub groundtruth: Option<Trajectory>,
    pub accelerometer: Option<Vec<AccelSample>>,
    pub gyroscope: Option<Vec<GyroSample>>,
}

/// A camera from a `CameraInfo` message (plumb-bob distortion or none).
pub fn camera_from_info(info: &CameraInfoMsg) -> Result<CameraConfig, String> {
    let k = info.k;
    if info.binning.iter().any(|&b| b > 1) || info.roi.0.iter().any(|&v| v != 0) {
        return Err("binning and regions of interest are not supported".into());
    }
    let mut d = [0.0; 5];
    match info.distortion_model.as_str() {
        "plumb_bob" | "rational_polynomial" | "" => {
            for (dst, src) in d.iter_mut().zip(&info.d) {
                *dst = *src;
            }
            if info.d.iter().skip(5).any(|&v| v != 0.0) {
                return Err(format!(
                    "{} distortion beyond k3 is not supported",
                    info.distortion_model
                ));
            }
        }
        other => return Err(format!("distortion model '{other}' is not supported")),
    }
    let camera = PinholeCamera::new(k[0], k[4], k[2], k[5], info.width, info.height)
        .and_then(|c| c.with_distortion(BrownConrady::from_array(d)))
        .map_err(|e| e.to_string())?;
    Ok(CameraConfig {
        camera,
        depth_scale: super::REP118_DEPTH_UNITS_PER_M,
        rolling_shutter_s: 0.0,
        exposure_s: 0.0,
    })
}

fn stamp_s(header_stamp: super::ros2::Time, log_time_ns: u64) -> f64 {
    if header_stamp == super::ros2::Time::default() {
        seconds_from_nanos(log_time_ns)
    } else {
        header_stamp.seconds()
    }
}

/// Checks a channel's encoding and schema against what a role needs.
fn check_channel(
    path: &Path,
    channel: &::mcap::Channel,
    role: &str,
    ok: impl Fn(&str) -> bool,
    wanted: &str,
) -> Result<(), DatasetError> {
    if channel.message_encoding != "cdr" {
        return Err(DatasetError::invalid(
            path,
            format!(
                "{role} topic {} has message encoding '{}': only ROS 2's 'cdr' is supported",
                channel.topic, channel.message_encoding
            ),
        ));
    }
    let schema = schema_name(channel);
    if !ok(&schema) {
        return Err(DatasetError::invalid(
            path,
            format!(
                "{role} topic {} carries {schema}, not {wanted}",
                channel.topic
            ),
        ));
    }
    Ok(())
}

/// Reads the stamps and side streams of a sequence in one pass.
pub(super) fn scan_sequence(path: &Path, topics: &McapTopics) -> Result<Scanned, DatasetError> {
    let info_topic = topics
        .camera_info
        .clone()
        .unwrap_or_else(|| DEFAULT_CAMERA_INFO_TOPIC.to_owned());
    let imu_topic = topics
        .imu
        .clone()
        .unwrap_or_else(|| DEFAULT_IMU_TOPIC.to_owned());
    let (gt_parent, gt_child) = topics
        .groundtruth_tf
        .clone()
        .unwrap_or_else(|| (GROUNDTRUTH_PARENT.to_owned(), GROUNDTRUTH_CHILD.to_owned()));
    let mut rgb = Vec::new();
    let mut depth = Vec::new();
    let mut kinds: [Option<bool>; 2] = [None, None];
    let mut units = None;
    let mut camera = None;
    let mut rgb_frame_id = None;
    let mut imu: Vec<AccelSample> = Vec::new();
    let mut gyro: Vec<GyroSample> = Vec::new();
    let mut imu_frame_id = None;
    let mut gt = Vec::new();
    let mut seen: BTreeMap<String, String> = BTreeMap::new();
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for_each_message(path, |message| {
        let channel = message.channel.as_ref();
        let topic = channel.topic.as_str();
        let k = {
            let c = counts.entry(topic.to_owned()).or_insert(0);
            *c += 1;
            *c - 1
        };
        if k == 0 {
            seen.insert(topic.to_owned(), schema_name(channel));
        }
        let data = &message.data;
        let bad = |m: String| DatasetError::message(path, topic, k, m);
        if topic == topics.rgb || topic == topics.depth {
            let which = usize::from(topic != topics.rgb);
            if k == 0 {
                let role = ["colour", "depth"][which];
                check_channel(path, channel, role, |s| image_kind(s).is_some(), "an image")?;
                kinds[which] = image_kind(&schema_name(channel));
                if which == 1 {
                    units = channel
                        .metadata
                        .get(DEPTH_UNITS_KEY)
                        .and_then(|v| v.parse::<f64>().ok());
                }
            }
            let header = leading_header(data).map_err(|e| bad(e.to_string()))?;
            if which == 0 && rgb_frame_id.is_none() {
                rgb_frame_id = Some(header.frame_id.clone());
            }
            let t = stamp_s(header.stamp, message.log_time);
            [&mut rgb, &mut depth][which].push((t, k));
        } else if topic == info_topic && camera.is_none() {
            check_channel(
                path,
                channel,
                "camera info",
                |s| Ros2Type::from_name(s) == Some(Ros2Type::CameraInfo),
                "sensor_msgs/msg/CameraInfo",
            )?;
            let info = CameraInfoMsg::decode(data).map_err(|e| bad(e.to_string()))?;
            camera = Some((camera_from_info(&info).map_err(bad)?, info_topic.clone()));
        } else if topic == imu_topic {
            check_channel(
                path,
                channel,
                "IMU",
                |s| Ros2Type::from_name(s) == Some(Ros2Type::Imu),
                "sensor_msgs/msg/Imu",
            )?;
            let m = ImuMsg::decode(data).map_err(|e| bad(e.to_string()))?;
            imu_frame_id.get_or_insert_with(|| m.header.frame_id.clone());
            // ROS's convention: -1 in a covariance's first element marks a field the
            // message does not carry (a gyroscope-only or accelerometer-only sample).
            let t = stamp_s(m.header.stamp, message.log_time);
            if m.linear_acceleration_covariance[0] != -1.0 {
                let a = m.linear_acceleration;
                imu.push((t, Vector3::new(a[0], a[1], a[2])));
            }
            if m.angular_velocity_covariance[0] != -1.0 {
                let w = m.angular_velocity;
                gyro.push((t, Vector3::new(w[0], w[1], w[2])));
            }
        } else if channel.message_encoding == "cdr"
            && Ros2Type::from_name(&schema_name(channel)) == Some(Ros2Type::TfMessage)
        {
            let tf = TfMessage::decode(data).map_err(|e| bad(e.to_string()))?;
            for x in tf.transforms {
                if x.header.frame_id == gt_parent && x.child_frame_id == gt_child {
                    let (pose, _) = pose_from_translation_quaternion(x.translation, x.rotation)
                        .map_err(|e| bad(format!("transform {gt_parent} -> {gt_child}: {e}")))?;
                    gt.push((stamp_s(x.header.stamp, message.log_time), pose));
                }
            }
        }
        Ok(true)
    })?;
    let missing = |role: &str, topic: &str| {
        let listed: Vec<String> = seen.iter().map(|(t, s)| format!("{t} ({s})")).collect();
        DatasetError::invalid(
            path,
            format!(
                "no {role} topic {topic}; the log holds: {}",
                if listed.is_empty() {
                    "no messages".to_owned()
                } else {
                    listed.join(", ")
                }
            ),
        )
    };
    let (Some(rgb_compressed), Some(depth_compressed)) = (kinds[0], kinds[1]) else {
        let (role, topic) = if kinds[0].is_none() {
            ("colour", &topics.rgb)
        } else {
            ("depth", &topics.depth)
        };
        return Err(missing(role, topic));
    };
    if let Some(t) = &topics.camera_info {
        if camera.is_none() {
            return Err(missing("camera info", t));
        }
    }
    if let Some(t) = &topics.imu {
        if imu.is_empty() && gyro.is_empty() {
            return Err(missing("IMU", t));
        }
    }
    // The default IMU topic counts only when it is in the colour camera's frame.
    let imu_usable =
        topics.imu.is_some() || (imu_frame_id.is_some() && imu_frame_id == rgb_frame_id);
    let has_imu = !(imu.is_empty() && gyro.is_empty());
    if has_imu && !imu_usable {
        tracing::warn!(
            "{}: {imu_topic} is in frame {:?}, not the colour camera's {:?}: not used for \
             the world frame (pass --imu-topic to use it as the camera's)",
            path.display(),
            imu_frame_id.unwrap_or_default(),
            rgb_frame_id.unwrap_or_default()
        );
    }
    if topics.groundtruth_tf.is_some() && gt.is_empty() {
        return Err(DatasetError::invalid(
            path,
            format!("no transform from {gt_parent} to {gt_child} on any tf2_msgs/TFMessage topic"),
        ));
    }
    rgb.sort_by(|a, b| a.0.total_cmp(&b.0));
    depth.sort_by(|a, b| a.0.total_cmp(&b.0));
    imu.sort_by(|a, b| a.0.total_cmp(&b.0));
    gyro.sort_by(|a, b| a.0.total_cmp(&b.0));
    gt.sort_by(|a, b| a.0.total_cmp(&b.0));
    let groundtruth = if gt.is_empty() {
        None
    } else {
        let (stamps, poses) = gt.into_iter().unzip();
        Some(Trajectory::from_parts(stamps, poses).map_err(|e| {
            DatasetError::invalid(path, format!("ground truth {gt_parent} -> {gt_child}: {e}"))
        })?)
    };
    Ok(Scanned {
        topics: McapTopics {
            camera_info: camera.as_ref().map(|c| c.1.clone()),
            imu: (imu_usable && has_imu).then(|| imu_topic.clone()),
            groundtruth_tf: groundtruth
                .as_ref()
                .map(|_| (gt_parent.clone(), gt_child.clone())),
            ..topics.clone()
        },
        rgb,
        depth,
        rgb_compressed,
        depth_compressed,
        depth_units_per_m: units,
        camera,
        groundtruth,
        accelerometer: (imu_usable && !imu.is_empty()).then_some(imu),
        gyroscope: (imu_usable && !gyro.is_empty()).then_some(gyro),
    })
}
