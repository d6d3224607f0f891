//! # stride-core
//!
//! The conventions every other stride crate shares:
//!
//! * [`pose`]: rigid transforms named `b_from_a` (they map points expressed in frame `a` into
//!   frame `b`), e.g. `world_from_camera`; metres and radians throughout.
//! * [`trajectory`]: time-stamped poses (seconds), sorted by time, with interpolation.
//! * [`geometry`]: Umeyama's closed-form alignment of two point sets (SE(3) or Sim(3)).
//! * [`plane`]: least-squares and RANSAC planes (the floor gives the direction of gravity).
//! * [`camera`]: the pinhole camera with Brown-Conrady distortion; the camera frame is
//!   x right, y down, z forward (OpenCV/TUM).
//! * [`image`] and [`frame`]: plain image buffers and the RGB-D frame (depth in metres).
//! * [`grid`]: regular x-y grids (elevation maps, ground-truth terrain), z up.
//! * [`rng`]: seeded and counter-based random numbers (reproducible runs).
//! * [`robust`]: Huber's kernel (weight and cost) for the estimators.
//! * [`time`]: timestamps (seconds) and the TUM and evo rules for associating them.
//! * [`uncertainty`]: per-point 3x3 covariances of RGB-D measurements (PrimeSense model).
//! * [`simd`]: loops written to vectorise run a copy compiled for AVX2 where the CPU has it.
//! * [`parallel`]: a thread's own rayon pool, for the threads that start parallel stages.
//!
//! This crate holds types and models only (no file I/O) and depends on nalgebra (and
//! `pulp` for [`simd`], `rayon` for [`parallel`]), so that mapping and evaluation can serve
//! any SLAM.

pub mod camera;
pub mod frame;
pub mod geometry;
pub mod grid;
pub mod image;
pub mod parallel;
pub mod plane;
pub mod pose;
pub mod range_sensor;
pub mod rng;
pub mod robust;
pub mod scan;
pub mod serde_opt;
pub mod simd;
pub mod time;
pub mod trajectory;
pub mod uncertainty;

pub use nalgebra;

/// The message of a thread's panic (`JoinHandle::join`'s error), for errors that report a
/// dead worker thread.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}
