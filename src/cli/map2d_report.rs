//! What `stride map2d` shows: the summary on stdout and report.html.

use super::map2d::Map2dArgs;
use anyhow::{Context, Result};
use serde_json::Value;
use std::path::Path;
use stride_core::grid::Grid;
use stride_mapping::range2d::mapper::ScanMapStats;

/// report.html: the map, its certainty, its error and the naive median as figures, the
/// scores and the objects as tables.
#[allow(clippy::too_many_arguments)]
pub fn html_report(
    dir: &Path,
    a: &Map2dArgs,
    report: &Value,
    elevation: &Grid<f32>,
    certainty: &Grid<f32>,
    naive: &Grid<f32>,
    truth: Option<&Grid<f32>>,
    path: &[(f64, f64)],
) -> Result<()> {
    use crate::cli::map_figures::{elevation_chart, error_chart, layer_chart};
    use stride_eval::plot::render;
    let mut rep = stride_eval::report::Report::new("stride map2d: terrain map from 2-D scans");
    let st = &report["stats"];
    rep.paragraph(format!(
        "Scans {} ({}), sensor {}; {} returns, {} dropped as isolated clusters, {} by the three-scan analysis (eq. 12), {} raw readings outside eq. 4's interval; {} cells filled by eq. 11; {:.3} ms per scan (median). World frame, z up; cells of {} m.",
        a.scans.display(),
        report["scans"],
        report["sensor"].as_str().unwrap_or("?"),
        st["returns"],
        st["dropped_clusters"],
        st["dropped_three_scan"],
        st["uncalibrated"],
        st["finish"]["filled"],
        report["scan_update_ms_median"].as_f64().unwrap_or(f64::NAN),
        a.resolution
    ));
    // Cells never measured show grey (unknown), not as certainty 0.
    let mut measured = certainty.clone();
    for w in measured.as_mut_slice() {
        if *w <= 0.0 {
            *w = f32::NAN;
        }
    }
    let mut charts = vec![
        elevation_chart("Elevation (paper 003's map)", elevation, path)?,
        layer_chart("Certainty (eq. 9)", &measured, "certainty", path)?,
        elevation_chart("Naive per-cell median of the same returns", naive, path)?,
    ];
    if let Some(t) = truth {
        charts.extend(error_chart(elevation, t, path)?);
    }
    rep.figure(
        "maps",
        render(&charts, 2, 540.0, 470.0),
        "The map, its certainty grid, the naive median of the same returns, and the map's error against the true terrain; the line is the sensor's path. Grey: unknown.",
    );
    let mut rows = Vec::new();
    for key in ["map", "naive_median"] {
        for over in ["over_seen", "over_swept"] {
            let s = &report[key][over];
            if s.is_null() {
                continue;
            }
            let mm = |k: &str| {
                s[k].as_f64()
                    .map_or("-".into(), |v| format!("{:.1}", v * 1e3))
            };
            rows.push(vec![
                key.replace('_', " "),
                over.replace("over_", "cells "),
                s["coverage"]
                    .as_f64()
                    .map_or("-".into(), |v| format!("{v:.3}")),
                mm("rmse_m"),
                mm("rmse_near_steps_m"),
                mm("rmse_away_m"),
            ]);
        }
    }
    if !rows.is_empty() {
        rep.table(
            &[
                "map",
                "scored over",
                "coverage",
                "RMSE (mm)",
                "near steps",
                "away",
            ],
            rows,
        );
    }
    let artifacts: Vec<Vec<String>> = ["map", "naive_median"]
        .iter()
        .filter(|k| !report[**k]["artifacts"].is_null())
        .map(|k| {
            let a = &report[*k]["artifacts"];
            vec![
                k.replace('_', " "),
                a["flat_cells"].to_string(),
                a["phantoms"].to_string(),
                a["pits"].to_string(),
            ]
        })
        .collect();
    if !artifacts.is_empty() {
        rep.table(
            &[
                "map",
                "cells over flat ground",
                "false peaks > 2 cm",
                "false pits > 2 cm",
            ],
            artifacts,
        );
    }
    let objects: Vec<Vec<String>> = report["map"]["objects"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|o| {
            let mm = |k: &str, v: &str| {
                o[k][v]
                    .as_f64()
                    .map_or("not seen".into(), |x| format!("{:.0}", x * 1e3))
            };
            vec![
                o["name"].as_str().unwrap_or("?").to_owned(),
                format!("{} / {}", mm("map_m", "length"), mm("true_m", "length")),
                format!("{} / {}", mm("map_m", "width"), mm("true_m", "width")),
                format!("{} / {}", mm("map_m", "height"), mm("true_m", "height")),
            ]
        })
        .collect();
    if !objects.is_empty() {
        rep.table(
            &["object (mm, map / truth)", "length", "width", "height"],
            objects,
        );
    }
    rep.write(dir).context("writing report.html")?;
    Ok(())
}

pub fn print_summary(report: &Value, stats: &ScanMapStats, out: &Path) -> Result<()> {
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
        let art = &report[key]["artifacts"];
        if !art.is_null() {
            crate::outln!(
                "{key:<13} artifacts over flat ground: {} false peaks and {} false pits of more than 2 cm among {} cells",
                art["phantoms"], art["pits"], art["flat_cells"]
            )?;
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
