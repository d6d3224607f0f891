//! Issue 12's "no allocation per frame": once the stack mapper has seen a view, mapping
//! the next frames of the same kind allocates nothing on the heap. Counted with a global
//! allocator of this test binary's own (`stats_alloc`: this project forbids unsafe code,
//! which a counting allocator needs; one test in the file, so no other test allocates
//! meanwhile).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};
use stats_alloc::{Region, StatsAlloc, INSTRUMENTED_SYSTEM};
use std::alloc::System;
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;
use stride_mapping::input::SensorFrame;
use stride_mapping::stack::{StackConfig, StackMapper};
use stride_mapping::ElevationMapper;

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

#[test]
fn mapping_a_frame_allocates_nothing_once_warm() {
    // A VGA camera 0.5 m above a floor with a box on it, looking down and ahead: every
    // stage has work (depth jumps for the edge filter and the steep push, established
    // cells for the visibility and see-through checks).
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480).unwrap();
    let depth: Vec<f32> = (0..480)
        .flat_map(|v| {
            (0..640).map(move |u| {
                if (200..300).contains(&u) && v > 240 {
                    0.9
                } else {
                    1.0 + 0.001 * v as f32
                }
            })
        })
        .collect();
    let depth = DepthImage::from_vec(640, 480, depth).unwrap();
    let rot = Rotation3::from_basis_unchecked(&[Vector3::x(), -Vector3::y(), -Vector3::z()]);
    let pose = |i: usize| {
        Isometry3::from_parts(
            Translation3::new(0.002 * i as f64, 0.0, 1.0),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    };
    // On a pool's thread: a parallel loop started from outside a pool goes through the
    // pool's shared queue, which grows block by block (crossbeam's injector: rayon's
    // allocation, every few dozen loops, not the mapper's); from a worker it goes on that
    // worker's own deque, warm after the first frames.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let (stats, allocated) = pool.install(|| {
        let mut mapper = StackMapper::new(StackConfig::default()).unwrap();
        for i in 0..5 {
            let frame = SensorFrame::depth(&depth, &cam, pose(i), i as f64 * 0.1).unwrap();
            mapper.integrate(&frame);
        }
        let frame = SensorFrame::depth(&depth, &cam, pose(5), 0.5).unwrap();
        let region = Region::new(GLOBAL);
        let stats = mapper.integrate(&frame);
        let change = region.change();
        (stats, change.allocations + change.reallocations)
    });
    assert!(
        stats.points_used > 100_000,
        "{} points used",
        stats.points_used
    );
    assert_eq!(allocated, 0, "allocations while mapping a frame");
}
