//! `stride eval ate|rpe`.

use crate::cli::gates::Limits;
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::{Path, PathBuf};
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_eval::report::Report;
use stride_eval::{ate, rpe, Align, AteOptions, DeltaUnit, EvalError, Preset, RpeOptions};
use stride_output::fs::{write_atomic, StagedDir};

#[derive(Debug, Subcommand)]
pub enum EvalCommand {
    /// Absolute trajectory error: distance between associated positions after alignment.
    Ate(AteArgs),
    /// Relative pose error: error of the motion between poses `delta` apart (drift).
    Rpe(RpeArgs),
    /// Many trajectory pairs at once, with limits: a Markdown summary, JUnit XML, JSON and
    /// HTML; exit code 1 when an entry exceeds a limit.
    Suite(super::eval_ci::SuiteArgs),
    /// Two results (suites or single) side by side: every statistic's change, regressions
    /// marked; exit code 1 on a regression with --fail-on-regression.
    Compare(super::eval_ci::CompareArgs),
}

/// Options shared by both metrics.
#[derive(Debug, Args)]
pub struct CommonArgs {
    /// Ground truth and estimate as positional arguments, in that order (evo's habit:
    /// `stride eval ate GT EST`); or use --gt and --est.
    #[arg(value_name = "GT EST", num_args = 0..=2, conflicts_with_all = ["gt", "est"])]
    files: Vec<PathBuf>,
    /// Ground-truth trajectory (TUM format: t tx ty tz qx qy qz qw).
    #[arg(long)]
    gt: Option<PathBuf>,
    /// Estimated trajectory (TUM format).
    #[arg(long)]
    est: Option<PathBuf>,
    /// Whose semantics to reproduce: evo (evo_ape/evo_rpe) or tum (evaluate_ate.py /
    /// evaluate_rpe.py --fixed_delta). See docs/evaluation.md.
    #[arg(long, default_value = "evo")]
    preset: Preset,
    /// Alignment of the estimate: se3, sim3, origin or none [default: ATE evo none, ATE tum
    /// se3, RPE none].
    #[arg(long)]
    align: Option<Align>,
    /// Association window in seconds [default: evo 0.01, tum 0.02].
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    t_max_diff: Option<f64>,
    /// Time offset in seconds added to the estimate's stamps before association.
    #[arg(
        long,
        value_name = "S",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    offset: f64,
    /// Print exactly one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Write the plots as SVG to this file (it must end in .svg).
    #[arg(long, value_name = "FILE.svg")]
    plot: Option<PathBuf>,
    /// Write report.md, report.html and the plots into this folder (an existing non-empty
    /// one only with --overwrite).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Replace the --report folder's contents.
    #[arg(long, requires = "report")]
    overwrite: bool,
    #[command(flatten)]
    limits: Limits,
}

#[derive(Debug, Args)]
pub struct AteArgs {
    #[command(flatten)]
    common: CommonArgs,
}

#[derive(Debug, Args)]
pub struct RpeArgs {
    #[command(flatten)]
    common: CommonArgs,
    /// Distance between the poses of a pair [default: evo 1 frame, tum 1 second].
    #[arg(long, allow_negative_numbers = true)]
    delta: Option<f64>,
    /// Unit of --delta: frames, seconds or metres.
    #[arg(long)]
    delta_unit: Option<DeltaUnit>,
    /// Use every pair `delta` apart instead of consecutive non-overlapping pairs (evo preset).
    #[arg(long)]
    all_pairs: bool,
    /// Relative tolerance on delta (metres/seconds) in --all-pairs mode.
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    delta_tol: f64,
}

pub fn run(cmd: EvalCommand) -> Result<()> {
    match cmd {
        EvalCommand::Ate(a) => run_ate(a),
        EvalCommand::Rpe(a) => run_rpe(a),
        EvalCommand::Suite(a) => super::eval_ci::run_suite_cmd(a),
        EvalCommand::Compare(a) => super::eval_ci::run_compare(a),
    }
}

impl CommonArgs {
    /// The ground truth and estimate files, from --gt/--est or the two positional
    /// arguments.
    fn paths(&self) -> Result<(&Path, &Path)> {
        match (self.files.as_slice(), &self.gt, &self.est) {
            ([], Some(gt), Some(est)) => Ok((gt, est)),
            ([gt, est], None, None) => Ok((gt, est)),
            _ => anyhow::bail!(
                "give the ground truth and the estimate, as `GT EST` or as `--gt GT --est EST`"
            ),
        }
    }

    /// Checks the outputs before any work: a plot must be asked for as .svg.
    fn check_outputs(&self) -> Result<()> {
        if let Some(p) = &self.plot {
            let ext = p
                .extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase());
            if ext.as_deref() != Some("svg") {
                anyhow::bail!(
                    "--plot {}: plots are written as SVG; give a file name ending in .svg \
                     (a browser or `rsvg-convert` turns it into PNG)",
                    p.display()
                );
            }
        }
        match &self.report {
            Some(d) => crate::cli::check_out_dir("--report", d, self.overwrite),
            None => Ok(()),
        }
    }
}

fn load(
    c: &CommonArgs,
) -> Result<(
    stride_core::trajectory::Trajectory,
    stride_core::trajectory::Trajectory,
)> {
    c.check_outputs()?;
    c.limits.validate()?;
    let (gt, est) = c.paths()?;
    let gt = read_tum_trajectory(gt).context("reading the ground truth")?;
    let est = read_tum_trajectory(est).context("reading the estimate")?;
    Ok((gt, est))
}

fn emit(
    c: &CommonArgs,
    json: serde_json::Value,
    table: String,
    warnings: &[String],
    svg: impl Fn() -> String,
    fill_report: impl Fn(&mut Report),
    title: &str,
) -> Result<()> {
    for w in warnings {
        tracing::warn!("{w}");
    }
    if c.json {
        crate::outln!("{}", serde_json::to_string(&json)?)?;
    } else {
        crate::outln!("{}", table.trim_end())?;
    }
    if let Some(p) = &c.plot {
        write_atomic(p, svg().as_bytes())
            .with_context(|| format!("writing the plot {}", p.display()))?;
        tracing::info!("plot written to {}", p.display());
    }
    if let Some(dir) = &c.report {
        let mut report = Report::new(title);
        let (gt, est) = c.paths()?;
        report.paragraph(format!(
            "Ground truth: {}. Estimate: {}.",
            gt.display(),
            est.display()
        ));
        fill_report(&mut report);
        report.code(std::env::args().collect::<Vec<_>>().join(" "));
        // Staged and published whole, as every command's output folder.
        let staged = StagedDir::new(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_report_json(staged.path(), &json)?;
        report
            .write(staged.path())
            .with_context(|| format!("writing the report into {}", dir.display()))?;
        staged
            .publish()
            .with_context(|| format!("publishing {}", dir.display()))?;
        tracing::info!("report written to {}", dir.join("report.html").display());
    }
    Ok(())
}

fn write_report_json(dir: &Path, json: &serde_json::Value) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let p = dir.join("report.json");
    write_atomic(&p, serde_json::to_string_pretty(json)?.as_bytes())
        .with_context(|| format!("writing {}", p.display()))
}

/// An eval error for a user of `stride eval`: an invalid option is named by the flag that
/// sets it (the eval crate names its options' fields).
fn in_flags(e: EvalError) -> anyhow::Error {
    let hint = match &e {
        EvalError::TooFewPairs { .. } => {
            "--t-max-diff widens the window, --offset shifts the clock"
        }
        EvalError::DegenerateAlignment { .. } => "--align origin, --align none or --preset tum",
        _ => "",
    };
    let EvalError::InvalidOption { option, message } = e else {
        return if hint.is_empty() {
            e.into()
        } else {
            anyhow::anyhow!("{e} ({hint})")
        };
    };
    let flag = match option {
        "t_max_diff_s" => "--t-max-diff",
        "offset_s" => "--offset",
        "delta" => "--delta",
        "rel_delta_tol" => "--delta-tol",
        "all_pairs" => "--all-pairs",
        other => other,
    };
    anyhow::anyhow!("{flag}: {message}")
}

fn run_ate(a: AteArgs) -> Result<()> {
    let c = &a.common;
    let (gt, est) = load(c)?;
    let mut o = AteOptions::for_preset(c.preset);
    if let Some(al) = c.align {
        o.align = al;
    }
    if let Some(t) = c.t_max_diff {
        o.t_max_diff_s = t;
    }
    o.offset_s = c.offset;
    let r = ate(&gt, &est, &o)
        .map_err(in_flags)
        .context("computing the ATE")?;
    emit(
        c,
        r.to_json(),
        r.table(),
        &r.warnings,
        || r.chart_svg(),
        |rep| r.add_to_report(rep, "ate"),
        "stride eval: absolute trajectory error",
    )?;
    c.limits.check("ATE", &r.trans_m, &r.rot_deg)
}

fn run_rpe(a: RpeArgs) -> Result<()> {
    let c = &a.common;
    let (gt, est) = load(c)?;
    let mut o = RpeOptions::for_preset(c.preset);
    if let Some(al) = c.align {
        o.align = al;
    }
    if let Some(t) = c.t_max_diff {
        o.t_max_diff_s = t;
    }
    o.offset_s = c.offset;
    if let Some(d) = a.delta {
        o.delta = d;
    }
    if let Some(u) = a.delta_unit {
        o.unit = u;
    }
    o.all_pairs = a.all_pairs;
    o.rel_delta_tol = a.delta_tol;
    let r = rpe(&gt, &est, &o)
        .map_err(in_flags)
        .context("computing the RPE")?;
    emit(
        c,
        r.to_json(),
        r.table(),
        &r.warnings,
        || r.chart_svg(),
        |rep| r.add_to_report(rep, "rpe"),
        "stride eval: relative pose error",
    )?;
    c.limits.check("RPE", &r.trans_m, &r.rot_deg)
}
