//! Summary statistics of an error series, with the definitions evo and the TUM tools use.

use serde::Serialize;

/// Statistics of a non-empty error series (same unit as the errors).
///
/// `rmse = sqrt(mean(e²))`, `std` is the population standard deviation (numpy's default,
/// as both tools), `median` averages the two middle values of an even count, and
/// `sse = Σ e²`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Statistics {
    /// Root mean square.
    pub rmse: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    /// Number of errors.
    pub count: usize,
}

impl Statistics {
    /// Statistics of `errors`; `None` when it is empty.
    pub fn from_errors(errors: &[f64]) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 {
            sorted.get(mid).copied()?
        } else {
            (sorted.get(mid - 1).copied()? + sorted.get(mid).copied()?) / 2.0
        };
        Some(Self {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: *sorted.first()?,
            max: *sorted.last()?,
            sse,
            count: errors.len(),
        })
    }

    /// The statistics as `(name, value)` rows in evo's order of importance.
    pub fn rows(&self) -> [(&'static str, f64); 7] {
        [
            ("rmse", self.rmse),
            ("mean", self.mean),
            ("median", self.median),
            ("std", self.std),
            ("min", self.min),
            ("max", self.max),
            ("sse", self.sse),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn numpy_definitions() {
        let s = Statistics::from_errors(&[3.0, 1.0, 4.0, 2.0]).unwrap();
        assert_eq!(s.median, 2.5);
        assert_eq!(s.mean, 2.5);
        assert_relative_eq!(s.std, 1.25f64.sqrt());
        assert_relative_eq!(s.rmse, 7.5f64.sqrt());
        assert_eq!((s.min, s.max, s.sse, s.count), (1.0, 4.0, 30.0, 4));
        assert_eq!(Statistics::from_errors(&[5.0]).unwrap().median, 5.0);
        assert!(Statistics::from_errors(&[]).is_none());
    }
}
