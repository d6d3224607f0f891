//! stride-frontend: keypoints, KLT tracking, ORB descriptors, Umeyama + RANSAC visual odometry.
//!
//! Empty for now: the front end is built in its own issue.
