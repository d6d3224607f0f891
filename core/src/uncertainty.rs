//! Spatial uncertainty of points measured by an RGB-D camera.
//!
//! The PrimeSense/Kinect model of paper 000 (section 4.3, after Park et al. 2012): a point
//! back-projected from pixel `(u, v)` with depth `d` (eq. 10),
//! `p = d K^-1 [u, v, 1]^T`, has covariance (eq. 11)
//! `Sigma_p = J diag(sigma_u^2, sigma_v^2, sigma_d^2) J^T`, with `J` the Jacobian of `p` with
//! respect to `(u, v, d)` and a depth standard deviation that grows with depth (eq. 12):
//! `sigma_d = k1 d^3 + k2 d^2 + k3 d + k4`.
//!
//! The defaults are PUT SLAM's published constants (sigma_u^2 = 1.1046 px^2,
//! sigma_v^2 = 0.6416 px^2, k = (-8.9997e-6, 3.069e-3, 3.6512e-6, -1.7512e-6)), read as the
//! paper writes them: the polynomial gives the standard deviation in metres (about 1.2 cm at
//! 2 m). Covariances are in the camera frame (x right, y down, z forward), in m^2.

use crate::camera::PinholeCamera;
use nalgebra::{Matrix3, Point3};

/// The PrimeSense/Kinect uncertainty model of paper 000, eqs. 10-12.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PrimeSenseModel {
    /// Variance of the pixel column (px^2).
    pub var_u_px2: f64,
    /// Variance of the pixel row (px^2).
    pub var_v_px2: f64,
    /// `(k1, k2, k3, k4)` of `sigma_d = k1 d^3 + k2 d^2 + k3 d + k4` (d and sigma_d in metres).
    pub depth_sigma_coeffs: [f64; 4],
    /// Smallest depth standard deviation used (m), so that the information stays finite.
    pub min_sigma_d_m: f64,
}

impl Default for PrimeSenseModel {
    /// PUT SLAM's constants (see the module documentation).
    fn default() -> Self {
        Self {
            var_u_px2: 1.1046,
            var_v_px2: 0.6416,
            depth_sigma_coeffs: [-8.9997e-6, 3.069e-3, 3.6512e-6, -1.7512e-6],
            min_sigma_d_m: 5e-4,
        }
    }
}

impl PrimeSenseModel {
    /// Standard deviation of a depth measurement `d` (m), eq. 12, floored at
    /// `min_sigma_d_m`.
    pub fn sigma_d(&self, d_m: f64) -> f64 {
        let [k1, k2, k3, k4] = self.depth_sigma_coeffs;
        (((k1 * d_m + k2) * d_m + k3) * d_m + k4).max(self.min_sigma_d_m)
    }

    /// Covariance (m^2, camera frame) of the point back-projected from undistorted pixel
    /// `(u, v)` (px) with depth `d` (m), eq. 11.
    pub fn covariance(&self, camera: &PinholeCamera, u: f64, v: f64, d_m: f64) -> Matrix3<f64> {
        let j = Matrix3::new(
            d_m / camera.fx(),
            0.0,
            (u - camera.cx()) / camera.fx(),
            0.0,
            d_m / camera.fy(),
            (v - camera.cy()) / camera.fy(),
            0.0,
            0.0,
            1.0,
        );
        let s = self.sigma_d(d_m);
        let r = Matrix3::from_diagonal(&nalgebra::Vector3::new(
            self.var_u_px2,
            self.var_v_px2,
            s * s,
        ));
        j * r * j.transpose()
    }

    /// The point (eq. 10) and its covariance (eq. 11) for undistorted pixel `(u, v)` and
    /// depth `d`.
    pub fn point_and_covariance(
        &self,
        camera: &PinholeCamera,
        u: f64,
        v: f64,
        d_m: f64,
    ) -> (Point3<f64>, Matrix3<f64>) {
        let p = Point3::new(
            (u - camera.cx()) / camera.fx() * d_m,
            (v - camera.cy()) / camera.fy() * d_m,
            d_m,
        );
        (p, self.covariance(camera, u, v, d_m))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn depth_sigma_grows_quadratically() {
        let m = PrimeSenseModel::default();
        assert!(
            (m.sigma_d(2.0) - 0.01221).abs() < 1e-4,
            "{}",
            m.sigma_d(2.0)
        );
        assert!(m.sigma_d(4.0) > 3.5 * m.sigma_d(2.0));
        assert_eq!(m.sigma_d(0.0), m.min_sigma_d_m);
    }

    #[test]
    fn covariance_matches_monte_carlo_sampling() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480).unwrap();
        let m = PrimeSenseModel::default();
        let (u, v, d) = (520.0, 80.0, 2.5);
        let sigma = m.covariance(&cam, u, v, d);
        let mut rng = SplitMix64::new(3);
        let n = 200_000;
        let mut mean = nalgebra::Vector3::zeros();
        let mut samples = Vec::with_capacity(n);
        for _ in 0..n {
            let uu = u + m.var_u_px2.sqrt() * rng.normal();
            let vv = v + m.var_v_px2.sqrt() * rng.normal();
            let dd = d + m.sigma_d(d) * rng.normal();
            let p = nalgebra::Vector3::new(
                (uu - cam.cx()) / cam.fx() * dd,
                (vv - cam.cy()) / cam.fy() * dd,
                dd,
            );
            mean += p;
            samples.push(p);
        }
        mean /= n as f64;
        let mut cov = Matrix3::zeros();
        for p in &samples {
            cov += (p - mean) * (p - mean).transpose();
        }
        cov /= (n - 1) as f64;
        // Linearisation is exact up to the small product term sigma_u^2 sigma_d^2 / f^2.
        for i in 0..3 {
            for j in 0..3 {
                let tol = 0.02 * (sigma[(i, i)] * sigma[(j, j)]).sqrt();
                assert!(
                    (cov[(i, j)] - sigma[(i, j)]).abs() < tol,
                    "({i},{j}): {} vs {}",
                    cov[(i, j)],
                    sigma[(i, j)]
                );
            }
        }
    }
}
