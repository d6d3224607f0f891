//! An RGB-D sequence from either source stride reads: a TUM folder or an MCAP log.

use crate::accelerometer::AccelSample;
use crate::camera_config::CameraConfig;
use crate::error::DatasetError;
use crate::mcap::{McapSequence, McapTopics};
use crate::stream::FrameStream;
use crate::tum::{AssociationOptions, TumSequence};
use std::path::Path;
use stride_core::trajectory::Trajectory;

/// An opened RGB-D sequence.
#[derive(Debug, Clone)]
pub enum Sequence {
    /// A TUM RGB-D folder.
    Tum(TumSequence),
    /// An MCAP log of ROS 2 messages.
    Mcap(McapSequence),
}

impl Sequence {
    /// Opens `path`: a file ending in `.mcap` as a log (with `topics`), anything else as a
    /// TUM folder. `camera` is a preset or camera file (see [`TumSequence::open`] and
    /// [`McapSequence::open`]).
    pub fn open(
        path: &Path,
        camera: Option<&str>,
        assoc: AssociationOptions,
        topics: &McapTopics,
    ) -> Result<Self, DatasetError> {
        if is_mcap(path) {
            McapSequence::open(path, topics, camera, assoc).map(Self::Mcap)
        } else {
            TumSequence::open(path, camera, assoc).map(Self::Tum)
        }
    }

    /// The folder or file.
    pub fn path(&self) -> &Path {
        match self {
            Self::Tum(s) => &s.dir,
            Self::Mcap(s) => &s.path,
        }
    }

    /// The camera the frames are decoded with.
    pub fn camera(&self) -> &CameraConfig {
        match self {
            Self::Tum(s) => &s.camera,
            Self::Mcap(s) => &s.camera,
        }
    }

    /// Where the camera came from, for reports.
    pub fn camera_source(&self) -> String {
        match self {
            Self::Tum(s) => s.camera_source.to_string(),
            Self::Mcap(s) => s.camera_source.clone(),
        }
    }

    /// The ground truth (`world_from_camera`), when the sequence has one.
    pub fn groundtruth(&self) -> Option<&Trajectory> {
        match self {
            Self::Tum(s) => s.groundtruth.as_ref(),
            Self::Mcap(s) => s.groundtruth.as_ref(),
        }
    }

    /// The accelerometer samples (specific force in the camera frame), when present.
    pub fn accelerometer(&self) -> Option<&[AccelSample]> {
        match self {
            Self::Tum(s) => s.accelerometer.as_deref(),
            Self::Mcap(s) => s.accelerometer.as_deref(),
        }
    }

    /// The gyroscope samples (angular velocity in the camera frame), when present.
    pub fn gyroscope(&self) -> Option<&[crate::accelerometer::GyroSample]> {
        match self {
            Self::Tum(s) => s.gyroscope.as_deref(),
            Self::Mcap(s) => s.gyroscope.as_deref(),
        }
    }

    /// Number of associated frames.
    pub fn len(&self) -> usize {
        match self {
            Self::Tum(s) => s.len(),
            Self::Mcap(s) => s.len(),
        }
    }

    /// True when there is no frame (never, for a successfully opened sequence).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Colour time (s) of frame `index`.
    pub fn frame_time_s(&self, index: usize) -> Option<f64> {
        match self {
            Self::Tum(s) => s.frames.get(index).map(|f| f.t_rgb_s),
            Self::Mcap(s) => s.frames.get(index).map(|f| f.t_rgb_s),
        }
    }

    /// Depth time (s) of every frame, in order.
    pub fn depth_times_s(&self) -> Vec<f64> {
        match self {
            Self::Tum(s) => s.frames.iter().map(|f| f.t_depth_s).collect(),
            Self::Mcap(s) => s.frames.iter().map(|f| f.t_depth_s).collect(),
        }
    }

    /// Colour images left without a depth partner.
    pub fn unmatched_rgb(&self) -> usize {
        match self {
            Self::Tum(s) => s.unmatched_rgb,
            Self::Mcap(s) => s.unmatched_rgb,
        }
    }

    /// Frames `indices` (ascending) decoded ahead on a background thread, each keeping its
    /// index; the others are not decoded.
    pub fn stream_frames(&self, indices: Vec<usize>, prefetch: usize) -> FrameStream {
        match self {
            Self::Tum(s) => s.stream_frames(indices, prefetch),
            Self::Mcap(s) => s.stream_frames(indices, prefetch),
        }
    }

    /// Frames decoded ahead on a background thread (see [`TumSequence::stream`]).
    pub fn stream(&self, max_frames: Option<usize>, prefetch: usize) -> FrameStream {
        match self {
            Self::Tum(s) => s.stream(max_frames, prefetch),
            Self::Mcap(s) => s.stream(max_frames, prefetch),
        }
    }
}

/// Whether `path` names an MCAP log (by its extension).
pub fn is_mcap(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}
