//! Revisit links on the back end's synthetic sweep (right, then back left over the same
//! place), with depth images rendered from a box room around it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;
use crate::backend_tests::{camera, descriptor, synthetic_run};
use crate::config::BackendConfig;
use nalgebra::Vector3;
use stride_core::rng::SplitMix64;

#[test]
fn half_resolution_averages_blocks_and_drops_mixed_ones() {
    // Left block: one surface at 1.00-1.02 m; right block: 1 m beside 2 m; bottom left
    // block: a missing pixel.
    let d = DepthImage::from_vec(
        4,
        4,
        vec![
            1.0, 1.02, 1.0, 2.0, //
            1.0, 1.02, 1.0, 2.0, //
            1.0, 0.0, 1.0, 1.0, //
            1.0, 1.0, 1.0, 1.0,
        ],
    )
    .unwrap();
    let h = half_resolution(&d, 0.04);
    assert_eq!((h.width(), h.height()), (2, 2));
    assert!((h.get(0, 0).unwrap() - 1.01).abs() < 1e-6);
    assert_eq!(h.get(1, 0), Some(0.0), "two surfaces in one block");
    assert_eq!(h.get(0, 1), Some(0.0), "a pixel without depth");
    assert_eq!(h.get(1, 1), Some(1.0));
}

/// The depth (m along the optical axis) a camera at `world_from_camera` sees of a box room
/// (walls, floor, ceiling and a slanted panel, in the sweep's world: y down).
fn render(world_from_camera: &Isometry3<f64>) -> DepthImage {
    let cam = camera();
    let planes: [(Vector3<f64>, f64); 6] = [
        (Vector3::z(), 5.0),
        (Vector3::y(), 1.4),
        (Vector3::y(), -1.5),
        (Vector3::x(), -3.0),
        (Vector3::x(), 4.5),
        (Vector3::new(0.6, 0.3, 0.74).normalize(), 3.6),
    ];
    let c = world_from_camera.translation.vector;
    let mut depth = Vec::new();
    for v in 0..cam.height() {
        for u in 0..cam.width() {
            let ray = cam.unproject(&nalgebra::Point2::new(f64::from(u), f64::from(v)), 1.0);
            let d = world_from_camera.rotation * ray.coords;
            let hit = planes
                .iter()
                .filter_map(|(n, o)| {
                    let s = (o - n.dot(&c)) / n.dot(&d);
                    (s > 0.0 && s.is_finite()).then_some(s)
                })
                .fold(f64::INFINITY, f64::min);
            depth.push(if hit.is_finite() { hit as f32 } else { 0.0 });
        }
    }
    DepthImage::from_vec(cam.width(), cam.height(), depth).unwrap()
}

/// The error (m) of the last keyframe's position relative to the first, after a sweep
/// whose way back ORB cannot match to the way out, with revisit links on or off; and how
/// many keyframes got a link.
fn sweep(revisit: bool) -> (f64, f64, usize) {
    let n = 40;
    let mut run = synthetic_run(n, 0.004, 7);
    // The way back starts new tracks that look different to ORB (new descriptors), so
    // only its odometry and the depth can tie it to the way out.
    let mut rng = SplitMix64::new(11);
    for input in run.inputs.iter_mut().skip(n / 2) {
        for f in &mut input.info.features {
            f.track_id += 1_000_000;
            f.descriptor = Some(descriptor(1_000_000 + rng.below(1_000_000), &mut rng));
        }
    }
    for (input, truth) in run.inputs.iter_mut().zip(&run.truth) {
        input.depth_m = Some(render(truth));
    }
    let mut cfg = BackendConfig::default();
    cfg.revisit.enabled = revisit;
    cfg.loop_closure.enabled = false;
    let mut backend = crate::Backend::new(camera(), cfg).unwrap();
    let mut links = 0;
    for input in run.inputs.clone() {
        links += usize::from(backend.add_keyframe(input).unwrap().report.revisit_edge);
    }
    backend.finish().unwrap();
    let last = n as u64 - 1;
    let est = backend.map().pose_of(0).unwrap().inverse() * backend.map().pose_of(last).unwrap();
    let truth = run.truth[0].inverse() * run.truth[n - 1];
    let odo = run.odometry[0].inverse() * run.odometry[n - 1];
    let err = |p: &Isometry3<f64>| (p.translation.vector - truth.translation.vector).norm();
    (err(&est), err(&odo), links)
}

#[test]
fn the_way_back_is_tied_to_the_way_out_by_depth() {
    let (with, odometry, links) = sweep(true);
    let (without, _, none) = sweep(false);
    assert_eq!(none, 0);
    assert!(links >= 5, "{links} keyframes linked");
    assert!(
        with < 0.005 && with < 0.25 * without,
        "last keyframe {:.1} mm off with links, {:.1} mm without (odometry {:.1} mm)",
        with * 1e3,
        without * 1e3,
        odometry * 1e3
    );
}

#[test]
fn a_link_may_not_move_a_keyframe_beyond_the_alignments_reach() {
    let start = Isometry3::translation(0.2, 0.0, 0.0);
    let near = Isometry3::translation(0.25, 0.03, 0.0);
    assert!(within_reach(&start, &near).is_ok());
    let far = Isometry3::translation(0.2, 0.0, 0.15);
    let err = within_reach(&start, &far).unwrap_err();
    assert!(err.contains("0.150 m"), "{err}");
    let turned = start * Isometry3::rotation(Vector3::y() * 0.2);
    assert!(within_reach(&start, &turned).is_err(), "11.5 degrees");
}

#[test]
fn kept_depth_rounds_to_quarter_millimetres_and_drops_what_it_cannot_hold() {
    let d = DepthImage::from_vec(4, 1, vec![1.23456, 0.0, 20.0, f32::NAN]).unwrap();
    let k = keep(&d);
    assert_eq!(k.as_slice(), &[4938, 0, 0, 0]);
    assert!((f32::from(k.as_slice()[0]) / KEPT_UNITS_PER_M - 1.23456).abs() < 0.000125);
}
