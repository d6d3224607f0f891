//! A gyroscope's angular velocity for the rolling-shutter correction.
//!
//! Each keypoint is brought back from its row's time to the frame's with the camera's
//! motion during the readout ([`ShutterMotion`]). Without an inertial sensor that motion is
//! the last frame interval's average, which lags a walking robot's shake: on the synthetic
//! lab's fastest tripod walk it is off the frame's angular velocity by 0.10 rad/s rms, 42 %
//! of the rate itself, and the rolling shutter then doubles the walk's error (1.0 mm ATE
//! against 0.45 mm with a global shutter). Every legged robot carries a gyroscope: given
//! one ([`VisualOdometry::add_gyroscope`]), the mean of its angular velocity over the
//! readout is used instead (the linear velocity stays the interval's; over a 20 ms readout
//! it moves points by a fraction of a millimetre). The mean, not the rate at the frame's
//! time: the gait's foot contacts put millisecond-scale wiggles into the rate (on the
//! lab's slow tripod walk the rate about the optical axis is 0.10 rad/s rms at 200 Hz
//! against 0.02 rad/s over a frame), and the rate at one instant made the slow walks worse
//! than the interval's velocity did (0.33 -> 0.46 mm ATE), where the readout's mean made
//! them better (0.30 mm).

use crate::points::ShutterMotion;
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, Vector3};

/// Largest gap between the two samples around a frame's time (s): beyond it the frame's
/// rate is not interpolated (the interval's motion is used, and the frame counted).
pub const MAX_GAP_S: f64 = 0.05;

/// How long samples are kept before the latest frame (s).
const KEEP_S: f64 = 1.0;

/// The gyroscope's samples and what they were used for.
#[derive(Debug, Clone, Default)]
pub(crate) struct Gyro {
    /// Time (s) and angular velocity in the camera frame (rad/s), in time order.
    samples: Vec<(f64, Vector3<f64>)>,
    /// Frames whose readout motion took the gyroscope's rate.
    pub(crate) used: usize,
    /// Frames with a rolling shutter that the samples did not cover.
    pub(crate) missed: usize,
}

impl Gyro {
    /// The angular velocity at `t_s`, linear between the samples around it.
    fn at(&self, t_s: f64) -> Option<Vector3<f64>> {
        let k = self.samples.partition_point(|(t, _)| *t <= t_s);
        let &(t0, w0) = self.samples.get(k.checked_sub(1)?)?;
        if t0 == t_s {
            return Some(w0);
        }
        let &(t1, w1) = self.samples.get(k)?;
        if t1 - t0 > MAX_GAP_S || t1 <= t0 {
            return None;
        }
        let a = (t_s - t0) / (t1 - t0);
        Some(w0 * (1.0 - a) + w1 * a)
    }

    /// Drops the samples before `t_s`, keeping the last one before it (the left end of
    /// an interpolation at `t_s`).
    fn forget_before(&mut self, t_s: f64) {
        let k = self.samples.partition_point(|(t, _)| *t < t_s);
        self.samples.drain(..k.saturating_sub(1));
    }

    /// The mean angular velocity over `[t0, t1]` (the rate linear between samples), when
    /// the samples cover both ends.
    fn mean(&self, t0: f64, t1: f64) -> Option<Vector3<f64>> {
        if t1 <= t0 {
            return self.at(t0);
        }
        let mut knots = vec![(t0, self.at(t0)?)];
        let first = self.samples.partition_point(|(t, _)| *t <= t0);
        let inside = self
            .samples
            .get(first..)?
            .iter()
            .take_while(|(t, _)| *t < t1);
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
}

impl VisualOdometry {
    /// Adds gyroscope samples: time (s, the frames' clock) and the camera's angular
    /// velocity in its own frame (rad/s; see `stride_datasets::accelerometer` for the
    /// convention). Samples older than the last one held are ignored, so a robot may hand
    /// them over as they arrive; a frame needs samples up to the end of its readout, so
    /// hand them over before the frame. Used while `readout_gyroscope` is on and the
    /// camera has a rolling shutter.
    pub fn add_gyroscope(&mut self, samples: &[(f64, Vector3<f64>)]) {
        for &(t, w) in samples {
            let newer = self.gyro.samples.last().is_none_or(|(last, _)| t > *last);
            if newer && t.is_finite() && w.iter().all(|x| x.is_finite()) {
                self.gyro.samples.push((t, w));
            }
        }
    }

    /// Frames whose rolling-shutter correction took the gyroscope's angular velocity, and
    /// frames the gyroscope's samples did not cover (their correction took the last frame
    /// interval's, as without a gyroscope).
    pub fn gyroscope_frames(&self) -> (usize, usize) {
        (self.gyro.used, self.gyro.missed)
    }

    /// The camera's motion during the readout of the frame at `t_s` (the middle row's
    /// time): `prev_from_cur` over `dt_s` (constant velocity), its angular velocity
    /// replaced by the gyroscope's mean over the readout when the samples cover it.
    /// `count` tallies the frame (once per frame).
    pub(crate) fn readout_motion(
        &mut self,
        prev_from_cur: &Isometry3<f64>,
        dt_s: f64,
        t_s: f64,
        count: bool,
    ) -> ShutterMotion {
        let readout = self.config.rolling_shutter_s;
        let mut motion = ShutterMotion::new(readout, self.camera.height(), prev_from_cur, dt_s);
        let wanted = self.config.readout_gyroscope && !self.gyro.samples.is_empty();
        if readout <= 0.0 || motion.row_s <= 0.0 || !wanted {
            return motion;
        }
        match self.gyro.mean(t_s - readout / 2.0, t_s + readout / 2.0) {
            Some(w) => {
                motion.omega_rad_s = w;
                self.gyro.used += usize::from(count);
            }
            _ => self.gyro.missed += usize::from(count),
        }
        if count {
            // Frames come in time order: samples well before this one are not needed again
            // (a long run's samples would otherwise grow without bound).
            self.gyro.forget_before(t_s - KEEP_S);
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
            samples: vec![
                (0.0, Vector3::new(0.0, 0.0, 0.0)),
                (0.01, Vector3::new(1.0, -2.0, 0.5)),
                (0.2, Vector3::new(0.0, 0.0, 0.0)),
            ],
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
        g.forget_before(0.1);
        assert_eq!(g.samples.len(), 2, "the sample before 0.1 s stays");
        assert!(g.at(0.1).is_none() && g.at(0.2).is_some());
    }
}
