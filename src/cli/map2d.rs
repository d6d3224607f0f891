//! `stride scans` (2-D range scans simulated in the synthetic world) and `stride map2d`
//! (paper 003's terrain map from a scan log).

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use serde_json::{json, Value};
use std::path::PathBuf;
use stride_core::grid::Grid;
use stride_core::scan::Scan;
use stride_datasets::grid_file::{read_grid, relief_png, write_header, write_layer};
use stride_datasets::mcap::laser::{read_laser_scans, write_laser_scans};
use stride_datasets::scan_log::{read_scan_log, write_scan_log};
use stride_datasets::synth::scanner::{walk_scans, RailRun, ScannerSim, MESSOR_TILT_RAD};
use stride_datasets::synth::stripe::StripeSim;
use stride_datasets::synth::{Synth, SynthConfig};
use stride_mapping::metrics::{compare, compare_over_seen, phantoms};
use stride_mapping::range2d::certainty::{CertaintyConfig, ElevationRule};
use stride_mapping::range2d::mapper::{
    calibrate_raw, covering_geometry, filter_scans, map_filtered, RangeError, ScanMapConfig,
};
use stride_mapping::range2d::mixed::MixedConfig;
use stride_mapping::range2d::yardstick::{
    measure_object, mixed_truth, naive_and_seen, swept, KnownObject,
};
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
    /// The sensor: `urg` (the URG-04LX, 0.26 m up, tilted 35 degrees, as on Messor) or
    /// `stripe` (the laser-stripe camera, 0.174 m up, tilted 10 degrees, as on Ragno).
    #[arg(long, value_enum, default_value = "urg")]
    pub sensor: SensorArg,
    /// Write raw URG readings (with the systematic error eq. 4 corrects).
    #[arg(long)]
    pub raw: bool,
    /// Probability that a beam straddling a depth edge returns a mixed range.
    #[arg(long, default_value_t = 0.5)]
    pub mixed_probability: f64,
    /// Half-angle of a beam's footprint (mrad): wider footprints straddle more edges.
    #[arg(long, default_value_t = 3.0)]
    pub footprint_mrad: f64,
    /// Also write the scans as an MCAP log (scans.mcap: sensor_msgs/LaserScan on /scan in
    /// frame `laser`, its pose as a transform world -> laser on /tf).
    #[arg(long)]
    pub mcap: bool,
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
            let scans = match a.sensor {
                SensorArg::Urg => run.scans(&sim),
                SensorArg::Stripe => {
                    let stripe = StripeSim {
                        seed: a.seed,
                        ..StripeSim::default()
                    };
                    // The stripe sensor has no mixed returns to mark.
                    run.stripe_scans(&stripe)
                        .into_iter()
                        .map(|s| (s, Vec::new()))
                        .collect()
                }
            };
            (scans, run.truth(), json!(run.objects))
        }
        SceneArg::Walk if a.sensor == SensorArg::Stripe => {
            anyhow::bail!("the stripe sensor is simulated on the rail run only (--scene rail)")
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
    if a.mcap {
        write_laser_scans(&dir.join("scans.mcap"), &scans, "/scan", "world", "laser")?;
    }
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
    /// The laser-stripe camera of paper 003's Ragno (b = 0.12 m, beta = 45 degrees), its
    /// returns expressed as beams in the light plane; eq. 8's errors: the stripe row 1 px,
    /// b 1 mm, beta 0.2 degrees, tau_c 0.1 degrees.
    Stripe,
}

#[derive(Debug, Args)]
pub struct Map2dArgs {
    /// The scan log (`t tx ty tz qx qy qz qw angle_min angle_increment n r_0 ...`), or an
    /// MCAP log (a file ending in .mcap) of sensor_msgs/LaserScan with their poses as
    /// transforms.
    #[arg(long)]
    pub scans: PathBuf,
    /// The LaserScan topic of an MCAP --scans.
    #[arg(long, default_value = "/scan")]
    pub scan_topic: String,
    /// The fixed frame of an MCAP --scans: each scan is placed by the transform from it to
    /// the scan's frame (world z up).
    #[arg(long, default_value = "world")]
    pub tf_frame: String,
    /// Output folder: elevation.npy, certainty.npy, grid.json, elevation.png, report.json,
    /// report.html (and the yardsticks: naive_median.npy, seen.npy, swept.npy).
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
                SensorArg::Stripe => RangeError::ragno_stripe(),
            },
            mixed: (!self.no_mixed_pixel_filter).then(MixedConfig::default),
            max_range_m: self.max_range,
            ..ScanMapConfig::default()
        })
    }
}

pub fn map2d(a: Map2dArgs) -> Result<()> {
    crate::cli::check_out_dir("--out", &a.out, a.overwrite)?;
    let mut config = a.config()?;
    let (mut scans, unplaced) = if stride_datasets::sequence::is_mcap(&a.scans) {
        read_laser_scans(&a.scans, &a.scan_topic, &a.tf_frame)?
    } else {
        (read_scan_log(&a.scans)?, 0)
    };
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
    let g = covering_geometry(&scans, a.resolution, 0.02, a.max_range)
        .with_context(|| format!("{}: no scan has a return", a.scans.display()))?;
    let (naive, seen) = naive_and_seen(&scans, g, truth.as_ref(), a.max_range);
    // The map gets the filtered scans; the yardsticks keep every return.
    let mut filtered = scans.clone();
    let filter_stats = filter_scans(&mut filtered, &config);
    let (elevation, certainty, mut stats) = map_filtered(&filtered, g, &config, filter_stats)?;
    stats.uncalibrated = uncalibrated;
    let swept = swept(&scans, g, a.max_range);
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
            if marks.len() != scans.len() {
                anyhow::bail!(
                    "{}: {} scans marked, the log has {}",
                    p.display(),
                    marks.len(),
                    scans.len()
                );
            }
            Some(mixed_truth(&scans, &filtered, &marks, g, a.max_range))
        }
        None => None,
    };
    let objects: Vec<(String, KnownObject)> = match a.scans.parent().map(|d| d.join("objects.json"))
    {
        Some(p) if p.is_file() => {
            let text =
                std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
            let list: Vec<Value> = serde_json::from_str(&text)
                .with_context(|| format!("{}: not a list of objects", p.display()))?;
            list.into_iter()
                .map(|v| {
                    let name = v
                        .get("name")
                        .and_then(Value::as_str)
                        .unwrap_or("?")
                        .to_owned();
                    serde_json::from_value::<KnownObject>(v)
                        .map(|o| (name, o))
                        .with_context(|| {
                            format!(
                                "{}: an object without x, y, length_m, width_m, height_m",
                                p.display()
                            )
                        })
                })
                .collect::<Result<_>>()?
        }
        _ => Vec::new(),
    };
    let score = |m: &Grid<f32>| -> Value {
        let Some(t) = &truth else { return Value::Null };
        json!({
            "all_cells": compare(m, t),
            "over_seen": compare_over_seen(m, &seen, t, 0.02, 0.02),
            "over_swept": compare_over_seen(m, &swept, t, 0.02, 0.02),
            // Artifacts: false peaks and pits of more than 2 cm over ground that is flat
            // (within 2 cm) for 2 cm around, where a cell cannot honestly hold two heights.
            "artifacts": phantoms(m, t, 0.02, 0.02, 0.02),
            "objects": objects.iter().map(|(name, o)| {
                let size = measure_object(m, o);
                let err = |m: Option<f64>, t: f64| m.map(|m| 100.0 * (m - t) / t);
                json!({
                    "name": name,
                    "true_m": {"length": o.length_m, "width": o.width_m, "height": o.height_m},
                    "map_m": {"length": size.length_m, "width": size.width_m, "height": size.height_m},
                    "error_percent": {
                        "length": err(size.length_m, o.length_m),
                        "width": err(size.width_m, o.width_m),
                        "height": err(size.height_m, o.height_m),
                    },
                })
            }).collect::<Vec<_>>(),
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
        "scans_without_pose": unplaced,
        "mixed_returns": mixed_report,
        "scans": scans.len(),
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
    write_layer(&dir.join("seen.npy"), &seen)?;
    write_layer(&dir.join("swept.npy"), &swept)?;
    write_header(&dir.join("grid.json"), &g)?;
    let png = relief_png(&elevation, 1200).map_err(anyhow::Error::msg)?;
    write_atomic(&dir.join("elevation.png"), &png)?;
    write_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    let path: Vec<(f64, f64)> = scans
        .iter()
        .map(|s| {
            let t = s.world_from_sensor.translation.vector;
            (t.x, t.y)
        })
        .collect();
    super::map2d_report::html_report(
        dir,
        &a,
        &report,
        &elevation,
        &certainty,
        &naive,
        truth.as_ref(),
        &path,
    )?;
    staged.publish()?;
    super::map2d_report::print_summary(&report, &stats, &a.out)
}
