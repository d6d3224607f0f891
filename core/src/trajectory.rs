//! Time-stamped trajectories.
//!
//! A [`Trajectory`] holds poses `world_from_body` (usually `world_from_camera`) at strictly
//! increasing timestamps in seconds. It does not know where it came from: reading and
//! writing files is the job of `stride-datasets`, comparing two trajectories the job of
//! `stride-eval`.

use crate::pose::Pose;
use nalgebra::Point3;

/// Why a set of stamps and poses is not a valid trajectory.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrajectoryError {
    /// The stamp and pose vectors differ in length.
    #[error("{stamps} timestamps but {poses} poses")]
    LengthMismatch {
        /// Number of timestamps.
        stamps: usize,
        /// Number of poses.
        poses: usize,
    },
    /// A timestamp is NaN or infinite.
    #[error("timestamp #{index} is not finite ({value})")]
    NonFiniteStamp {
        /// Zero-based index of the pose.
        index: usize,
        /// The value found.
        value: f64,
    },
    /// A pose holds a NaN or infinite number.
    #[error("pose #{index} holds a non-finite number")]
    NonFinitePose {
        /// Zero-based index of the pose.
        index: usize,
    },
    /// A timestamp is earlier than the one before it.
    #[error(
        "timestamp #{index} ({value:.6} s) is earlier than the previous one ({previous:.6} s)"
    )]
    Decreasing {
        /// Zero-based index of the offending pose.
        index: usize,
        /// Its timestamp (s).
        value: f64,
        /// The previous timestamp (s).
        previous: f64,
    },
}

/// Poses at timestamps in time order (seconds; any epoch).
///
/// Invariants: as many stamps as poses, every number finite, stamps never decreasing (equal
/// stamps come from a line duplicated in a file).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    stamps_s: Vec<f64>,
    poses: Vec<Pose>,
}

fn pose_is_finite(p: &Pose) -> bool {
    p.translation.vector.iter().all(|v| v.is_finite())
        && p.rotation.coords.iter().all(|v| v.is_finite())
}

impl Trajectory {
    /// An empty trajectory.
    pub fn new() -> Self {
        Self::default()
    }

    /// Builds a trajectory from parallel vectors, checking the invariants.
    pub fn from_parts(stamps_s: Vec<f64>, poses: Vec<Pose>) -> Result<Self, TrajectoryError> {
        if stamps_s.len() != poses.len() {
            return Err(TrajectoryError::LengthMismatch {
                stamps: stamps_s.len(),
                poses: poses.len(),
            });
        }
        let mut traj = Self {
            stamps_s: Vec::with_capacity(poses.len()),
            poses: Vec::with_capacity(poses.len()),
        };
        for (t, p) in stamps_s.into_iter().zip(poses) {
            traj.push(t, p)?;
        }
        Ok(traj)
    }

    /// Appends a pose; its stamp must be finite and not earlier than the last one. An equal
    /// stamp is allowed (a line duplicated in a file, which evo and the TUM tools accept);
    /// [`Trajectory::interpolate`] at such a time gives the later of the two poses.
    pub fn push(&mut self, t_s: f64, pose: Pose) -> Result<(), TrajectoryError> {
        let index = self.stamps_s.len();
        if !t_s.is_finite() {
            return Err(TrajectoryError::NonFiniteStamp { index, value: t_s });
        }
        if !pose_is_finite(&pose) {
            return Err(TrajectoryError::NonFinitePose { index });
        }
        if let Some(&previous) = self.stamps_s.last() {
            if t_s < previous {
                return Err(TrajectoryError::Decreasing {
                    index,
                    value: t_s,
                    previous,
                });
            }
        }
        self.stamps_s.push(t_s);
        self.poses.push(pose);
        Ok(())
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Timestamps in seconds, strictly increasing.
    pub fn stamps_s(&self) -> &[f64] {
        &self.stamps_s
    }

    /// Poses (`world_from_body`), parallel to [`Self::stamps_s`].
    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }

    /// Positions of the body in the world frame (metres).
    pub fn positions(&self) -> Vec<Point3<f64>> {
        self.poses
            .iter()
            .map(|p| Point3::from(p.translation.vector))
            .collect()
    }

    /// Iterates over `(t_s, pose)`.
    pub fn iter(&self) -> impl Iterator<Item = (f64, &Pose)> + '_ {
        self.stamps_s.iter().copied().zip(self.poses.iter())
    }

    /// Time span `(first, last)` in seconds, or `None` when empty.
    pub fn time_span_s(&self) -> Option<(f64, f64)> {
        Some((*self.stamps_s.first()?, *self.stamps_s.last()?))
    }

    /// Sum of the distances between consecutive positions (metres).
    pub fn path_length_m(&self) -> f64 {
        self.poses
            .windows(2)
            .map(|w| (w[1].translation.vector - w[0].translation.vector).norm())
            .sum()
    }

    /// The pose at time `t_s`, interpolated linearly in translation and by slerp in rotation
    /// between the two poses around it; `None` outside the trajectory's time span.
    pub fn interpolate(&self, t_s: f64) -> Option<Pose> {
        let (first, last) = self.time_span_s()?;
        if !(first..=last).contains(&t_s) {
            return None;
        }
        // Index of the first stamp strictly greater than t_s.
        let upper = self.stamps_s.partition_point(|&s| s <= t_s);
        if upper == 0 {
            return None;
        }
        let lower = upper - 1;
        let (&t0, p0) = (self.stamps_s.get(lower)?, self.poses.get(lower)?);
        let (Some(&t1), Some(p1)) = (self.stamps_s.get(upper), self.poses.get(upper)) else {
            return Some(*p0); // t_s is exactly the last stamp
        };
        let alpha = (t_s - t0) / (t1 - t0);
        let translation = p0.translation.vector.lerp(&p1.translation.vector, alpha);
        let rotation = p0.rotation.slerp(&p1.rotation, alpha);
        Some(Pose::from_parts(translation.into(), rotation))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn pose(x: f64, yaw: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        )
    }

    #[test]
    fn rejects_unsorted_and_nan_stamps_and_keeps_duplicates() {
        let mut t = Trajectory::new();
        t.push(1.0, pose(0.0, 0.0)).unwrap();
        t.push(1.0, pose(1.0, 0.0)).unwrap();
        t.push(2.0, pose(3.0, 0.0)).unwrap();
        assert_eq!(t.len(), 3);
        // At a duplicated stamp the later pose counts; after it, interpolation starts there.
        assert_relative_eq!(t.interpolate(1.0).unwrap().translation.x, 1.0);
        assert_relative_eq!(t.interpolate(1.5).unwrap().translation.x, 2.0);
        assert!(matches!(
            t.push(0.5, pose(0.0, 0.0)),
            Err(TrajectoryError::Decreasing { index: 3, .. })
        ));
        assert!(matches!(
            t.push(f64::NAN, pose(0.0, 0.0)),
            Err(TrajectoryError::NonFiniteStamp { .. })
        ));
        assert_eq!(t.len(), 3, "refused poses are not added");
    }

    #[test]
    fn interpolates_linearly_and_by_slerp() {
        let t =
            Trajectory::from_parts(vec![0.0, 2.0], vec![pose(0.0, 0.0), pose(2.0, 1.0)]).unwrap();
        let mid = t.interpolate(0.5).unwrap();
        assert_relative_eq!(mid.translation.vector.x, 0.5, epsilon = 1e-12);
        assert_relative_eq!(mid.rotation.angle(), 0.25, epsilon = 1e-12);
        assert_eq!(t.interpolate(2.0).unwrap(), pose(2.0, 1.0));
        assert!(t.interpolate(-0.1).is_none());
        assert!(t.interpolate(2.1).is_none());
        assert_relative_eq!(t.path_length_m(), 2.0);
    }
}
