//! 2-D range scans from an MCAP log: `sensor_msgs/LaserScan` messages of one topic, each
//! placed at its frame's pose in a fixed frame, interpolated at the scan's stamp from the
//! `tf2_msgs/TFMessage` transforms `fixed_frame -> header.frame_id` (direct transforms
//! only: a chain through intermediate frames is not composed).

use super::ros2::{Header, LaserScanMsg, TfMessage, Time, TransformStamped};
use super::schema::Ros2Type;
use super::writer::write_log;
use crate::error::DatasetError;
use std::collections::BTreeMap;
use std::path::Path;
use stride_core::pose::pose_from_translation_quaternion;
use stride_core::scan::Scan;
use stride_core::trajectory::Trajectory;

/// The scans of `topic`, in time order, and how many had no pose (outside the transforms'
/// time span); an error when the topic is missing or no scan can be placed.
pub fn read_laser_scans(
    path: &Path,
    topic: &str,
    fixed_frame: &str,
) -> Result<(Vec<Scan>, usize), DatasetError> {
    let mut raw: Vec<(f64, String, Scan)> = Vec::new();
    let mut tf: BTreeMap<String, Vec<(f64, stride_core::pose::Pose)>> = BTreeMap::new();
    let mut pairs: BTreeMap<(String, String), usize> = BTreeMap::new();
    let mut index = 0usize;
    super::scan::for_each_message(path, |message| {
        let channel = message.channel.as_ref();
        let schema = channel
            .schema
            .as_ref()
            .map(|s| s.name.as_str())
            .unwrap_or("");
        let ty = Ros2Type::from_name(schema);
        if channel.topic == topic {
            let k = index;
            index += 1;
            let bad = |m: String| DatasetError::message(path, topic, k, m);
            if ty != Some(Ros2Type::LaserScan) || channel.message_encoding != "cdr" {
                return Err(bad(format!(
                    "{schema} ({}), not a CDR sensor_msgs/msg/LaserScan",
                    channel.message_encoding
                )));
            }
            let m = LaserScanMsg::decode(&message.data).map_err(|e| bad(e.to_string()))?;
            let (lo, hi) = (f64::from(m.range_min), f64::from(m.range_max));
            let ranges = m
                .ranges
                .iter()
                .map(|&r| {
                    let r = f64::from(r);
                    if r.is_finite() && r >= lo && r <= hi && r > 0.0 {
                        r
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            let t = m.header.stamp.seconds();
            raw.push((
                t,
                m.header.frame_id.clone(),
                Scan {
                    t_s: t,
                    world_from_sensor: nalgebra::Isometry3::identity(),
                    angle_min_rad: f64::from(m.angle_min),
                    angle_increment_rad: f64::from(m.angle_increment),
                    ranges,
                },
            ));
        } else if ty == Some(Ros2Type::TfMessage) && channel.message_encoding == "cdr" {
            if let Ok(m) = TfMessage::decode(&message.data) {
                for x in m.transforms {
                    *pairs
                        .entry((x.header.frame_id.clone(), x.child_frame_id.clone()))
                        .or_insert(0) += 1;
                    if x.header.frame_id == fixed_frame {
                        if let Ok((pose, _)) =
                            pose_from_translation_quaternion(x.translation, x.rotation)
                        {
                            tf.entry(x.child_frame_id)
                                .or_default()
                                .push((x.header.stamp.seconds(), pose));
                        }
                    }
                }
            }
        }
        Ok(true)
    })?;
    if raw.is_empty() {
        return Err(DatasetError::invalid(
            path,
            format!("no LaserScan message on {topic}"),
        ));
    }
    let mut trajectories: BTreeMap<String, Trajectory> = BTreeMap::new();
    for (frame, mut poses) in tf {
        poses.sort_by(|a, b| a.0.total_cmp(&b.0));
        poses.dedup_by(|a, b| a.0 == b.0);
        let (t, p) = poses.into_iter().unzip();
        if let Ok(traj) = Trajectory::from_parts(t, p) {
            trajectories.insert(frame, traj);
        }
    }
    raw.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = Vec::with_capacity(raw.len());
    let mut unplaced = 0;
    for (t, frame, mut scan) in raw {
        match trajectories
            .get(&frame)
            .and_then(|traj| traj.interpolate(t))
        {
            Some(pose) => {
                scan.world_from_sensor = pose;
                out.push(scan);
            }
            None => unplaced += 1,
        }
    }
    if out.is_empty() {
        let listed: Vec<String> = pairs.keys().map(|(p, c)| format!("{p} -> {c}")).collect();
        return Err(DatasetError::invalid(
            path,
            format!(
                "no scan of {topic} could be placed: no transform from {fixed_frame} to the \
                 scans' frame at their times (transforms in the log: {})",
                if listed.is_empty() {
                    "none".to_owned()
                } else {
                    listed.join(", ")
                }
            ),
        ));
    }
    Ok((out, unplaced))
}

/// Writes `scans` as an MCAP log (a temporary sibling renamed into place): each scan a
/// `sensor_msgs/LaserScan` on `topic` in frame `sensor_frame`, and its pose a
/// `tf2_msgs/TFMessage` transform `fixed_frame -> sensor_frame` on `/tf` at the same stamp.
/// Ranges are written as f32; no return is NaN.
pub fn write_laser_scans(
    path: &Path,
    scans: &[Scan],
    topic: &str,
    fixed_frame: &str,
    sensor_frame: &str,
) -> Result<(), DatasetError> {
    let options = ::mcap::WriteOptions::new()
        .profile("ros2")
        .compression(Some(::mcap::Compression::Zstd));
    write_log(path, options, |w| {
        let ch_scan = w.add_ros2_channel(Ros2Type::LaserScan, topic, &[])?;
        let ch_tf = w.add_ros2_channel(Ros2Type::TfMessage, "/tf", &[])?;
        for s in scans {
            let stamp = Time::from_seconds(s.t_s);
            let (translation, rotation) =
                stride_core::pose::pose_to_translation_quaternion(&s.world_from_sensor);
            let tf = TfMessage {
                transforms: vec![TransformStamped {
                    header: Header {
                        stamp,
                        frame_id: fixed_frame.into(),
                    },
                    child_frame_id: sensor_frame.into(),
                    translation,
                    rotation,
                }],
            };
            let n = s.ranges.len().max(1) as f32;
            let scan = LaserScanMsg {
                header: Header {
                    stamp,
                    frame_id: sensor_frame.into(),
                },
                angle_min: s.angle_min_rad as f32,
                angle_max: (s.angle_min_rad + (n - 1.0) as f64 * s.angle_increment_rad) as f32,
                angle_increment: s.angle_increment_rad as f32,
                time_increment: 0.0,
                scan_time: 0.1,
                range_min: 0.02,
                range_max: 5.6,
                ranges: s
                    .ranges
                    .iter()
                    .map(|&r| {
                        if r.is_finite() && r > 0.0 {
                            r as f32
                        } else {
                            f32::NAN
                        }
                    })
                    .collect(),
                intensities: Vec::new(),
            };
            w.write(ch_tf, stamp.nanos(), &tf.encode())?;
            w.write(ch_scan, stamp.nanos(), &scan.encode())?;
        }
        Ok(())
    })
}
