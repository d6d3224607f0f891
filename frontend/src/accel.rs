//! An accelerometer's translation for the rolling-shutter correction.
//!
//! Each keypoint is brought back from its row's time to the frame's with the camera's
//! motion during the readout ([`ShutterMotion`]). Its rotation comes from a gyroscope
//! (`crate::gyro`); without an accelerometer its translation is the last frame interval's
//! mean velocity times the row's delay. On a walking robot both parts of that are wrong
//! at a foot's impact: the interval's mean velocity is the velocity of 17 ms before the
//! frame (at 30 Hz), and the velocity changes within the 20 ms readout. On the synthetic
//! lab's fastest tripod walk, the true velocity in place of the interval's took the ATE
//! from 0.40 to 0.35 mm and a global shutter to 0.21 (docs/blur.md, "Where the fastest
//! walk's error is").
//!
//! Given an accelerometer that samples the readout densely enough (at least 200 Hz,
//! [`MAX_ACCEL_GAP_S`]), the camera's acceleration `a = R f - up` (the specific force `f`
//! rotated into the frame's camera, less the reaction to gravity `up`) gives
//! * the frame's velocity: `v = D / dt + (1 / dt) integral over the interval of
//!   (sigma - t_prev) a(sigma)`, exact for any acceleration when `D` is the interval's
//!   displacement (the estimated motion's; the prediction's before the motion is known);
//! * each row's position: `p(s) = v s + double integral of a from 0 to s`, averaged over
//!   the row's exposure when it is known, as the rotations are.
//!
//! `up` is the mean of every specific force seen so far, each rotated into the odometry's
//! world by its frame's pose: over a walk the robot's own accelerations average out. An
//! error of 1 m/s² in it moves a row 10 ms from the middle by 0.05 mm and the frame's
//! velocity by 8 mm/s at 30 Hz. Each sample is turned into the frame's camera by the
//! gyroscope's rotation integrated back from the frame when it covers the interval (at
//! 10 Hz the camera turns by up to 0.1 rad within one, tilting `f` by up to 1 m/s²), else
//! by the interval's constant rate.

use crate::points::{RowTranslations, ShutterMotion, ROTATION_KNOTS};
use crate::series::Series;
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};

/// Largest gap between the two accelerometer samples around an instant (s): an
/// accelerometer of 200 Hz or more. A foot's impact changes the acceleration within a few
/// milliseconds; a slower one (a Kinect's tilt sensor) is not used for the readout.
pub const MAX_ACCEL_GAP_S: f64 = 0.0055;

/// Longest frame interval whose velocity change is integrated (s): beyond it (a dropped
/// stretch of frames) the interval's mean velocity says little about the frame's.
const MAX_INTERVAL_S: f64 = 0.2;

/// Integration substeps between two knots of [`RowTranslations`].
const SUBSTEPS: usize = 4;

/// Longest integration step over the frame interval (s).
const INTERVAL_STEP_S: f64 = 0.00125;

/// The integration steps over a frame interval of `dt_s` (s): how many, and how long (s).
fn interval_steps(dt_s: f64) -> (usize, f64) {
    let n = (dt_s / INTERVAL_STEP_S).ceil().max(1.0) as usize;
    (n, dt_s / n as f64)
}

/// How many frames took an accelerometer's samples for their readout
/// ([`VisualOdometry::add_accelerometer`]), and how many the samples did not cover (those
/// kept the interval's mean velocity, as without an accelerometer).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct AccelerometerFrames {
    /// Frames whose rolling-shutter correction took the accelerometer's translation
    /// ([`crate::VoConfig::readout_accelerometer`]) ...
    pub readout: usize,
    /// ... and frames with a rolling shutter and a frame interval that the samples did not
    /// cover (or covered too sparsely: samples more than 5.5 ms apart).
    pub readout_not_covered: usize,
}

/// The accelerometer's samples, the reaction to gravity they show, and what they were
/// used for.
#[derive(Debug, Clone, Default)]
pub(crate) struct Accel {
    /// Time (s) and specific force in the camera frame (m/s²), in time order.
    samples: Series,
    /// The sum of the samples summed so far, each rotated into the odometry's world frame
    /// by its frame's orientation (m/s²), and how many.
    up_sum_world: Vector3<f64>,
    up_count: usize,
    /// Time of the last sample summed (s).
    summed_until_s: Option<f64>,
    /// Frames whose readout took the accelerometer's translation, and frames it missed.
    used: usize,
    missed: usize,
}

impl Accel {
    /// Adds to the reaction to gravity the samples after the last summed, up to `until_s`,
    /// each rotated into the world by `world_from_camera` (the orientation of the frame
    /// at `until_s`; the walk turns the camera by a few degrees within an interval).
    fn sum_up_to(&mut self, world_from_camera: &UnitQuaternion<f64>, until_s: f64) {
        let after = self.summed_until_s;
        for (_, f) in self.samples.between(after, until_s) {
            self.up_sum_world += world_from_camera * f;
            self.up_count += 1;
        }
        if self.up_count > 0 {
            self.summed_until_s = Some(after.map_or(until_s, |a| a.max(until_s)));
        }
    }

    /// The mean specific force over `[t0_s, t1_s]` in the camera frame (m/s²), from the
    /// samples in it; `None` without one.
    fn mean_between(&self, t0_s: f64, t1_s: f64) -> Option<Vector3<f64>> {
        let inside = self
            .samples
            .between(None, t1_s)
            .iter()
            .filter(|(t, _)| *t >= t0_s);
        let (sum, n) = inside.fold((Vector3::zeros(), 0usize), |(s, n), (_, f)| (s + f, n + 1));
        (n > 0).then(|| sum / n as f64)
    }

    /// The camera's position over the readout of the frame at `t_s` (see the module's
    /// doc), in its frame at `t_s`: `up_cam` the reaction to gravity (m/s²), `d_cam` the
    /// displacement over the last `dt_s` seconds and `omega_rad_s` the angular velocity,
    /// all in that frame; `interval_rotations`, when a gyroscope gives them, the rotations
    /// `cam(t_s) <- cam(t_s - (k + 0.5) h)` over the [`interval_steps`] of `dt_s` (else the
    /// constant rate `omega_rad_s`). `None` unless the samples cover the interval, the
    /// readout and half an exposure either side.
    #[allow(clippy::too_many_arguments)] // each is one physical quantity of the frame
    fn translations(
        &self,
        up_cam: &Vector3<f64>,
        d_cam: &Vector3<f64>,
        omega_rad_s: &Vector3<f64>,
        interval_rotations: Option<&[UnitQuaternion<f64>]>,
        dt_s: f64,
        t_s: f64,
        (readout_s, exposure_s): (f64, f64),
    ) -> Option<RowTranslations> {
        let step_s = readout_s / (ROTATION_KNOTS - 1) as f64;
        if !(step_s > 0.0 && exposure_s >= 0.0 && dt_s > 0.0 && dt_s <= MAX_INTERVAL_S) {
            return None;
        }
        // The camera's acceleration at t_s + sigma in its frame at t_s (m/s²), the camera
        // at t_s + sigma turned by `frame_from` from the frame's.
        let accel_turned = |sigma: f64, frame_from: UnitQuaternion<f64>| {
            let f = self.samples.at(t_s + sigma, MAX_ACCEL_GAP_S)?;
            Some(frame_from * f - up_cam)
        };
        let accel =
            |sigma: f64| accel_turned(sigma, UnitQuaternion::from_scaled_axis(omega_rad_s * sigma));
        // The frame's velocity, midpoint rule over the interval (u: time since its start).
        let (n, h) = interval_steps(dt_s);
        let mut weighted = Vector3::zeros();
        for k in 0..n {
            let u = (k as f64 + 0.5) * h;
            let a = match interval_rotations {
                Some(r) => accel_turned(u - dt_s, *r.get(n - 1 - k)?)?,
                None => accel(u - dt_s)?,
            };
            weighted += a * (u * h);
        }
        let v_frame = (d_cam + weighted) / dt_s;
        // Positions at the knots, padded by half an exposure, integrated outwards from the
        // frame's time (the middle knot) in both directions.
        let pad = (0.5 * exposure_s / step_s).round() as usize;
        let mid = pad + ROTATION_KNOTS / 2;
        let knots = ROTATION_KNOTS + 2 * pad;
        let mut p_knot = vec![Vector3::zeros(); knots];
        for (dir, count) in [(1.0, knots - 1 - mid), (-1.0, mid)] {
            let hh = dir * step_s / SUBSTEPS as f64;
            let (mut p, mut v, mut s) = (Vector3::zeros(), v_frame, 0.0);
            for j in 1..=count {
                for _ in 0..SUBSTEPS {
                    let a = accel(s + 0.5 * hh)?;
                    p += v * hh + a * (0.5 * hh * hh);
                    v += a * hh;
                    s += hh;
                }
                let i = if dir > 0.0 { mid + j } else { mid - j };
                *p_knot.get_mut(i)? = p;
            }
        }
        // Each readout knot: the mean position over the exposure centred on it (the
        // trapezoid rule over the knots within half an exposure).
        let mut mean = [Vector3::zeros(); ROTATION_KNOTS];
        for (m, window) in mean.iter_mut().zip(p_knot.windows(2 * pad + 1)) {
            *m = match window {
                [only] => *only,
                [first, inner @ .., last] => {
                    let sum = inner.iter().sum::<Vector3<f64>>() + (first + last) * 0.5;
                    sum / (window.len() - 1) as f64
                }
                [] => Vector3::zeros(), // windows of 2 pad + 1 >= 1 knots
            };
        }
        Some(RowTranslations {
            first_s: -readout_s / 2.0,
            step_s,
            p_frame_knot: mean,
        })
    }
}

impl VisualOdometry {
    /// Adds accelerometer samples: time (s, the frames' clock) and the specific force in
    /// the camera frame (m/s²; see `stride_datasets::accelerometer` for the convention).
    /// Samples older than the last one held are ignored, so a robot may hand them over as
    /// they arrive; a frame needs samples up to the end of its readout, so hand them over
    /// before the frame. Used for the rolling-shutter correction's translation while
    /// `readout_accelerometer` is on, the camera has a rolling shutter and the samples are
    /// dense enough (at most 5.5 ms apart: 200 Hz or more).
    pub fn add_accelerometer(&mut self, samples: &[(f64, Vector3<f64>)]) {
        self.accel.samples.extend(samples);
    }

    /// What the accelerometer's samples were used for, frame by frame.
    pub fn accelerometer_frames(&self) -> AccelerometerFrames {
        AccelerometerFrames {
            readout: self.accel.used,
            readout_not_covered: self.accel.missed,
        }
    }

    /// Replaces `motion`'s translation by the accelerometer's over the readout of the frame
    /// at `t_s`, which moved by `prev_from_cur` over the last `dt_s` seconds, when
    /// `readout_accelerometer` is on and the samples cover it. `count` tallies the frame
    /// (once per frame) and sums its interval's samples into the reaction to gravity.
    pub(crate) fn readout_translation(
        &mut self,
        motion: &mut ShutterMotion,
        prev_from_cur: &Isometry3<f64>,
        dt_s: f64,
        t_s: f64,
        count: bool,
    ) {
        if !self.config.readout_accelerometer || self.accel.samples.is_empty() {
            return;
        }
        if count {
            let world_from_prev = self.world_from_prev.rotation;
            self.accel.sum_up_to(&world_from_prev, self.prev_t);
        }
        let world_from_cur = (self.world_from_prev * prev_from_cur).rotation;
        let up_cam = if self.accel.up_count > 0 {
            Some(world_from_cur.inverse() * self.accel.up_sum_world / self.accel.up_count as f64)
        } else {
            self.accel.mean_between(t_s - dt_s, t_s)
        };
        let d_cam = prev_from_cur.rotation.inverse() * prev_from_cur.translation.vector;
        // Over a long interval (10 Hz frames) the camera's turn within it matters to the
        // acceleration's direction: the gyroscope's, when it covers the interval.
        let (n, h) = interval_steps(dt_s);
        let turned = (self.config.readout_gyroscope && dt_s <= MAX_INTERVAL_S)
            .then(|| self.gyro.rotations_before(t_s, h, n))
            .flatten();
        let rows = up_cam.and_then(|up| {
            self.accel.translations(
                &up,
                &d_cam,
                &motion.omega_rad_s,
                turned.as_deref(),
                dt_s,
                t_s,
                (self.config.rolling_shutter_s, self.config.exposure_s),
            )
        });
        if rows.is_some() {
            self.accel.used += usize::from(count);
        } else {
            self.accel.missed += usize::from(count);
        }
        motion.translations = rows;
        if count {
            // Frames come in time order; the interval and readout of the next frame start
            // after this one's interval began.
            self.accel.samples.forget_before(t_s - 2.0 * MAX_INTERVAL_S);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of a camera that does not turn, accelerating along x by `a(t)` while the
    /// reaction to gravity reads `up` (both m/s², the camera frame), at 1 kHz from -0.1 s.
    fn accel_of(a: impl Fn(f64) -> f64, up: Vector3<f64>) -> Accel {
        let samples: Vec<_> = (0..=200)
            .map(|k| {
                let t = -0.1 + k as f64 * 1e-3;
                (t, up + Vector3::x() * a(t))
            })
            .collect();
        Accel {
            samples: Series::from(samples),
            ..Accel::default()
        }
    }

    #[test]
    fn integrates_the_frames_velocity_and_each_rows_position() {
        // Velocity along x: v(t) = 0.1 + 3 t^2 (m/s), a = 6 t; the frame at t = 0, the
        // previous one 33 ms before. The interval's mean velocity is 0.1 + 1.1e-3, the
        // frame's 0.1; a row s after the frame is at 0.1 s + s^3.
        let up = Vector3::new(0.0, -9.81, 0.0);
        let acc = accel_of(|t| 6.0 * t, up);
        let dt = 0.033;
        let d = Vector3::x() * (0.1 * dt + dt * dt * dt);
        let r = acc
            .translations(&up, &d, &Vector3::zeros(), None, dt, 0.0, (0.02, 0.0))
            .unwrap();
        for s in [-0.01, -0.004, 0.0, 0.0035, 0.01] {
            let truth = 0.1 * s + s * s * s;
            let got = r.at(s);
            assert!(
                (got - Vector3::x() * truth).norm() < 1e-8,
                "s {s}: {got} against {truth}"
            );
        }
        // The interval's mean velocity would be off at the last row by 1e-5 m.
        let mean_v = d / dt;
        assert!((mean_v * 0.01 - r.at(0.01)).norm() > 9e-6);
        // Gravity mistaken by 1 m/s² moves the last row by 0.5 * 1 * 0.01^2 plus the
        // velocity's error over the interval (half the interval's integral) times 0.01.
        let wrong = acc
            .translations(
                &(up + Vector3::x()),
                &d,
                &Vector3::zeros(),
                None,
                dt,
                0.0,
                (0.02, 0.0),
            )
            .unwrap();
        let expected = 0.5 * 1e-4 + 0.5 * dt * 0.01;
        assert!(((wrong.at(0.01) - r.at(0.01)).norm() - expected).abs() < 1e-6);
    }

    #[test]
    fn averages_over_the_exposure_and_refuses_what_it_cannot_cover() {
        // A constant acceleration of 2 m/s² through rest at the frame's time (v = 2 t, the
        // interval's displacement -dt^2): a row s after it is at s^2, whose mean over an
        // exposure e centred on s is s^2 + e^2 / 12.
        let up = Vector3::new(0.0, -9.81, 0.0);
        let acc = accel_of(|_| 2.0, up);
        let (e, dt) = (0.01, 0.033);
        let d = -Vector3::x() * dt * dt;
        let r = acc
            .translations(&up, &d, &Vector3::zeros(), None, dt, 0.0, (0.02, e))
            .unwrap();
        let got = r.at(0.01).x;
        let truth = 0.01f64.powi(2) + e * e / 12.0;
        // The trapezoid over 9 knots 1.25 ms apart is the continuous mean within 1e-6 m.
        assert!((got - truth).abs() < 1e-6, "{got} against {truth}");
        let none = |dt: f64, t: f64| {
            acc.translations(
                &up,
                &Vector3::zeros(),
                &Vector3::zeros(),
                None,
                dt,
                t,
                (0.02, 0.0),
            )
            .is_none()
        };
        assert!(none(0.3, 0.0), "an interval longer than 0.2 s");
        assert!(none(0.033, 0.095), "the readout ends past the samples");
        assert!(none(0.033, -0.08), "the interval starts before them");
        // Samples 10 ms apart (a 100 Hz accelerometer) are too sparse.
        let sparse = Accel {
            samples: Series::from(
                acc.samples
                    .samples()
                    .iter()
                    .step_by(10)
                    .copied()
                    .collect::<Vec<_>>(),
            ),
            ..Accel::default()
        };
        let sparse_r = sparse.translations(
            &up,
            &Vector3::zeros(),
            &Vector3::zeros(),
            None,
            0.033,
            0.0,
            (0.02, 0.0),
        );
        assert!(sparse_r.is_none());
    }

    #[test]
    fn the_reaction_to_gravity_is_the_mean_in_the_world() {
        let mut acc = accel_of(|t| (t * 40.0).sin(), Vector3::new(0.0, -9.81, 0.0));
        let level = UnitQuaternion::identity();
        acc.sum_up_to(&level, 0.0005);
        assert_eq!(acc.up_count, 101, "the samples from -0.1 s to 0 s");
        acc.sum_up_to(&level, 0.0005);
        assert_eq!(acc.up_count, 101, "none twice");
        acc.sum_up_to(&level, 0.0505);
        assert_eq!(acc.up_count, 151);
        // The mean of sin(40 t) over -0.1..0.05 s is -0.04.
        let up = acc.up_sum_world / acc.up_count as f64;
        assert!(
            (up.y + 9.81).abs() < 1e-9 && (up.x + 0.04).abs() < 0.01,
            "{up}"
        );
    }
}
