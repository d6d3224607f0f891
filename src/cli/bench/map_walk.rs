//! `stride bench map-walk`: the stack map over a long walk that goes out and comes back,
//! for its memory (peak RSS), the archive's cap, and the columns found again on return.

use anyhow::{bail, Result};
use clap::Args;
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde_json::json;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;
use stride_mapping::input::SensorFrame;
use stride_mapping::stack::{StackConfig, StackMapper};
use stride_mapping::ElevationMapper;

#[derive(Debug, Args)]
pub struct MapWalkBenchArgs {
    /// Frames (640x480 depth at 30 Hz, 0.15 m/s): half walking out along x, half back.
    #[arg(long, default_value_t = 10_000)]
    frames: usize,
    /// The archive's cap (columns) [default: the mapper's default].
    #[arg(long)]
    archive_max_cells: Option<usize>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Camera height above the floor (m), pitch below the horizon (deg), speed (m/s), rate (Hz).
const HEIGHT_M: f64 = 0.45;
const PITCH_DEG: f64 = 25.0;
const SPEED_M_S: f64 = 0.15;
const FPS: f64 = 30.0;

/// The camera at `x_m` along the x axis, looking along +x (`forward`) or -x, pitched down.
fn pose(x_m: f64, forward: bool) -> Isometry3<f64> {
    // Camera z (optical axis) along world +x, camera x along world -y, camera y down.
    let level = Rotation3::from_basis_unchecked(&[-Vector3::y(), -Vector3::z(), Vector3::x()]);
    let pitch = Rotation3::from_axis_angle(&Vector3::y_axis(), PITCH_DEG.to_radians());
    let turn = if forward {
        Rotation3::identity()
    } else {
        Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
    };
    Isometry3::from_parts(
        Translation3::new(x_m, 0.0, HEIGHT_M),
        UnitQuaternion::from_rotation_matrix(&(turn * pitch * level)),
    )
}

/// The depth image of a flat floor (z = 0) seen from `world_from_camera` (m along the
/// optical axis; 0 where the ray misses it or beyond 5 m).
fn floor_depth(camera: &PinholeCamera, world_from_camera: &Isometry3<f64>, out: &mut DepthImage) {
    let h = world_from_camera.translation.vector.z;
    for v in 0..camera.height() {
        for u in 0..camera.width() {
            let ray = Vector3::new(
                (f64::from(u) - camera.cx()) / camera.fx(),
                (f64::from(v) - camera.cy()) / camera.fy(),
                1.0,
            );
            let down = (world_from_camera.rotation * ray).z;
            // The depth along the optical axis is the ray's parameter (its z is 1).
            let d = if down < -1e-9 { h / -down } else { 0.0 };
            if let Some(px) = out.get_mut(u, v) {
                *px = if d < 5.0 { d as f32 } else { 0.0 };
            }
        }
    }
}

/// This process's peak resident set size (MB), from /proc/self/status.
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

pub fn bench_map_walk(a: MapWalkBenchArgs) -> Result<()> {
    if a.frames < 2 {
        bail!("--frames must be at least 2");
    }
    let camera = PinholeCamera::KINECT_DEFAULT;
    let mut cfg = StackConfig::default();
    if let Some(n) = a.archive_max_cells {
        cfg.archive_max_cells = n;
    }
    let mut mapper = StackMapper::new(cfg)?;
    let rss_start = peak_rss_mb();
    let mut depth = DepthImage::filled(camera.width(), camera.height(), 0.0);
    let half = a.frames / 2;
    let step_m = SPEED_M_S / FPS;
    let mut update_ms = Vec::with_capacity(a.frames);
    // The map once the window has left the start (5 m out; it reaches 3.2 m ahead of the
    // camera and 0.8 m behind).
    let snapshot = ((5.0 / step_m) as usize).min(half.saturating_sub(1));
    let mut after_out = None;
    let bar = indicatif::ProgressBar::new(a.frames as u64);
    for i in 0..a.frames {
        // Out to half * step_m, then back to the start.
        let (x, forward) = if i < half {
            (i as f64 * step_m, true)
        } else {
            ((a.frames - 1 - i) as f64 * step_m, false)
        };
        let world_from_camera = pose(x, forward);
        floor_depth(&camera, &world_from_camera, &mut depth);
        let frame = SensorFrame::depth(&depth, &camera, world_from_camera, i as f64 / FPS)?;
        let u = mapper.integrate(&frame);
        update_ms.push(u.update_s * 1e3);
        if i == snapshot {
            after_out = Some(mapper.export());
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let rss_walk = peak_rss_mb();
    let (archived, dropped, resumed) = mapper.archive_cells();
    let end = mapper.export();
    let rss_export = peak_rss_mb();
    // The columns mapped within 2 m of the start, as the map held them 5 m out: found
    // again on the way back (still in the map and updated again).
    let (mut first, mut found, mut updated) = (0usize, 0usize, 0usize);
    if let Some(out) = &after_out {
        let g = out.updates.geometry;
        for r in 0..g.rows {
            for c in 0..g.cols {
                let (x, y) = g.center(r, c);
                let Some(n0) = out.updates.get(r, c).filter(|n| !n.is_nan()) else {
                    continue;
                };
                if x > 2.0 + HEIGHT_M || y.abs() > 2.0 {
                    continue;
                }
                first += 1;
                if let Some(n1) = end.updates.at(x, y).filter(|n| !n.is_nan()) {
                    found += 1;
                    updated += usize::from(n1 > n0);
                }
            }
        }
    }
    let (med, p95) = stride::pipeline::median_p95(update_ms.iter().copied());
    let j = json!({
        "frames": a.frames,
        "path_m": 2.0 * half as f64 * step_m,
        "archive_max_cells": mapper.config().archive_max_cells,
        "archive_cells": archived,
        "archive_dropped_cells": dropped,
        "archive_resumed_cells": resumed,
        "mapper_mb": mapper.memory_bytes() as f64 / 1e6,
        "update_ms": {"median": med, "p95": p95},
        "peak_rss_mb": {"start": rss_start, "after_walk": rss_walk, "after_export": rss_export},
        "export_cells": end.elevation.geometry.rows * end.elevation.geometry.cols,
        "near_start": {"mapped_going_out": first, "found_at_the_end": found, "updated_again": updated},
    });
    if a.json {
        println!("{j}");
    } else {
        println!(
            "{} frames, {:.1} m walked out and back: {:.2} ms median per frame ({:.2} p95)",
            a.frames,
            2.0 * half as f64 * step_m,
            med,
            p95
        );
        println!(
            "archive: {archived} columns kept (cap {}), {dropped} dropped, {resumed} resumed when the window came back; mapper {:.1} MB",
            mapper.config().archive_max_cells,
            mapper.memory_bytes() as f64 / 1e6
        );
        println!(
            "peak RSS: {:.0} MB at the start, {:.0} MB after the walk, {:.0} MB after exporting the map",
            rss_start.unwrap_or(f64::NAN),
            rss_walk.unwrap_or(f64::NAN),
            rss_export.unwrap_or(f64::NAN)
        );
        println!(
            "near the start: {first} columns mapped going out (map 5 m out), {found} still in the map at the end, {updated} updated again on the way back"
        );
    }
    Ok(())
}
