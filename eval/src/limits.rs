//! Limits a result must stay within (the gates of a CI build): the translation error's RMSE
//! and mean (m) and the rotation error's RMSE (degrees).

use crate::error::EvalError;
use crate::stats::Statistics;
use serde::{Deserialize, Serialize};

/// The limits; none by default.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Largest translation RMSE allowed (m).
    pub max_rmse: Option<f64>,
    /// Largest translation mean allowed (m).
    pub max_mean: Option<f64>,
    /// Largest rotation RMSE allowed (degrees).
    pub max_rot_deg: Option<f64>,
}

/// A statistic beyond its limit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Exceeded {
    /// The limit's name (`max_rmse`, `max_mean`, `max_rot_deg`).
    pub limit_name: &'static str,
    /// The statistic (`translation rmse`, ...).
    pub statistic: &'static str,
    /// Its value (m or degrees; NaN exceeds every limit).
    pub value: f64,
    /// The limit.
    pub limit: f64,
    /// `m` or `deg`.
    pub unit: &'static str,
}

impl Limits {
    /// Whether any limit is set.
    pub fn any(&self) -> bool {
        self.named().iter().any(|(_, v)| v.is_some())
    }

    /// The limits by name.
    pub fn named(&self) -> [(&'static str, Option<f64>); 3] {
        [
            ("max_rmse", self.max_rmse),
            ("max_mean", self.max_mean),
            ("max_rot_deg", self.max_rot_deg),
        ]
    }

    /// Checks the limits themselves: finite and not negative.
    pub fn validate(&self) -> Result<(), EvalError> {
        for (name, v) in self.named() {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(EvalError::InvalidOption {
                    option: name,
                    message: format!("{v}: a limit must be a finite number, 0 or more"),
                });
            }
        }
        Ok(())
    }

    /// The statistics of a result (translation in m, rotation in degrees) beyond their
    /// limits; a statistic that is not a number exceeds any limit.
    pub fn exceeded(&self, trans_m: &Statistics, rot_deg: &Statistics) -> Vec<Exceeded> {
        let measured = [
            ("translation rmse", trans_m.rmse, "m"),
            ("translation mean", trans_m.mean, "m"),
            ("rotation rmse", rot_deg.rmse, "deg"),
        ];
        self.named()
            .into_iter()
            .zip(measured)
            .filter_map(|((limit_name, limit), (statistic, value, unit))| {
                let limit = limit?;
                let within = value.is_finite() && value <= limit;
                (!within).then_some(Exceeded {
                    limit_name,
                    statistic,
                    value,
                    limit,
                    unit,
                })
            })
            .collect()
    }
}

impl Exceeded {
    /// One line: `{what} {statistic} {value} {unit} > {limit name} {limit} {unit}`, the limit
    /// named by `name_of` (a command-line flag, a file key).
    pub fn describe(&self, what: &str, name_of: impl Fn(&str) -> String) -> String {
        format!(
            "{what} {} {:.6} {} > {} {} {}",
            self.statistic,
            self.value,
            self.unit,
            name_of(self.limit_name),
            self.limit,
            self.unit
        )
    }
}
