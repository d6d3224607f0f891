//! The pinhole camera with Brown-Conrady lens distortion.
//!
//! Camera frame: x right, y down, z forward along the optical axis (OpenCV/TUM). Pixel
//! coordinates `(u, v)` have their origin at the centre of the top-left pixel, u to the
//! right, v down. Depth is the z coordinate of the point in the camera frame (metres), as
//! Kinect-class sensors and the TUM benchmark report it, not the length of the ray.

use nalgebra::{Point2, Point3, Vector2};

/// Why camera parameters were rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A parameter is NaN, infinite, or out of its valid range.
    #[error("camera parameter {name} = {value} is invalid: {reason}")]
    InvalidParameter {
        /// Name of the parameter (`fx`, `width`, ...).
        name: &'static str,
        /// The value found.
        value: f64,
        /// What is expected of it.
        reason: &'static str,
    },
}

/// Brown-Conrady distortion with OpenCV's five coefficients `(k1, k2, p1, p2, k3)`.
///
/// Maps undistorted normalised coordinates `(x, y) = (X/Z, Y/Z)` to distorted ones:
/// `x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)` and
/// `y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y`, with `r² = x² + y²`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BrownConrady {
    /// Radial coefficient of r².
    pub k1: f64,
    /// Radial coefficient of r⁴.
    pub k2: f64,
    /// First tangential coefficient.
    pub p1: f64,
    /// Second tangential coefficient.
    pub p2: f64,
    /// Radial coefficient of r⁶.
    pub k3: f64,
}

impl BrownConrady {
    /// Coefficients in OpenCV's order `[k1, k2, p1, p2, k3]`.
    pub fn from_array(c: [f64; 5]) -> Self {
        Self {
            k1: c[0],
            k2: c[1],
            p1: c[2],
            p2: c[3],
            k3: c[4],
        }
    }

    /// Coefficients in OpenCV's order `[k1, k2, p1, p2, k3]`.
    pub fn to_array(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// True when every coefficient is zero (no distortion).
    pub fn is_zero(&self) -> bool {
        self.to_array().iter().all(|&c| c == 0.0)
    }

    /// Distorts undistorted normalised coordinates.
    pub fn distort(&self, xn: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (xn.x, xn.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Inverts [`Self::distort`] by fixed-point iteration (as OpenCV's `undistortPoints`),
    /// up to 50 iterations or until the update is below 1e-14.
    pub fn undistort(&self, xd: Vector2<f64>) -> Vector2<f64> {
        let mut x = xd;
        for _ in 0..50 {
            let r2 = x.norm_squared();
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dx = 2.0 * self.p1 * x.x * x.y + self.p2 * (r2 + 2.0 * x.x * x.x);
            let dy = self.p1 * (r2 + 2.0 * x.y * x.y) + 2.0 * self.p2 * x.x * x.y;
            let next = Vector2::new((xd.x - dx) / radial, (xd.y - dy) / radial);
            let step = (next - x).norm();
            x = next;
            if step.is_nan() || step < 1e-14 {
                break;
            }
        }
        x
    }
}

/// A pinhole camera: focal lengths and principal point in pixels, image size in pixels, and
/// optional Brown-Conrady distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
///
/// Invariant (why the fields are private): focal lengths and the image size are positive,
/// every number is finite, and distortion is `None` or has a non-zero coefficient. Only
/// [`PinholeCamera::new`] and [`PinholeCamera::with_distortion`] build one, so a camera
/// with a negative focal length cannot exist:
///
/// ```compile_fail
/// let mut c = stride_core::camera::PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480)?;
/// c.fx = -1.0; // private field: does not compile
/// # Ok::<(), stride_core::camera::CameraError>(())
/// ```
///
/// ```
/// use stride_core::camera::PinholeCamera;
/// assert!(PinholeCamera::new(-1.0, 525.0, 319.5, 239.5, 640, 480).is_err());
/// ```
pub struct PinholeCamera {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: u32,
    height: u32,
    distortion: Option<BrownConrady>,
}

fn check(name: &'static str, value: f64, positive: bool) -> Result<(), CameraError> {
    if !value.is_finite() {
        return Err(CameraError::InvalidParameter {
            name,
            value,
            reason: "must be finite",
        });
    }
    if positive && value <= 0.0 {
        return Err(CameraError::InvalidParameter {
            name,
            value,
            reason: "must be positive",
        });
    }
    Ok(())
}

impl PinholeCamera {
    /// A camera without distortion; checks that every parameter is finite and that focal
    /// lengths and the image size are positive.
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
    ) -> Result<Self, CameraError> {
        check("fx", fx, true)?;
        check("fy", fy, true)?;
        check("cx", cx, false)?;
        check("cy", cy, false)?;
        check("width", f64::from(width), true)?;
        check("height", f64::from(height), true)?;
        Ok(Self {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            distortion: None,
        })
    }

    /// The default intrinsics of a 640 x 480 PrimeSense/Kinect camera in ROS's openni
    /// driver (fx = fy = 525, cx = 319.5, cy = 239.5 pixels, no distortion), which the TUM
    /// benchmark documents for uncalibrated use.
    pub const KINECT_DEFAULT: Self = Self {
        fx: 525.0,
        fy: 525.0,
        cx: 319.5,
        cy: 239.5,
        width: 640,
        height: 480,
        distortion: None,
    };

    /// The same camera without lens distortion (an ideal pinhole with its intrinsics).
    pub fn without_distortion(self) -> Self {
        Self {
            distortion: None,
            ..self
        }
    }

    /// The same camera with lens distortion; all-zero coefficients mean none. Non-finite
    /// coefficients are rejected.
    pub fn with_distortion(mut self, d: BrownConrady) -> Result<Self, CameraError> {
        const NAMES: [&str; 5] = ["k1", "k2", "p1", "p2", "k3"];
        for (name, v) in NAMES.iter().zip(d.to_array()) {
            check(name, v, false)?;
        }
        self.distortion = (!d.is_zero()).then_some(d);
        Ok(self)
    }

    /// Focal length along u (pixels).
    pub fn fx(&self) -> f64 {
        self.fx
    }

    /// Focal length along v (pixels).
    pub fn fy(&self) -> f64 {
        self.fy
    }

    /// Principal point u (pixels).
    pub fn cx(&self) -> f64 {
        self.cx
    }

    /// Principal point v (pixels).
    pub fn cy(&self) -> f64 {
        self.cy
    }

    /// Image width (pixels).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height (pixels).
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Lens distortion; `None` for an ideal pinhole.
    pub fn distortion(&self) -> Option<&BrownConrady> {
        self.distortion.as_ref()
    }

    /// Projects a camera-frame point (metres) to pixel coordinates, applying distortion.
    /// `None` when the point is not in front of the camera (z <= 0).
    pub fn project(&self, p_camera: &Point3<f64>) -> Option<Point2<f64>> {
        if p_camera.z.is_nan() || p_camera.z <= 0.0 {
            return None;
        }
        let xn = Vector2::new(p_camera.x / p_camera.z, p_camera.y / p_camera.z);
        let xd = match &self.distortion {
            Some(d) => d.distort(xn),
            None => xn,
        };
        Some(Point2::new(
            self.fx * xd.x + self.cx,
            self.fy * xd.y + self.cy,
        ))
    }

    /// Undistorted normalised coordinates `(X/Z, Y/Z)` of the ray through a pixel.
    pub fn normalized_from_pixel(&self, pixel: &Point2<f64>) -> Vector2<f64> {
        let xd = Vector2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        match &self.distortion {
            Some(d) => d.undistort(xd),
            None => xd,
        }
    }

    /// Removes lens distortion from a pixel: the pixel an ideal pinhole with the same
    /// intrinsics would have seen.
    pub fn undistort_pixel(&self, pixel: &Point2<f64>) -> Point2<f64> {
        let xn = self.normalized_from_pixel(pixel);
        Point2::new(self.fx * xn.x + self.cx, self.fy * xn.y + self.cy)
    }

    /// Back-projects a pixel with its depth (z, metres) to a camera-frame point.
    pub fn unproject(&self, pixel: &Point2<f64>, depth_m: f64) -> Point3<f64> {
        let xn = self.normalized_from_pixel(pixel);
        Point3::new(xn.x * depth_m, xn.y * depth_m, depth_m)
    }

    /// True when a pixel lies inside the image (continuous bounds `[-0.5, size - 0.5)`).
    pub fn contains(&self, pixel: &Point2<f64>) -> bool {
        pixel.x >= -0.5
            && pixel.y >= -0.5
            && pixel.x < f64::from(self.width) - 0.5
            && pixel.y < f64::from(self.height) - 0.5
    }

    /// This camera for an image scaled by `factor` (e.g. 0.5 for the next pyramid level):
    /// focal lengths scale, the principal point moves with pixel centres.
    pub fn scaled(&self, factor: f64) -> Self {
        Self {
            fx: self.fx * factor,
            fy: self.fy * factor,
            cx: (self.cx + 0.5) * factor - 0.5,
            cy: (self.cy + 0.5) * factor - 0.5,
            width: ((f64::from(self.width) * factor).round() as u32).max(1),
            height: ((f64::from(self.height) * factor).round() as u32).max(1),
            distortion: self.distortion,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn fr1() -> PinholeCamera {
        PinholeCamera::new(517.306408, 516.469215, 318.643040, 255.313989, 640, 480)
            .unwrap()
            .with_distortion(BrownConrady::from_array([
                0.262383, -0.953104, -0.005358, 0.002628, 1.163314,
            ]))
            .unwrap()
    }

    #[test]
    fn project_unproject_round_trip_with_distortion() {
        let cam = fr1();
        for &(u, v) in &[(0.0, 0.0), (320.0, 240.0), (639.0, 479.0), (100.0, 400.0)] {
            let px = Point2::new(u, v);
            let p = cam.unproject(&px, 2.5);
            assert_relative_eq!(p.z, 2.5);
            let back = cam.project(&p).unwrap();
            assert_relative_eq!(back, px, epsilon = 1e-9);
        }
    }

    #[test]
    fn ideal_pinhole_matches_the_textbook_formula() {
        let cam = PinholeCamera::new(500.0, 400.0, 320.0, 240.0, 640, 480).unwrap();
        let px = cam.project(&Point3::new(0.2, -0.1, 2.0)).unwrap();
        assert_relative_eq!(px, Point2::new(370.0, 220.0), epsilon = 1e-12);
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(cam.contains(&px));
        assert!(!cam.contains(&Point2::new(640.0, 0.0)));
    }

    #[test]
    fn rejects_invalid_parameters() {
        assert!(PinholeCamera::new(0.0, 1.0, 0.0, 0.0, 10, 10).is_err());
        assert!(PinholeCamera::new(1.0, 1.0, f64::NAN, 0.0, 10, 10).is_err());
        assert!(PinholeCamera::new(1.0, 1.0, 0.0, 0.0, 0, 10).is_err());
        let cam = PinholeCamera::new(1.0, 1.0, 0.0, 0.0, 10, 10).unwrap();
        assert!(cam
            .with_distortion(BrownConrady::from_array([
                f64::INFINITY,
                0.0,
                0.0,
                0.0,
                0.0
            ]))
            .is_err());
        assert!(cam
            .with_distortion(BrownConrady::default())
            .unwrap()
            .distortion
            .is_none());
    }
}
