//! Motion blur along each pixel's own image motion, for asking paper 004's question of
//! recorded frames: how does the SLAM cope when the camera moves during the exposure?
//!
//! A frame's motion comes from its ground truth: each pixel is back-projected with its
//! depth (the frame's median depth where it has none), moved with the camera's poses
//! `half_window_s` before and after the frame, and re-projected; the difference is the
//! pixel's image motion. The blur of a pixel is a line along that motion, centred on the
//! pixel, whose length is the pixel's motion scaled so that the frame's median motion is
//! `length_px`: every frame gets the same amount of blur (as a fixed exposure at a fixed
//! gait would give) while each pixel keeps its own direction and its relative length
//! (near surfaces and the far side of a rotation blur more). The colour image is blurred;
//! depth is left as it is (structured-light depth is not blurred the same way).
//!
//! The line is sampled every pixel or closer (bilinear, clamped at the image's borders)
//! and averaged: the image the pixel would gather over the exposure.

use nalgebra::{Isometry3, Point2};
use rayon::prelude::*;
use stride_core::camera::PinholeCamera;
use stride_core::image::{DepthImage, RgbImage};
use stride_core::trajectory::Trajectory;

/// Depth (m) assumed where a frame has no depth at all.
const FALLBACK_DEPTH_M: f64 = 1.5;

/// How a frame is blurred.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionBlur {
    /// The frame's median blur length (px): 0 leaves the frame as it is.
    pub length_px: f64,
    /// The motion is measured between the poses this long before and after the frame (s):
    /// long enough that motion-capture noise does not turn the direction (0.1 s, as the
    /// peers' blur tool), short enough to follow the camera's turns.
    pub half_window_s: f64,
}

impl Default for MotionBlur {
    fn default() -> Self {
        Self {
            length_px: 15.0,
            half_window_s: 0.1,
        }
    }
}

/// Why a frame could not be blurred.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotionBlurError {
    /// The blur length or window is not a finite, non-negative (window: positive) number.
    #[error("blur length {length_px} px and half window {half_window_s} s: the length must be finite and not negative, the window finite and positive")]
    Parameter {
        /// The length asked for (px).
        length_px: f64,
        /// The half window asked for (s).
        half_window_s: f64,
    },
    /// The colour and depth images, or the camera, differ in size.
    #[error("colour {rgb:?}, depth {depth:?} and camera {camera:?} (width, height) differ")]
    Size {
        /// Colour image size (px).
        rgb: (u32, u32),
        /// Depth image size (px).
        depth: (u32, u32),
        /// Camera image size (px).
        camera: (u32, u32),
    },
    /// The ground truth does not cover any time near the frame.
    #[error("no ground-truth pose near t = {t_s:.6} s (the ground truth spans {span:?})")]
    NoPose {
        /// The frame's time (s).
        t_s: f64,
        /// The ground truth's time span (s), when it has poses.
        span: Option<(f64, f64)>,
    },
}

/// A blurred frame and what its motion was.
#[derive(Debug, Clone, PartialEq)]
pub struct Blurred {
    /// The blurred colour image.
    pub rgb: RgbImage,
    /// The frame's median image motion over `2 half_window_s` before scaling (px): 0 when
    /// the camera did not move (the frame is then left as it is).
    pub median_motion_px: f64,
}

/// Blurs the colour image `rgb` of a frame taken at `t_s` (s) with depth `depth_m` through
/// `camera`, along each pixel's image motion from the ground truth `world_from_camera` (see
/// the module documentation). Times outside the ground truth's span take the motion at its
/// nearest end.
pub fn blur_frame(
    rgb: &RgbImage,
    depth_m: &DepthImage,
    camera: &PinholeCamera,
    groundtruth: &Trajectory,
    t_s: f64,
    blur: &MotionBlur,
) -> Result<Blurred, MotionBlurError> {
    let MotionBlur {
        length_px,
        half_window_s: h,
    } = *blur;
    if !(length_px.is_finite() && length_px >= 0.0 && h.is_finite() && h > 0.0) {
        return Err(MotionBlurError::Parameter {
            length_px,
            half_window_s: h,
        });
    }
    let (w, ht) = (rgb.width(), rgb.height());
    if (w, ht) != (depth_m.width(), depth_m.height())
        || (w, ht) != (camera.width(), camera.height())
    {
        return Err(MotionBlurError::Size {
            rgb: (w, ht),
            depth: (depth_m.width(), depth_m.height()),
            camera: (camera.width(), camera.height()),
        });
    }
    let span = groundtruth.time_span_s();
    let no_pose = || MotionBlurError::NoPose { t_s, span };
    let (t0, t1) = span.ok_or_else(no_pose)?;
    // The window, moved inside the ground truth's span when it reaches past an end.
    let tc = t_s.clamp(t0, t1);
    let (ta, tb) = ((tc - h).max(t0), (tc + h).min(t1));
    let pose = |t: f64| groundtruth.interpolate(t).ok_or_else(no_pose);
    let world_from_now = pose(tc)?;
    let before_from_now = pose(ta)?.inverse() * world_from_now;
    let after_from_now = pose(tb)?.inverse() * world_from_now;
    let flow = motion_field(depth_m, camera, &before_from_now, &after_from_now);
    let mut norms: Vec<f64> = flow
        .iter()
        .map(|f| f.0.hypot(f.1))
        .filter(|n| n.is_finite())
        .collect();
    let median = if norms.is_empty() {
        0.0
    } else {
        let mid = norms.len() / 2;
        *norms.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    if median <= 1e-9 || length_px == 0.0 {
        return Ok(Blurred {
            rgb: rgb.clone(),
            median_motion_px: median,
        });
    }
    let scale = length_px / median;
    let src = rgb.as_slice();
    let wu = w as usize;
    let mut out = vec![[0u8; 3]; src.len()];
    out.par_chunks_mut(wu.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            for (u, px) in row.iter_mut().enumerate() {
                let (fx, fy) = flow.get(v * wu + u).copied().unwrap_or((0.0, 0.0));
                let (dx, dy) = (fx * scale, fy * scale);
                *px = line_average(src, (w, ht), (u as f64, v as f64), (dx, dy));
            }
        });
    let rgb = RgbImage::from_vec(w, ht, out).map_err(|_| MotionBlurError::Size {
        rgb: (w, ht),
        depth: (depth_m.width(), depth_m.height()),
        camera: (camera.width(), camera.height()),
    })?;
    Ok(Blurred {
        rgb,
        median_motion_px: median,
    })
}

/// Each pixel's image motion (px, row-major) from the pose `before_from_now` to
/// `after_from_now` (camera frames), at its depth or the frame's median depth; NaN where a
/// pose puts the point behind the camera.
fn motion_field(
    depth_m: &DepthImage,
    camera: &PinholeCamera,
    before_from_now: &Isometry3<f64>,
    after_from_now: &Isometry3<f64>,
) -> Vec<(f64, f64)> {
    let d = depth_m.as_slice();
    let mut valid: Vec<f32> = d
        .iter()
        .copied()
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    let fallback = if valid.is_empty() {
        FALLBACK_DEPTH_M
    } else {
        let mid = valid.len() / 2;
        f64::from(*valid.select_nth_unstable_by(mid, f32::total_cmp).1)
    };
    let w = depth_m.width() as usize;
    (0..d.len())
        .into_par_iter()
        .map(|i| {
            let z = d
                .get(i)
                .map(|&x| f64::from(x))
                .filter(|x| x.is_finite() && *x > 0.0)
                .unwrap_or(fallback);
            let px = Point2::new((i % w.max(1)) as f64, (i / w.max(1)) as f64);
            let p = camera.unproject(&px, z);
            match (
                camera.project(&(before_from_now * p)),
                camera.project(&(after_from_now * p)),
            ) {
                (Some(a), Some(b)) => (b.x - a.x, b.y - a.y),
                _ => (f64::NAN, f64::NAN),
            }
        })
        .collect()
}

/// The mean colour along the segment from `c - s/2` to `c + s/2` (px), sampled at least
/// once per pixel of its length, bilinearly, clamped at the borders of the `size` image.
fn line_average(src: &[[u8; 3]], size: (u32, u32), c: (f64, f64), s: (f64, f64)) -> [u8; 3] {
    let (w, h) = (size.0 as usize, size.1 as usize);
    let len = s.0.hypot(s.1);
    let n = if len.is_finite() {
        len.ceil() as usize + 1
    } else {
        1
    };
    let at = |x: usize, y: usize| src.get(y * w + x).copied().unwrap_or([0; 3]);
    let mut acc = [0.0f64; 3];
    for k in 0..n {
        let f = if n == 1 {
            0.0
        } else {
            k as f64 / (n - 1) as f64 - 0.5
        };
        let x = (c.0 + f * s.0).clamp(0.0, (w.max(1) - 1) as f64);
        let y = (c.1 + f * s.1).clamp(0.0, (h.max(1) - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w.max(1) - 1), (y0 + 1).min(h.max(1) - 1));
        let (ax, ay) = (x - x0 as f64, y - y0 as f64);
        let (p00, p10, p01, p11) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
        for (ch, a) in acc.iter_mut().enumerate() {
            let v = |p: [u8; 3]| f64::from(p.get(ch).copied().unwrap_or(0));
            *a += (v(p00) * (1.0 - ax) + v(p10) * ax) * (1.0 - ay)
                + (v(p01) * (1.0 - ax) + v(p11) * ax) * ay;
        }
    }
    acc.map(|a| (a / n as f64).round().clamp(0.0, 255.0) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn camera() -> PinholeCamera {
        PinholeCamera::new(100.0, 100.0, 39.5, 29.5, 80, 60).unwrap()
    }

    /// A vertical bar seen by a camera moving sideways (along x) smears along x only, by
    /// the requested length, and keeps its mean brightness; a frame without motion, or
    /// asked for no blur, is left as it is.
    #[test]
    fn a_sideways_move_smears_a_bar_along_the_motion() {
        let cam = camera();
        let mut rgb = RgbImage::filled(80, 60, [0, 0, 0]);
        for v in 0..60 {
            for u in 38..42 {
                *rgb.get_mut(u, v).unwrap() = [200, 100, 50];
            }
        }
        let depth = DepthImage::filled(80, 60, 2.0);
        let mut gt = Trajectory::new();
        for k in 0..=20 {
            let t = f64::from(k) * 0.01;
            let pose = Isometry3::from_parts(
                Translation3::new(0.1 * t, 0.0, 0.0),
                UnitQuaternion::identity(),
            );
            gt.push(t, pose).unwrap();
        }
        let blur = MotionBlur {
            length_px: 12.0,
            half_window_s: 0.05,
        };
        let b = blur_frame(&rgb, &depth, &cam, &gt, 0.1, &blur).unwrap();
        // 0.01 m of motion at 2 m and f = 100 px: 0.5 px, scaled to 12.
        assert!(
            (b.median_motion_px - 0.5).abs() < 1e-9,
            "{}",
            b.median_motion_px
        );
        let row = |img: &RgbImage, v: u32| -> Vec<u8> {
            (0..80).map(|u| img.get(u, v).unwrap()[0]).collect()
        };
        let r = row(&b.rgb, 30);
        // Smeared over about 4 + 12 px, no longer a sharp bar, brightness kept.
        let lit = r.iter().filter(|&&x| x > 0).count();
        assert!((14..=18).contains(&lit), "{r:?}");
        assert!(r.iter().all(|&x| x < 200), "{r:?}");
        let sum: u32 = r.iter().map(|&x| u32::from(x)).sum();
        assert!((sum as i64 - 800).abs() < 24, "{sum}");
        // Every row the same: no vertical smear.
        assert!((0..60).all(|v| row(&b.rgb, v) == r));
        let still = MotionBlur {
            length_px: 0.0,
            ..blur
        };
        assert_eq!(
            blur_frame(&rgb, &depth, &cam, &gt, 0.1, &still)
                .unwrap()
                .rgb,
            rgb
        );
        let mut fixed = Trajectory::new();
        fixed.push(0.0, Isometry3::identity()).unwrap();
        fixed.push(1.0, Isometry3::identity()).unwrap();
        assert_eq!(
            blur_frame(&rgb, &depth, &cam, &fixed, 0.5, &blur)
                .unwrap()
                .rgb,
            rgb
        );
    }

    #[test]
    fn bad_input_is_an_error() {
        let cam = camera();
        let rgb = RgbImage::filled(80, 60, [9, 9, 9]);
        let depth = DepthImage::filled(80, 60, 1.0);
        let mut gt = Trajectory::new();
        let blur = MotionBlur::default();
        assert!(matches!(
            blur_frame(&rgb, &depth, &cam, &gt, 0.0, &blur),
            Err(MotionBlurError::NoPose { span: None, .. })
        ));
        gt.push(0.0, Isometry3::identity()).unwrap();
        let small = DepthImage::filled(40, 30, 1.0);
        assert!(matches!(
            blur_frame(&rgb, &small, &cam, &gt, 0.0, &blur),
            Err(MotionBlurError::Size { .. })
        ));
        let nan = MotionBlur {
            length_px: f64::NAN,
            ..blur
        };
        assert!(matches!(
            blur_frame(&rgb, &depth, &cam, &gt, 0.0, &nan),
            Err(MotionBlurError::Parameter { .. })
        ));
    }
}
