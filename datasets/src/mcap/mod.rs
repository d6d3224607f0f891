//! MCAP logs (the ROS 2 bag format) as RGB-D sequences, and TUM folders converted to and
//! from them.
//!
//! A log is read in one streaming pass when it is opened ([`McapSequence::open`]): the
//! stamps of the colour and depth topics (from each message's `header.stamp`), the camera
//! from a `sensor_msgs/CameraInfo` topic, the accelerometer and the gyroscope from a
//! `sensor_msgs/Imu` topic (a field whose covariance starts with -1 is not given) and a
//! ground truth from `tf2_msgs/TFMessage` transforms between two named frames. Colour
//! and depth are then paired by time as TUM's `associate.py` pairs a folder's images, and
//! [`McapSequence::stream`] decodes the pairs ahead on a background thread in a second
//! streaming pass. Memory is bounded by the messages waiting for their partner, not by the
//! file's size. Indexed and unindexed files are read the same way; chunks compressed with
//! zstd or lz4 are supported.
//!
//! Topics are chosen by name ([`McapTopics`]); their defaults are the names
//! [`convert::tum_to_mcap`] writes (TUM's own ROS bags' names). A missing topic, a message
//! in another encoding than CDR, or a schema that is not an image is an error naming the
//! topic (and the message's index among its topic's messages).

pub mod cdr;
pub mod convert;
pub mod foxglove;
pub mod images;
pub mod laser;
pub mod ros2;
mod scan;
pub mod schema;
mod writer;

use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use crate::stream::{DecodedFrame, FrameFailure, FrameStream};
use crate::tum::AssociationOptions;
use images::ImagePayload;
use ros2::{CompressedImageMsg, ImageMsg};
pub use scan::{summarize, LogSummary, TopicSummary};
use schema::Ros2Type;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_core::frame::RgbdFrame;
use stride_core::time::associate_greedy;
use stride_core::trajectory::Trajectory;

/// Default colour topic (as TUM's ROS bags and `stride convert`).
pub const DEFAULT_RGB_TOPIC: &str = "/camera/rgb/image_color";
/// Default depth topic.
pub const DEFAULT_DEPTH_TOPIC: &str = "/camera/depth/image";
/// Default camera-info topic.
pub const DEFAULT_CAMERA_INFO_TOPIC: &str = "/camera/rgb/camera_info";
/// Default IMU topic.
pub const DEFAULT_IMU_TOPIC: &str = "/imu";
/// Topic of the transforms `stride convert` writes the ground truth on.
pub const TF_TOPIC: &str = "/tf";
/// Parent frame of the ground truth `stride convert` writes.
pub const GROUNDTRUTH_PARENT: &str = "world";
/// Child frame of the ground truth `stride convert` writes (the colour camera's optical
/// frame, x right, y down, z forward).
pub const GROUNDTRUTH_CHILD: &str = "groundtruth";
/// Channel metadata key giving a 16-bit depth topic's units per metre (stride writes it;
/// without it REP 118's millimetres apply).
pub const DEPTH_UNITS_KEY: &str = "depth_units_per_m";
/// REP 118: 16-bit depth images hold millimetres.
pub const REP118_DEPTH_UNITS_PER_M: f64 = 1000.0;

/// Which topics of a log make the sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct McapTopics {
    /// Colour images (`sensor_msgs/Image` or `CompressedImage`).
    pub rgb: String,
    /// Depth images, registered to the colour camera.
    pub depth: String,
    /// The colour camera's `sensor_msgs/CameraInfo`; `None`: [`DEFAULT_CAMERA_INFO_TOPIC`]
    /// when the log has it (a camera given to [`McapSequence::open`] wins over either).
    pub camera_info: Option<String>,
    /// `sensor_msgs/Imu` whose linear acceleration is the specific force in the colour
    /// camera's optical frame; `None`: [`DEFAULT_IMU_TOPIC`] when the log has it and its
    /// `frame_id` is the colour images' (no extrinsics are applied).
    pub imu: Option<String>,
    /// Ground truth: the transforms from this parent frame to this child frame
    /// (`world_from_camera`); `None`: [`GROUNDTRUTH_PARENT`] to [`GROUNDTRUTH_CHILD`] when
    /// the log has them.
    pub groundtruth_tf: Option<(String, String)>,
    /// Units per metre of 16-bit depth; `None`: the depth channel's [`DEPTH_UNITS_KEY`],
    /// else [`REP118_DEPTH_UNITS_PER_M`].
    pub depth_units_per_m: Option<f64>,
}

impl Default for McapTopics {
    fn default() -> Self {
        Self {
            rgb: DEFAULT_RGB_TOPIC.into(),
            depth: DEFAULT_DEPTH_TOPIC.into(),
            camera_info: None,
            imu: None,
            groundtruth_tf: None,
            depth_units_per_m: None,
        }
    }
}

/// One colour/depth pair of a log: stamps and each message's index among its topic's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct McapFrame {
    /// Colour image time (s).
    pub t_rgb_s: f64,
    /// Depth image time (s).
    pub t_depth_s: f64,
    /// Index of the colour message among the colour topic's messages (file order).
    pub rgb_message: usize,
    /// Index of the depth message among the depth topic's messages.
    pub depth_message: usize,
}

/// An opened MCAP log as an RGB-D sequence.
#[derive(Debug, Clone)]
pub struct McapSequence {
    /// The file.
    pub path: PathBuf,
    /// The topics read (defaults resolved).
    pub topics: McapTopics,
    /// Intrinsics, image size and the depth topic's units per metre.
    pub camera: CameraConfig,
    /// Where the camera came from, for reports.
    pub camera_source: String,
    /// Associated colour/depth pairs, in time order.
    pub frames: Vec<McapFrame>,
    /// The ground truth (`world_from_camera`), when the log has it.
    pub groundtruth: Option<Trajectory>,
    /// The accelerometer (specific force in the camera frame), when the log has it.
    pub accelerometer: Option<Vec<crate::accelerometer::AccelSample>>,
    /// The gyroscope (angular velocity in the camera frame), when the log's IMU messages
    /// carry it.
    pub gyroscope: Option<Vec<crate::accelerometer::GyroSample>>,
    /// Colour images left without a depth partner.
    pub unmatched_rgb: usize,
    /// Whether the colour and the depth topics carry `CompressedImage`s.
    compressed: [bool; 2],
}

impl McapSequence {
    /// Reads the log's stamps, camera, accelerometer and ground truth, and pairs colour
    /// with depth. `camera` (a preset or a camera file) overrides the log's camera info;
    /// its depth scale is not used (16-bit depth units come from the log, see
    /// [`McapTopics::depth_units_per_m`]).
    pub fn open(
        path: &Path,
        topics: &McapTopics,
        camera: Option<&str>,
        assoc: AssociationOptions,
    ) -> Result<Self, DatasetError> {
        let scanned = scan::scan_sequence(path, topics)?;
        let units = topics
            .depth_units_per_m
            .or(scanned.depth_units_per_m)
            .unwrap_or(REP118_DEPTH_UNITS_PER_M);
        if !(units.is_finite() && units > 0.0) {
            return Err(DatasetError::invalid(
                path,
                format!("depth units per metre must be positive, not {units}"),
            ));
        }
        let (mut camera, camera_source) = match (camera, scanned.camera) {
            (Some(spec), _) => (CameraConfig::resolve(spec)?, format!("{spec} (requested)")),
            (None, Some((config, topic))) => (config, format!("{topic} (camera info)")),
            (None, None) => {
                return Err(DatasetError::invalid(
                    path,
                    format!(
                        "no camera: the log has no camera info on {} and none was given \
                         (pass --camera fr1|fr2|fr3|FILE or --camera-info-topic)",
                        topics
                            .camera_info
                            .as_deref()
                            .unwrap_or(DEFAULT_CAMERA_INFO_TOPIC)
                    ),
                ))
            }
        };
        camera.depth_scale = units;
        let t_rgb: Vec<f64> = scanned.rgb.iter().map(|s| s.0).collect();
        let t_depth: Vec<f64> = scanned.depth.iter().map(|s| s.0).collect();
        let pairs = associate_greedy(&t_rgb, &t_depth, assoc.offset_s, assoc.max_diff_s);
        let frames: Vec<McapFrame> = pairs
            .iter()
            .filter_map(|&(i, j)| {
                let (tr, mr) = scanned.rgb.get(i)?;
                let (td, md) = scanned.depth.get(j)?;
                Some(McapFrame {
                    t_rgb_s: *tr,
                    t_depth_s: *td,
                    rgb_message: *mr,
                    depth_message: *md,
                })
            })
            .collect();
        if frames.is_empty() {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "no colour image of {} has a depth image of {} within {} s ({} colour, \
                     {} depth messages)",
                    topics.rgb,
                    topics.depth,
                    assoc.max_diff_s,
                    t_rgb.len(),
                    t_depth.len()
                ),
            ));
        }
        Ok(Self {
            path: path.to_path_buf(),
            topics: scanned.topics,
            camera,
            camera_source,
            unmatched_rgb: t_rgb.len() - frames.len(),
            frames,
            groundtruth: scanned.groundtruth,
            accelerometer: scanned.accelerometer,
            gyroscope: scanned.gyroscope,
            compressed: [scanned.rgb_compressed, scanned.depth_compressed],
        })
    }

    /// Number of associated frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when the sequence has no frame (never, for a successfully opened log).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Decodes frames `0..max_frames` (all when `None`) on a background thread that reads
    /// the log once more, keeping up to `prefetch` decoded frames ready. A frame whose
    /// message cannot be decoded is reported in place (naming topic and message index); a
    /// log that can no longer be read ends the stream with
    /// [`crate::stream::StreamError::Stopped`] after a failure naming the cause.
    pub fn stream(&self, max_frames: Option<usize>, prefetch: usize) -> FrameStream {
        let n = max_frames.map_or(self.frames.len(), |m| m.min(self.frames.len()));
        self.stream_frames((0..n).collect(), prefetch)
    }

    /// As [`Self::stream`], for the frames `indices` only (ascending; others are skipped
    /// without being decoded). Each frame keeps its index in the sequence.
    pub fn stream_frames(&self, indices: Vec<usize>, prefetch: usize) -> FrameStream {
        let seq = self.clone();
        FrameStream::spawn(&self.path, indices.len(), prefetch, move |tx| {
            seq.decode_frames(&indices, &tx)
        })
    }

    /// The decoder thread's loop: frames `indices` in order, sent through `tx`.
    fn decode_frames(
        &self,
        indices: &[usize],
        tx: &std::sync::mpsc::SyncSender<crate::stream::Decoded>,
    ) {
        let n = indices.len();
        // Message index on its topic -> position in `indices`.
        let mut rgb_of: HashMap<usize, usize> = HashMap::new();
        let mut depth_of: HashMap<usize, usize> = HashMap::new();
        for (position, f) in indices
            .iter()
            .enumerate()
            .filter_map(|(p, &i)| Some((p, self.frames.get(i)?)))
        {
            rgb_of.insert(f.rgb_message, position);
            depth_of.insert(f.depth_message, position);
        }
        // Messages waiting for their partner or for earlier frames, by position.
        let mut pending: BTreeMap<usize, Halves> = BTreeMap::new();
        let mut next = 0usize;
        let mut counts = [0usize; 2];
        // Reading time since the last frame went out, charged to the next one.
        let mut read_s = 0.0;
        let mut last = Instant::now();
        let result = scan::for_each_message(&self.path, |message| {
            read_s += last.elapsed().as_secs_f64();
            let topic = message.channel.topic.as_str();
            let which = if topic == self.topics.rgb {
                0
            } else if topic == self.topics.depth {
                1
            } else {
                last = Instant::now();
                return Ok(next < n);
            };
            let k = counts[which];
            counts[which] += 1;
            let Some(&position) = [&rgb_of, &depth_of][which].get(&k) else {
                last = Instant::now();
                return Ok(next < n);
            };
            let entry = pending.entry(position).or_default();
            entry.0[which] = Some(message.data.into_owned());
            while let Some(Halves([Some(_), Some(_)])) = pending.get(&next) {
                let Some(Halves([Some(rgb), Some(depth)])) = pending.remove(&next) else {
                    break;
                };
                let index = indices.get(next).copied().unwrap_or(next);
                let start = Instant::now();
                let item = self
                    .decode_frame(index, &rgb, &depth)
                    .map(|frame| DecodedFrame {
                        frame,
                        decode_s: read_s + start.elapsed().as_secs_f64(),
                    })
                    .map_err(|error| FrameFailure { index, error });
                read_s = 0.0;
                if tx.send(item).is_err() {
                    return Ok(false); // the consumer hung up
                }
                next += 1;
            }
            last = Instant::now();
            Ok(next < n)
        });
        if let Err(error) = result {
            if let Some(&index) = indices.get(next) {
                let _ = tx.send(Err(FrameFailure { index, error }));
            }
        }
    }

    /// Decodes frame `index` from its colour and depth messages.
    fn decode_frame(
        &self,
        index: usize,
        rgb: &[u8],
        depth: &[u8],
    ) -> Result<RgbdFrame, DatasetError> {
        let f = self
            .frames
            .get(index)
            .ok_or_else(|| DatasetError::invalid(&self.path, format!("no frame #{index}")))?;
        let err = |topic: &str, k: usize, m: String| DatasetError::message(&self.path, topic, k, m);
        let rgb_payload = payload(rgb, self.compressed[0])
            .map_err(|m| err(&self.topics.rgb, f.rgb_message, m))?;
        let depth_payload = payload(depth, self.compressed[1])
            .map_err(|m| err(&self.topics.depth, f.depth_message, m))?;
        let rgb =
            images::rgb_image(&rgb_payload).map_err(|m| err(&self.topics.rgb, f.rgb_message, m))?;
        let depth_m = images::depth_image(&depth_payload, self.camera.depth_scale)
            .map_err(|m| err(&self.topics.depth, f.depth_message, m))?;
        let (w, h) = (self.camera.camera.width(), self.camera.camera.height());
        for (topic, k, iw, ih) in [
            (&self.topics.rgb, f.rgb_message, rgb.width(), rgb.height()),
            (
                &self.topics.depth,
                f.depth_message,
                depth_m.width(),
                depth_m.height(),
            ),
        ] {
            if (iw, ih) != (w, h) {
                return Err(err(
                    topic,
                    k,
                    format!("image is {iw}x{ih} but the camera is {w}x{h}"),
                ));
            }
        }
        Ok(RgbdFrame {
            index,
            t_s: f.t_rgb_s,
            t_depth_s: f.t_depth_s,
            rgb,
            depth_m,
        })
    }
}

/// The colour and depth messages of one frame, as they arrive.
#[derive(Default)]
struct Halves([Option<Vec<u8>>; 2]);

/// Decodes an image message as raw (`compressed == false`) or compressed.
pub fn payload(data: &[u8], compressed: bool) -> Result<ImagePayload<'_>, String> {
    if compressed {
        CompressedImageMsg::decode(data)
            .map(ImagePayload::Compressed)
            .map_err(|e| e.to_string())
    } else {
        ImageMsg::decode(data)
            .map(ImagePayload::Raw)
            .map_err(|e| e.to_string())
    }
}

/// Whether a schema is an image type stride reads: `Some(true)` compressed, `Some(false)`
/// raw.
pub fn image_kind(schema: &str) -> Option<bool> {
    match Ros2Type::from_name(schema)? {
        Ros2Type::Image => Some(false),
        Ros2Type::CompressedImage => Some(true),
        _ => None,
    }
}
