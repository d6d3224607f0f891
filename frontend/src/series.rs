//! A time series of three-axis inertial samples (a gyroscope's or an accelerometer's), in
//! time order, read linearly between samples.

use nalgebra::Vector3;

/// Time (s, the frames' clock) and a three-axis reading (camera frame), strictly
/// increasing in time and finite (samples that are not are left out when added).
#[derive(Debug, Clone, Default)]
pub(crate) struct Series {
    samples: Vec<(f64, Vector3<f64>)>,
}

impl From<Vec<(f64, Vector3<f64>)>> for Series {
    /// The samples as given (the caller keeps them in time order; tests build series so).
    fn from(samples: Vec<(f64, Vector3<f64>)>) -> Self {
        Self { samples }
    }
}

impl Series {
    /// Appends the samples newer than the last one held, finite ones only, so that a robot
    /// may hand them over as they arrive (repeated or older samples are ignored).
    pub(crate) fn extend(&mut self, samples: &[(f64, Vector3<f64>)]) {
        for &(t, x) in samples {
            let newer = self.samples.last().is_none_or(|(last, _)| t > *last);
            if newer && t.is_finite() && x.iter().all(|v| v.is_finite()) {
                self.samples.push((t, x));
            }
        }
    }

    /// Whether no sample is held.
    pub(crate) fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The samples held, in time order (the tests look at them; the code reads them through
    /// [`Self::between`] and [`Self::at`]).
    #[cfg(test)]
    pub(crate) fn samples(&self) -> &[(f64, Vector3<f64>)] {
        &self.samples
    }

    /// The samples at times in `(after_s, until_s]` (`after_s` `None`: from the first).
    pub(crate) fn between(&self, after_s: Option<f64>, until_s: f64) -> &[(f64, Vector3<f64>)] {
        let start = after_s.map_or(0, |a| self.samples.partition_point(|(t, _)| *t <= a));
        let end = self.samples.partition_point(|(t, _)| *t <= until_s);
        self.samples.get(start..end.max(start)).unwrap_or(&[])
    }

    /// The reading at `t_s`, linear between the samples around it; `None` outside the
    /// samples or where those two are more than `max_gap_s` apart.
    pub(crate) fn at(&self, t_s: f64, max_gap_s: f64) -> Option<Vector3<f64>> {
        let k = self.samples.partition_point(|(t, _)| *t <= t_s);
        let &(t0, x0) = self.samples.get(k.checked_sub(1)?)?;
        if t0 == t_s {
            return Some(x0);
        }
        let &(t1, x1) = self.samples.get(k)?;
        if t1 - t0 > max_gap_s || t1 <= t0 {
            return None;
        }
        let a = (t_s - t0) / (t1 - t0);
        Some(x0 * (1.0 - a) + x1 * a)
    }

    /// Drops the samples before `t_s`, keeping the last one before it (the left end of an
    /// interpolation at `t_s`).
    pub(crate) fn forget_before(&mut self, t_s: f64) {
        let k = self.samples.partition_point(|(t, _)| *t < t_s);
        self.samples.drain(..k.saturating_sub(1));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_newer_finite_samples_only() {
        let mut s = Series::default();
        s.extend(&[
            (0.0, Vector3::x()),
            (0.01, Vector3::y()),
            (0.005, Vector3::z()),
            (0.02, Vector3::new(f64::NAN, 0.0, 0.0)),
            (f64::INFINITY, Vector3::x()),
        ]);
        assert_eq!(s.samples().len(), 2);
        s.extend(&[(0.01, Vector3::z()), (0.03, Vector3::z())]);
        assert_eq!(s.samples().len(), 3, "a repeated time is not newer");
        let x = s.at(0.0025, 0.05).unwrap();
        assert!((x - Vector3::new(0.75, 0.25, 0.0)).norm() < 1e-12);
        assert!(s.at(0.02, 0.015).is_none(), "0.02 s between 0.01 and 0.03");
        assert!(s.at(0.02, 0.05).is_some());
        assert_eq!(s.between(None, 0.01).len(), 2);
        assert_eq!(s.between(Some(0.0), 0.01).len(), 1);
        assert_eq!(s.between(Some(0.03), 0.01).len(), 0);
    }
}
