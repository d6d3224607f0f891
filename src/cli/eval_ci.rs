//! `stride eval suite` and `stride eval compare`: trajectory evaluation for CI.

use crate::cli::gates::LimitExceeded;
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use stride::eval_suite::{compare, run_suite};
use stride_output::fs::{write_atomic, StagedDir};

#[derive(Debug, Args)]
pub struct SuiteArgs {
    /// The suite file (TOML: [[entry]] tables with name, gt, est, metric, options and
    /// limits; paths relative to the file; see docs/evaluation.md).
    #[arg(value_name = "FILE.toml")]
    pub suite: PathBuf,
    /// Write results.json, summary.md, junit.xml and report.html into this folder.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Replace the --out folder's contents.
    #[arg(long, requires = "out")]
    pub overwrite: bool,
}

#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The base: a suite's output folder (results.json) or a single result's (`stride eval
    /// ate|rpe --report DIR`: report.json), or the JSON file itself.
    #[arg(value_name = "BASE")]
    pub base: PathBuf,
    /// The new result, the same way.
    #[arg(value_name = "NEW")]
    pub new: PathBuf,
    /// Mark a statistic worse by more than this many percent as a regression.
    #[arg(long, value_name = "PCT", default_value_t = 5.0)]
    pub tolerance: f64,
    /// Exit with code 1 when a statistic is worse by more than this many percent (or an
    /// entry is missing from the new result).
    #[arg(long, value_name = "PCT")]
    pub fail_on_regression: Option<f64>,
    /// Write compare.md and compare.json into this folder.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Replace the --out folder's contents.
    #[arg(long, requires = "out")]
    pub overwrite: bool,
}

/// Checks a percentage given as `flag`.
fn percent(flag: &str, v: f64) -> Result<()> {
    anyhow::ensure!(
        v.is_finite() && v >= 0.0,
        "{flag} {v}: a percentage must be a finite number, 0 or more"
    );
    Ok(())
}

pub fn run_suite_cmd(a: SuiteArgs) -> Result<()> {
    if let Some(out) = &a.out {
        crate::cli::check_out_dir("--out", out, a.overwrite)?;
    }
    let result = run_suite(&a.suite)?;
    if let Some(out) = &a.out {
        let staged = StagedDir::new(out).with_context(|| format!("creating {}", out.display()))?;
        result
            .write(staged.path())
            .with_context(|| format!("writing the suite's results into {}", out.display()))?;
        staged
            .publish()
            .with_context(|| format!("publishing {}", out.display()))?;
    }
    crate::outln!("{}", result.markdown().trim_end())?;
    let failed = result.failed();
    if failed > 0 {
        let first = result
            .entries
            .iter()
            .find(|e| !e.passed())
            .map(|e| format!("{}: {}", e.name, e.failures().join("; ")))
            .unwrap_or_default();
        return Err(LimitExceeded(format!(
            "{failed} of {} suite entries ({first})",
            result.entries.len()
        ))
        .into());
    }
    Ok(())
}

pub fn run_compare(a: CompareArgs) -> Result<()> {
    percent("--tolerance", a.tolerance)?;
    if let Some(p) = a.fail_on_regression {
        percent("--fail-on-regression", p)?;
    }
    if let Some(out) = &a.out {
        crate::cli::check_out_dir("--out", out, a.overwrite)?;
    }
    let c = compare(&a.base, &a.new)?;
    if let Some(out) = &a.out {
        let staged = StagedDir::new(out).with_context(|| format!("creating {}", out.display()))?;
        write_atomic(
            &staged.path().join("compare.md"),
            c.markdown(a.tolerance).as_bytes(),
        )?;
        write_atomic(
            &staged.path().join("compare.json"),
            serde_json::to_string_pretty(&c.to_json(a.tolerance))?.as_bytes(),
        )?;
        staged
            .publish()
            .with_context(|| format!("publishing {}", out.display()))?;
    }
    crate::outln!("{}", c.markdown(a.tolerance).trim_end())?;
    if let Some(pct) = a.fail_on_regression {
        let worse = c.regressions(pct);
        if !worse.is_empty() || !c.missing.is_empty() {
            let lines: Vec<String> = worse
                .iter()
                .map(|r| {
                    format!(
                        "{} {} {} {:.6} -> {:.6} ({:+.1} %)",
                        r.entry,
                        r.metric.to_uppercase(),
                        r.statistic,
                        r.base,
                        r.new,
                        r.change_pct()
                    )
                })
                .chain(c.missing.iter().map(|m| format!("{m} missing")))
                .collect();
            return Err(
                LimitExceeded(format!("regression beyond {pct} %: {}", lines.join("; "))).into(),
            );
        }
    }
    Ok(())
}
