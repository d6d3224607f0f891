//! A gyroscope's rotation for the rolling-shutter correction and the motion prediction.
//!
//! Each keypoint is brought back from its row's time to the frame's with the camera's
//! motion during the readout ([`ShutterMotion`]). Without an inertial sensor that motion is
//! the last frame interval's average, which lags a walking robot's shake: on the synthetic
//! lab's fastest tripod walk it is off the frame's angular velocity by 0.10 rad/s rms, 42 %
//! of the rate itself, and the rolling shutter then doubles the walk's error (1.0 mm ATE
//! against 0.45 mm with a global shutter). Every legged robot carries a gyroscope: given
//! one ([`VisualOdometry::add_gyroscope`]), its rate is integrated over the readout into
//! the rotation from the frame's time to each row's ([`RowRotations`]; the translation is
//! the interval's velocity's, or an accelerometer's integral: `crate::accel`). The
//! integral, not one rate: a gait's foot impacts change the rate within the 20 ms readout
//! (on that walk, the rotation of a constant mean rate is off each row's by 0.30 px rms,
//! the integrated 400 Hz gyroscope's by 0.09 px), and the rate at the frame's time alone
//! made the lab's slow walks worse than the interval's velocity (0.33 -> 0.46 mm ATE).
//!
//! The same samples, integrated between two frames' times, give the rotation from one
//! frame to the next, which the odometry predicts before Lucas-Kanade tracks (the
//! constant-velocity prediction keeps its translation): at 30 Hz the lab's shake moves the
//! image 4 px per frame and the pyramid absorbs any guess, but with frames 100-170 ms apart
//! (dropped frames, a slow camera) the prediction matters (docs/blur.md). The rate around
//! each frame also tells the keyframe decision when a foot's impact has jolted the camera
//! (`crate::keyframe`).

use crate::points::{RowRotations, ShutterMotion, ROTATION_KNOTS};
use crate::series::Series;
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};

/// Largest gap between the two samples around a frame's time (s): beyond it the frame's
/// rate is not interpolated (the interval's motion is used, and the frame counted).
pub const MAX_GAP_S: f64 = 0.05;

/// Integration substeps between two knots of [`RowRotations`].
const ROTATION_SUBSTEPS: usize = 4;

/// How long samples are kept before the latest frame (s).
const KEEP_S: f64 = 1.0;

/// Longest integration step of the rotation between two frames (s).
const PREDICTION_STEP_S: f64 = 0.0025;

/// How many frames took a gyroscope's samples ([`VisualOdometry::add_gyroscope`]), and how
/// many the samples did not cover (those fell back on the last frame interval's motion, as
/// without a gyroscope).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct GyroscopeFrames {
    /// Frames whose rolling-shutter correction took the gyroscope's rotation
    /// ([`crate::VoConfig::readout_gyroscope`]) ...
    pub readout: usize,
    /// ... and frames with a rolling shutter that the samples did not cover.
    pub readout_not_covered: usize,
    /// Frames whose predicted rotation came from the gyroscope
    /// ([`crate::VoConfig::predict_gyroscope`]) ...
    pub predicted: usize,
    /// ... and frames whose interval the samples did not cover.
    pub prediction_not_covered: usize,
    /// Keyframes that lost tracks asked for on a frame the gyroscope showed jolted, and
    /// that waited for a later frame ([`crate::VoConfig::keyframe_jolt_ratio`]).
    pub keyframes_deferred: usize,
    /// Motion estimates rejected because their rotation disagreed with the gyroscope's
    /// ([`crate::VoConfig::max_gyroscope_disagreement_deg`]): tracking's (the frame then
    /// went to recovery as a lost one would) and the poses that recovery, relocalization
    /// or depth alignment found (the next way was then tried). A frame can count several.
    pub estimates_rejected: usize,
}

/// The gyroscope's samples and what they were used for.
#[derive(Debug, Clone, Default)]
pub(crate) struct Gyro {
    /// Time (s) and angular velocity in the camera frame (rad/s), in time order.
    samples: Series,
    /// Frames whose readout motion took the gyroscope's rate.
    pub(crate) used: usize,
    /// Frames with a rolling shutter that the samples did not cover.
    pub(crate) missed: usize,
    /// Frames whose predicted rotation came from the samples, and frames whose interval
    /// they did not cover (predicted by constant velocity alone).
    pub(crate) predicted: usize,
    pub(crate) not_predicted: usize,
    /// Motion estimates rejected for disagreeing with the gyroscope's rotation.
    pub(crate) rejected: usize,
}

impl Gyro {
    /// The angular velocity at `t_s`, linear between the samples around it; `None` across
    /// a gap longer than [`MAX_GAP_S`].
    fn at(&self, t_s: f64) -> Option<Vector3<f64>> {
        self.samples.at(t_s, MAX_GAP_S)
    }

    /// The mean angular velocity over `[t0, t1]` (the rate linear between samples), when
    /// the samples cover both ends: what one constant rate over the readout would be (the
    /// tests hold the integrated rotations against it).
    #[cfg(test)]
    fn mean(&self, t0: f64, t1: f64) -> Option<Vector3<f64>> {
        if t1 <= t0 {
            return self.at(t0);
        }
        let mut knots = vec![(t0, self.at(t0)?)];
        let samples = self.samples.samples();
        let first = samples.partition_point(|(t, _)| *t <= t0);
        let inside = samples.get(first..)?.iter().take_while(|(t, _)| *t < t1);
        knots.extend(inside.copied());
        knots.push((t1, self.at(t1)?));
        let integral = knots
            .windows(2)
            .fold(Vector3::zeros(), |acc, pair| match pair {
                [(ta, wa), (tb, wb)] => acc + (wa + wb) * 0.5 * (tb - ta),
                _ => acc,
            });
        Some(integral / (t1 - t0))
    }

    /// The rotation `cam(t0) <- cam(t1)` integrated from the rate (linear between samples,
    /// midpoint rule on steps of at most [`PREDICTION_STEP_S`]); `None` unless the samples
    /// cover `[t0, t1]` and `t1 > t0` (both finite).
    fn rotation_between(&self, t0: f64, t1: f64) -> Option<UnitQuaternion<f64>> {
        if !(t0.is_finite() && t1.is_finite()) || t1 <= t0 {
            return None;
        }
        self.at(t0)?;
        self.at(t1)?;
        let n = ((t1 - t0) / PREDICTION_STEP_S).ceil().max(1.0) as usize;
        let mut q = UnitQuaternion::identity();
        self.integrate(&mut q, t0, (t1 - t0) / n as f64, n)?;
        Some(q)
    }

    /// `cam(t_s) <- cam(t_s - (k + 0.5) h_s)` for `k` in `0..n`: the rotation back from
    /// `t_s` to the middle of each of `n` steps of `h_s` before it, integrated from the
    /// rate (midpoint rule on half steps); `None` unless the samples cover them.
    pub(crate) fn rotations_before(
        &self,
        t_s: f64,
        h_s: f64,
        n: usize,
    ) -> Option<Vec<UnitQuaternion<f64>>> {
        let half = 0.5 * h_s;
        let mut q = UnitQuaternion::identity();
        let mut out = Vec::with_capacity(n);
        for j in 0..2 * n {
            // cam(t) <- cam(t - half) is the inverse of the rotation over the half step.
            let t = t_s - j as f64 * half;
            q *= UnitQuaternion::from_scaled_axis(-self.at(t - 0.5 * half)? * half);
            if j % 2 == 0 {
                out.push(q);
            }
        }
        Some(out)
    }

    /// Composes onto `q` the rotation over `n` steps of `h_s` from `t0_s`, each step's
    /// rotation the rate at its middle (midpoint rule); `None` where the samples do not
    /// give a rate.
    fn integrate(&self, q: &mut UnitQuaternion<f64>, t0_s: f64, h_s: f64, n: usize) -> Option<()> {
        for k in 0..n {
            *q *= UnitQuaternion::from_scaled_axis(self.at(t0_s + (k as f64 + 0.5) * h_s)? * h_s);
        }
        Some(())
    }

    /// The rotation over the readout `[t0, t1]` relative to its middle instant,
    /// integrated from the rate (linear between samples, midpoint rule on
    /// [`ROTATION_SUBSTEPS`] substeps per knot interval), each knot's rotation averaged
    /// over an exposure of `exposure_s` centred on it; `None` unless the samples cover the
    /// readout and half an exposure either side.
    fn rotations(&self, t0: f64, t1: f64, exposure_s: f64) -> Option<RowRotations> {
        let step_s = (t1 - t0) / (ROTATION_KNOTS - 1) as f64;
        if !(step_s > 0.0 && exposure_s >= 0.0) {
            return None;
        }
        // Knots past each end of the readout by half an exposure.
        let pad = (0.5 * exposure_s / step_s).round() as usize;
        let start = t0 - pad as f64 * step_s;
        let n = ROTATION_KNOTS + 2 * pad;
        self.at(start)?;
        self.at(start + (n - 1) as f64 * step_s)?;
        let h = step_s / ROTATION_SUBSTEPS as f64;
        // start_from_knot[i]: cam(start) <- cam(start + i step_s).
        let mut start_from_knot = Vec::with_capacity(n);
        let mut q = UnitQuaternion::identity();
        start_from_knot.push(q);
        for i in 1..n {
            self.integrate(
                &mut q,
                start + (i - 1) as f64 * step_s,
                h,
                ROTATION_SUBSTEPS,
            )?;
            start_from_knot.push(q);
        }
        // A (blurred) keypoint sits where the scene was on average over its row's
        // exposure: each readout knot takes the mean of the rotations within half an
        // exposure of it (their mean rotation vector about the knot's own rotation).
        let mut mean = [UnitQuaternion::identity(); ROTATION_KNOTS];
        for (i, (m, window)) in mean
            .iter_mut()
            .zip(start_from_knot.windows(2 * pad + 1))
            .enumerate()
        {
            let centre = start_from_knot.get(i + pad)?;
            let sum = window.iter().fold(Vector3::zeros(), |acc, q| {
                acc + (centre.inverse() * q).scaled_axis()
            });
            *m = centre * UnitQuaternion::from_scaled_axis(sum / window.len() as f64);
        }
        // Relative to the camera at the frame's time (the depth image's instant).
        let mid_from_start = start_from_knot.get(pad + ROTATION_KNOTS / 2)?.inverse();
        Some(RowRotations {
            first_s: -(t1 - t0) / 2.0,
            step_s,
            frame_from_knot: mean.map(|q| mid_from_start * q),
        })
    }
}

impl VisualOdometry {
    /// Adds gyroscope samples: time (s, the frames' clock) and the camera's angular
    /// velocity in its own frame (rad/s; see `stride_datasets::accelerometer` for the
    /// convention). Samples older than the last one held are ignored, so a robot may hand
    /// them over as they arrive; a frame needs samples up to the end of its readout, so
    /// hand them over before the frame. Used for the rolling-shutter correction while
    /// `readout_gyroscope` is on and the camera has a rolling shutter, and for the rotation
    /// predicted from frame to frame while `predict_gyroscope` is on.
    pub fn add_gyroscope(&mut self, samples: &[(f64, Vector3<f64>)]) {
        self.gyro.samples.extend(samples);
    }

    /// What the gyroscope's samples were used for, frame by frame.
    pub fn gyroscope_frames(&self) -> GyroscopeFrames {
        GyroscopeFrames {
            readout: self.gyro.used,
            readout_not_covered: self.gyro.missed,
            predicted: self.gyro.predicted,
            prediction_not_covered: self.gyro.not_predicted,
            keyframes_deferred: self.jolts.deferred,
            estimates_rejected: self.gyro.rejected,
        }
    }

    /// Whether a motion estimate `prev_from_cur` turns by more than
    /// `max_gyroscope_disagreement_deg` from `gyroscope`, the gyroscope's rotation over the
    /// same interval (`None` when it measured none): then it is rejected, and counted.
    pub(crate) fn disagrees_with_gyroscope(
        &mut self,
        prev_from_cur: &Isometry3<f64>,
        gyroscope: Option<&UnitQuaternion<f64>>,
    ) -> bool {
        let max_deg = self.config.max_gyroscope_disagreement_deg;
        let disagrees = gyroscope.is_some_and(|r| {
            max_deg > 0.0 && (r.inverse() * prev_from_cur.rotation).angle().to_degrees() > max_deg
        });
        self.gyro.rejected += usize::from(disagrees);
        disagrees
    }

    /// The camera's angular rate around the frame at `t_s` (rad/s): the mean norm of the
    /// gyroscope's rate over the frame's exposure (10 ms when unknown), at its start,
    /// middle and end; `None` without samples there.
    pub(crate) fn gyroscope_rate(&self, t_s: f64) -> Option<f64> {
        let half = 0.5
            * if self.config.exposure_s > 0.0 {
                self.config.exposure_s
            } else {
                0.01
            };
        let norms = [t_s - half, t_s, t_s + half].map(|t| self.gyro.at(t).map(|w| w.norm()));
        let [a, b, c] = norms;
        Some((a? + b? + c?) / 3.0)
    }

    /// The motion predicted from the previous frame to the frame at `t_s`
    /// (`prev_from_cur`): the constant-velocity prediction, its rotation replaced by the
    /// gyroscope's integrated between the two frames' times when `predict_gyroscope` is on
    /// and the samples cover the interval (counted either way). A walking robot's shake
    /// turns the camera back and forth within a few frames, which a constant angular
    /// velocity gets wrong; Lucas-Kanade starts each track from this prediction. The flag
    /// says whether the rotation is the gyroscope's.
    pub(crate) fn predicted_with_gyroscope(&mut self, t_s: f64) -> (Isometry3<f64>, bool) {
        let cv = self.motion_model.prev_from_cur(self.prev_t, t_s);
        if !self.config.predict_gyroscope || self.gyro.samples.is_empty() {
            return (cv, false);
        }
        match self.gyro.rotation_between(self.prev_t, t_s) {
            Some(r) => {
                self.gyro.predicted += 1;
                (Isometry3::from_parts(cv.translation, r), true)
            }
            None => {
                self.gyro.not_predicted += 1;
                (cv, false)
            }
        }
    }

    /// The camera's motion during the readout of the frame at `t_s` (the middle row's
    /// time): `interval`'s `prev_from_cur` over `dt_s` (constant velocity; none for a
    /// first frame: no translation), its rotation replaced by the gyroscope's integrated
    /// over the readout (and averaged over the exposure) and its translation by the
    /// accelerometer's (`crate::accel`) when the samples cover them.
    /// `count` tallies the frame (once per frame).
    pub(crate) fn readout_motion(
        &mut self,
        interval: Option<(&Isometry3<f64>, f64)>,
        t_s: f64,
        count: bool,
    ) -> ShutterMotion {
        let readout = self.config.rolling_shutter_s;
        let still = Isometry3::identity();
        let (prev_from_cur, dt_s) = interval.unwrap_or((&still, 1.0));
        let mut motion = ShutterMotion::new(readout, self.camera.height(), prev_from_cur, dt_s);
        if readout <= 0.0 || motion.row_s <= 0.0 {
            return motion;
        }
        if let Some((prev_from_cur, dt_s)) = interval {
            self.readout_translation(&mut motion, prev_from_cur, dt_s, t_s, count);
        }
        if !self.config.readout_gyroscope || self.gyro.samples.is_empty() {
            return motion;
        }
        let (t0, t1) = (t_s - readout / 2.0, t_s + readout / 2.0);
        match self.gyro.rotations(t0, t1, self.config.exposure_s) {
            Some(r) => {
                motion.rotations = Some(r);
                self.gyro.used += usize::from(count);
            }
            None => self.gyro.missed += usize::from(count),
        }
        if count {
            // Frames come in time order: samples well before this one are not needed again
            // (a long run's samples would otherwise grow without bound).
            self.gyro.samples.forget_before(t_s - KEEP_S);
        }
        motion
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_between_samples_and_refuses_gaps() {
        let g = Gyro {
            samples: Series::from(vec![
                (0.0, Vector3::new(0.0, 0.0, 0.0)),
                (0.01, Vector3::new(1.0, -2.0, 0.5)),
                (0.2, Vector3::new(0.0, 0.0, 0.0)),
            ]),
            ..Gyro::default()
        };
        let w = g.at(0.0025).unwrap();
        assert!((w - Vector3::new(0.25, -0.5, 0.125)).norm() < 1e-12);
        assert!(g.at(0.1).is_none(), "0.19 s between the samples around it");
        assert!(g.at(-0.001).is_none() && g.at(0.3).is_none());
        // The mean over [0, 0.01] of a rate rising linearly from 0 to (1, -2, 0.5).
        let m = g.mean(0.0, 0.01).unwrap();
        assert!((m - Vector3::new(0.5, -1.0, 0.25)).norm() < 1e-12);
        assert!(g.mean(0.005, 0.1).is_none(), "its end is in the gap");
        let mut g = g;
        g.samples.forget_before(0.1);
        assert_eq!(
            g.samples.samples().len(),
            2,
            "the sample before 0.1 s stays"
        );
        assert!(g.at(0.1).is_none() && g.at(0.2).is_some());
    }

    #[test]
    fn integrates_the_rotation_between_two_frames() {
        // A rate about a fixed axis rising from 1 to 4 rad/s over 33 ms at 400 Hz: the angle
        // between the frames at 2 ms and 35 ms is the rate's integral; a constant rate from
        // the interval before (1 rad/s) would be off by about a third of it.
        let axis = Vector3::new(0.6, -0.8, 0.0);
        let rate = |t: f64| 1.0 + 3.0 * t / 0.033;
        let samples: Vec<_> = (0..=16)
            .map(|k| {
                let t = k as f64 * 0.0025;
                (t, axis * rate(t))
            })
            .collect();
        let g = Gyro {
            samples: Series::from(samples),
            ..Gyro::default()
        };
        let (t0, t1) = (0.002, 0.035);
        let truth = (t1 - t0) * (rate(t0) + rate(t1)) / 2.0;
        let q = g.rotation_between(t0, t1).unwrap();
        assert!(
            (q.scaled_axis() - axis * truth).norm() < 1e-9,
            "{} against {truth}",
            q.scaled_axis()
        );
        assert!(g.rotation_between(t0, 0.05).is_none(), "past the samples");
        assert!(g.rotation_between(t1, t0).is_none(), "backwards");
    }

    #[test]
    fn integrates_the_rotation_back_from_a_frame() {
        // A rate about z rising linearly, 2 + 30 t rad/s, sampled at 400 Hz over 0-0.1 s:
        // from the frame at 0.1 s back to 0.1 - s the camera turned by the rate's integral,
        // so cam(0.1) <- cam(0.1 - s) is the rotation by minus that angle.
        let samples: Vec<_> = (0..=40)
            .map(|k| {
                let t = k as f64 * 0.0025;
                (t, Vector3::new(0.0, 0.0, 2.0 + 30.0 * t))
            })
            .collect();
        let g = Gyro {
            samples: Series::from(samples),
            ..Gyro::default()
        };
        let (h, n) = (0.00125, 80);
        let r = g.rotations_before(0.1, h, n).unwrap();
        assert_eq!(r.len(), n);
        for k in [0, 7, 40, 79] {
            let s = (k as f64 + 0.5) * h;
            let angle = (2.0 + 30.0 * 0.1) * s - 15.0 * s * s;
            let got = r[k].scaled_axis();
            assert!(
                (got + Vector3::z() * angle).norm() < 1e-9,
                "k {k}: {got}, {angle}"
            );
        }
        assert!(
            g.rotations_before(0.1, h, 81).is_none(),
            "before the first sample"
        );
    }

    #[test]
    fn integrates_a_changing_rate_over_the_readout() {
        // A rate about y rising from 2 to 2.2 rad/s over a 20 ms readout, sampled at 1 kHz:
        // the rotation from the middle instant (10 ms) to 10 + s ms is the integral of the
        // rate, 2.1 s + 5 s^2 rad, which a constant mean rate (2.1 s) misses at the ends.
        let samples: Vec<_> = (0..=20)
            .map(|k| {
                let t = k as f64 * 1e-3;
                (t, Vector3::new(0.0, 2.0 + 10.0 * t, 0.0))
            })
            .collect();
        let g = Gyro {
            samples: Series::from(samples),
            ..Gyro::default()
        };
        let r = g.rotations(0.0, 0.02, 0.0).unwrap();
        for s in [-0.01, -0.0031, 0.0, 0.004, 0.01] {
            let truth = 2.1 * s + 5.0 * s * s;
            let q = r.at(s);
            assert!(
                (q.scaled_axis() - Vector3::new(0.0, truth, 0.0)).norm() < 1e-5,
                "s {s}: {} against {truth}",
                q.scaled_axis()
            );
        }
        // The constant mean rate misses the end rows by 5e-4 rad (0.26 px at f = 517 px).
        let w = g.mean(0.0, 0.02).unwrap();
        assert!((w * 0.01 - Vector3::new(0.0, 2.1 * 0.01 + 5.0 * 1e-4, 0.0)).norm() > 4e-4);
        assert!(
            g.rotations(0.0, 0.03, 0.0).is_none(),
            "its end is past the samples"
        );
    }

    #[test]
    fn averages_each_rows_rotation_over_its_exposure() {
        // A rate about y of 2 + 100 t rad/s (t from 5 ms before the readout), a 20 ms
        // readout and a 10 ms exposure: the angle from the middle instant is
        // 3.5 s + 50 s^2, and its mean over an exposure centred on s is
        // 3.5 s + 50 (s^2 + e^2 / 12); the exposure adds 4.2e-4 rad (0.2 px at 517 px).
        let samples: Vec<_> = (0..=30)
            .map(|k| {
                let t = k as f64 * 1e-3;
                (t - 0.005, Vector3::new(0.0, 2.0 + 100.0 * t, 0.0))
            })
            .collect();
        let g = Gyro {
            samples: Series::from(samples),
            ..Gyro::default()
        };
        let e = 0.01;
        let r = g.rotations(0.0, 0.02, e).unwrap();
        for s in [-0.01, -0.004, 0.0, 0.0065, 0.01] {
            let truth = 3.5 * s + 50.0 * (s * s + e * e / 12.0);
            let got = r.at(s).scaled_axis();
            // The mean over the 9 knots within half an exposure, 1.25 ms apart, is the
            // continuous mean within 1e-4 rad.
            assert!(
                (got - Vector3::new(0.0, truth, 0.0)).norm() < 1.5e-4,
                "s {s}: {got} against {truth}"
            );
        }
        assert!(
            g.rotations(0.0, 0.02, 0.02).is_none(),
            "half an exposure before the readout is before the samples"
        );
    }
}
