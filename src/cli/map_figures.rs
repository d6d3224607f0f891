//! Elevation maps as report figures: the colour relief and the error against the true
//! terrain, each on axes in metres with a colour bar, a scale bar and the walked path.

use anyhow::Result;
use stride_core::grid::Grid;
use stride_datasets::grid_file::{heat_png, preview_geometry, relief_png};
use stride_eval::plot::{nice_ticks, Chart, Raster, Series, PALETTE};

/// Largest side of an embedded map image (pixels).
const MAX_SIDE_PX: usize = 800;

/// A scale bar just below the lower-left corner of `extent` (x_min, x_max, y_min, y_max;
/// m), off the map so that it shows on any colour: a round length about a fifth of the
/// width, as a labelled series.
fn scale_bar(extent: (f64, f64, f64, f64)) -> Series {
    let (x0, x1, y0, y1) = extent;
    let (ticks, step) = nice_ticks(0.0, (x1 - x0) / 5.0, 2);
    let length = ticks.last().copied().filter(|l| *l > 0.0).unwrap_or(step);
    let (x, y) = (x0 + 0.05 * (x1 - x0), y0 - 0.05 * (y1 - y0));
    let label = if length >= 1.0 {
        format!("scale bar: {length} m")
    } else {
        format!("scale bar: {:.0} cm", length * 100.0)
    };
    Series::line(label, PALETTE[6], vec![(x, y), (x + length, y)])
}

/// The map as a colour relief (height in metres on the colour bar) with the walked path
/// (world x-y, m) drawn on it.
pub fn elevation_chart(title: &str, elevation: &Grid<f32>, path: &[(f64, f64)]) -> Result<Chart> {
    let (_, extent) = preview_geometry(elevation, MAX_SIDE_PX);
    let (lo, hi) = elevation.min_max().unwrap_or((0.0, 1.0));
    let png = relief_png(elevation, MAX_SIDE_PX).map_err(anyhow::Error::msg)?;
    Ok(map_chart(
        title,
        Raster {
            label: "height (m)".into(),
            png,
            extent,
            range: (f64::from(lo), f64::from(hi)),
        },
        path,
    ))
}

/// Any layer (certainty, counts) as a heat map from 0 to its largest value, on metric
/// axes with a colour bar labelled `label`, and the path.
pub fn layer_chart(
    title: &str,
    layer: &Grid<f32>,
    label: &str,
    path: &[(f64, f64)],
) -> Result<Chart> {
    let (_, extent) = preview_geometry(layer, MAX_SIDE_PX);
    let top = layer
        .min_max()
        .map_or(1.0, |(_, hi)| f64::from(hi).max(1e-6));
    let png = heat_png(layer, (0.0, top), MAX_SIDE_PX).map_err(anyhow::Error::msg)?;
    Ok(map_chart(
        title,
        Raster {
            label: label.into(),
            png,
            extent,
            range: (0.0, top),
        },
        path,
    ))
}

/// A map image from above on metric world axes, with its colour bar, a scale bar and the
/// walked path (world x-y, m).
fn map_chart(title: &str, raster: Raster, path: &[(f64, f64)]) -> Chart {
    Chart {
        title: title.into(),
        x_label: "world x (m)".into(),
        y_label: "world y (m)".into(),
        series: vec![
            Series::line("walked path (sensor)", PALETTE[1], path.to_vec()),
            scale_bar(raster.extent),
        ],
        raster: Some(raster),
        equal_aspect: true,
        ..Chart::default()
    }
}

/// The map's absolute error against the true terrain (cm on the colour bar, up to twice
/// the 95th percentile), over the cells both know; `None` when they share none.
pub fn error_chart(
    elevation: &Grid<f32>,
    truth: &Grid<f32>,
    path: &[(f64, f64)],
) -> Result<Option<Chart>> {
    let g = elevation.geometry;
    let mut error = Grid::filled(g, f32::NAN);
    let mut errors = Vec::new();
    for r in 0..g.rows {
        for c in 0..g.cols {
            let (x, y) = g.center(r, c);
            let (Some(h), Some(t)) = (
                elevation.get(r, c).filter(|v| !v.is_nan()),
                truth.sample_bilinear(x, y),
            ) else {
                continue;
            };
            let e = (h - t).abs() * 100.0;
            if let Some(slot) = error.get_mut(r, c) {
                *slot = e;
            }
            errors.push(f64::from(e));
        }
    }
    if errors.is_empty() {
        return Ok(None);
    }
    errors.sort_by(f64::total_cmp);
    let p95 = errors.get(errors.len() * 95 / 100).copied().unwrap_or(1.0);
    let top = (2.0 * p95).max(0.5);
    let (_, extent) = preview_geometry(&error, MAX_SIDE_PX);
    let png = heat_png(&error, (0.0, top), MAX_SIDE_PX).map_err(anyhow::Error::msg)?;
    Ok(Some(map_chart(
        "Map error against the true terrain",
        Raster {
            label: format!("|error| (cm), clamped at {top:.1}"),
            png,
            extent,
            range: (0.0, top),
        },
        path,
    )))
}
