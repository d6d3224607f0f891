//! # stride-datasets
//!
//! Where stride's data comes from and goes to:
//!
//! * [`trajectory_file`]: TUM trajectory files (`t tx ty tz qx qy qz qw`), read with errors
//!   that name the file and line, written atomically.
//! * [`camera_config`]: camera presets (TUM fr1/fr2/fr3) and camera files (JSON, TOML,
//!   YAML) holding intrinsics, image size, depth scale and optional distortion.
//! * [`tum`]: TUM RGB-D sequence folders (`rgb.txt`, `depth.txt`, `groundtruth.txt`),
//!   rgb/depth association as TUM's `associate.py`, and a frame iterator that decodes PNGs
//!   ahead on a background thread.
//! * [`mcap`]: MCAP logs (ROS 2 CDR messages) as RGB-D sequences, and TUM folders converted
//!   to and from them.
//! * [`sequence`]: either source as one [`sequence::Sequence`].
//! * [`scan_log`]: 2-D range scans with their poses as text (paper 003's sensors).
//! * [`png_io`]: PNG decoding and encoding for colour and 16-bit depth images.
//! * [`grid_file`]: the grid format (`.npy` float32 layers + a JSON header) shared by the
//!   synthetic ground truth and the elevation mapper.
//! * [`synth`]: the synthetic legged-robot RGB-D generator with ground truth.
//! * [`motion_blur`]: recorded frames blurred along each pixel's image motion from their
//!   ground truth (the real side of the blur study).

pub mod accelerometer;
pub mod camera_config;
pub mod error;
pub mod grid_file;
pub mod mcap;
pub mod motion_blur;
pub mod orbslam_settings;
pub mod png_io;
pub mod scan_log;
pub mod sequence;
pub mod stream;
pub mod synth;
pub mod text;
pub mod trajectory_file;
pub mod tum;

pub use camera_config::CameraConfig;
pub use error::DatasetError;
