//! # stride
//!
//! RGB-D SLAM and 2.5-D elevation mapping for walking robots, as a library: feed
//! [`Pipeline`] one RGB-D frame at a time (as a robot's driver delivers them) and get each
//! frame's pose, and at the end the optimized trajectory and the elevation map built on it.
//!
//! * [`pipeline`]: the pipeline and its stages' glue: the SLAM (visual odometry with the
//!   back end in its own thread), the gravity-aligned world frame, the elevation map fed by
//!   keyframes at their optimized poses.
//! * [`config`]: every stage's parameters as one TOML file, with documented defaults and
//!   validation that names the key.
//! * [`eval_suite`]: trajectory evaluation for CI: suites of entries with limits, JUnit XML,
//!   Markdown summaries, comparisons between results.
//! * [`known_poses`]: elevation maps of a recorded sequence with known poses (ground truth
//!   or a trajectory file), several mappers side by side, scored against the true terrain.
//! * [`study`]: paper 004's study of gait-dependent motion blur, one gait, speed and seed at
//!   a time, on the synthetic lab.
//! * [`vocab`]: training the place-recognition vocabulary on the synthetic lab.
//!
//! The stages themselves live in the workspace's crates: `stride-frontend` (odometry),
//! `stride-backend` (feature map, bundle adjustment), `stride-mapping` (elevation maps),
//! `stride-datasets` (TUM folders, the synthetic lab), `stride-eval` (ATE/RPE).
//!
//! Frames: every pose is `world_from_camera`, the world z up and gravity-aligned in
//! metres, cameras with x right, y down, z forward. See ARCHITECTURE.md.

pub mod config;
pub mod eval_suite;
pub mod known_poses;
pub mod pipeline;
pub mod study;
pub mod vocab;

pub use pipeline::{
    run_sequence, FrameRecord, FrameStatus, MapOutput, Pipeline, PipelineConfig, PipelineError,
    PipelineOutput,
};
