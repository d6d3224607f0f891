//! # stride-backend
//!
//! The back end of stride's SLAM, after PUT SLAM (paper 004, section 3.1): a persistent map
//! of 3-D point features and keyframes, fed with the frontend's keyframes, optimized by
//! bundle adjustment with 3-D Euclidean errors weighted by each measurement's information
//! matrix (eq. 1).
//!
//! * [`map`]: keyframes (pose, features, covisibility), points (position, descriptor,
//!   observations) and the bookkeeping between them.
//! * [`matching`]: ORB matching of map points near their predicted projections, gated by
//!   Hamming distance, Lowe's ratio and the 3-D Mahalanobis distance.
//! * [`ba`]: the optimization problem, Levenberg-Marquardt with the Schur complement, and
//!   the reduced camera system on faer's sparse Cholesky.
//! * [`Backend`] ([`backend`]): per keyframe, associate (by track, then by ORB), add points,
//!   optimize a local window, cull; at the end, optimize everything.
//! * [`BackendThread`] ([`thread`]): the same in its own thread, over channels.
//! * [`loop_closure`]: a keyframe that sees a place mapped long before is matched to it,
//!   verified, and the loop's drift corrected (pose graph, then point fusion and BA).
//! * [`revisit`]: a new keyframe's depth aligned with an old keyframe's near it, the
//!   relative pose kept as an edge, so that passes over the same place are tied.
//! * [`SavedMap`] ([`map_file`]): a map saved to a file, read back and checked, for a later
//!   run to localize in and extend.
//!
//! Frames: every pose is `world_from_camera` (camera x right, y down, z forward); points
//! are `p_world`; units are metres and radians. Deterministic: every collection is iterated
//! in identifier order and the optimizer's parallel sums have a fixed order.

mod associate;
pub mod ba;
pub mod backend;
#[cfg(test)]
mod backend_tests;
pub mod config;
mod culling;
pub mod error;
pub mod loop_closure;
pub mod map;
pub mod map_file;
pub mod map_file_places;
pub mod matching;
mod pose_graph;
pub mod revisit;
pub mod se3;
pub mod thread;
mod window;

pub use backend::{Backend, KeyframeInput, KeyframeReport, KeyframeUpdate};
pub use config::{BackendConfig, BackendMode};
pub use error::BackendError;
pub use loop_closure::{LoopParams, LoopReport};
pub use map_file::{MapFileError, SavedMap};
pub use revisit::RevisitConfig;
pub use thread::{BackendThread, Finished};
