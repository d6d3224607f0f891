//! `stride bench scans`: paper 003's map update per 683-beam scan, against a one-pass
//! reference loop over the same returns, in the same run.

use super::median;
use anyhow::{Context, Result};
use clap::Args;
use std::time::Instant;
use stride_core::grid::Grid;
use stride_core::scan::Scan;
use stride_datasets::synth::scanner::{walk_scans, ScannerSim, MESSOR_TILT_RAD};
use stride_datasets::synth::{Synth, SynthConfig};
use stride_mapping::range2d::mapper::{covering_geometry, map_scans, ScanMapConfig};

#[derive(Debug, Args)]
pub struct ScansBenchArgs {
    /// Seconds of the simulated walk (10 scans a second).
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Runs (medians are reported).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
}

/// The practical limit: each return moved into the world and kept as its cell's highest
/// point, one pass, no filter, no bound. Returns the seconds per scan.
fn reference(scans: &[Scan], grid: &mut Grid<f32>) -> f64 {
    let g = grid.geometry;
    let start = Instant::now();
    for s in scans {
        for i in 0..s.ranges.len() {
            let Some(p) = s.p_world(i) else { continue };
            if let Some(v) = g.cell_of(p.x, p.y).and_then(|(r, c)| grid.get_mut(r, c)) {
                if v.is_nan() || (p.z as f32) > *v {
                    *v = p.z as f32;
                }
            }
        }
    }
    start.elapsed().as_secs_f64() / scans.len().max(1) as f64
}

pub fn bench_scans(a: ScansBenchArgs) -> Result<()> {
    let fps = 30.0;
    let synth = Synth::new(SynthConfig {
        frames: (a.seconds * fps).ceil() as usize + 1,
        fps,
        ..SynthConfig::default()
    })
    .context("building the synthetic world")?;
    let sim = ScannerSim::default();
    let scans: Vec<Scan> = walk_scans(&synth, &sim, MESSOR_TILT_RAD, 10.0, a.seconds)
        .into_iter()
        .map(|(s, _)| s)
        .collect();
    let g = covering_geometry(&scans, 0.01, 0.02, ScanMapConfig::default().max_range_m)
        .context("no return in the simulated scans")?;
    let config = ScanMapConfig::default();
    let no_filter = ScanMapConfig {
        mixed: None,
        ..config
    };
    let returns: usize = scans
        .iter()
        .map(|s| (0..s.ranges.len()).filter(|&i| s.valid(i)).count())
        .sum();
    let (mut full, mut bare, mut refs) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..a.runs.max(1) {
        // Interleaved, so that a change of the machine's speed hits all three alike.
        let (_, _, s) = map_scans(scans.clone(), g, &config)?;
        full.push(s.scan_median_s);
        let (_, _, s) = map_scans(scans.clone(), g, &no_filter)?;
        bare.push(s.scan_median_s);
        refs.push(reference(&scans, &mut Grid::filled(g, f32::NAN)));
    }
    let (f, b, r) = (median(full), median(bare), median(refs));
    crate::outln!(
        "{} scans of {} beams ({returns} returns), {}x{} cells of 1 cm, {} runs, medians per scan:",
        scans.len(),
        sim.sensor.beams,
        g.cols,
        g.rows,
        a.runs.max(1)
    )?;
    for (name, t) in [
        ("map update with mixed-pixel filters", f),
        ("map update without filters", b),
        ("reference loop (highest point per cell)", r),
    ] {
        crate::outln!(
            "{name:<42} {:>8.3} ms  {:>6.1}x the reference",
            t * 1e3,
            t / r
        )?;
    }
    Ok(())
}
