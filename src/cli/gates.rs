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
    /// The limits as the eval crate checks them.
    fn eval(&self) -> stride_eval::Limits {
        stride_eval::Limits {
            max_rmse: self.max_rmse,
            max_mean: self.max_mean,
            max_rot_deg: self.max_rot_deg,
        }
    }

    /// Checks the limits themselves (before any work): finite and not negative.
    pub fn validate(&self) -> Result<()> {
        self.eval().validate().map_err(|e| match e {
            stride_eval::EvalError::InvalidOption { option, message } => {
                anyhow::anyhow!("{} {message}", flag(option))
            }
            other => other.into(),
        })
    }

    /// Checks `what`'s translation (m) and rotation (degrees) statistics against the
    /// limits; a statistic that is not a number exceeds any limit.
    pub fn check(&self, what: &str, trans_m: &Statistics, rot_deg: &Statistics) -> Result<()> {
        let failures: Vec<String> = self
            .eval()
            .exceeded(trans_m, rot_deg)
            .iter()
            .map(|e| e.describe(what, flag))
            .collect();
        if failures.is_empty() {
            Ok(())
        } else {
            Err(LimitExceeded(failures.join("; ")).into())
        }
    }
}

/// The command-line flag of a limit (`max_rmse` is `--max-rmse`).
fn flag(limit_name: &str) -> String {
    format!("--{}", limit_name.replace('_', "-"))
}
