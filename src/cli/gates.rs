//! Limits that fail a build: `stride eval ate|rpe ... --max-rmse M --max-mean M
//! --max-rot-deg D`. Exit codes of every command: 0 success, 1 a limit exceeded (the
//! results are still printed and written), 2 an error (bad input, unreadable file).

use anyhow::Result;
use clap::Args;
use stride_eval::Statistics;

/// The limits a result must stay within; none by default.
#[derive(Debug, Clone, Copy, Args)]
pub struct Limits {
    /// Fail (exit code 1) when the translation error's RMSE exceeds this (m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub max_rmse: Option<f64>,
    /// Fail (exit code 1) when the translation error's mean exceeds this (m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub max_mean: Option<f64>,
    /// Fail (exit code 1) when the rotation error's RMSE exceeds this (degrees).
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub max_rot_deg: Option<f64>,
}

/// A result beyond a limit: the one-line reason (statistic, value, limit). The binary
/// exits with code 1 for it.
#[derive(Debug)]
pub struct LimitExceeded(pub String);

impl std::fmt::Display for LimitExceeded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "limit exceeded: {}", self.0)
    }
}

impl std::error::Error for LimitExceeded {}

impl Limits {
    /// Checks the limits themselves (before any work): finite and not negative.
    pub fn validate(&self) -> Result<()> {
        for (flag, v) in self.flags() {
            if let Some(v) = v.filter(|v| !(v.is_finite() && *v >= 0.0)) {
                anyhow::bail!("{flag} {v}: a limit must be a finite number, 0 or more");
            }
        }
        Ok(())
    }

    /// Checks `what`'s translation (m) and rotation (degrees) statistics against the
    /// limits; a statistic that is not a number exceeds any limit.
    pub fn check(&self, what: &str, trans_m: &Statistics, rot_deg: &Statistics) -> Result<()> {
        let measured = [
            ("translation rmse", trans_m.rmse, "m"),
            ("translation mean", trans_m.mean, "m"),
            ("rotation rmse", rot_deg.rmse, "deg"),
        ];
        let failures: Vec<String> = self
            .flags()
            .into_iter()
            .zip(measured)
            .filter_map(|((flag, limit), (name, value, unit))| {
                let limit = limit?;
                // A NaN statistic exceeds every limit.
                let within = value.is_finite() && value <= limit;
                (!within)
                    .then(|| format!("{what} {name} {value:.6} {unit} > {flag} {limit} {unit}"))
            })
            .collect();
        if failures.is_empty() {
            Ok(())
        } else {
            Err(LimitExceeded(failures.join("; ")).into())
        }
    }

    fn flags(&self) -> [(&'static str, Option<f64>); 3] {
        [
            ("--max-rmse", self.max_rmse),
            ("--max-mean", self.max_mean),
            ("--max-rot-deg", self.max_rot_deg),
        ]
    }
}
