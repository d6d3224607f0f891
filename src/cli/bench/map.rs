//! `stride bench map`: elevation-map update time per depth frame, ours and the baseline.

use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::json;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct MapBenchArgs {
    /// Sequence folder with ground-truth poses (TUM layout) [default: a synthetic sequence
    /// rendered into a temporary folder]. With --octomap it may be repeated: one table.
    #[arg(long)]
    dataset: Vec<PathBuf>,
    /// Frames mapped (the median update time is reported).
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Which mappers to time.
    #[arg(long, value_enum, default_value = "both")]
    mapper: crate::cli::map::MapperArg,
    /// Time the stack mapper without its depth-edge filter.
    #[arg(long)]
    no_edge_filter: bool,
    /// Time the stack mapper without the visibility check.
    #[arg(long)]
    no_visibility: bool,
    /// Time the stack mapper without the see-through check.
    #[arg(long)]
    no_see_through: bool,
    /// Time the stack mapper without its depth smoothing.
    #[arg(long)]
    no_depth_smoothing: bool,
    /// Time the stack mapper without its push of steep faces' pixels.
    #[arg(long)]
    no_steep_push: bool,
    /// Also time each mapper on the portable (x86-64-v2) copies of the vectorised loops,
    /// taking turns with the others frame by frame, for the ratio to the copies this CPU
    /// runs (AVX2 where present; the same maps: stride_mapping::simd).
    #[arg(long)]
    portable: bool,
    /// Python of a throwaway venv with pyoctomap and numpy: compare our maps with OctoMap
    /// on the same clouds (paper 000's Table 2) through scripts/peers/octomap_peer.py
    /// (never a project dependency), both mappers with their default settings. Ray casting
    /// at 1 cm takes seconds per frame.
    #[arg(long, value_name = "PYTHON")]
    octomap: Option<PathBuf>,
    /// OctoMap's resolutions (m).
    #[arg(long, value_delimiter = ',', default_values_t = [0.01, 0.02])]
    octomap_resolution: Vec<f64>,
    /// Also write the --octomap table as Markdown to this file.
    #[arg(long, value_name = "FILE.md", requires = "octomap")]
    report: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

pub fn bench_map(a: MapBenchArgs) -> Result<()> {
    use stride_datasets::tum::{AssociationOptions, TumSequence};
    use stride_mapping::fankhauser::{FankhauserConfig, FankhauserMapper};
    use stride_mapping::input::SensorFrame;
    use stride_mapping::stack::{StackConfig, StackMapper};
    use stride_mapping::ElevationMapper;
    let tmp = tempfile::tempdir()?;
    if a.dataset.len() > 1 && a.octomap.is_none() {
        bail!("more than one --dataset needs --octomap");
    }
    let dir = match a.dataset.first() {
        Some(d) => d.clone(),
        None => {
            let d = tmp.path().join("seq");
            let cfg = stride_datasets::synth::SynthConfig {
                frames: a.frames,
                blur: false,
                ..Default::default()
            };
            stride_datasets::synth::generate(&cfg, &d, false, &mut |_, _| {})?;
            d
        }
    };
    if let Some(py) = &a.octomap {
        let dirs = if a.dataset.is_empty() {
            vec![dir]
        } else {
            a.dataset.clone()
        };
        return super::octomap::octomap_table(
            &dirs,
            a.frames,
            py,
            &a.octomap_resolution,
            a.report.as_deref(),
            a.json,
        );
    }
    let seq = TumSequence::open(&dir, None, AssociationOptions::default())?;
    let gt = seq
        .groundtruth
        .clone()
        .context("the sequence has no ground truth poses")?;
    let mut frames = Vec::new();
    for i in 0..seq.len().min(a.frames) {
        let f = seq.load_frame(i)?;
        if let Some(pose) = gt.interpolate(f.t_depth_s) {
            frames.push((f, pose));
        }
    }
    if frames.is_empty() {
        bail!("no frame of {} has a ground-truth pose", dir.display());
    }
    let valid: f64 = frames
        .iter()
        .map(|(f, _)| f.depth_m.as_slice().iter().filter(|&&z| z > 0.0).count() as f64)
        .sum::<f64>()
        / frames.len() as f64;
    use crate::cli::map::MapperArg;
    // Each mapper with its name in the output and whether it runs the portable loops.
    let mut mappers: Vec<(Box<dyn ElevationMapper>, &str, bool)> = Vec::new();
    if a.mapper != MapperArg::Fankhauser {
        let d = StackConfig::default();
        let cfg = StackConfig {
            edge_filter: d.edge_filter.filter(|_| !a.no_edge_filter),
            visibility_check: !a.no_visibility,
            see_through_check: !a.no_see_through,
            depth_smoothing: d.depth_smoothing.filter(|_| !a.no_depth_smoothing),
            steep_push_sigmas: if a.no_steep_push {
                0.0
            } else {
                d.steep_push_sigmas
            },
            ..d
        };
        if a.portable {
            mappers.push((
                Box::new(StackMapper::new(cfg.clone())?),
                "stack_portable",
                true,
            ));
        }
        mappers.push((Box::new(StackMapper::new(cfg)?), "stack", false));
    }
    if a.mapper != MapperArg::Stack {
        if a.portable {
            mappers.push((
                Box::new(FankhauserMapper::new(FankhauserConfig::default())?),
                "fankhauser_portable",
                true,
            ));
        }
        mappers.push((
            Box::new(FankhauserMapper::new(FankhauserConfig::default())?),
            "fankhauser",
            false,
        ));
    }
    let simd = stride_mapping::simd::instruction_set();
    let mut out = serde_json::Map::new();
    // The mappers take turns frame by frame, so that both see the same machine state (these
    // VMs drift by tens of percent within a minute); the ratio of medians is the figure to
    // trust.
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); mappers.len()];
    let mut phases: Vec<[Vec<f64>; 2]> = vec![[Vec::new(), Vec::new()]; mappers.len()];
    let mut used = vec![0usize; mappers.len()];
    let mut reference = super::map_reference::ReferencePass::new(400, 0.01);
    let (mut ref_times, mut ref_used) = (Vec::new(), 0usize);
    for (f, pose) in &frames {
        let sf = SensorFrame::depth(&f.depth_m, &seq.camera.camera, *pose, f.t_depth_s)
            .with_context(|| format!("frame {}", f.index))?;
        for ((((m, _, portable), t), u), ph) in mappers
            .iter_mut()
            .zip(&mut times)
            .zip(&mut used)
            .zip(&mut phases)
        {
            stride_mapping::simd::force_portable(*portable);
            let s = m.integrate(&sf);
            stride_mapping::simd::force_portable(false);
            t.push(s.update_s);
            let [p, c] = ph;
            p.push(s.prepare_s);
            c.push(s.checks_s);
            *u += s.points_used;
        }
        let (t, n) = reference.run(&f.depth_m, &seq.camera.camera, pose);
        ref_times.push(t);
        ref_used += n;
    }
    let (ref_med, ref_p95) = stride::pipeline::median_p95(ref_times.iter().copied());
    out.insert(
        "reference".into(),
        json!({"update_ms_median": ref_med * 1e3, "update_ms_p95": ref_p95 * 1e3, "threads": 1, "points_per_s": ref_used as f64 / ref_times.iter().sum::<f64>()}),
    );
    for ((((_, name, _), t), u), [p, c]) in mappers.iter().zip(&times).zip(&used).zip(&phases) {
        let total: f64 = t.iter().sum();
        let (med, p95) = stride::pipeline::median_p95(t.iter().copied());
        let (pm, _) = stride::pipeline::median_p95(p.iter().copied());
        let (cm, _) = stride::pipeline::median_p95(c.iter().copied());
        out.insert(
            (*name).into(),
            json!({"update_ms_median": med * 1e3, "update_ms_p95": p95 * 1e3, "prepare_ms_median": pm * 1e3, "checks_ms_median": cm * 1e3, "points_per_s": *u as f64 / total, "points_used": *u}),
        );
    }
    if a.json {
        crate::outln!(
            "{}",
            json!({"frames": frames.len(), "pixels_per_frame": frames[0].0.depth_m.as_slice().len(), "valid_depth_per_frame": valid, "threads": rayon::current_num_threads(), "instruction_set": simd, "mappers": out})
        )?;
        return Ok(());
    }
    crate::outln!("{} frames of {} ({} pixels, {:.0} with depth on average), 1 cm cells, 4 x 4 m window, {} threads, {simd} loops", frames.len(), dir.display(), frames[0].0.depth_m.as_slice().len(), valid, rayon::current_num_threads())?;
    let g = |k: &str, f: &str| {
        out.get(k)
            .and_then(|v| v.get(f))
            .and_then(|v| v.as_f64())
            .unwrap_or(f64::NAN)
    };
    // Only the mappers timed in this run (--mapper chooses them).
    for k in [
        "stack",
        "stack_portable",
        "fankhauser",
        "fankhauser_portable",
        "reference",
    ]
    .into_iter()
    .filter(|k| out.contains_key(*k))
    {
        crate::outln!(
            "{k:<19} update {:>7.2} ms median, {:>7.2} ms p95, {:.2e} points/s",
            g(k, "update_ms_median"),
            g(k, "update_ms_p95"),
            g(k, "points_per_s")
        )?;
    }
    crate::outln!(
        "(reference: one plain pass on one thread, each pixel back-projected and kept as its cell's highest point: the practical limit)"
    )?;
    let ratio = |a: &str, b: &str| {
        (out.contains_key(a) && out.contains_key(b))
            .then(|| g(a, "update_ms_median") / g(b, "update_ms_median"))
    };
    for (a, b) in [
        ("stack", "stack_portable"),
        ("fankhauser", "fankhauser_portable"),
        ("stack", "reference"),
        ("fankhauser", "reference"),
        ("fankhauser", "stack"),
    ] {
        if let Some(r) = ratio(a, b) {
            crate::outln!("{a} / {b} update time: {r:.2}")?;
        }
    }
    Ok(())
}
