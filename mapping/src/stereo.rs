//! Paper 000's stereo camera: the uncertainty of a triangulated point propagated from the
//! calibration and the pixel positions through undistortion (eqs. 5-6), rectification
//! (eq. 7), disparity (eq. 8) and triangulation (eq. 9), and the artifact filter of
//! section 4.1 for depth or disparity images.
//!
//! The pipeline `p = f(calibration, pixels)` is evaluated exactly; its covariance is
//! `J Sigma J^T` with `J` the Jacobian of the whole chain with respect to every uncertain
//! input (central differences), which is the product of the per-step Jacobians of eqs. 6, 7
//! and 9. Frames: left camera (x right, y down, z forward), metres.

use nalgebra::{Isometry3, Matrix3, Point2, Point3, SMatrix, Vector3};
use stride_core::camera::{BrownConrady, PinholeCamera};

/// Standard deviations of a camera's calibration (pixels for intrinsics, unitless for
/// distortion).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IntrinsicSigmas {
    /// Of fx, fy, cx, cy (px).
    pub focal_and_centre_px: [f64; 4],
    /// Of k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
}

/// A calibrated stereo pair with the uncertainty of its calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoModel {
    /// Left camera (the reference frame).
    pub left: PinholeCamera,
    /// Right camera.
    pub right: PinholeCamera,
    /// `right_from_left` extrinsics (metres, radians).
    pub right_from_left: Isometry3<f64>,
    /// Calibration uncertainty of the left camera.
    pub left_sigmas: IntrinsicSigmas,
    /// Calibration uncertainty of the right camera.
    pub right_sigmas: IntrinsicSigmas,
    /// Standard deviation of the extrinsic translation (m, per axis).
    pub translation_sigma_m: f64,
    /// Standard deviation of the extrinsic rotation (rad, per axis).
    pub rotation_sigma_rad: f64,
    /// Standard deviation of a matched pixel position (px): quantisation and matching.
    pub pixel_sigma_px: f64,
}

/// Number of uncertain inputs: 4 pixel coordinates, 2 x 9 intrinsics, 6 extrinsics.
const N_IN: usize = 28;

/// Nine consecutive inputs from `offset` (zeros past the end).
fn nine(x: &[f64; N_IN], offset: usize) -> [f64; 9] {
    std::array::from_fn(|i| x.get(offset + i).copied().unwrap_or(0.0))
}

/// `base` with the intrinsics `p = [fx, fy, cx, cy, k1, k2, p1, p2, k3]`; `None` when they
/// make no valid camera.
fn camera_with(base: &PinholeCamera, p: [f64; 9]) -> Option<PinholeCamera> {
    let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = p;
    PinholeCamera::new(fx, fy, cx, cy, base.width(), base.height())
        .and_then(|c| c.with_distortion(BrownConrady::from_array([k1, k2, p1, p2, k3])))
        .ok()
}

fn intrinsics_of(c: &PinholeCamera) -> [f64; 9] {
    let d = c.distortion().copied().unwrap_or_default().to_array();
    [c.fx(), c.fy(), c.cx(), c.cy(), d[0], d[1], d[2], d[3], d[4]]
}

impl StereoModel {
    /// The nominal input vector: pixels, left and right intrinsics, extrinsic perturbation
    /// (zero).
    fn nominal(&self, left_px: Point2<f64>, right_px: Point2<f64>) -> [f64; N_IN] {
        let mut x = [0.0; N_IN];
        x[0] = left_px.x;
        x[1] = left_px.y;
        x[2] = right_px.x;
        x[3] = right_px.y;
        x[4..13].copy_from_slice(&intrinsics_of(&self.left));
        x[13..22].copy_from_slice(&intrinsics_of(&self.right));
        x
    }

    fn sigmas(&self) -> [f64; N_IN] {
        let mut s = [0.0; N_IN];
        s[..4].fill(self.pixel_sigma_px);
        s[4..8].copy_from_slice(&self.left_sigmas.focal_and_centre_px);
        s[8..13].copy_from_slice(&self.left_sigmas.distortion);
        s[13..17].copy_from_slice(&self.right_sigmas.focal_and_centre_px);
        s[17..22].copy_from_slice(&self.right_sigmas.distortion);
        s[22..25].fill(self.translation_sigma_m);
        s[25..28].fill(self.rotation_sigma_rad);
        s
    }

    /// The pipeline: undistort both pixels (eq. 5), rectify (eq. 7: a common rotation that
    /// makes the baseline the x axis, a common focal length), disparity (eq. 8), triangulate
    /// (eq. 9), back to the left camera frame. `None` for a non-positive disparity or
    /// intrinsics that make no camera.
    fn pipeline(&self, x: &[f64; N_IN]) -> Option<Point3<f64>> {
        let left = camera_with(&self.left, nine(x, 4))?;
        let right = camera_with(&self.right, nine(x, 13))?;
        let dt = Vector3::new(x[22], x[23], x[24]);
        let dr = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(x[25], x[26], x[27]));
        let extr = Isometry3::from_parts(
            (self.right_from_left.translation.vector + dt).into(),
            dr * self.right_from_left.rotation,
        );
        let nl = left.normalized_from_pixel(&Point2::new(x[0], x[1]));
        let nr = right.normalized_from_pixel(&Point2::new(x[2], x[3]));
        let ray_l = Vector3::new(nl.x, nl.y, 1.0);
        // The right ray and camera centre in the left frame.
        let left_from_right = extr.inverse();
        let ray_r = left_from_right.rotation * Vector3::new(nr.x, nr.y, 1.0);
        let c_r = left_from_right.translation.vector;
        let baseline = c_r.norm();
        if baseline <= 0.0 {
            return None;
        }
        // Rectifying rotation: x along the baseline, z as close to the left optical axis.
        let e1 = c_r / baseline;
        let e2 = Vector3::z().cross(&e1);
        let e2 = if e2.norm() > 1e-12 {
            e2.normalize()
        } else {
            Vector3::y()
        };
        let e3 = e1.cross(&e2);
        let rect = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]);
        let (ql, qr) = (rect * ray_l, rect * ray_r);
        if ql.z <= 0.0 || qr.z <= 0.0 {
            return None;
        }
        let f = 0.5 * (left.fx() + right.fx());
        let (ul, vl, ur) = (f * ql.x / ql.z, f * ql.y / ql.z, f * qr.x / qr.z);
        let d = ul - ur;
        if d <= 0.0 {
            return None;
        }
        let z = f * baseline / d;
        let p_rect = Vector3::new(ul * z / f, vl * z / f, z);
        Some(Point3::from(rect.transpose() * p_rect))
    }

    /// The point seen at `left_px` and `right_px` (raw, distorted pixels) in the left camera
    /// frame, and its covariance (m²) from the calibration and pixel uncertainties. `None`
    /// when the pixels do not triangulate (non-positive disparity).
    pub fn point_and_covariance(
        &self,
        left_px: Point2<f64>,
        right_px: Point2<f64>,
    ) -> Option<(Point3<f64>, Matrix3<f64>)> {
        let x0 = self.nominal(left_px, right_px);
        let p0 = self.pipeline(&x0)?;
        let sig = self.sigmas();
        let mut j = SMatrix::<f64, 3, N_IN>::zeros();
        for k in 0..N_IN {
            let sk = sig.get(k).copied().unwrap_or(0.0);
            if sk == 0.0 {
                continue;
            }
            let h = (sk * 1e-2).max(1e-9);
            let (mut a, mut b) = (x0, x0);
            a[k] += h;
            b[k] -= h;
            let (pa, pb) = (self.pipeline(&a)?, self.pipeline(&b)?);
            j.set_column(k, &((pa - pb) / (2.0 * h)));
        }
        let s = SMatrix::<f64, N_IN, N_IN>::from_diagonal(&SMatrix::<f64, N_IN, 1>::from_iterator(
            sig.iter().map(|v| v * v),
        ));
        Some((p0, j * s * j.transpose()))
    }

    /// One Monte-Carlo sample of the point: every uncertain input drawn from its Gaussian.
    pub fn sample(
        &self,
        left_px: Point2<f64>,
        right_px: Point2<f64>,
        rng: &mut stride_core::rng::SplitMix64,
    ) -> Option<Point3<f64>> {
        let mut x = self.nominal(left_px, right_px);
        for (xi, s) in x.iter_mut().zip(self.sigmas()) {
            *xi += s * rng.normal();
        }
        self.pipeline(&x)
    }
}

/// Paper 000's stereo artifact filter (section 4.1) for a depth or disparity image
/// (0 = no data):
///
/// 1. empty pixels are filled with the mean of the non-zero pixels of their row and column
///    (eq. 4);
/// 2. the filled image is smoothed with a `median_window` x `median_window` median filter
///    (75 px in the paper);
/// 3. a mask keeps the pixels that differ from the smoothed image by less than
///    `max_relative_difference` (10 %) of it;
/// 4. the mask is opened (eroded then dilated with a 3 x 3 square) to drop small groups;
/// 5. pixels outside the mask are cleared.
///
/// Returns the filtered image and the number of pixels removed. The median uses a 256-bin
/// histogram over the image's value range (Huang's running median), so values are compared
/// at 1/256 of that range, far finer than the 10 % test.
pub fn artifact_filter(
    image: &[f32],
    width: usize,
    height: usize,
    median_window: usize,
    max_relative_difference: f32,
) -> (Vec<f32>, usize) {
    let n = width * height;
    if image.len() != n || n == 0 {
        return (image.to_vec(), 0);
    }
    // 1. Row/column means of the non-zero pixels (eq. 4).
    let (mut row_sum, mut row_n) = (vec![0.0f64; height], vec![0usize; height]);
    let (mut col_sum, mut col_n) = (vec![0.0f64; width], vec![0usize; width]);
    for (i, &v) in image.iter().enumerate() {
        if v > 0.0 && v.is_finite() {
            let (r, c) = (i / width, i % width);
            if let (Some(rs), Some(rn)) = (row_sum.get_mut(r), row_n.get_mut(r)) {
                *rs += f64::from(v);
                *rn += 1;
            }
            if let (Some(cs), Some(cn)) = (col_sum.get_mut(c), col_n.get_mut(c)) {
                *cs += f64::from(v);
                *cn += 1;
            }
        }
    }
    let filled: Vec<f32> = image
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            if v > 0.0 && v.is_finite() {
                return v;
            }
            let (r, c) = (i / width, i % width);
            let at = |v: &[usize], k: usize| v.get(k).copied().unwrap_or(0);
            let sum = |v: &[f64], k: usize| v.get(k).copied().unwrap_or(0.0);
            let cnt = at(&row_n, r) + at(&col_n, c);
            if cnt == 0 {
                0.0
            } else {
                ((sum(&row_sum, r) + sum(&col_sum, c)) / cnt as f64) as f32
            }
        })
        .collect();
    // 2. Median filter (Huang's running histogram median).
    let (lo, hi) = filled
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let span = (hi - lo).max(1e-12);
    let bin = |v: f32| (((v - lo) / span * 255.0).round() as usize).min(255);
    let r = (median_window.max(1) / 2) as i64;
    let mut smooth = vec![0.0f32; n];
    for y in 0..height as i64 {
        let mut hist = [0u32; 256];
        let mut count = 0u32;
        let add = |hist: &mut [u32; 256], count: &mut u32, x: i64, sign: i32| {
            if x < 0 || x >= width as i64 {
                return;
            }
            for yy in (y - r).max(0)..=(y + r).min(height as i64 - 1) {
                let Some(&v) = filled.get(yy as usize * width + x as usize) else {
                    continue;
                };
                let Some(h) = hist.get_mut(bin(v)) else {
                    continue;
                };
                if sign > 0 {
                    *h += 1;
                    *count += 1;
                } else {
                    *h = h.saturating_sub(1);
                    *count = count.saturating_sub(1);
                }
            }
        };
        for x in -r..r {
            add(&mut hist, &mut count, x, 1);
        }
        for x in 0..width as i64 {
            add(&mut hist, &mut count, x + r, 1);
            if x - r > 0 {
                add(&mut hist, &mut count, x - r - 1, -1);
            }
            let half = count.div_ceil(2);
            let (mut acc, mut b) = (0u32, 0usize);
            while let Some(&h) = hist.get(b).filter(|&&h| b < 255 && acc + h < half) {
                acc += h;
                b += 1;
            }
            if let Some(out) = smooth.get_mut(y as usize * width + x as usize) {
                *out = lo + b as f32 / 255.0 * span;
            }
        }
    }
    // 3. Mask of pixels close to the smoothed image.
    let mut mask: Vec<bool> = image
        .iter()
        .zip(&smooth)
        .map(|(&v, &s)| {
            v > 0.0 && v.is_finite() && (v - s).abs() < max_relative_difference * s.abs()
        })
        .collect();
    // 4. Opening: erosion then dilation, 3 x 3.
    let morph = |m: &[bool], erode: bool| -> Vec<bool> {
        (0..n)
            .map(|i| {
                let (y, x) = ((i / width) as i64, (i % width) as i64);
                let mut all = true;
                let mut any = false;
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (yy, xx) = (y + dy, x + dx);
                        let v = yy >= 0
                            && xx >= 0
                            && yy < height as i64
                            && xx < width as i64
                            && m.get(yy as usize * width + xx as usize)
                                .copied()
                                .unwrap_or(false);
                        all &= v;
                        any |= v;
                    }
                }
                if erode {
                    all
                } else {
                    any
                }
            })
            .collect()
    };
    mask = morph(&morph(&mask, true), false);
    // 5. Apply.
    let mut removed = 0;
    let out = image
        .iter()
        .zip(&mask)
        .map(|(&v, &keep)| {
            if keep {
                v
            } else {
                if v > 0.0 {
                    removed += 1;
                }
                0.0
            }
        })
        .collect();
    (out, removed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stride_core::rng::SplitMix64;

    fn rig() -> StereoModel {
        let left = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480)
            .unwrap()
            .with_distortion(BrownConrady::from_array([-0.2, 0.05, 0.001, -0.001, 0.0]))
            .unwrap();
        let right = PinholeCamera::new(502.0, 501.0, 318.0, 242.0, 640, 480)
            .unwrap()
            .with_distortion(BrownConrady::from_array([-0.19, 0.04, 0.0, 0.001, 0.0]))
            .unwrap();
        StereoModel {
            left,
            right,
            right_from_left: Isometry3::from_parts(
                nalgebra::Translation3::new(-0.09, 0.001, 0.0),
                nalgebra::UnitQuaternion::from_euler_angles(0.002, -0.003, 0.001),
            ),
            left_sigmas: IntrinsicSigmas {
                focal_and_centre_px: [0.5, 0.5, 0.4, 0.4],
                distortion: [0.002, 0.002, 0.0002, 0.0002, 0.0],
            },
            right_sigmas: IntrinsicSigmas {
                focal_and_centre_px: [0.5, 0.5, 0.4, 0.4],
                distortion: [0.002, 0.002, 0.0002, 0.0002, 0.0],
            },
            translation_sigma_m: 0.0005,
            rotation_sigma_rad: 0.0005,
            pixel_sigma_px: 0.3,
        }
    }

    #[test]
    fn triangulates_a_known_point_and_its_covariance_matches_monte_carlo() {
        let m = rig();
        let p = Point3::new(0.3, -0.2, 2.5);
        let lp = m.left.project(&p).unwrap();
        let rp = m.right.project(&(m.right_from_left * p)).unwrap();
        let (q, cov) = m.point_and_covariance(lp, rp).unwrap();
        assert!((q - p).norm() < 1e-6, "{q} vs {p}");
        // Depth is the least certain direction.
        assert!(cov[(2, 2)] > 10.0 * cov[(0, 0)]);
        let mut rng = SplitMix64::new(11);
        let n = 20_000;
        let samples: Vec<Point3<f64>> = (0..n).filter_map(|_| m.sample(lp, rp, &mut rng)).collect();
        let mean =
            samples.iter().fold(Vector3::zeros(), |a, s| a + s.coords) / samples.len() as f64;
        let mut mc = Matrix3::zeros();
        for s in &samples {
            mc += (s.coords - mean) * (s.coords - mean).transpose();
        }
        mc /= (samples.len() - 1) as f64;
        for i in 0..3 {
            let rel = (mc[(i, i)] / cov[(i, i)] - 1.0).abs();
            assert!(
                rel < 0.1,
                "axis {i}: Monte Carlo {} vs model {}",
                mc[(i, i)],
                cov[(i, i)]
            );
        }
    }

    #[test]
    fn artifact_filter_removes_halos_and_speckles_and_keeps_surfaces() {
        let (w, h) = (160, 120);
        let mut img = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let inside = (60..100).contains(&x) && (40..80).contains(&y);
                img[y * w + x] = if inside { 1.0 } else { 3.0 + 0.002 * y as f32 };
            }
        }
        let mut rng = SplitMix64::new(3);
        let mut artifacts = 0;
        // A halo of intermediate depths around the object's right edge.
        for y in 40..80 {
            for x in 100..103 {
                img[y * w + x] = 2.0;
                artifacts += 1;
            }
        }
        // Isolated speckles and some holes.
        for _ in 0..40 {
            let i = rng.below(w * h);
            img[i] = 0.4;
            artifacts += 1;
        }
        for _ in 0..200 {
            img[rng.below(w * h)] = 0.0;
        }
        let (out, _) = artifact_filter(&img, w, h, 75, 0.1);
        let halo_left = (40..80)
            .flat_map(|y| (100..103).map(move |x| y * w + x))
            .filter(|&i| out[i] > 0.0)
            .count();
        let speckles_left = out
            .iter()
            .filter(|&&v| v > 0.0 && (v - 0.4).abs() < 1e-6)
            .count();
        let kept = out.iter().filter(|&&v| v > 2.5).count() as f64
            / img.iter().filter(|&&v| v > 2.5).count() as f64;
        assert_eq!(halo_left, 0, "halo pixels survive");
        assert_eq!(speckles_left, 0);
        assert!(kept > 0.9, "background kept: {kept}");
        assert!(artifacts > 100);
    }
}
