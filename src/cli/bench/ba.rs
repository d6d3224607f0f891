//! `stride bench ba`: one local bundle adjustment (by default 10 keyframes, 3000 points, 5
//! iterations) on a synthetic problem shaped like the SLAM's windows, against the same
//! solve on one thread and against one pass over the edges (the floor: every iteration
//! must at least touch every edge once), all in the same run.

use super::median;
use anyhow::{bail, Result};
use clap::Args;
use serde_json::json;
use std::time::Instant;
use stride_backend::ba::problem::point_error;
use stride_backend::ba::synthetic::{generate, SyntheticSpec};
use stride_backend::ba::{solve, SolverOptions};

#[derive(Debug, Args)]
pub struct BaBenchArgs {
    /// Keyframes of the window (the first is fixed).
    #[arg(long, default_value_t = 10)]
    keyframes: usize,
    /// Points.
    #[arg(long, default_value_t = 3000)]
    points: usize,
    /// Levenberg-Marquardt iterations per solve.
    #[arg(long, default_value_t = 5)]
    iterations: usize,
    /// Solves timed (the median is reported).
    #[arg(long, default_value_t = 30)]
    runs: usize,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

pub fn bench_ba(a: BaBenchArgs) -> Result<()> {
    if a.runs == 0 || a.keyframes < 2 || a.points == 0 || a.iterations == 0 {
        bail!("--runs, --points and --iterations must be at least 1, --keyframes at least 2");
    }
    let s = generate(&SyntheticSpec {
        keyframes: a.keyframes,
        points: a.points,
        ..SyntheticSpec::default()
    });
    let opts = SolverOptions {
        max_iterations: a.iterations,
        function_tolerance: 0.0,
        ..SolverOptions::default()
    };
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let (mut par, mut seq, mut pass) = (Vec::new(), Vec::new(), Vec::new());
    let mut accepted = 0;
    // The three take turns, so that they see the same machine state; the two solves swap
    // places every run, since the first after the problem's copy pays about 1 ms more for
    // fresh memory (page faults).
    for run in 0..a.runs {
        for first in [run % 2 == 0, run % 2 == 1] {
            let mut p = s.problem.clone();
            if first {
                let r = solve(&mut p, &opts)?;
                par.push(r.time_s * 1e3);
                accepted = r.accepted;
            } else {
                let r = one.install(|| solve(&mut p, &opts))?;
                seq.push(r.time_s * 1e3);
            }
        }
        let t = Instant::now();
        let cost: f64 = s
            .problem
            .point_edges
            .iter()
            .filter_map(|e| {
                let pose = s.problem.poses.get(e.pose)?;
                let pt = s.problem.points.get(e.point)?;
                let r = point_error(&pose.world_from_camera, &pt.p_world, &e.p_camera);
                Some(r.dot(&(e.information * r)))
            })
            .sum();
        pass.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(cost);
    }
    let (mp, ms, mc) = (median(par), median(seq), median(pass));
    let edges = s.problem.point_edges.len();
    if a.json {
        crate::outln!(
            "{}",
            json!({"keyframes": a.keyframes, "points": a.points, "edges": edges, "iterations": a.iterations,
                   "accepted_steps": accepted, "runs": a.runs, "threads": rayon::current_num_threads(),
                   "solve_ms_median": mp, "solve_1_thread_ms_median": ms, "one_pass_ms_median": mc,
                   "ratio_to_one_pass_per_iteration": mp / (mc * a.iterations as f64)})
        )?;
        return Ok(());
    }
    crate::outln!(
        "{} keyframes, {} points, {} observations, {} iterations ({} accepted), median of {} solves",
        a.keyframes,
        a.points,
        edges,
        a.iterations,
        accepted,
        a.runs
    )?;
    crate::outln!(
        "solve {mp:.2} ms on {} threads, {ms:.2} ms on 1 (speed-up {:.2}); one pass over the edges {mc:.3} ms: an iteration costs {:.1} passes",
        rayon::current_num_threads(),
        ms / mp,
        mp / (mc * a.iterations as f64)
    )?;
    Ok(())
}
