//! `stride scans` (2-D range scans simulated in the synthetic world) and `stride map2d`
//! (paper 003's terrain map from a scan log).

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use stride_core::grid::Grid;
use stride_core::scan::Scan;
use stride_datasets::grid_file::{read_grid, relief_png, write_header, write_layer};
use stride_datasets::scan_log::{read_scan_log, write_scan_log};
use stride_datasets::synth::scanner::{walk_scans, RailRun, ScannerSim, MESSOR_TILT_RAD};
use stride_datasets::synth::{Synth, SynthConfig};
use stride_mapping::metrics::{compare, compare_over_seen};
use stride_mapping::range2d::certainty::{weighted_median, CertaintyConfig, ElevationRule};
use stride_mapping::range2d::mapper::{
    calibrate_raw, covering_geometry, filter_scans, map_scans, RangeError, ScanMapConfig,
    ScanMapStats,
};
use stride_mapping::range2d::mixed::MixedConfig;
use stride_output::fs::{write_atomic, StagedDir};

/// The simulated scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SceneArg {
    /// Paper 003's rail run: a cart moving in 10 mm steps past two boxes and a cylinder.
    Rail,
    /// The synthetic robot walking the lab's rough terrain with the scanner on its trunk.
    Walk,
}

#[derive(Debug, Args)]
pub struct ScansArgs {
    /// Output folder: scans.txt (the scan log), terrain.npy + terrain.json (the true
    /// elevation), objects.json (the rail run's objects), mixed.json (per scan, the beams
    /// whose return is mixed: the truth the filters are scored against).
    #[arg(long)]
    pub out: PathBuf,
    /// The scene.
    #[arg(long, value_enum, default_value = "rail")]
    pub scene: SceneArg,
    /// Write raw URG readings (with the systematic error eq. 4 corrects).
    #[arg(long)]
    pub raw: bool,
    /// Probability that a beam straddling a depth edge returns a mixed range.
    #[arg(long, default_value_t = 0.5)]
    pub mixed_probability: f64,
    /// Half-angle of a beam's footprint (mrad): wider footprints straddle more edges.
    #[arg(long, default_value_t = 3.0)]
    pub footprint_mrad: f64,
    /// Seconds of walking (scene walk; 10 scans a second).
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Seed of the noise (and of the walk's terrain).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Replace an existing output folder.
    #[arg(long)]
    pub overwrite: bool,
}

pub fn scans(a: ScansArgs) -> Result<()> {
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    if !(a.footprint_mrad.is_finite() && (0.0..=100.0).contains(&a.footprint_mrad)) {
        anyhow::bail!(
            "--footprint-mrad {} must be within [0, 100]",
            a.footprint_mrad
        );
    }
    if !(0.0..=1.0).contains(&a.mixed_probability) {
        anyhow::bail!(
            "--mixed-probability {} must be within [0, 1]",
            a.mixed_probability
        );
    }
    let sim = ScannerSim {
        raw: a.raw,
        mixed_probability: a.mixed_probability,
        footprint_rad: a.footprint_mrad * 1e-3,
        seed: a.seed,
        ..ScannerSim::default()
    };
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let dir = staged.path();
    let (marked, truth, objects) = match a.scene {
        SceneArg::Rail => {
            let run = RailRun::new();
            (run.scans(&sim), run.truth(), json!(run.objects))
        }
        SceneArg::Walk => {
            let fps = 30.0;
            let config = SynthConfig {
                seed: a.seed,
                frames: (a.seconds * fps).ceil() as usize + 1,
                fps,
                ..SynthConfig::default()
            };
            let synth = Synth::new(config).context("building the synthetic world")?;
            let scans = walk_scans(&synth, &sim, MESSOR_TILT_RAD, 10.0, a.seconds);
            (scans, synth.ground_truth_elevation(), json!([]))
        }
    };
    let mixed: Vec<Vec<usize>> = marked.iter().map(|(_, m)| m.clone()).collect();
    let scans: Vec<Scan> = marked.into_iter().map(|(s, _)| s).collect();
    write_scan_log(&dir.join("scans.txt"), &scans)?;
    write_atomic(
        &dir.join("mixed.json"),
        serde_json::to_string(&mixed)?.as_bytes(),
    )?;
    write_layer(&dir.join("terrain.npy"), &truth)?;
    write_header(&dir.join("terrain.json"), &truth.geometry)?;
    write_atomic(
        &dir.join("objects.json"),
        serde_json::to_string_pretty(&objects)?.as_bytes(),
    )?;
    staged.publish()?;
    let returns: usize = scans
        .iter()
        .map(|s| (0..s.ranges.len()).filter(|&i| s.valid(i)).count())
        .sum();
    crate::outln!(
        "{} scans ({returns} returns) written to {}",
        scans.len(),
        a.out.display()
    )?;
    Ok(())
}

/// How a cell takes a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum RuleArg {
    /// Consistent measurements averaged by certainty; a higher inconsistent one taken.
    Mean,
    /// Eq. 10: the highest measurement.
    Highest,
}

/// The sensor model of a log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SensorArg {
    /// Hokuyo URG-04LX (range error 2 sigma of 10 mm up to 1 m, 1 % beyond).
    Urg,
    /// A laser-stripe camera (b = 0.12 m, f = 600 px, stripe row error 0.5 px), its
    /// returns expressed as beams in the light plane.
    Stripe,
}

#[derive(Debug, Args)]
pub struct Map2dArgs {
    /// The scan log (`t tx ty tz qx qy qz qw angle_min angle_increment n r_0 ...`).
    #[arg(long)]
    pub scans: PathBuf,
    /// Output folder: elevation.npy, certainty.npy, grid.json, elevation.png, report.json.
    #[arg(long)]
    pub out: PathBuf,
    /// The sensor.
    #[arg(long, value_enum, default_value = "urg")]
    pub sensor: SensorArg,
    /// The log holds raw URG readings: correct them by eq. 4 (50 to 1000 mm raw; others are
    /// dropped and counted).
    #[arg(long)]
    pub raw_urg: bool,
    /// Map every return (no range clustering, no three-scan analysis).
    #[arg(long)]
    pub no_mixed_pixel_filter: bool,
    /// How a cell takes a measurement: `mean` (consistent measurements averaged, a higher
    /// inconsistent one taken) or `highest` (paper 003's eq. 10).
    #[arg(long, value_enum, default_value = "mean")]
    pub elevation_rule: RuleArg,
    /// Run the CAS filter before the fill.
    #[arg(long)]
    pub cas: bool,
    /// Cell size (m).
    #[arg(long, default_value_t = 0.01)]
    pub resolution: f64,
    /// Returns farther than this are not mapped (m), by either map.
    #[arg(long, default_value_t = 1.5)]
    pub max_range: f64,
    /// The true elevation, to score the map (and the naive median of the same returns).
    #[arg(long, value_name = "FILE.npy")]
    pub gt_terrain: Option<PathBuf>,
    /// Replace an existing output folder.
    #[arg(long)]
    pub overwrite: bool,
}

impl Map2dArgs {
    fn config(&self) -> Result<ScanMapConfig> {
        if !(self.max_range.is_finite() && self.max_range > 0.0) {
            anyhow::bail!("--max-range {} must be positive (m)", self.max_range);
        }
        if !(self.resolution.is_finite() && self.resolution >= 0.001 && self.resolution <= 1.0) {
            anyhow::bail!(
                "--resolution {} must be within [0.001, 1] m",
                self.resolution
            );
        }
        if self.raw_urg && self.sensor != SensorArg::Urg {
            anyhow::bail!("--raw-urg applies to --sensor urg only");
        }
        Ok(ScanMapConfig {
            certainty: CertaintyConfig {
                rule: match self.elevation_rule {
                    RuleArg::Mean => ElevationRule::ConsistentMean,
                    RuleArg::Highest => ElevationRule::Highest,
                },
                cas_fraction: self.cas.then_some(0.5),
                ..CertaintyConfig::default()
            },
            range_error: match self.sensor {
                SensorArg::Urg => RangeError::Urg {
                    sigmas: 2.0,
                    raw: self.raw_urg,
                },
                SensorArg::Stripe => RangeError::Stripe {
                    baseline_m: 0.12,
                    focal_px: 600.0,
                    row_px: 0.5,
                },
            },
            mixed: (!self.no_mixed_pixel_filter).then(MixedConfig::default),
            max_range_m: self.max_range,
            ..ScanMapConfig::default()
        })
    }
}

/// The cells the sensor swept: cells inside the quadrilaterals of returns of neighbouring
/// beams in consecutive scans (all four returns present and within 5 cm of each other, so
/// no depth edge is bridged). A map that fills the gaps between scan lines covers them; the
/// returns alone do not.
fn swept(scans: &[Scan], g: stride_core::grid::GridGeometry, max_range_m: f64) -> Grid<f32> {
    let mut out = Grid::filled(g, f32::NAN);
    let point = |s: &Scan, i: usize| {
        s.ranges
            .get(i)
            .filter(|&&r| r <= max_range_m)
            .and_then(|_| s.p_world(i))
    };
    for pair in scans.windows(2) {
        let [a, b] = pair else { continue };
        for i in 0..a.ranges.len().min(b.ranges.len()).saturating_sub(1) {
            let (Some(p0), Some(p1), Some(q0), Some(q1)) =
                (point(a, i), point(a, i + 1), point(b, i), point(b, i + 1))
            else {
                continue;
            };
            let quad = [p0, p1, q1, q0];
            let close = quad
                .iter()
                .all(|p| quad.iter().all(|q| (p - q).norm() <= 0.05));
            if !close {
                continue;
            }
            let (x0, x1) = quad
                .iter()
                .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p.x), h.max(p.x)));
            let (y0, y1) = quad
                .iter()
                .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p.y), h.max(p.y)));
            let (Some((r0, c0)), Some((r1, c1))) = (g.cell_of(x0, y0), g.cell_of(x1, y1)) else {
                continue;
            };
            for r in r0..=r1 {
                for c in c0..=c1 {
                    let (x, y) = g.center(r, c);
                    if inside_quad(&quad, x, y) {
                        if let Some(v) = out.get_mut(r, c) {
                            *v = 1.0;
                        }
                    }
                }
            }
        }
    }
    out
}

/// Whether `(x, y)` lies in the convex quadrilateral `q` (its x-y projection, either
/// winding).
fn inside_quad(q: &[nalgebra::Point3<f64>; 4], x: f64, y: f64) -> bool {
    let mut sign = 0.0f64;
    for k in 0..4 {
        let (a, b) = (q[k], q[(k + 1) % 4]);
        let cross = (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x);
        if cross.abs() < 1e-15 {
            continue;
        }
        if sign == 0.0 {
            sign = cross.signum();
        } else if cross.signum() != sign {
            return false;
        }
    }
    true
}

/// The objects' sizes read from a map: height the median of the cells inside the true
/// footprint; length and width the extent, along x and y through the object's centre, of
/// the cells above half its true height.
fn object_table(map: &Grid<f32>, objects: &[Value]) -> Vec<Value> {
    let g = map.geometry;
    objects
        .iter()
        .filter_map(|o| {
            let f = |k: &str| o.get(k).and_then(Value::as_f64);
            let (x, y, l, w, h) = (f("x")?, f("y")?, f("length_m")?, f("width_m")?, f("height_m")?);
            let mut inside: Vec<(f32, f32)> = Vec::new();
            for r in 0..g.rows {
                for c in 0..g.cols {
                    let (cx, cy) = g.center(r, c);
                    if (cx - x).abs() <= l / 2.0 && (cy - y).abs() <= w / 2.0 {
                        if let Some(v) = map.get(r, c).filter(|v| !v.is_nan()) {
                            inside.push((v, 1.0));
                        }
                    }
                }
            }
            let height = (!inside.is_empty()).then(|| f64::from(weighted_median(&mut inside)));
            let above = |px: f64, py: f64| map.at(px, py).is_some_and(|v| f64::from(v) > h / 2.0);
            let extent = |dx: f64, dy: f64| {
                let step = g.resolution;
                let (mut lo, mut hi) = (0.0, 0.0);
                while above(x - (lo + step) * dx, y - (lo + step) * dy) && lo < 1.0 {
                    lo += step;
                }
                while above(x + (hi + step) * dx, y + (hi + step) * dy) && hi < 1.0 {
                    hi += step;
                }
                above(x, y).then_some(lo + hi + step)
            };
            let err = |m: Option<f64>, t: f64| m.map(|m| 100.0 * (m - t) / t);
            let (ml, mw) = (extent(1.0, 0.0), extent(0.0, 1.0));
            Some(json!({
                "name": o.get("name"),
                "true_m": {"length": l, "width": w, "height": h},
                "map_m": {"length": ml, "width": mw, "height": height},
                "error_percent": {"length": err(ml, l), "width": err(mw, w), "height": err(height, h)},
            }))
        })
        .collect()
}

/// The simulator's mixed returns (`mixed.json` beside the log: per scan, the beams whose
/// return is mixed) against what the filters removed: how many there were, how many the
/// filters removed, how many good returns they removed with them, and the cells the mixed
/// returns landed in.
fn mixed_truth(
    scans: &[Scan],
    filtered: &[Scan],
    mixed: &[Vec<usize>],
    g: stride_core::grid::GridGeometry,
    max_range_m: f64,
) -> (usize, usize, usize, Vec<(usize, usize)>) {
    let (mut n, mut caught, mut good_removed, mut cells) = (0, 0, 0, Vec::new());
    for ((s, f), m) in scans.iter().zip(filtered).zip(mixed) {
        for i in 0..s.ranges.len() {
            if !s.valid(i) || s.ranges.get(i).is_some_and(|&r| r > max_range_m) {
                continue;
            }
            let is_mixed = m.contains(&i);
            let removed = !f.valid(i);
            if is_mixed {
                n += 1;
                caught += usize::from(removed);
                if let Some(p) = s.p_world(i) {
                    cells.extend(g.cell_of(p.x, p.y));
                }
            } else {
                good_removed += usize::from(removed);
            }
        }
    }
    (n, caught, good_removed, cells)
}

/// The per-cell median of every return (the naive reference), and the cells seen: cells
/// with a return within 3 cm of the true surface.
fn naive_and_seen(
    scans: &[Scan],
    g: stride_core::grid::GridGeometry,
    truth: Option<&Grid<f32>>,
    max_range_m: f64,
) -> (Grid<f32>, Grid<f32>) {
    let mut cells: Vec<Vec<(f32, f32)>> = vec![Vec::new(); g.len()];
    let mut seen = Grid::filled(g, f32::NAN);
    for s in scans {
        for i in 0..s.ranges.len() {
            let Some(p) = s.p_world(i) else { continue };
            if s.ranges.get(i).is_none_or(|&r| r > max_range_m) {
                continue;
            }
            let Some((r, c)) = g.cell_of(p.x, p.y) else {
                continue;
            };
            let Some(k) = g.index(r, c) else { continue };
            if let Some(v) = cells.get_mut(k) {
                v.push((p.z as f32, 1.0));
            }
            let on_surface = truth
                .and_then(|t| t.sample_bilinear(p.x, p.y))
                .is_some_and(|t| (f64::from(t) - p.z).abs() <= 0.03);
            if on_surface {
                if let Some(v) = seen.get_mut(r, c) {
                    *v = 1.0;
                }
            }
        }
    }
    let naive = cells
        .iter_mut()
        .map(|v| {
            if v.is_empty() {
                f32::NAN
            } else {
                weighted_median(v)
            }
        })
        .collect();
    (
        Grid::from_vec(g, naive).unwrap_or_else(|| Grid::filled(g, f32::NAN)),
        seen,
    )
}

pub fn map2d(a: Map2dArgs) -> Result<()> {
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    let mut config = a.config()?;
    let mut scans = read_scan_log(&a.scans)?;
    // Raw readings are corrected first, so that every map and yardstick below sees ranges.
    let uncalibrated = if a.raw_urg {
        calibrate_raw(&mut scans)
    } else {
        0
    };
    config.range_error = match config.range_error {
        RangeError::Urg { sigmas, .. } => RangeError::Urg { sigmas, raw: false },
        other => other,
    };
    let truth = match &a.gt_terrain {
        Some(p) => Some(read_grid(p, None).context("reading the true terrain")?),
        None => None,
    };
    let g = covering_geometry(&scans, a.resolution, 0.02)
        .with_context(|| format!("{}: no scan has a return", a.scans.display()))?;
    let (naive, seen) = naive_and_seen(&scans, g, truth.as_ref(), a.max_range);
    let scans_for_swept = scans.clone();
    let n_scans = scans.len();
    let (elevation, certainty, mut stats) = map_scans(scans, g, &config)?;
    stats.uncalibrated = uncalibrated;
    let swept = swept(&scans_for_swept, g, a.max_range);
    let mixed_file = a
        .scans
        .parent()
        .map(|d| d.join("mixed.json"))
        .filter(|p| p.is_file());
    let mixed_json = match mixed_file {
        Some(p) => {
            let text =
                std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
            let marks: Vec<Vec<usize>> = serde_json::from_str(&text)
                .with_context(|| format!("{}: not a list of beam lists", p.display()))?;
            if marks.len() != scans_for_swept.len() {
                anyhow::bail!(
                    "{}: {} scans marked, the log has {}",
                    p.display(),
                    marks.len(),
                    scans_for_swept.len()
                );
            }
            let mut filtered = scans_for_swept.clone();
            filter_scans(&mut filtered, &config);
            Some(mixed_truth(
                &scans_for_swept,
                &filtered,
                &marks,
                g,
                a.max_range,
            ))
        }
        None => None,
    };
    let objects: Vec<Value> = match a.scans.parent().map(|d| d.join("objects.json")) {
        Some(p) if p.is_file() => {
            let text =
                std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
            serde_json::from_str(&text)
                .with_context(|| format!("{}: not a list of objects", p.display()))?
        }
        _ => Vec::new(),
    };
    let score = |m: &Grid<f32>| -> Value {
        let Some(t) = &truth else { return Value::Null };
        json!({
            "all_cells": compare(m, t),
            "over_seen": compare_over_seen(m, &seen, t, 0.02, 0.02),
            "over_swept": compare_over_seen(m, &swept, t, 0.02, 0.02),
            "objects": object_table(m, &objects),
        })
    };
    let mean_certainty = |cells: &[(usize, usize)]| {
        let v: Vec<f64> = cells
            .iter()
            .filter_map(|&(r, c)| certainty.get(r, c))
            .map(f64::from)
            .collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    let known: Vec<(usize, usize)> = (0..g.rows)
        .flat_map(|r| (0..g.cols).map(move |c| (r, c)))
        .filter(|&(r, c)| certainty.get(r, c).is_some_and(|w| w > 0.0))
        .collect();
    let mixed_report = mixed_json.as_ref().map(|(n, caught, good, cells)| {
        json!({
            "mixed_returns": n,
            "removed_by_the_filters": caught,
            "good_returns_removed": good,
            "mean_certainty_where_they_landed": mean_certainty(cells),
            "mean_certainty_of_known_cells": mean_certainty(&known),
        })
    });
    let report = json!({
        "mixed_returns": mixed_report,
        "scans": n_scans,
        "grid": {"rows": g.rows, "cols": g.cols, "resolution_m": g.resolution},
        "sensor": format!("{:?}", a.sensor).to_lowercase(),
        "mixed_pixel_filter": !a.no_mixed_pixel_filter,
        "cas": a.cas,
        "stats": stats,
        "scan_update_ms_median": stats.scan_median_s * 1e3,
        "map": score(&elevation),
        "naive_median": score(&naive),
    });
    let staged = StagedDir::new(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let dir = staged.path();
    write_layer(&dir.join("elevation.npy"), &elevation)?;
    write_layer(&dir.join("certainty.npy"), &certainty)?;
    write_layer(&dir.join("naive_median.npy"), &naive)?;
    write_header(&dir.join("grid.json"), &g)?;
    let png = relief_png(&elevation, 1200).map_err(anyhow::Error::msg)?;
    write_atomic(&dir.join("elevation.png"), &png)?;
    write_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    staged.publish()?;
    print_summary(&report, &stats, &a.out)
}

fn print_summary(report: &Value, stats: &ScanMapStats, out: &Path) -> Result<()> {
    crate::outln!(
        "{} scans, {} returns: {} dropped as isolated clusters, {} by the three-scan analysis, {} uncalibrated; {} filled; {:.3} ms per scan (median)",
        stats.scans,
        stats.returns,
        stats.dropped_clusters,
        stats.dropped_three_scan,
        stats.uncalibrated,
        stats.finish.filled,
        stats.scan_median_s * 1e3
    )?;
    let o = &report["mixed_returns"];
    if !o.is_null() {
        crate::outln!(
            "mixed returns (the simulator's): {}, {} removed by the filters (with {} good ones); mean certainty where they landed {:.2} (known cells: {:.2})",
            o["mixed_returns"],
            o["removed_by_the_filters"],
            o["good_returns_removed"],
            o["mean_certainty_where_they_landed"].as_f64().unwrap_or(f64::NAN),
            o["mean_certainty_of_known_cells"].as_f64().unwrap_or(f64::NAN),
        )?;
    }
    for key in ["map", "naive_median"] {
        for (over, what) in [("over_seen", "seen"), ("over_swept", "swept")] {
            let s = &report[key][over];
            if !s.is_null() {
                crate::outln!(
                    "{key:<13} over the cells {what:<5}: coverage {:.3}, RMSE {:.1} mm ({:.1} near steps, {:.1} away)",
                    s["coverage"].as_f64().unwrap_or(f64::NAN),
                    s["rmse_m"].as_f64().unwrap_or(f64::NAN) * 1e3,
                    s["rmse_near_steps_m"].as_f64().unwrap_or(f64::NAN) * 1e3,
                    s["rmse_away_m"].as_f64().unwrap_or(f64::NAN) * 1e3,
                )?;
            }
        }
        for o in report[key]["objects"].as_array().into_iter().flatten() {
            let mm = |k: &str, v: &str| {
                o[k][v]
                    .as_f64()
                    .map_or("-".into(), |x| format!("{:.0}", x * 1e3))
            };
            crate::outln!(
                "  {:<9} length {} / {} mm, width {} / {} mm, height {} / {} mm (map / true)",
                o["name"].as_str().unwrap_or("?"),
                mm("map_m", "length"),
                mm("true_m", "length"),
                mm("map_m", "width"),
                mm("true_m", "width"),
                mm("map_m", "height"),
                mm("true_m", "height"),
            )?;
        }
    }
    crate::outln!("written to {}", out.display())?;
    Ok(())
}
