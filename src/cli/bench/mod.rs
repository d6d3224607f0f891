//! `stride bench ...`: speed measurements reported as medians of repeated runs, with the
//! ratio to a baseline or peer measured in the same session (these machines are noisy).

mod ba;
mod eval;
mod map;
mod map_reference;
mod map_walk;
mod mcap;
mod octomap;
mod place;
mod scans;
mod slam;
mod synth;

use anyhow::{bail, Context, Result};
use clap::Subcommand;
use std::path::{Path, PathBuf};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// ATE + RPE on a large synthetic trajectory pair, against evo on the same files.
    Eval(eval::EvalBenchArgs),
    /// Rendering speed of the synthetic generator at 640x480, without and with motion blur.
    Synth(synth::SynthBenchArgs),
    /// SLAM speed and accuracy on a sequence decoded up front (PNG decoding timed
    /// separately): the full SLAM against the odometry alone, and ORB-SLAM3 when asked.
    Vo(slam::VoBenchArgs),
    /// One local bundle adjustment on a synthetic window (10 keyframes, 3000 points, 5
    /// iterations by default), against the same on one thread and one pass over the edges.
    Ba(ba::BaBenchArgs),
    /// Elevation-map update time for full depth frames, ours and the Fankhauser baseline,
    /// frames decoded up front.
    Map(map::MapBenchArgs),
    /// The stack map over a long walk out and back on a flat floor (10,000 frames by
    /// default): peak RSS, the archive's cap, and the columns found again on return.
    MapWalk(map_walk::MapWalkBenchArgs),
    /// Frames per second read from MCAP logs (raw, zstd, PNG) converted from a TUM folder,
    /// against reading the folder itself.
    Mcap(mcap::McapBenchArgs),
    /// Place recognition (bags of words) on a real sequence: recall against exhaustive
    /// descriptor matching, and the query time on 1,000 keyframes against exhaustive matching.
    Place(place::PlaceBenchArgs),
    /// Paper 003's map update per 683-beam scan on a simulated walk, against a one-pass
    /// reference loop over the same returns.
    Scans(scans::ScansBenchArgs),
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Eval(a) => eval::bench_eval(a),
        BenchCommand::Synth(a) => synth::bench_synth(a),
        BenchCommand::Vo(a) => slam::bench_vo(a),
        BenchCommand::Map(a) => map::bench_map(a),
        BenchCommand::MapWalk(a) => map_walk::bench_map_walk(a),
        BenchCommand::Ba(a) => ba::bench_ba(a),
        BenchCommand::Mcap(a) => mcap::bench_mcap(a),
        BenchCommand::Place(a) => place::bench_place(a),
        BenchCommand::Scans(a) => scans::bench_scans(a),
    }
}

/// The median of a series (NaNs ignored; NaN when empty).
fn median(v: Vec<f64>) -> f64 {
    stride::pipeline::median_p95(v.into_iter()).0
}

/// Runs the ORB-SLAM3 peer harness and returns its summary JSON (last stdout line).
pub(crate) fn orbslam3_summary(
    python: &Path,
    dataset: &Path,
    camera: &str,
    runs: usize,
) -> Result<serde_json::Value> {
    // The peers live in the shared tree beside the data: `$STRIDE_DATA/../tools/peers`, or
    // `../shared/tools/peers` from the working directory or from the repository.
    let shared = std::env::var_os("STRIDE_DATA").map(|d| PathBuf::from(d).join(".."));
    let harness = shared
        .into_iter()
        .chain([
            PathBuf::from("../shared"),
            PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared")),
        ])
        .map(|d| d.join("tools/peers/orbslam3_tum.py"))
        .find(|p| p.is_file())
        .context("the ORB-SLAM3 harness ../shared/tools/peers/orbslam3_tum.py was not found")?;
    let out_dir = std::env::temp_dir().join(format!("stride-orbslam3-{}", std::process::id()));
    let out = std::process::Command::new(python)
        .arg(&harness)
        .arg(dataset)
        .args(["--camera", camera, "--repeat", &runs.to_string(), "--out"])
        .arg(&out_dir)
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or("");
    if !out.status.success() {
        bail!(
            "the ORB-SLAM3 harness failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    serde_json::from_str(last).with_context(|| format!("parsing the harness output: {last}"))
}
