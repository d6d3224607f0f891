//! What the pipeline reports when it cannot go on: each stage's own error, with the frame
//! it happened at.

use stride_backend::BackendError;
use stride_core::trajectory::TrajectoryError;
use stride_datasets::error::DatasetError;
use stride_frontend::FrontendError;
use stride_mapping::MappingError;

/// Why the pipeline stopped.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The odometry could not be created from the camera and its configuration.
    #[error("creating the visual odometry: {0}")]
    Odometry(#[source] FrontendError),
    /// The odometry failed on a frame (not a tracking failure, which is a frame status).
    #[error("frame {index} ({t_s:.6} s): {source}")]
    Frontend {
        /// The frame's index in its sequence.
        index: usize,
        /// Its timestamp (s).
        t_s: f64,
        /// What went wrong.
        #[source]
        source: FrontendError,
    },
    /// The back end failed or its thread died.
    #[error("back end: {0}")]
    Backend(#[from] BackendError),
    /// The back end answered out of order (a bug, reported rather than hidden).
    #[error("the back end answered keyframe {answered} where {expected:?} was due")]
    BackendOrder {
        /// The keyframe it answered.
        answered: u64,
        /// The keyframe that was due (`None`: none was).
        expected: Option<u64>,
    },
    /// The elevation map's thread stopped: it panicked (the message) or failed.
    #[error("the elevation-map thread stopped unexpectedly: {0}")]
    MapThread(String),
    /// The elevation map refused its parameters or a frame.
    #[error("elevation map: {0}")]
    Mapping(#[from] MappingError),
    /// A configuration value is out of range.
    #[error("configuration: {key} = {value}: {allowed}")]
    Config {
        /// The key, as in the TOML configuration (`section.name`).
        key: String,
        /// The value given.
        value: String,
        /// What is allowed.
        allowed: &'static str,
    },
    /// A configuration file could not be read or parsed (an unknown key, a wrong type).
    #[error("configuration {path}: {message}")]
    ConfigFile {
        /// The file.
        path: String,
        /// What is wrong, with the line.
        message: String,
    },
    /// Frames came out of time order, so no trajectory can be made of them.
    #[error("frame {index} at {t_s:.6} s: {source}")]
    Trajectory {
        /// The frame's index.
        index: usize,
        /// Its timestamp (s).
        t_s: f64,
        /// What went wrong.
        #[source]
        source: TrajectoryError,
    },
    /// The sequence's frame decoder stopped before the end.
    #[error("reading the sequence: {0}")]
    Dataset(#[from] DatasetError),
}
