//! `stride bench eval`: ATE and RPE on a large trajectory pair, against evo.

use super::median;
use anyhow::{bail, Context, Result};
use clap::Args;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_core::rng::SplitMix64;
use stride_core::trajectory::Trajectory;
use stride_datasets::trajectory_file::{read_tum_trajectory, write_tum_trajectory};
use stride_eval::{ate, rpe, Align, AteOptions, Preset, RpeOptions};

#[derive(Debug, Args)]
pub struct EvalBenchArgs {
    /// Poses in each trajectory.
    #[arg(long, default_value_t = 100_000)]
    poses: usize,
    /// Repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Python interpreter of a venv with evo, to time evo on the same files. Default: the
    /// STRIDE_EVO_PYTHON environment variable, if set.
    #[arg(long, value_name = "PYTHON")]
    evo_python: Option<PathBuf>,
    /// Repetitions for evo (it is slow).
    #[arg(long, default_value_t = 3)]
    evo_runs: usize,
    /// Where to write the generated trajectories (default: a temporary folder, removed after).
    #[arg(long, value_name = "DIR")]
    keep: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

/// A 100 Hz ground truth on a smooth 3-D path and an estimate with random-walk drift, noise,
/// stamp jitter below the association window and a different world frame.
fn make_pair(n: usize, seed: u64) -> Result<(Trajectory, Trajectory)> {
    let mut rng = SplitMix64::new(seed);
    let world_est_from_gt = Isometry3::from_parts(
        Translation3::new(1.0, -2.0, 0.5),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
    );
    let (mut gt_t, mut gt_p, mut est_t, mut est_p) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let mut drift = Vector3::zeros();
    for i in 0..n {
        let t = 1_700_000_000.0 + i as f64 * 0.01;
        let s = i as f64 * 0.01;
        let pos = Vector3::new(
            3.0 * (0.05 * s).sin(),
            2.0 * (0.031 * s).cos(),
            0.4 + 0.2 * (0.2 * s).sin(),
        );
        let rot = UnitQuaternion::from_euler_angles(
            0.05 * (0.7 * s).sin(),
            0.1 * (0.3 * s).cos(),
            0.05 * s,
        );
        let gt = Isometry3::from_parts(pos.into(), rot);
        drift += Vector3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        ) * 2e-4;
        let noise = Vector3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        ) * 3e-3;
        let rot_noise = UnitQuaternion::from_euler_angles(
            rng.range(-1.0, 1.0) * 2e-3,
            rng.range(-1.0, 1.0) * 2e-3,
            rng.range(-1.0, 1.0) * 2e-3,
        );
        let est = world_est_from_gt
            * Isometry3::from_parts((pos + drift + noise).into(), rot * rot_noise);
        gt_t.push(t);
        gt_p.push(gt);
        est_t.push(t + rng.range(-1.0, 1.0) * 0.002);
        est_p.push(est);
    }
    Ok((
        Trajectory::from_parts(gt_t, gt_p)?,
        Trajectory::from_parts(est_t, est_p)?,
    ))
}

fn evo_timing(python: &Path, gt: &Path, est: &Path, runs: usize) -> Result<serde_json::Value> {
    let script = include_str!("../../../scripts/peers/evo_bench.py");
    let out = std::process::Command::new(python)
        .arg("-c")
        .arg(script)
        .arg(gt)
        .arg(est)
        .arg(runs.to_string())
        .output()
        .with_context(|| format!("running {}", python.display()))?;
    if !out.status.success() {
        bail!(
            "evo benchmark failed ({}): {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or("");
    serde_json::from_str(last).with_context(|| format!("parsing evo's output: {last}"))
}

pub fn bench_eval(a: EvalBenchArgs) -> Result<()> {
    if a.poses < 10 || a.runs == 0 {
        bail!("--poses must be at least 10 and --runs at least 1");
    }
    let tmp;
    let dir = match &a.keep {
        Some(d) => {
            std::fs::create_dir_all(d)?;
            d.clone()
        }
        None => {
            tmp = tempfile::tempdir()?;
            tmp.path().to_path_buf()
        }
    };
    let (gt, est) = make_pair(a.poses, 42)?;
    let (gt_path, est_path) = (dir.join("bench_gt.txt"), dir.join("bench_est.txt"));
    write_tum_trajectory(&gt_path, &gt)?;
    write_tum_trajectory(&est_path, &est)?;

    let ate_opts = AteOptions {
        align: Align::Se3,
        ..AteOptions::for_preset(Preset::Evo)
    };
    let rpe_opts = RpeOptions::for_preset(Preset::Evo);
    let (mut load, mut ate_t, mut rpe_t) = (Vec::new(), Vec::new(), Vec::new());
    let (mut ate_rmse, mut rpe_rmse) = (f64::NAN, f64::NAN);
    for _ in 0..a.runs {
        let t0 = Instant::now();
        let g = read_tum_trajectory(&gt_path)?;
        let e = read_tum_trajectory(&est_path)?;
        let t1 = Instant::now();
        ate_rmse = ate(&g, &e, &ate_opts)?.trans_m.rmse;
        let t2 = Instant::now();
        rpe_rmse = rpe(&g, &e, &rpe_opts)?.trans_m.rmse;
        let t3 = Instant::now();
        load.push((t1 - t0).as_secs_f64());
        ate_t.push((t2 - t1).as_secs_f64());
        rpe_t.push((t3 - t2).as_secs_f64());
    }
    let ours = json!({
        "load_s": median(load),
        "ate_s": median(ate_t),
        "rpe_s": median(rpe_t),
        "ate_rmse": ate_rmse,
        "rpe_rmse": rpe_rmse,
        "runs": a.runs,
    });
    let python = a
        .evo_python
        .clone()
        .or_else(|| std::env::var_os("STRIDE_EVO_PYTHON").map(PathBuf::from));
    let evo = match &python {
        Some(p) => Some(evo_timing(p, &gt_path, &est_path, a.evo_runs)?),
        None => None,
    };
    let f = |v: &serde_json::Value, k: &str| v.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN);
    if a.json {
        crate::outln!("{}", json!({"poses": a.poses, "stride": ours, "evo": evo}))?;
        return Ok(());
    }
    crate::outln!(
        "ATE (SE(3), evo preset) + RPE (1 frame) on {} poses per trajectory; medians",
        a.poses
    )?;
    crate::outln!(
        "{:<22}{:>14}{:>14}{:>14}",
        "",
        "stride (ms)",
        "evo (ms)",
        "evo / stride"
    )?;
    for (label, key) in [
        ("load both files", "load_s"),
        ("ATE", "ate_s"),
        ("RPE", "rpe_s"),
    ] {
        let s = f(&ours, key) * 1e3;
        match &evo {
            Some(e) => crate::outln!(
                "{label:<22}{s:>14.2}{:>14.1}{:>14.1}",
                f(e, key) * 1e3,
                f(e, key) * 1e3 / s
            )?,
            None => crate::outln!("{label:<22}{s:>14.2}{:>14}{:>14}", "-", "-")?,
        }
    }
    let total = |v: &serde_json::Value| f(v, "load_s") + f(v, "ate_s") + f(v, "rpe_s");
    match &evo {
        Some(e) => {
            crate::outln!(
                "{:<22}{:>14.2}{:>14.1}{:>14.1}",
                "total",
                total(&ours) * 1e3,
                total(e) * 1e3,
                total(e) / total(&ours)
            )?;
            crate::outln!(
                "results agree: ATE rmse {:.9} vs {:.9} m, RPE rmse {:.9} vs {:.9} m",
                ate_rmse,
                f(e, "ate_rmse"),
                rpe_rmse,
                f(e, "rpe_rmse")
            )?;
        }
        None => crate::outln!(
            "{:<22}{:>14.2}   (pass --evo-python to time evo on the same files)",
            "total",
            total(&ours) * 1e3
        )?,
    }
    Ok(())
}
