//! The HTML report of `stride run`.

use super::map_figures;
use super::run::RunArgs;
use anyhow::{Context, Result};
use serde_json::Value;
use std::path::Path;
use stride::pipeline::{BackendSummary, FrameStatus, RunOutput};
use stride::MapOutput;
use stride_core::grid::Grid;
use stride_eval::plot::{render, Chart, Series, Style, PALETTE};
use stride_eval::report::Report;
use stride_eval::{AteResult, RpeResult};

fn backend_title(j: &Value) -> &'static str {
    match j["backend"].as_str() {
        Some("ba") => "SLAM with bundle adjustment",
        Some("pose-graph") => "SLAM with a pose graph",
        _ => "visual odometry",
    }
}

/// The map's points and the trajectory from above (world x and y).
fn map_chart(out: &RunOutput, b: &BackendSummary) -> Chart {
    Chart {
        title: "Map from above".into(),
        x_label: "x (m)".into(),
        y_label: "y (m)".into(),
        series: vec![
            Series::line(
                "map points",
                PALETTE[5],
                b.points_world.iter().map(|p| (p.x, p.y)).collect(),
            )
            .with_style(Style::Markers),
            Series::line(
                "trajectory",
                PALETTE[1],
                out.final_poses()
                    .iter()
                    .map(|p| (p.translation.x, p.translation.y))
                    .collect(),
            ),
        ],
        equal_aspect: true,
        ..Chart::default()
    }
}

/// What the run page shows.
pub struct RunPage<'a> {
    /// The command's arguments.
    pub args: &'a RunArgs,
    /// report.json's object.
    pub json: &'a Value,
    /// The SLAM's output.
    pub out: &'a RunOutput,
    /// The elevation map, when there is one.
    pub map: Option<&'a MapOutput>,
    /// The true terrain, when the folder has one.
    pub terrain: Option<&'a Grid<f32>>,
    /// ATE against ground truth.
    pub ate: Option<&'a AteResult>,
    /// RPE against ground truth.
    pub rpe: Option<&'a RpeResult>,
    /// The configuration used, as TOML.
    pub config_toml: &'a str,
}

/// Writes report.html (self-contained) and report.md into `dir`.
/// The elevation map: its figures and numbers.
fn map_section(
    rep: &mut Report,
    j: &Value,
    out: &RunOutput,
    m: &MapOutput,
    terrain: Option<&Grid<f32>>,
) -> Result<()> {
    let path: Vec<(f64, f64)> = out
        .final_poses()
        .iter()
        .map(|p| (p.translation.x, p.translation.y))
        .collect();
    let jm = &j["map"];
    rep.heading("Elevation map");
    rep.paragraph(format!(
        "Built inside the pipeline from {} views (a frame's depth every few frames and at keyframes, each tied to its keyframe) at their optimized poses ({} rebuilds when the back end moved keyframes; {} views settled), in the world frame (z up). {} cells known; floor: {}.",
        jm["views"],
        jm["rebuilds"],
        jm["views_settled"],
        jm["cells_observed"],
        match jm["floor"].as_object() {
            Some(f) => format!(
                "tilted {:.2} deg from the world's x-y plane, heights about it std {:.1} mm",
                f.get("tilt_deg").and_then(Value::as_f64).unwrap_or(f64::NAN),
                1e3 * f.get("residual_std_m").and_then(Value::as_f64).unwrap_or(f64::NAN)
            ),
            None => "none found".into(),
        }
    ));
    rep.paragraph(format!(
        "The map runs in its own thread: a view is mapped in {:.1} ms (median; {:.1} ms p95), a rebuild takes {} ms (median), and the caller's thread spent {:.2} s on the map in all (handing views over, the final rebuild).",
        jm["update_ms"]["median"].as_f64().unwrap_or(f64::NAN),
        jm["update_ms"]["p95"].as_f64().unwrap_or(f64::NAN),
        jm["rebuild_ms"]["median"]
            .as_f64()
            .map_or("-".to_owned(), |v| format!("{v:.0}")),
        jm["wall_s"].as_f64().unwrap_or(f64::NAN)
    ));
    let mut charts = vec![map_figures::elevation_chart(
        "Elevation map from above",
        &m.layers.elevation,
        &path,
    )?];
    if let Some(t) = terrain {
        charts.extend(map_figures::error_chart(&m.layers.elevation, t, &path)?);
        let sc = &jm["against_true_terrain"];
        rep.paragraph(format!(
            "Against the true terrain: RMSE {:.1} mm, mean {:.1} mm, 95th percentile {:.1} mm over {} cells; coverage {:.2}.",
            1e3 * sc["rmse"].as_f64().unwrap_or(f64::NAN),
            1e3 * sc["mean_abs"].as_f64().unwrap_or(f64::NAN),
            1e3 * sc["p95_abs"].as_f64().unwrap_or(f64::NAN),
            sc["cells_compared"],
            sc["coverage"].as_f64().unwrap_or(f64::NAN)
        ));
        let mm = |v: &Value, key: &str| 1e3 * v[key].as_f64().unwrap_or(f64::NAN);
        let by = &jm["against_true_terrain_near_and_away_from_steps"];
        if by.is_object() {
            rep.paragraph(format!(
                "Away from steps and obstacles' feet (true heights spanning more than 2 cm within 2 cm of a cell, or none there: a wall's or an object's footprint): RMSE {:.1} mm; near them, {} cells: {:.1} mm.",
                mm(by, "rmse_away_m"),
                by["cells_near_steps"],
                mm(by, "rmse_near_steps_m"),
            ));
        }
        let gt = &jm["same_views_groundtruth_poses"];
        if gt.is_object() {
            let (all, by) = (
                &gt["against_true_terrain"],
                &gt["against_true_terrain_near_and_away_from_steps"],
            );
            rep.paragraph(format!(
                "The same views at ground-truth poses (the mapper's own share of the error): RMSE {:.1} mm, away from steps and obstacles' feet {:.1} mm; coverage {:.2}.",
                mm(all, "rmse"),
                mm(by, "rmse_away_m"),
                all["coverage"].as_f64().unwrap_or(f64::NAN),
            ));
        }
    }
    let n = charts.len();
    rep.figure(
        "elevation",
        render(&charts, n, 540.0, 470.0),
        "The elevation map (colour relief, height in metres) with the camera's path; the error map, where the true terrain is known. Grey: unknown.",
    );
    Ok(())
}

pub fn write_html(dir: &Path, page: &RunPage<'_>) -> Result<()> {
    let (a, j, out, at, rp) = (page.args, page.json, page.out, page.ate, page.rpe);
    let mut rep = Report::new(format!("stride run: {}", backend_title(j)));
    rep.paragraph(format!(
        "Dataset {}; {} frames; seed {}. World frame: {}.",
        a.dataset.display(),
        out.frames.len(),
        j["seed"],
        out.world.describe()
    ));
    // A report value as text (strings without JSON's quotes).
    let g = |k: &str| match j.get(k) {
        Some(Value::String(s)) => s.clone(),
        Some(v) => v.to_string(),
        None => "null".into(),
    };
    rep.table(
        &["quantity", "value"],
        vec![
            vec!["frames".into(), g("frames")],
            vec!["tracked".into(), g("frames_tracked")],
            vec![
                "recovered (ORB matching against recent keyframes)".into(),
                g("frames_recovered"),
            ],
            vec![
                "recoveries refused: a step no camera makes".into(),
                j["recoveries_refused"].to_string(),
            ],
            vec![
                "relocalized (in the loaded map)".into(),
                g("frames_relocalized"),
            ],
            vec![
                "lost (constant-velocity prediction)".into(),
                g("frames_lost"),
            ],
            vec!["skipped (could not load)".into(), g("frames_skipped")],
            vec![
                "rolling shutter corrected with the gyroscope / not covered by it".into(),
                format!(
                    "{} / {}",
                    j["gyroscope_frames"]["used"], j["gyroscope_frames"]["not_covered"]
                ),
            ],
            vec![
                "rolling shutter's translation from the accelerometer / not covered by it".into(),
                format!(
                    "{} / {}",
                    j["accelerometer_frames"]["used"], j["accelerometer_frames"]["not_covered"]
                ),
            ],
            vec![
                "rotation predicted by the gyroscope / not covered by it".into(),
                format!(
                    "{} / {}",
                    j["gyroscope_frames"]["predicted"],
                    j["gyroscope_frames"]["prediction_not_covered"]
                ),
            ],
            vec![
                "keyframes that waited for a jolt to pass (gyroscope)".into(),
                j["gyroscope_frames"]["keyframes_deferred"].to_string(),
            ],
            vec![
                "motion estimates rejected: rotation off the gyroscope's".into(),
                j["gyroscope_frames"]["estimates_rejected"].to_string(),
            ],
            vec!["keyframes".into(), g("keyframes")],
            vec![
                "frames/s, whole SLAM (decoding excluded)".into(),
                format!("{:.1}", j["fps"].as_f64().unwrap_or(f64::NAN)),
            ],
            vec![
                "frames/s, odometry alone".into(),
                format!("{:.1}", j["odometry_fps"].as_f64().unwrap_or(f64::NAN)),
            ],
        ],
    );
    if let Some(b) = &out.backend {
        let ms = |k: &str| format!("{:.2}", j["ba_ms"][k].as_f64().unwrap_or(f64::NAN));
        rep.table(
            &["back end", "value"],
            vec![
                vec!["mode".into(), g("backend")],
                vec!["map points (final)".into(), g("map_points")],
                vec!["keyframes in the map (final)".into(), g("map_keyframes")],
                vec!["keyframes culled".into(), g("culled_keyframes")],
                vec!["loops closed".into(), g("loop_closures")],
                vec!["segments (pieces placed by a guess)".into(), g("segments")],
                vec!["keyframe step median (ms)".into(), ms("median")],
                vec!["keyframe step p95 (ms)".into(), ms("p95")],
                vec![
                    "of it local optimization, median / p95 (ms)".into(),
                    format!(
                        "{:.2} / {:.2}",
                        j["optimize_ms"]["median"].as_f64().unwrap_or(f64::NAN),
                        j["optimize_ms"]["p95"].as_f64().unwrap_or(f64::NAN)
                    ),
                ],
                vec!["final optimization (ms)".into(), ms("final")],
                vec![
                    "associations by track / by ORB / new points".into(),
                    format!(
                        "{} / {} / {}",
                        j["associations"]["by_track"],
                        j["associations"]["by_orb"],
                        j["associations"]["new_points"]
                    ),
                ],
                vec![
                    "frames the odometry waited for the back end".into(),
                    j["frontend_waits"]["frames"].to_string(),
                ],
            ],
        );
        rep.figure(
            "map",
            render(&[map_chart(out, b)], 1, 640.0, 480.0),
            "The final map's points and the trajectory, seen from above (the world's x-y plane, z up).",
        );
    }
    if let Some(m) = page.map {
        map_section(&mut rep, j, out, m, page.terrain)?;
    }
    let stages = [
        "decode", "detect", "track", "ransac", "refine", "recover", "total",
    ];
    rep.table(
        &["stage", "median (ms)", "p95 (ms)"],
        stages
            .iter()
            .map(|s| {
                let v = &j["timing_ms"][*s];
                vec![
                    (*s).to_owned(),
                    format!("{:.3}", v["median"].as_f64().unwrap_or(f64::NAN)),
                    format!("{:.3}", v["p95"].as_f64().unwrap_or(f64::NAN)),
                ]
            })
            .collect(),
    );
    if let Some(at) = at {
        at.add_to_report(&mut rep, "ate");
    }
    if let Some(rp) = rp {
        rp.add_to_report(&mut rep, "rpe");
    }
    let t0 = out.frames.first().map_or(0.0, |f| f.t_s);
    let per_frame = [
        Chart {
            title: "Tracking".into(),
            x_label: "time (s)".into(),
            y_label: "keypoints".into(),
            series: vec![
                Series::line(
                    "tracked",
                    PALETTE[0],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.tracked as f64))
                        .collect(),
                ),
                Series::line(
                    "inliers",
                    PALETTE[2],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.inliers as f64))
                        .collect(),
                ),
                Series::line(
                    "lost/skipped",
                    PALETTE[1],
                    out.frames
                        .iter()
                        .filter(|f| matches!(f.status, FrameStatus::Lost | FrameStatus::Skipped))
                        .map(|f| (f.t_s - t0, 0.0))
                        .collect(),
                )
                .with_style(Style::Markers),
                Series::line(
                    "recovered/relocalized/depth",
                    PALETTE[3],
                    out.frames
                        .iter()
                        .filter(|f| {
                            matches!(
                                f.status,
                                FrameStatus::Recovered
                                    | FrameStatus::Relocalized
                                    | FrameStatus::DepthAligned
                            )
                        })
                        .map(|f| (f.t_s - t0, f.inliers as f64))
                        .collect(),
                )
                .with_style(Style::Markers),
            ],
            y_from_zero: true,
            ..Chart::default()
        },
        Chart {
            title: "Time per frame".into(),
            x_label: "time (s)".into(),
            y_label: "ms".into(),
            series: vec![
                Series::line(
                    "total",
                    PALETTE[0],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.timing.total_s * 1e3))
                        .collect(),
                ),
                Series::line(
                    "track",
                    PALETTE[2],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.timing.track_s * 1e3))
                        .collect(),
                ),
                Series::line(
                    "decode (other thread)",
                    PALETTE[4],
                    out.frames
                        .iter()
                        .map(|f| (f.t_s - t0, f.decode_s * 1e3))
                        .collect(),
                )
                .with_style(Style::Dashed),
            ],
            y_from_zero: true,
            ..Chart::default()
        },
    ];
    rep.figure("tracking", render(&per_frame, 2, 560.0, 360.0), "Left: keypoints tracked and RANSAC inliers per frame, failures marked. Right: processing time per frame.");
    rep.heading("Configuration");
    rep.paragraph("Every stage's parameters (config.toml beside this report; `stride run --config config.toml` repeats the run).");
    rep.code(page.config_toml);
    rep.write(dir)
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    Ok(())
}
