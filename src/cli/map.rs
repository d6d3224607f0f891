//! `stride map`: elevation mapping of a sequence with known poses.

use crate::cli::map_figures::{elevation_chart, error_chart};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};
use stride::known_poses::{map_sequence, FrameCounts, MapperRun};
use stride_core::grid::Grid;
use stride_core::rng::SplitMix64;
use stride_core::trajectory::Trajectory;
use stride_datasets::grid_file::{read_grid, relief_png, surface_ply, write_header, write_layer};
use stride_datasets::trajectory_file::read_tum_trajectory;
use stride_eval::plot::render;
use stride_eval::report::Report;
use stride_mapping::fankhauser::{FankhauserConfig, FankhauserMapper};
use stride_mapping::metrics::performance_index;
use stride_mapping::naive::NaiveMedian;
use stride_mapping::stack::{StackConfig, StackMapper};
use stride_mapping::{ElevationMapper, MapLayers, MappingError};
use stride_output::fs::{write_atomic, StagedDir};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MapperArg {
    /// Paper 000's voxel-stack map.
    Stack,
    /// The Fankhauser et al. 2014 baseline.
    Fankhauser,
    /// Both, on the same frames, side by side.
    Both,
    /// The naive reference: each cell the median of every height that landed in it.
    Naive,
    /// Stack, Fankhauser and the naive reference side by side, and with a true terrain
    /// the cells seen (measurements within 3 cm of the true surface whose ray meets it
    /// within 3 sigma_d), over which every map is also scored.
    All,
}

/// A measurement within this height of the true surface (m) shows that its cell was seen
/// (when its ray also meets the surface near it, `NaiveMedian::seen`): the sensor's noise
/// and bias at 3-4 m.
const SEEN_TOLERANCE_M: f64 = 0.03;

#[derive(Debug, Args)]
pub struct MapArgs {
    /// Sequence folder (TUM layout), or an MCAP log (a file ending in .mcap).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Topics of an MCAP --dataset.
    #[command(flatten)]
    pub topics: super::run::TopicArgs,
    /// Poses: `groundtruth` (the folder's groundtruth.txt) or a TUM trajectory file; each is
    /// `world_from_camera` with the world's z axis up.
    #[arg(long, default_value = "groundtruth")]
    pub poses: String,
    /// Output folder (created if missing; an existing non-empty one only with --overwrite).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the output folder's contents.
    #[arg(long)]
    pub overwrite: bool,
    /// Camera: fr1, fr2, fr3 or a camera file [default: from the folder].
    #[arg(long)]
    pub camera: Option<String>,
    /// Which mapper.
    #[arg(long, value_enum, default_value = "stack")]
    pub mapper: MapperArg,
    /// Cell size (m).
    #[arg(long, allow_negative_numbers = true)]
    pub resolution: Option<f64>,
    /// Side of the moving window (m).
    #[arg(long, allow_negative_numbers = true)]
    pub size: Option<f64>,
    /// The stack mapper's parameters from a configuration file's [map.stack] (see `stride
    /// config --print-defaults`); the flags override it.
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<PathBuf>,
    /// Ground-truth elevation (.npy with its .json or grid.json beside it) to evaluate
    /// against, in the poses' world [default: with `--poses groundtruth`, the folder's
    /// terrain.npy when present; with a pose file, none, since its world (a `stride run`'s
    /// gravity-aligned one) is not the ground truth's unless it says so].
    #[arg(long, value_name = "FILE.npy")]
    pub gt_terrain: Option<PathBuf>,
    /// Perturb the poses with a random-walk drift of this many percent of the distance
    /// travelled (and 1 degree of yaw per metre per percent), to see how the maps degrade
    /// with realistic odometry.
    #[arg(
        long,
        value_name = "PERCENT",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub drift: f64,
    /// Seed of the drift.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Map at most this many frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Turn off the visibility check of the stack mapper.
    #[arg(long)]
    pub no_visibility: bool,
    /// Turn off the see-through check of the stack mapper.
    #[arg(long)]
    pub no_see_through: bool,
    /// Turn off the stack mapper's depth-edge (flying pixel) filter.
    #[arg(long)]
    pub no_edge_filter: bool,
    /// Turn off the stack mapper's depth smoothing (it then bins the depth as measured).
    #[arg(long)]
    pub no_depth_smoothing: bool,
    /// Turn off the stack mapper's push of steep faces' pixels behind the faces (it then
    /// bins them where their depth puts them).
    #[arg(long)]
    pub no_steep_push: bool,
    /// Write the stack map without the median filter (hole filling, isolated-cell removal).
    #[arg(long)]
    pub no_median_filter: bool,
}

/// Perturbs a trajectory with a seeded random-walk drift: translation error growing by
/// `percent`/100 of each step's length in a random horizontal-ish direction, yaw error by
/// `percent` degrees per metre (Gaussian steps).
pub fn drifted(traj: &Trajectory, percent: f64, seed: u64) -> Result<Trajectory> {
    let mut rng = SplitMix64::new(seed ^ 0xD21F7);
    let mut out = Trajectory::new();
    let (mut e, mut yaw) = (Vector3::zeros(), 0.0f64);
    let mut prev: Option<Vector3<f64>> = None;
    for (t, p) in traj.iter() {
        let pos = p.translation.vector;
        if let Some(q) = prev {
            let step = (pos - q).norm();
            let dir = Vector3::new(rng.normal(), rng.normal(), 0.3 * rng.normal());
            let dir = if dir.norm() > 1e-12 {
                dir.normalize()
            } else {
                Vector3::x()
            };
            e += dir * (percent / 100.0 * step);
            yaw += (percent * step).to_radians() * rng.normal();
        }
        prev = Some(pos);
        // The error rotates the pose about the current position and shifts it.
        let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        let pose = Isometry3::from_parts(Translation3::from(pos + e), rot * p.rotation);
        out.push(t, pose)?;
    }
    Ok(out)
}

/// The stack mapper's parameters: the --config file's [map.stack] (or the defaults [1 cm
/// cells, a 4 m window]), then the flags.
pub fn stack_config(a: &MapArgs) -> Result<StackConfig> {
    let d = match &a.config {
        Some(path) => stride::config::Config::load(path)?
            .map
            .map(|m| m.stack)
            .unwrap_or_default(),
        None => StackConfig::default(),
    };
    Ok(StackConfig {
        resolution_m: a.resolution.unwrap_or(d.resolution_m),
        size_m: a.size.unwrap_or(d.size_m),
        visibility_check: d.visibility_check && !a.no_visibility,
        see_through_check: d.see_through_check && !a.no_see_through,
        edge_filter: d.edge_filter.filter(|_| !a.no_edge_filter),
        depth_smoothing: d.depth_smoothing.filter(|_| !a.no_depth_smoothing),
        steep_push_sigmas: if a.no_steep_push {
            0.0
        } else {
            d.steep_push_sigmas
        },
        median_filter: d.median_filter.filter(|_| !a.no_median_filter),
        ..d
    })
}

/// The mappers asked for; an error naming the flags when the mapping crate refuses their
/// parameters.
fn make_mappers(
    a: &MapArgs,
    c: &StackConfig,
    gt: Option<&Grid<f32>>,
) -> Result<Vec<Box<dyn ElevationMapper>>> {
    let stack = || -> Result<Box<dyn ElevationMapper>, MappingError> {
        Ok(Box::new(StackMapper::new(c.clone())?))
    };
    let fank = || -> Result<Box<dyn ElevationMapper>, MappingError> {
        Ok(Box::new(FankhauserMapper::new(FankhauserConfig {
            resolution_m: c.resolution_m,
            size_m: c.size_m,
            ..FankhauserConfig::default()
        })?))
    };
    let range_m = (c.sensor.min_depth_m, c.sensor.max_depth_m);
    let naive =
        || -> Box<dyn ElevationMapper> { Box::new(NaiveMedian::new(c.resolution_m, range_m)) };
    let mappers = match a.mapper {
        MapperArg::Stack => vec![stack()?],
        MapperArg::Fankhauser => vec![fank()?],
        MapperArg::Both => vec![stack()?, fank()?],
        MapperArg::Naive => vec![naive()],
        MapperArg::All => {
            let mut v = vec![stack()?, fank()?, naive()];
            // The cells seen, when the true terrain is known.
            match gt {
                Some(g) => v.push(Box::new(NaiveMedian::seen(
                    c.resolution_m,
                    range_m,
                    g.clone(),
                    SEEN_TOLERANCE_M,
                    c.sensor.model,
                ))),
                None => tracing::warn!(
                    "--mapper all without a true terrain: the cells seen are not mapped and no map is scored over them"
                ),
            }
            v
        }
    };
    Ok(mappers)
}

/// The report object of one mapper.
pub fn run_json(r: &MapperRun, counts: &FrameCounts) -> Value {
    let (med, p95) = stride::pipeline::median_p95(r.update_s.iter().copied());
    let total_s: f64 = r.update_s.iter().sum();
    let mut m = Map::new();
    m.insert("mapper".into(), json!(r.name));
    if let Some(s) = &r.score {
        m.insert("mse".into(), json!(s.mse));
        m.insert("rmse".into(), json!(s.rmse));
        m.insert("mean_abs".into(), json!(s.mean_abs));
        m.insert("p95_abs".into(), json!(s.p95_abs));
        m.insert("max_abs".into(), json!(s.max_abs));
        m.insert("coverage".into(), json!(s.coverage));
        m.insert("cells_compared".into(), json!(s.cells_compared));
    } else {
        m.insert("mse".into(), Value::Null);
        m.insert("coverage".into(), Value::Null);
    }
    m.insert("cells_observed".into(), json!(r.layers.cells_observed()));
    m.insert(
        "over_seen_cells".into(),
        r.seen
            .and_then(|s| serde_json::to_value(s).ok())
            .unwrap_or(Value::Null),
    );
    if let Some(p) = &r.phantoms {
        m.insert(
            "phantoms".into(),
            serde_json::to_value(p).unwrap_or(Value::Null),
        );
    }
    m.insert(
        "floor".into(),
        r.floor
            .and_then(|f| serde_json::to_value(f).ok())
            .unwrap_or(Value::Null),
    );
    m.insert(
        "update_ms".into(),
        json!({"median": med * 1e3, "p95": p95 * 1e3}),
    );
    m.insert(
        "points_per_s".into(),
        json!(if total_s > 0.0 {
            r.points_used as f64 / total_s
        } else {
            f64::NAN
        }),
    );
    m.insert("points_used".into(), json!(r.points_used));
    m.insert("points_overflow".into(), json!(r.points_overflow));
    m.insert(
        "rejected".into(),
        serde_json::to_value(r.rejected).unwrap_or(Value::Null),
    );
    m.insert("cells_cleared_by_visibility".into(), json!(r.cells_cleared));
    m.insert("steep_pixels_pushed".into(), json!(r.steep_pushed));
    m.insert(
        "archive_dropped_cells".into(),
        json!(r.archive_dropped_cells),
    );
    m.insert(
        "median_filter".into(),
        serde_json::to_value(r.median).unwrap_or(Value::Null),
    );
    m.insert("frames".into(), json!(counts.frames));
    m.insert("frames_mapped".into(), json!(counts.mapped));
    m.insert("frames_skipped_no_pose".into(), json!(counts.no_pose));
    m.insert("frames_skipped_unreadable".into(), json!(counts.unreadable));
    Value::Object(m)
}

/// Writes one mapper's layers, grid header, preview and surface into `dir`.
pub fn write_layers(dir: &Path, layers: &MapLayers) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    write_layer(&dir.join("elevation.npy"), &layers.elevation)?;
    write_layer(&dir.join("variance.npy"), &layers.variance)?;
    write_layer(&dir.join("vitality.npy"), &layers.vitality)?;
    write_layer(&dir.join("updates.npy"), &layers.updates)?;
    write_header(&dir.join("grid.json"), &layers.elevation.geometry)?;
    let png = relief_png(&layers.elevation, 1200).map_err(anyhow::Error::msg)?;
    write_atomic(&dir.join("elevation.png"), &png)?;
    write_atomic(&dir.join("surface.ply"), &surface_ply(&layers.elevation))?;
    Ok(())
}

pub const MAP_FRAME_NOTE: &str = "map frame = the pose file's world frame (z up, metres); each depth pixel is back-projected in the camera frame (x right, y down, z forward) and placed with world_from_camera interpolated at the depth image's time";

pub fn run(a: MapArgs) -> Result<()> {
    let (_, runs, counts) = execute(&a)?;
    for r in &runs {
        let j = run_json(r, &counts);
        crate::outln!(
            "{:<11} MSE {} m², coverage {}, {} cells, update {:.2} ms median ({:.2} p95), {:.2e} points/s",
            r.name,
            j["mse"].as_f64().map_or("-".into(), |v| format!("{v:.3e}")),
            j["coverage"].as_f64().map_or("-".into(), |v| format!("{v:.3}")),
            j["cells_observed"],
            j["update_ms"]["median"].as_f64().unwrap_or(f64::NAN),
            j["update_ms"]["p95"].as_f64().unwrap_or(f64::NAN),
            j["points_per_s"].as_f64().unwrap_or(f64::NAN)
        )?;
        if let Some(s) = &r.seen {
            crate::outln!(
                "{:<11} over the {} cells seen: coverage {:.3}, RMSE {:.2} mm; near steps ({} cells) coverage {:.3}, RMSE {:.2} mm; away RMSE {:.2} mm",
                "",
                s.cells_seen,
                s.coverage,
                s.rmse_m * 1e3,
                s.cells_near_steps,
                s.coverage_near_steps,
                s.rmse_near_steps_m * 1e3,
                s.rmse_away_m * 1e3
            )?;
        }
    }
    crate::outln!("written to {}", a.out.display())?;
    Ok(())
}

/// The sensor's path (world x, y; m) over the frames mapped: the poses within the time span
/// of the first `max_frames` depth images (all of them without a limit).
fn sensor_path(
    poses: &Trajectory,
    depth_times_s: &[f64],
    max_frames: Option<usize>,
) -> Vec<(f64, f64)> {
    let last = max_frames.map_or(depth_times_s.len(), |m| m.min(depth_times_s.len()));
    let (Some(&t0), Some(&t1)) = (
        depth_times_s.first(),
        depth_times_s.get(last.saturating_sub(1)),
    ) else {
        return Vec::new();
    };
    poses
        .iter()
        .filter(|(t, _)| (t0..=t1).contains(t))
        .map(|(_, p)| (p.translation.x, p.translation.y))
        .collect()
}

/// Maps the sequence and writes everything into `a.out`; returns the report.json object,
/// the runs and the frame counts.
pub fn execute(a: &MapArgs) -> Result<(Value, Vec<MapperRun>, FrameCounts)> {
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    let stack = stack_config(a)?;
    let seq = a.topics.open(&a.dataset, a.camera.as_deref())?;
    let poses = if a.poses == "groundtruth" {
        seq.groundtruth().cloned().with_context(|| {
            format!(
                "{} has no ground truth; pass --poses FILE",
                a.dataset.display()
            )
        })?
    } else {
        read_tum_trajectory(Path::new(&a.poses)).context("reading --poses")?
    };
    if !(a.drift.is_finite() && a.drift >= 0.0) {
        bail!("--drift {} must be a non-negative percentage", a.drift);
    }
    let poses = if a.drift > 0.0 {
        drifted(&poses, a.drift, a.seed)?
    } else {
        poses
    };
    // The folder's true terrain is in the ground truth's world: poses from a file are
    // scored against it only when the user says they share it.
    let folder_terrain = Some(a.dataset.join("terrain.npy")).filter(|p| p.is_file());
    let gt_path = match (&a.gt_terrain, folder_terrain) {
        (Some(p), _) => Some(p.clone()),
        (None, Some(p)) if a.poses == "groundtruth" => Some(p),
        (None, Some(p)) => {
            tracing::info!(
                "not scored against {}: it is in the ground truth's world, which --poses {} need not share (pass --gt-terrain to score)",
                p.display(),
                a.poses
            );
            None
        }
        (None, None) => None,
    };
    let gt = match &gt_path {
        Some(p) => Some(read_grid(p, None).context("reading the ground-truth terrain")?),
        None => None,
    };
    let mappers = make_mappers(a, &stack, gt.as_ref()).with_context(|| {
        format!(
            "--resolution {} and --size {} give no valid map",
            stack.resolution_m, stack.size_m
        )
    })?;
    let pb = crate::cli::progress_bar(
        a.max_frames.map_or(seq.len(), |m| m.min(seq.len())),
        "mapping",
        true,
    );
    let (runs, counts) = map_sequence(&seq, &poses, mappers, a.max_frames, gt.as_ref(), || {
        pb.inc(1)
    })?;
    pb.finish_and_clear();
    if counts.mapped == 0 {
        let span = |t: &[f64]| match (t.first(), t.last()) {
            (Some(a), Some(b)) => format!("{a:.3} to {b:.3} s"),
            _ => "empty".to_owned(),
        };
        let images: Vec<f64> = seq.depth_times_s();
        anyhow::bail!(
            "no frame could be mapped, nothing written: of {} frames, {} lie outside the poses' \
             time span and {} could not be read (poses {}: {}; depth images: {})",
            counts.frames,
            counts.no_pose,
            counts.unreadable,
            a.poses,
            span(poses.stamps_s()),
            span(&images)
        );
    }
    // Written into a staging folder published at the end: a killed run leaves the previous
    // output or the complete new one.
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let out = staged.path();
    let path = sensor_path(&poses, &seq.depth_times_s(), a.max_frames);
    let mut report = Map::new();
    let mut rep = Report::new("stride map: elevation map");
    rep.paragraph(format!("Dataset {}; poses {}{}; {} of {} frames mapped ({} outside the poses' time span, {} unreadable).", a.dataset.display(), a.poses, if a.drift > 0.0 { format!(" with {} % drift (seed {})", a.drift, a.seed) } else { String::new() }, counts.mapped, counts.frames, counts.no_pose, counts.unreadable));
    rep.paragraph(MAP_FRAME_NOTE);
    let mut rows = Vec::new();
    for r in &runs {
        let dir = if runs.len() > 1 {
            out.join(r.name)
        } else {
            out.to_path_buf()
        };
        write_layers(&dir, &r.layers)?;
        if r.archive_dropped_cells > 0 {
            tracing::warn!(
                "{}: {} mapped columns dropped from the archive at its cap (map.stack.archive_max_cells); the exported map lacks them",
                r.name,
                r.archive_dropped_cells
            );
        }
        let j = run_json(r, &counts);
        let f = |k: &str| {
            j.get(k)
                .and_then(Value::as_f64)
                .map_or("-".to_owned(), |v| format!("{v:.6}"))
        };
        rows.push(vec![
            r.name.to_owned(),
            f("mse"),
            f("rmse"),
            f("coverage"),
            j["cells_observed"].to_string(),
            format!(
                "{:.2}",
                j["update_ms"]["median"].as_f64().unwrap_or(f64::NAN)
            ),
            format!("{:.3e}", j["points_per_s"].as_f64().unwrap_or(f64::NAN)),
            r.seen.map_or("-".to_owned(), |s| {
                format!(
                    "{:.3} / {:.2} / {:.2} / {:.2}",
                    s.coverage,
                    s.rmse_m * 1e3,
                    s.rmse_near_steps_m * 1e3,
                    s.rmse_away_m * 1e3
                )
            }),
        ]);
        let mut charts = vec![elevation_chart(
            &format!("{}: elevation", r.name),
            &r.layers.elevation,
            &path,
        )?];
        if let Some(g) = &gt {
            charts.extend(error_chart(&r.layers.elevation, g, &path)?);
        }
        let mut caption = format!(
            "{}: the map as a colour relief (height on the colour bar) with the sensor's path{}. Grey: unknown.",
            r.name,
            if charts.len() > 1 {
                "; right: its error against the true terrain"
            } else {
                ""
            }
        );
        if let Some(f) = &r.floor {
            caption.push_str(&format!(
                " Floor: {} cells ({:.0} % of the map) fit a plane tilted {:.2} deg from the world x-y plane; heights about it: std {:.1} cm, 95 % within {:.1} cm.",
                f.cells,
                100.0 * f.fraction,
                f.tilt_deg,
                100.0 * f.residual_std_m,
                100.0 * f.residual_p95_m
            ));
        }
        if let Some(p) = &r.phantoms {
            caption.push_str(&format!(
                " Phantoms: {} of {} cells over flat ground truth stand more than {:.0} cm above it (highest {:.1} cm).",
                p.phantoms,
                p.flat_cells,
                100.0 * p.threshold_m,
                100.0 * p.max_excess_m
            ));
        }
        rep.figure(
            &format!("{}_map", r.name),
            render(&charts, 2, 540.0, 470.0),
            caption,
        );
        if runs.len() > 1 {
            report.insert(r.name.into(), j);
        } else {
            report = j.as_object().cloned().unwrap_or_default();
        }
    }
    if let (Some(g), [s, f]) = (&gt, runs.as_slice()) {
        if let Some(pi) = performance_index(&s.layers.elevation, &f.layers.elevation, g) {
            report.insert("performance_index_stack_vs_fankhauser".into(), json!(pi));
            rep.paragraph(format!("Performance index (paper 000, eq. 13) of the stack map against the Fankhauser map: {pi:.3} (below 1: the stack map's MSE is lower)."));
        }
    }
    rep.table(
        &[
            "mapper",
            "MSE (m²)",
            "RMSE (m)",
            "coverage",
            "cells",
            "update ms (median)",
            "points/s",
            "over the cells seen: coverage / RMSE / near steps / away (mm)",
        ],
        rows,
    );
    report.insert("map_frame".into(), json!(MAP_FRAME_NOTE));
    report.insert(
        "ground_truth".into(),
        json!(gt_path.as_ref().map(|p| p.display().to_string())),
    );
    report.insert("drift_percent".into(), json!(a.drift));
    if a.mapper != MapperArg::Fankhauser {
        // Every parameter, as a configuration file's [map.stack] holds them.
        report.insert(
            "stack_config".into(),
            serde_json::to_value(&stack).unwrap_or(Value::Null),
        );
    }
    write_atomic(
        &out.join("report.json"),
        serde_json::to_string_pretty(&Value::Object(report.clone()))?.as_bytes(),
    )?;
    rep.write(out)?;
    staged
        .publish()
        .with_context(|| format!("publishing {}", a.out.display()))?;
    Ok((Value::Object(report), runs, counts))
}
