//! # stride-backend
//!
//! The back end of stride's SLAM, after PUT SLAM (paper 004, section 3.1).

pub mod ba;
pub mod error;
pub mod se3;

pub use error::BackendError;
