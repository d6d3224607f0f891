//! One 2-D range scan (a tilted laser scanner's, or a laser stripe's expressed as beams in
//! its light plane): ranges along beams in the sensor's x-y plane, angles from +x towards +y
//! (ROS's `LaserScan`), with the pose it was taken at.

use nalgebra::{Isometry3, Point3, Vector3};

/// A scan and its pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// Time (s).
    pub t_s: f64,
    /// `world_from_sensor` (world z up, m).
    pub world_from_sensor: Isometry3<f64>,
    /// Angle of beam 0 from +x towards +y (rad).
    pub angle_min_rad: f64,
    /// Angle between beams (rad).
    pub angle_increment_rad: f64,
    /// Ranges (m); NaN (or 0) for no return.
    pub ranges: Vec<f64>,
}

impl Scan {
    /// Whether beam `i` has a return.
    pub fn valid(&self, i: usize) -> bool {
        self.ranges
            .get(i)
            .is_some_and(|&r| r.is_finite() && r > 0.0)
    }

    /// The angle of beam `i` (rad).
    pub fn angle(&self, i: usize) -> f64 {
        self.angle_min_rad + i as f64 * self.angle_increment_rad
    }

    /// Beam `i`'s return in the sensor's plane, `(x, y)` (m), when it has one.
    pub fn point_2d(&self, i: usize) -> Option<(f64, f64)> {
        let r = *self.ranges.get(i)?;
        if !(r.is_finite() && r > 0.0) {
            return None;
        }
        let (s, c) = self.angle(i).sin_cos();
        Some((r * c, r * s))
    }

    /// Beam `i`'s return in the sensor frame.
    pub fn p_sensor(&self, i: usize) -> Option<Vector3<f64>> {
        self.point_2d(i).map(|(x, y)| Vector3::new(x, y, 0.0))
    }

    /// Beam `i`'s return in the world.
    pub fn p_world(&self, i: usize) -> Option<Point3<f64>> {
        self.p_sensor(i)
            .map(|p| self.world_from_sensor * Point3::from(p))
    }

    /// Removes beam `i`'s return.
    pub fn drop_return(&mut self, i: usize) {
        if let Some(r) = self.ranges.get_mut(i) {
            *r = f64::NAN;
        }
    }
}
