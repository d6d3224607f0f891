//! `stride bench map --octomap PYTHON`: paper 000's Table 2 comparison. Our stack map, the
//! Fankhauser baseline and OctoMap (run by scripts/peers/octomap_peer.py in a throwaway venv
//! with pyoctomap, never a project dependency) get the same frames, poses (ground truth) and
//! clouds (our mappers' own depth filtering); OctoMap's occupied voxels are turned into a
//! 2.5-D grid of the stack map's geometry (the highest occupied voxel per column) and every
//! map is scored with the same metrics.

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use stride::known_poses::{map_sequence, phantom_score, FLOOR_BAND_M};
use stride_core::grid::Grid;
use stride_datasets::grid_file::read_grid;
use stride_datasets::sequence::Sequence;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_mapping::fankhauser::{FankhauserConfig, FankhauserMapper};
use stride_mapping::input::{filtered_map_points, SensorFrame};
use stride_mapping::metrics::{compare, floor_fit};
use stride_mapping::stack::{StackConfig, StackMapper};
use stride_mapping::ElevationMapper;

/// The peer script, beside the sources.
const PEER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/peers/octomap_peer.py");

/// One map's figures on one sequence.
fn row(
    dataset: &str,
    mapper: String,
    map: &Grid<f32>,
    terrain: Option<&Grid<f32>>,
    update_ms: f64,
    memory_bytes: usize,
) -> Value {
    let score = terrain.and_then(|t| compare(map, t));
    let phantoms = terrain.map(|t| phantom_score(map, t).phantoms);
    // The floor's flatness stands in for the error where no true terrain is known.
    let floor = floor_fit(map, FLOOR_BAND_M).filter(|_| terrain.is_none());
    json!({
        "dataset": dataset, "mapper": mapper,
        "rmse_m": score.map(|s| s.rmse), "mean_abs_m": score.map(|s| s.mean_abs),
        "coverage": score.map(|s| s.coverage), "phantoms": phantoms,
        "cells_observed": map.as_slice().iter().filter(|v| !v.is_nan()).count(),
        "floor_residual_std_m": floor.map(|f| f.residual_std_m),
        "floor_tilt_deg": floor.map(|f| f.tilt_deg),
        "update_ms_median": update_ms, "memory_mb": memory_bytes as f64 / 1e6,
    })
}

/// Writes the clouds our mappers get for the first `frames` frames with a pose into `dir`
/// (`frames.json`, `points.f32`) for a grid of `geometry`.
fn export_clouds(
    seq: &TumSequence,
    frames: usize,
    geometry: &stride_core::grid::GridGeometry,
    dir: &Path,
) -> Result<usize> {
    let gt = seq.groundtruth.as_ref().context("no ground truth")?;
    let cfg = StackConfig::default();
    let mut points = std::io::BufWriter::new(std::fs::File::create(dir.join("points.f32"))?);
    let mut list = Vec::new();
    for i in 0..seq.len().min(frames) {
        let f = seq.load_frame(i)?;
        let Some(pose) = gt.interpolate(f.t_depth_s) else {
            continue;
        };
        let sf = SensorFrame::depth(&f.depth_m, &seq.camera.camera, pose, f.t_depth_s)?;
        let (pts, _) = filtered_map_points(&sf, &cfg.sensor, cfg.edge_filter.as_ref());
        for p in &pts {
            for v in [p.x, p.y, p.z] {
                points.write_all(&(v as f32).to_le_bytes())?;
            }
        }
        let o = pose.translation.vector;
        list.push(json!({"origin": [o.x, o.y, o.z], "points": pts.len()}));
    }
    points.flush()?;
    let spec = json!({
        "grid": {"origin_x": geometry.origin_x, "origin_y": geometry.origin_y,
                 "resolution": geometry.resolution, "rows": geometry.rows, "cols": geometry.cols},
        "frames": list,
    });
    std::fs::write(dir.join("frames.json"), spec.to_string())?;
    Ok(list.len())
}

/// The table's rows for one sequence.
fn one_sequence(
    dir: &Path,
    frames: usize,
    python: &Path,
    resolutions: &[f64],
) -> Result<Vec<Value>> {
    let name = dir
        .file_name()
        .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into());
    let seq = TumSequence::open(dir, None, AssociationOptions::default())?;
    let gt = seq
        .groundtruth
        .clone()
        .with_context(|| format!("{}: no ground-truth poses", dir.display()))?;
    let terrain_path = dir.join("terrain.npy");
    let terrain = if terrain_path.is_file() {
        Some(read_grid(&terrain_path, None).context("reading terrain.npy")?)
    } else {
        None
    };
    let mappers: Vec<Box<dyn ElevationMapper>> = vec![
        Box::new(StackMapper::new(StackConfig::default())?),
        Box::new(FankhauserMapper::new(FankhauserConfig::default())?),
    ];
    let (runs, counts) = map_sequence(
        &Sequence::Tum(seq.clone()),
        &gt,
        mappers,
        Some(frames),
        terrain.as_ref(),
        || {},
    )?;
    let geometry = runs
        .first()
        .map(|r| r.layers.elevation.geometry)
        .context("no map")?;
    let mut rows = Vec::new();
    for r in &runs {
        let (med, _) = stride::pipeline::median_p95(r.update_s.iter().map(|s| s * 1e3));
        let m = &r.layers.elevation;
        rows.push(row(
            &name,
            r.name.into(),
            m,
            terrain.as_ref(),
            med,
            r.memory_bytes,
        ));
    }
    let tmp = tempfile::tempdir()?;
    let (inp, out) = (tmp.path().join("in"), tmp.path().join("out"));
    std::fs::create_dir_all(&inp)?;
    std::fs::create_dir_all(&out)?;
    let exported = export_clouds(&seq, frames, &geometry, &inp)?;
    if exported != counts.mapped {
        bail!(
            "{name}: {exported} clouds exported for {} frames mapped",
            counts.mapped
        );
    }
    tracing::info!(
        "{name}: OctoMap on {exported} frames at {resolutions:?} m (ray casting: minutes at 1 cm)"
    );
    let status = std::process::Command::new(python)
        .arg(PEER)
        .arg("map")
        .arg(&inp)
        .arg(&out)
        .args(resolutions.iter().map(|r| r.to_string()))
        .status()
        .with_context(|| format!("running {} {PEER}", python.display()))?;
    if !status.success() {
        bail!(
            "{PEER} failed ({status}); does {} have pyoctomap and numpy?",
            python.display()
        );
    }
    let result: Value = serde_json::from_str(&std::fs::read_to_string(out.join("result.json"))?)?;
    for res in resolutions {
        let file = format!("elevation_{}mm.f32", (res * 1000.0).round());
        let bytes = std::fs::read(out.join(&file))?;
        let data: Vec<f32> = bytes
            .chunks_exact(4)
            .filter_map(|c| <[u8; 4]>::try_from(c).ok().map(f32::from_le_bytes))
            .collect();
        let grid = Grid::from_vec(geometry, data)
            .with_context(|| format!("{file} does not hold the grid's cells"))?;
        let run = &result["runs"][&file];
        let insert: Vec<f64> = run["insert_ms"]
            .as_array()
            .map(|a| a.iter().filter_map(Value::as_f64).collect())
            .unwrap_or_default();
        let (med, _) = stride::pipeline::median_p95(insert.into_iter());
        let memory = run["memory_bytes"].as_u64().unwrap_or(0) as usize;
        rows.push(row(
            &name,
            format!("octomap {:.0} cm", res * 100.0),
            &grid,
            terrain.as_ref(),
            med,
            memory,
        ));
    }
    Ok(rows)
}

/// Runs the comparison on every dataset, prints the table (or JSON) and writes it to
/// `report` (Markdown) when given.
pub fn octomap_table(
    datasets: &[PathBuf],
    frames: usize,
    python: &Path,
    resolutions: &[f64],
    report: Option<&Path>,
    as_json: bool,
) -> Result<()> {
    if datasets.is_empty() {
        bail!("--octomap needs at least one --dataset with ground-truth poses");
    }
    if resolutions.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
        bail!("--octomap-resolution must be positive (m)");
    }
    let mut rows = Vec::new();
    for d in datasets {
        rows.extend(one_sequence(d, frames, python, resolutions)?);
    }
    let f = |v: &Value, k: &str, scale: f64, digits: usize| {
        v[k].as_f64()
            .map_or("-".to_owned(), |x| format!("{:.*}", digits, x * scale))
    };
    let mut md = format!(
        "# Elevation maps side by side (paper 000, Table 2)\n\n{frames} frames per sequence at ground-truth poses; the same clouds for every map. Errors against the true terrain over the cells each map knows; coverage of the true terrain's cells; phantoms: cells over 2 cm above flat ground; floor: plane fit where no terrain is known.\n\n| sequence | map | RMSE mm | mean abs mm | coverage | phantoms | floor std mm | floor tilt deg | update ms/frame | memory MB |\n|---|---|---|---|---|---|---|---|---|---|\n"
    );
    for r in &rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r["dataset"].as_str().unwrap_or("?"),
            r["mapper"].as_str().unwrap_or("?"),
            f(r, "rmse_m", 1e3, 2),
            f(r, "mean_abs_m", 1e3, 2),
            f(r, "coverage", 1.0, 3),
            r["phantoms"]
                .as_u64()
                .map_or("-".to_owned(), |p| p.to_string()),
            f(r, "floor_residual_std_m", 1e3, 1),
            f(r, "floor_tilt_deg", 1.0, 2),
            f(r, "update_ms_median", 1.0, 1),
            f(r, "memory_mb", 1.0, 1),
        );
    }
    if let Some(p) = report {
        stride_output::fs::write_atomic(p, md.as_bytes())
            .with_context(|| format!("writing {}", p.display()))?;
    }
    if as_json {
        crate::outln!("{}", json!({"frames": frames, "rows": rows}))?;
    } else {
        crate::outln!("{md}")?;
    }
    Ok(())
}
