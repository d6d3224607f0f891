//! A run's results as an MCAP log that Foxglove shows in 3-D: Foxglove's schemas
//! (`foxglove.FrameTransform`, `foxglove.PosesInFrame`, `foxglove.PointCloud`,
//! `foxglove.Grid`) in JSON encoding, every pose and point in one world frame (z up, m).
//!
//! Topics: [`TF_TOPIC`] carries `world_from_camera` of every frame at its time (parent
//! [`WORLD_FRAME`], child [`CAMERA_FRAME`]); at the last frame's time [`TRAJECTORY_TOPIC`]
//! holds the whole camera path and [`KEYFRAMES_TOPIC`] the keyframes' poses,
//! [`POINTS_TOPIC`] the feature map's points, and [`ELEVATION_TOPIC`] the elevation map
//! (fields `elevation` and `variance`, float32, NaN where unknown; rows along +y, columns
//! along +x, the grid's pose at the corner of cell (0, 0)).

use super::writer::{write_log, LogWriter};
use crate::error::DatasetError;
use base64::Engine as _;
use nalgebra::{Isometry3, Point3};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::Path;
use stride_core::grid::Grid;
use stride_core::pose::{pose_to_translation_quaternion, Pose};

/// The world frame's id.
pub const WORLD_FRAME: &str = "world";
/// The camera frame's id (x right, y down, z forward).
pub const CAMERA_FRAME: &str = "camera";
/// Per-frame camera transforms.
pub const TF_TOPIC: &str = "/tf";
/// The camera path.
pub const TRAJECTORY_TOPIC: &str = "/stride/trajectory";
/// The keyframes' poses.
pub const KEYFRAMES_TOPIC: &str = "/stride/keyframes";
/// The feature map's points.
pub const POINTS_TOPIC: &str = "/stride/map_points";
/// The elevation map.
pub const ELEVATION_TOPIC: &str = "/stride/elevation";

/// What a run hands to [`write_run_log`], all in the world frame.
pub struct RunLog<'a> {
    /// `(t s, world_from_camera)` of every frame, in time order.
    pub poses: &'a [(f64, Pose)],
    /// `(t s, world_from_camera)` of the keyframes.
    pub keyframes: &'a [(f64, Pose)],
    /// The feature map's points (m).
    pub points_world: &'a [Point3<f64>],
    /// The elevation map's height (m) and height variance (m²) layers, same geometry.
    pub elevation: Option<(&'a Grid<f32>, &'a Grid<f32>)>,
}

fn time(t_s: f64) -> Value {
    let t = super::ros2::Time::from_seconds(t_s);
    json!({"sec": t.sec, "nsec": t.nanosec})
}

fn pose_json(p: &Pose) -> Value {
    let (t, q) = pose_to_translation_quaternion(p);
    json!({
        "position": {"x": t[0], "y": t[1], "z": t[2]},
        "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    })
}

fn vec3() -> Value {
    json!({"type": "object", "properties": {
        "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}})
}

fn quaternion() -> Value {
    json!({"type": "object", "properties": {
        "x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"},
        "w": {"type": "number"}}})
}

fn timestamp() -> Value {
    json!({"type": "object", "properties": {
        "sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}})
}

fn pose_schema() -> Value {
    json!({"type": "object", "properties": {"position": vec3(), "orientation": quaternion()}})
}

fn fields_schema() -> Value {
    json!({"type": "array", "items": {"type": "object", "properties": {
        "name": {"type": "string"}, "offset": {"type": "integer"},
        "type": {"type": "integer", "description": "numeric type: 7 float32, 8 float64"}}}})
}

/// The JSON Schema of a Foxglove message type, as written in the log's schema record.
fn schema(name: &str) -> Value {
    let properties = match name {
        "foxglove.FrameTransform" => json!({
            "timestamp": timestamp(), "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"}, "translation": vec3(),
            "rotation": quaternion()}),
        "foxglove.PosesInFrame" => json!({
            "timestamp": timestamp(), "frame_id": {"type": "string"},
            "poses": {"type": "array", "items": pose_schema()}}),
        "foxglove.PointCloud" => json!({
            "timestamp": timestamp(), "frame_id": {"type": "string"}, "pose": pose_schema(),
            "point_stride": {"type": "integer"}, "fields": fields_schema(),
            "data": {"type": "string", "contentEncoding": "base64"}}),
        _ => json!({
            "timestamp": timestamp(), "frame_id": {"type": "string"}, "pose": pose_schema(),
            "column_count": {"type": "integer"},
            "cell_size": {"type": "object", "properties": {
                "x": {"type": "number"}, "y": {"type": "number"}}},
            "row_stride": {"type": "integer"}, "cell_stride": {"type": "integer"},
            "fields": fields_schema(),
            "data": {"type": "string", "contentEncoding": "base64"}}),
    };
    json!({"title": name, "type": "object", "properties": properties})
}

/// Float32 field type in Foxglove's `PackedElementField`.
const FLOAT32: u32 = 7;

/// Writes `run` as an MCAP log at `path` (a temporary sibling renamed into place).
pub fn write_run_log(path: &Path, run: &RunLog) -> Result<(), DatasetError> {
    let options = ::mcap::WriteOptions::new().compression(Some(::mcap::Compression::Zstd));
    write_log(path, options, |w| fill_log(w, run))
}

fn fill_log(w: &mut LogWriter, run: &RunLog) -> Result<(), DatasetError> {
    let mut channels: BTreeMap<&str, u16> = BTreeMap::new();
    let mut put = |w: &mut LogWriter, topic: &'static str, ty: &str, t_s: f64, msg: Value| {
        let ch = match channels.get(topic) {
            Some(&c) => c,
            None => {
                let s = schema(ty).to_string();
                let c = w.add_channel(ty, "jsonschema", s.as_bytes(), topic, "json", &[])?;
                channels.insert(topic, c);
                c
            }
        };
        let ns = super::ros2::Time::from_seconds(t_s).nanos();
        w.write(ch, ns, msg.to_string().as_bytes())
    };
    for (t, p) in run.poses {
        let (tr, q) = pose_to_translation_quaternion(p);
        put(
            w,
            TF_TOPIC,
            "foxglove.FrameTransform",
            *t,
            json!({
                "timestamp": time(*t), "parent_frame_id": WORLD_FRAME, "child_frame_id": CAMERA_FRAME,
                "translation": {"x": tr[0], "y": tr[1], "z": tr[2]},
                "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
            }),
        )?;
    }
    let t_end = run.poses.last().map_or(0.0, |p| p.0);
    for (topic, poses) in [
        (TRAJECTORY_TOPIC, run.poses),
        (KEYFRAMES_TOPIC, run.keyframes),
    ] {
        let poses: Vec<Value> = poses.iter().map(|(_, p)| pose_json(p)).collect();
        put(
            w,
            topic,
            "foxglove.PosesInFrame",
            t_end,
            json!({
                "timestamp": time(t_end), "frame_id": WORLD_FRAME, "poses": poses,
            }),
        )?;
    }
    let identity = pose_json(&Isometry3::identity());
    let mut xyz = Vec::with_capacity(run.points_world.len() * 12);
    for p in run.points_world {
        for v in [p.x, p.y, p.z] {
            xyz.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    let b64 = base64::engine::general_purpose::STANDARD;
    put(
        w,
        POINTS_TOPIC,
        "foxglove.PointCloud",
        t_end,
        json!({
            "timestamp": time(t_end), "frame_id": WORLD_FRAME, "pose": identity,
            "point_stride": 12,
            "fields": [
                {"name": "x", "offset": 0, "type": FLOAT32},
                {"name": "y", "offset": 4, "type": FLOAT32},
                {"name": "z", "offset": 8, "type": FLOAT32},
            ],
            "data": b64.encode(&xyz),
        }),
    )?;
    if let Some((height, variance)) = run.elevation {
        let g = height.geometry;
        let mut cells = Vec::with_capacity(g.len() * 8);
        for (h, v) in height.as_slice().iter().zip(variance.as_slice()) {
            cells.extend_from_slice(&h.to_le_bytes());
            cells.extend_from_slice(&v.to_le_bytes());
        }
        let corner = Isometry3::translation(
            g.origin_x - g.resolution / 2.0,
            g.origin_y - g.resolution / 2.0,
            0.0,
        );
        put(
            w,
            ELEVATION_TOPIC,
            "foxglove.Grid",
            t_end,
            json!({
                "timestamp": time(t_end), "frame_id": WORLD_FRAME, "pose": pose_json(&corner),
                "column_count": g.cols,
                "cell_size": {"x": g.resolution, "y": g.resolution},
                "row_stride": g.cols * 8, "cell_stride": 8,
                "fields": [
                    {"name": "elevation", "offset": 0, "type": FLOAT32},
                    {"name": "variance", "offset": 4, "type": FLOAT32},
                ],
                "data": b64.encode(&cells),
            }),
        )?;
    }
    Ok(())
}
