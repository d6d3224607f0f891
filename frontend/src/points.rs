//! 3-D points from keypoints and depth, with their covariance.

use crate::config::VoConfig;
use nalgebra::{Matrix3, Point2, Point3};
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;

/// A keypoint's 3-D position in its camera's frame (m) and covariance (m^2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measurement {
    /// Position in the camera frame (m).
    pub p: Point3<f64>,
    /// Covariance (m^2, camera frame), paper 000 eq. 11.
    pub cov: Matrix3<f64>,
}

/// Back-projects the keypoint at `(u, v)` (px, distorted image coordinates) with the depth
/// image. Rejected (`None`) when the depth is missing or outside the range, or when the 3x3
/// neighbourhood crosses a depth edge (a pixel without depth or differing by more than
/// `depth_edge_rel` of the depth): there the depth belongs to either surface. Depth is
/// interpolated bilinearly between the four pixels around `(u, v)`.
pub fn measure(
    depth: &DepthImage,
    camera: &PinholeCamera,
    u: f32,
    v: f32,
    config: &VoConfig,
) -> Option<Measurement> {
    let (w, h) = (depth.width() as i64, depth.height() as i64);
    let (cx, cy) = (u.round() as i64, v.round() as i64);
    if cx < 1 || cy < 1 || cx >= w - 1 || cy >= h - 1 {
        return None;
    }
    let z0 = f64::from(depth.get(cx as u32, cy as u32)?);
    if !(z0 >= config.min_depth_m && z0 <= config.max_depth_m) {
        return None;
    }
    let tol = config.depth_edge_rel * z0;
    for dy in -1..=1 {
        for dx in -1..=1 {
            let z = f64::from(depth.get((cx + dx) as u32, (cy + dy) as u32)?);
            if z <= 0.0 || (z - z0).abs() > tol {
                return None;
            }
        }
    }
    // Bilinear depth between the four pixels around (u, v), all validated above.
    let (fx, fy) = (f64::from(u).floor(), f64::from(v).floor());
    let (ax, ay) = (f64::from(u) - fx, f64::from(v) - fy);
    let (x0, y0) = (fx as u32, fy as u32);
    let d = |x: u32, y: u32| depth.get(x, y).map(f64::from);
    let z = (d(x0, y0)? * (1.0 - ax) + d(x0 + 1, y0)? * ax) * (1.0 - ay)
        + (d(x0, y0 + 1)? * (1.0 - ax) + d(x0 + 1, y0 + 1)? * ax) * ay;
    let pixel = Point2::new(f64::from(u), f64::from(v));
    let p = camera.unproject(&pixel, z);
    let ideal = camera.undistort_pixel(&pixel);
    let cov = config.uncertainty.covariance(camera, ideal.x, ideal.y, z);
    Some(Measurement { p, cov })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_edges_holes_and_range() {
        let cam = PinholeCamera::new(500.0, 500.0, 10.0, 10.0, 20, 20).unwrap();
        let cfg = VoConfig::default();
        let mut depth = DepthImage::filled(20, 20, 2.0);
        let m = measure(&depth, &cam, 10.0, 10.0, &cfg).unwrap();
        assert!((m.p.z - 2.0).abs() < 1e-12 && m.p.x.abs() < 1e-12);
        assert!(
            m.cov[(2, 2)] > m.cov[(0, 0)],
            "depth is the least certain axis"
        );
        *depth.get_mut(11, 10).unwrap() = 2.5; // an edge next to the keypoint
        assert!(measure(&depth, &cam, 10.0, 10.0, &cfg).is_none());
        *depth.get_mut(11, 10).unwrap() = 0.0; // a hole
        assert!(measure(&depth, &cam, 10.0, 10.0, &cfg).is_none());
        assert!(measure(&DepthImage::filled(20, 20, 9.0), &cam, 10.0, 10.0, &cfg).is_none());
        assert!(measure(&DepthImage::filled(20, 20, 2.0), &cam, 0.2, 10.0, &cfg).is_none());
    }
}
