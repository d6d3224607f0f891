//! 3-D points from keypoints and depth, with their covariance.

use crate::config::VoConfig;
use nalgebra::{Isometry3, Matrix3, Point2, Point3, UnitQuaternion, Vector3};
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

/// The camera's motion while a rolling shutter reads out the image, to bring a keypoint
/// seen in row `v` back to the frame's time. The frame's timestamp is taken as the time of
/// the middle row; row `v` is read `(v - mid_row) * row_s` seconds later. The default is a
/// global shutter (no correction).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ShutterMotion {
    /// Seconds per image row: the readout time over `rows - 1` (0 for a global shutter).
    pub row_s: f64,
    /// The row exposed at the frame's timestamp (px): the middle row.
    pub mid_row: f64,
    /// Angular velocity of the camera in its own frame (rad/s).
    pub omega_rad_s: Vector3<f64>,
    /// Linear velocity of the camera in its own frame (m/s).
    pub v_m_s: Vector3<f64>,
    /// The rotation over the readout integrated from a gyroscope, when one covers it: it
    /// replaces the constant `omega_rad_s` (a gait's foot impacts change the rate within
    /// the readout).
    pub rotations: Option<RowRotations>,
    /// The translation over the readout integrated from an accelerometer, when one covers
    /// it and the frame interval: it replaces `v_m_s s` (a foot's impact changes the
    /// velocity within the readout, and the interval's mean velocity is not the frame's).
    pub translations: Option<RowTranslations>,
}

impl ShutterMotion {
    /// The motion for a camera with `rows` image rows read out in `readout_s` (s), moving by
    /// `prev_from_cur` over the last `dt_s` seconds (constant velocity: the camera keeps
    /// moving so during this frame's readout). A global shutter, a non-positive `dt_s` or a
    /// non-finite motion give no correction.
    pub fn new(readout_s: f64, rows: u32, prev_from_cur: &Isometry3<f64>, dt_s: f64) -> Self {
        let finite = prev_from_cur
            .translation
            .vector
            .iter()
            .all(|v| v.is_finite())
            && prev_from_cur.rotation.coords.iter().all(|v| v.is_finite());
        if !(readout_s > 0.0 && dt_s > 0.0 && rows > 1 && finite) {
            return Self::default();
        }
        Self {
            row_s: readout_s / f64::from(rows - 1),
            mid_row: f64::from(rows - 1) / 2.0,
            omega_rad_s: prev_from_cur.rotation.scaled_axis() / dt_s,
            v_m_s: prev_from_cur.translation.vector / dt_s,
            rotations: None,
            translations: None,
        }
    }

    /// `p_camera` (m), measured in image row `v_px`, expressed in the camera frame at the
    /// frame's time: `cam(t) <- cam(t + s)` with `s` the row's delay, which is the rotation
    /// by `omega s` (or the gyroscope's integrated rotation) followed by the translation
    /// `v s` (or the accelerometer's integrated translation).
    pub fn to_frame_time(&self, p_camera: Point3<f64>, v_px: f64) -> Point3<f64> {
        let s = (v_px - self.mid_row) * self.row_s;
        let frame_from_row = match (&self.rotations, &self.translations) {
            (Some(r), _) => r.at(s),
            (None, None) if s == 0.0 => return p_camera,
            (None, _) => UnitQuaternion::from_scaled_axis(self.omega_rad_s * s),
        };
        let translation = match &self.translations {
            Some(t) => t.at(s),
            None => self.v_m_s * s,
        };
        frame_from_row * p_camera + translation
    }
}

/// Knots of [`RowRotations`] over the readout: 1.25 ms apart over a 20 ms readout.
pub const ROTATION_KNOTS: usize = 17;

/// The camera's rotation from the frame's time `t` to evenly spaced instants over the
/// readout, `cam(t) <- cam(t + s_i)` with `s_i = first_s + i step_s` (s), the middle knot
/// at `s = 0`; between knots the rotation is interpolated. With a known exposure, each
/// knot holds the mean rotation over the exposure centred on its instant (where a blurred
/// keypoint sits), so even the middle knot may differ from the identity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowRotations {
    /// Delay of the first knot (s; negative: the top row is read before the frame's time).
    pub first_s: f64,
    /// Time between knots (s).
    pub step_s: f64,
    /// `cam(t) <- cam(t + s_i)` for each knot.
    pub frame_from_knot: [UnitQuaternion<f64>; ROTATION_KNOTS],
}

impl RowRotations {
    /// `cam(t) <- cam(t + s_s)`, interpolated between the knots around `s_s` (clamped to
    /// the readout).
    pub fn at(&self, s_s: f64) -> UnitQuaternion<f64> {
        let (i, frac) = knot_interval(self.first_s, self.step_s, s_s);
        let (a, b) = match (self.frame_from_knot.get(i), self.frame_from_knot.get(i + 1)) {
            (Some(a), Some(b)) => (a, b),
            _ => return UnitQuaternion::identity(), // i < last by knot_interval
        };
        // Along the geodesic from a to b (no slerp: it panics on opposite rotations, which
        // a corrupt rate could integrate to).
        a * UnitQuaternion::from_scaled_axis((a.inverse() * b).scaled_axis() * frac)
    }
}

/// The knot interval `[i, i + 1]` of [`ROTATION_KNOTS`] knots from `first_s`, `step_s`
/// apart (s), that holds `s_s` (clamped to the knots), and where in it `s_s` lies (0-1).
fn knot_interval(first_s: f64, step_s: f64, s_s: f64) -> (usize, f64) {
    let last = ROTATION_KNOTS - 1;
    let x = ((s_s - first_s) / step_s).clamp(0.0, last as f64);
    let i = (x.floor() as usize).min(last - 1);
    (i, x - i as f64)
}

/// The camera's position at evenly spaced instants over the readout, in its frame at the
/// frame's time `t` (m): where `cam(t + s_i)`'s origin is in `cam(t)`, `s_i = first_s + i
/// step_s` (s) on the knots of [`RowRotations`]; linear between knots. With a known
/// exposure each knot holds the mean position over the exposure centred on its instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowTranslations {
    /// Delay of the first knot (s; negative: the top row is read before the frame's time).
    pub first_s: f64,
    /// Time between knots (s).
    pub step_s: f64,
    /// `cam(t + s_i)`'s origin in `cam(t)` (m), for each knot.
    pub p_frame_knot: [Vector3<f64>; ROTATION_KNOTS],
}

impl RowTranslations {
    /// `cam(t + s_s)`'s origin in `cam(t)` (m), linear between the knots around `s_s`
    /// (clamped to the readout).
    pub fn at(&self, s_s: f64) -> Vector3<f64> {
        let (i, frac) = knot_interval(self.first_s, self.step_s, s_s);
        match (self.p_frame_knot.get(i), self.p_frame_knot.get(i + 1)) {
            (Some(a), Some(b)) => a + (b - a) * frac,
            _ => Vector3::zeros(), // i < last by knot_interval
        }
    }
}

/// Back-projects the keypoint at `(u, v)` (px, distorted image coordinates) with the depth
/// image. Rejected (`None`) when the depth is missing or outside the range, or when the 3x3
/// neighbourhood crosses a depth edge (a pixel without depth or differing by more than
/// `depth_edge_rel` of the depth): there the depth belongs to either surface. Depth is
/// interpolated bilinearly between the four pixels around `(u, v)`.
///
/// With a rolling shutter (`shutter`), the colour keypoint was seen after (or before) the
/// frame's time while the depth image is taken at the frame's time (as a global-shutter
/// depth sensor gives it): the keypoint's ray is brought to the frame's time, and the depth
/// is read where that ray meets the depth image.
///
/// The covariance is the sensor model's, plus `occluded_sigma_px` (turned into m at the
/// depth) in every direction when the keypoint lies just behind an occluding edge.
pub fn measure(
    depth: &DepthImage,
    camera: &PinholeCamera,
    (u, v): (f32, f32),
    shutter: &ShutterMotion,
    config: &VoConfig,
) -> Option<Measurement> {
    let seen = Point2::new(f64::from(u), f64::from(v));
    let mut pixel = seen;
    let mut z = depth_at(depth, &pixel, config)?;
    if shutter.row_s > 0.0 {
        let p_now = shutter.to_frame_time(camera.unproject(&seen, z), seen.y);
        pixel = camera.project(&p_now)?;
        z = depth_at(depth, &pixel, config)?;
    }
    let p = camera.unproject(&pixel, z);
    let ideal = camera.undistort_pixel(&pixel);
    let mut cov = config.uncertainty.covariance(camera, ideal.x, ideal.y, z);
    if config.occluded_sigma_px > 0.0 && behind_an_edge(depth, &pixel, config) {
        let sigma_m = config.occluded_sigma_px * z / camera.fx();
        cov += Matrix3::identity() * (sigma_m * sigma_m);
    }
    Some(Measurement { p, cov })
}

/// True when the keypoint at `pixel` (whose own depth [`depth_at`] accepted) lies just
/// behind an occluding edge: a pixel within half the Lucas-Kanade window of it (16 samples
/// on two rings, at that radius and half of it) is nearer than its depth by more than
/// `depth_edge_rel` of it. The patch that Lucas-Kanade follows then holds the nearer
/// surface's edge, which moves with that surface, so the track can report the edge's image
/// motion at the farther surface's depth: too little translation when the camera circles a
/// near object, more so under blur, which spreads each edge over its neighbours.
fn behind_an_edge(depth: &DepthImage, pixel: &Point2<f64>, config: &VoConfig) -> bool {
    let r = i64::from(config.klt_window / 2);
    let (cx, cy) = (pixel.x.round() as i64, pixel.y.round() as i64);
    let at = |x: i64, y: i64| -> Option<f64> {
        let (x, y) = (u32::try_from(x).ok()?, u32::try_from(y).ok()?);
        depth.get(x, y).map(f64::from).filter(|z| *z > 0.0)
    };
    let Some(z0) = at(cx, cy) else {
        return false;
    };
    let nearer = z0 * (1.0 - config.depth_edge_rel);
    [r, (r + 1) / 2].iter().any(|&k| {
        [(1, 0), (1, 1), (0, 1), (-1, 1)]
            .iter()
            .flat_map(|&(dx, dy)| [(dx, dy), (-dx, -dy)])
            .any(|(dx, dy)| at(cx + dx * k, cy + dy * k).is_some_and(|z| z < nearer))
    })
}

/// The depth (m) at a sub-pixel position: bilinear between the four pixels around it, once
/// the 3 x 3 neighbourhood of the nearest pixel is free of holes and depth edges and its
/// depth is within range (see [`measure`]).
fn depth_at(depth: &DepthImage, pixel: &Point2<f64>, config: &VoConfig) -> Option<f64> {
    let (w, h) = (i64::from(depth.width()), i64::from(depth.height()));
    let (cx, cy) = (pixel.x.round() as i64, pixel.y.round() as i64);
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
    // Bilinear depth between the four pixels around the position, all validated above.
    let (fx, fy) = (pixel.x.floor(), pixel.y.floor());
    let (ax, ay) = (pixel.x - fx, pixel.y - fy);
    let (x0, y0) = (fx as u32, fy as u32);
    let d = |x: u32, y: u32| depth.get(x, y).map(f64::from);
    Some(
        (d(x0, y0)? * (1.0 - ax) + d(x0 + 1, y0)? * ax) * (1.0 - ay)
            + (d(x0, y0 + 1)? * (1.0 - ax) + d(x0 + 1, y0 + 1)? * ax) * ay,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_edges_holes_and_range() {
        let cam = PinholeCamera::new(500.0, 500.0, 10.0, 10.0, 20, 20).unwrap();
        let cfg = VoConfig::default();
        let mut depth = DepthImage::filled(20, 20, 2.0);
        let m = measure(&depth, &cam, (10.0, 10.0), &ShutterMotion::default(), &cfg).unwrap();
        assert!((m.p.z - 2.0).abs() < 1e-12 && m.p.x.abs() < 1e-12);
        assert!(
            m.cov[(2, 2)] > m.cov[(0, 0)],
            "depth is the least certain axis"
        );
        let rejected = |depth: &DepthImage, px: (f32, f32)| {
            measure(depth, &cam, px, &ShutterMotion::default(), &cfg).is_none()
        };
        *depth.get_mut(11, 10).unwrap() = 2.5; // an edge next to the keypoint
        assert!(rejected(&depth, (10.0, 10.0)));
        *depth.get_mut(11, 10).unwrap() = 0.0; // a hole
        assert!(rejected(&depth, (10.0, 10.0)));
        assert!(rejected(&DepthImage::filled(20, 20, 9.0), (10.0, 10.0)));
        assert!(rejected(&DepthImage::filled(20, 20, 2.0), (0.2, 10.0)));
    }

    #[test]
    fn a_point_just_behind_an_occluding_edge_is_trusted_less() {
        let cam = PinholeCamera::new(500.0, 500.0, 15.0, 15.0, 30, 30).unwrap();
        let cfg = VoConfig::default();
        let still = ShutterMotion::default();
        let cov_xx = |depth: &DepthImage, cfg: &VoConfig| {
            measure(depth, &cam, (15.0, 15.0), &still, cfg).unwrap().cov[(0, 0)]
        };
        let clear = cov_xx(&DepthImage::filled(30, 30, 2.0), &cfg);
        // A nearer surface (1.5 m) from 4 px to the right: inside the tracking window.
        let mut occluded = DepthImage::filled(30, 30, 2.0);
        let mut farther = DepthImage::filled(30, 30, 2.0);
        for y in 0..30 {
            for x in 19..30 {
                *occluded.get_mut(x, y).unwrap() = 1.5;
                *farther.get_mut(x, y).unwrap() = 2.5;
            }
        }
        let sigma_m = cfg.occluded_sigma_px * 2.0 / 500.0;
        let added = cov_xx(&occluded, &cfg) - clear;
        assert!((added - sigma_m * sigma_m).abs() < 1e-12, "{added}");
        // A farther surface beside it occludes nothing; the test can be turned off.
        assert_eq!(cov_xx(&farther, &cfg), clear);
        let off = VoConfig {
            occluded_sigma_px: 0.0,
            ..VoConfig::default()
        };
        assert_eq!(cov_xx(&occluded, &off), clear);
    }

    #[test]
    fn rolling_shutter_points_come_back_to_the_frame_time() {
        // A camera turning at 1 rad/s about y and moving at 0.3 m/s along x; 480 rows read
        // out in 30 ms. A point seen in the last row was measured 15 ms after the frame time.
        let (omega, vel) = (Vector3::new(0.0, 1.0, 0.0), Vector3::new(0.3, 0.0, 0.0));
        let dt = 1.0 / 30.0;
        let prev_from_cur = Isometry3::from_parts(
            (vel * dt).into(),
            UnitQuaternion::from_scaled_axis(omega * dt),
        );
        let shutter = ShutterMotion::new(0.03, 480, &prev_from_cur, dt);
        let world_from_cam = |t: f64| {
            Isometry3::from_parts(
                (vel * t).into(),
                UnitQuaternion::from_scaled_axis(omega * t),
            )
        };
        let x_world = Point3::new(0.4, 0.3, 2.0);
        let s = (479.0 - 239.5) * 0.03 / 479.0;
        let seen = world_from_cam(s).inverse() * x_world;
        let truth = world_from_cam(0.0).inverse() * x_world;
        let fixed = shutter.to_frame_time(seen, 479.0);
        assert!((seen - truth).norm() > 0.02, "the readout moves the point");
        assert!((fixed - truth).norm() < 1e-3, "{}", (fixed - truth).norm());
        // The middle row and a global shutter are left as they are.
        assert_eq!(shutter.to_frame_time(seen, 239.5), seen);
        let global = ShutterMotion::new(0.0, 480, &prev_from_cur, dt);
        assert_eq!(global.to_frame_time(seen, 479.0), seen);
    }
}
