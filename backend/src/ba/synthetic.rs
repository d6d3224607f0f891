//! Synthetic bundle-adjustment problems shaped like a local window of the SLAM: keyframes
//! along a walking camera's path, points in front of them, each point seen by a run of
//! consecutive keyframes (as KLT tracks are), with the PrimeSense model's depth-heavy
//! covariances and noise drawn from them. For benchmarks and tests.

use super::problem::{PointEdge, PointVar, PoseEdge, PoseVar, Problem};
use crate::se3::retract;
use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6,
};
use stride_core::rng::SplitMix64;

/// Shape of a synthetic problem.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticSpec {
    /// Keyframes (the first is fixed: the gauge).
    pub keyframes: usize,
    /// Points.
    pub points: usize,
    /// Fewest and most consecutive keyframes that see a point.
    pub track_length: (usize, usize),
    /// Add measurement noise drawn from each measurement's covariance.
    pub noise: bool,
    /// Standard deviations of the initial error of free poses (m, rad) and points (m).
    pub perturbation: (f64, f64, f64),
    /// Add an odometry pose-pose edge between consecutive keyframes.
    pub odometry_edges: bool,
    /// Seed.
    pub seed: u64,
}

impl Default for SyntheticSpec {
    fn default() -> Self {
        Self {
            keyframes: 10,
            points: 3000,
            track_length: (2, 6),
            noise: true,
            perturbation: (0.01, 0.01, 0.02),
            odometry_edges: false,
            seed: 1,
        }
    }
}

/// A synthetic problem and its true poses (`world_from_camera`) and points (`p_world`).
#[derive(Debug, Clone)]
pub struct Synthetic {
    /// The problem, perturbed away from the truth.
    pub problem: Problem,
    /// True poses.
    pub poses: Vec<Isometry3<f64>>,
    /// True points.
    pub points: Vec<Point3<f64>>,
}

/// A PrimeSense-like covariance (m^2, camera frame) of a point at depth `z_m`: about
/// 1.5 px laterally, depth standard deviation growing with the square of the depth.
pub fn sensor_covariance(z_m: f64) -> Matrix3<f64> {
    let lateral = (0.0028 * z_m).powi(2);
    let depth = (0.0015 + 0.0028 * z_m * z_m).powi(2);
    Matrix3::from_diagonal(&Vector3::new(lateral, lateral, depth))
}

/// Builds a problem as described by `spec`.
pub fn generate(spec: &SyntheticSpec) -> Synthetic {
    let mut rng = SplitMix64::new(spec.seed);
    let n = spec.keyframes.max(1);
    let poses: Vec<Isometry3<f64>> = (0..n)
        .map(|i| {
            let s = i as f64;
            Isometry3::from_parts(
                Translation3::new(0.08 * s, 0.01 * (0.7 * s).sin(), 0.03 * s),
                UnitQuaternion::from_euler_angles(0.02 * (0.9 * s).sin(), -0.05 * s, 0.01 * s),
            )
        })
        .collect();
    let (lo, hi) = (
        spec.track_length.0.max(1),
        spec.track_length.1.max(spec.track_length.0).max(1),
    );
    let mut problem = Problem {
        poses: poses
            .iter()
            .enumerate()
            .map(|(i, t)| PoseVar {
                world_from_camera: *t,
                fixed: i == 0,
            })
            .collect(),
        ..Problem::default()
    };
    let mut points = Vec::with_capacity(spec.points);
    for j in 0..spec.points {
        let len = (lo + rng.below(hi - lo + 1)).min(n);
        let first = rng.below(n - len + 1);
        // A point in front of the middle keyframe of its run.
        let mid = poses[first + len / 2];
        let q = Point3::new(
            rng.range(-1.2, 1.2),
            rng.range(-0.9, 0.9),
            rng.range(0.8, 3.5),
        );
        let p_world = mid * q;
        points.push(p_world);
        problem.points.push(PointVar { p_world });
        for (i, t) in poses.iter().enumerate().skip(first).take(len) {
            let q = t.inverse_transform_point(&p_world);
            let cov = sensor_covariance(q.z.max(0.3));
            let noise = match (spec.noise, cov.cholesky()) {
                (true, Some(c)) => c.l() * Vector3::new(rng.normal(), rng.normal(), rng.normal()),
                _ => Vector3::zeros(),
            };
            problem.point_edges.push(PointEdge {
                pose: i,
                point: j,
                p_camera: q + noise,
                information: cov.try_inverse().unwrap_or_else(Matrix3::identity),
            });
        }
    }
    if spec.odometry_edges {
        let info = Matrix6::from_diagonal(&Vector6::new(1e4, 1e4, 1e4, 1e5, 1e5, 1e5));
        for i in 1..n {
            problem.pose_edges.push(PoseEdge {
                from: i - 1,
                to: i,
                from_from_to: poses[i - 1].inverse() * poses[i],
                information: info,
            });
        }
    }
    let (pt, pr, pp) = spec.perturbation;
    for v in problem.poses.iter_mut().filter(|v| !v.fixed) {
        let d = Vector6::from_fn(|r, _| rng.normal() * if r < 3 { pt } else { pr });
        v.world_from_camera = retract(&v.world_from_camera, &d);
    }
    for v in &mut problem.points {
        v.p_world += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * pp;
    }
    Synthetic {
        problem,
        poses,
        points,
    }
}
