//! Command-line interface: argument definitions and dispatch.

mod bench;
mod config;
mod convert;
mod demo;
mod eval;
mod eval_ci;
pub mod gates;
mod map;
mod map2d;
mod map2d_report;
mod map_figures;
mod run;
mod run_files;
mod run_report;
mod study;
mod study_real;
mod synth;
mod vocab;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// stride: feature-based RGB-D SLAM and 2.5-D elevation mapping for walking robots, with
/// evaluation against ground truth that matches evo and the TUM benchmark tools.
#[derive(Debug, Parser)]
#[command(name = "stride", version, about, long_about = None)]
pub struct Cli {
    /// More log output (-v: debug, -vv: trace). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    /// Only warnings and errors on stderr.
    #[arg(short, long, global = true)]
    pub quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Compare an estimated trajectory with ground truth (ATE, RPE).
    #[command(subcommand)]
    Eval(eval::EvalCommand),
    /// Run the SLAM (visual odometry and a bundle-adjusting back end) on an RGB-D sequence.
    Run(run::RunArgs),
    /// Build an elevation map of a sequence from its depth images and known poses.
    Map(map::MapArgs),
    /// Build paper 003's terrain map (elevation and certainty grids) from a 2-D range-scan log.
    Map2d(map2d::Map2dArgs),
    /// Simulate a tilted 2-D laser scanner (URG-04LX) in the synthetic world: a scan log and
    /// the true terrain.
    Scans(map2d::ScansArgs),
    /// Render a synthetic legged-robot RGB-D sequence with ground truth (TUM layout).
    Synth(synth::SynthArgs),
    /// The whole pipeline on the embedded synthetic sequence: render, track, map, report.
    Demo(demo::DemoArgs),
    /// Convert a TUM folder to an MCAP log of ROS 2 messages, or an MCAP log to a TUM folder.
    Convert(convert::ConvertArgs),
    /// List what an MCAP log holds: topics, schemas, message counts, rates, transforms.
    Info(convert::InfoArgs),
    /// The configuration file of every stage: print the documented defaults, or check a file.
    Config(config::ConfigArgs),
    /// Measure speed (medians over repeated runs, ratios against peers run in the same session).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Studies on the synthetic lab: `study blur`, paper 004's gait-dependent motion blur.
    #[command(subcommand)]
    Study(study::StudyCommand),
    /// Train the place-recognition vocabulary on the synthetic lab (how the shipped one
    /// was made).
    Vocab(vocab::VocabArgs),
}

/// Prints to stdout, returning an error (instead of panicking like `println!`) when stdout
/// is closed, e.g. by `| head`.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout(), $($arg)*)
    }};
}

/// Fails at once, before any work, when an output folder given as `flag` exists as
/// something other than a folder, or as a folder with contents and `overwrite` is false:
/// results are never mixed with, or silently replace, an earlier run's.
pub fn check_out_dir(flag: &str, dir: &std::path::Path, overwrite: bool) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("{flag} {}: exists and is not a folder", dir.display());
    }
    let non_empty = std::fs::read_dir(dir).is_ok_and(|mut d| d.next().is_some());
    if non_empty && !overwrite {
        anyhow::bail!(
            "{flag} {}: the folder exists and is not empty; pass --overwrite to replace it",
            dir.display()
        );
    }
    Ok(())
}

/// A progress bar on stderr labelled `what` (hidden when `show` is false): the one style of
/// every long command.
pub fn progress_bar(total: usize, what: &str, show: bool) -> indicatif::ProgressBar {
    use indicatif::{ProgressBar, ProgressStyle};
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({per_sec}, eta {eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(what.to_owned());
    pb
}

/// Logs go to stderr so that stdout carries only results (tables or JSON).
pub fn init_logging(verbose: u8, quiet: bool) {
    let default = match (quiet, verbose) {
        (true, _) => "warn",
        (false, 0) => "info",
        (false, 1) => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .without_time()
        .try_init();
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Eval(c) => eval::run(c),
        Command::Bench(c) => bench::run(c),
        Command::Study(c) => study::run(c),
        Command::Vocab(a) => vocab::run(a),
        Command::Synth(a) => synth::run(a),
        Command::Run(a) => run::run(a),
        Command::Map(a) => map::run(a),
        Command::Map2d(a) => map2d::map2d(a),
        Command::Scans(a) => map2d::scans(a),
        Command::Demo(a) => demo::run(a),
        Command::Config(a) => config::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Info(a) => convert::info(a),
    }
}
