//! stride-backend: feature map, keyframes, bundle adjustment (faer sparse), loop closure.
//!
//! Empty for now: the back end is built in its own issue.
