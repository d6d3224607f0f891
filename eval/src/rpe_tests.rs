//! Tests of `rpe`.

use super::*;
use approx::assert_relative_eq;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

fn straight(n: usize, step_m: f64, dt: f64) -> Trajectory {
    Trajectory::from_parts(
        (0..n).map(|i| i as f64 * dt).collect(),
        (0..n)
            .map(|i| {
                Isometry3::from_parts(
                    Translation3::new(i as f64 * step_m, 0.1 * (i as f64 * 0.3).sin(), 0.0),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, 0.02 * i as f64),
                )
            })
            .collect(),
    )
    .unwrap()
}

#[test]
fn find_closest_index_behaves_like_the_tum_tool() {
    let l = [0.0, 1.0, 2.0, 3.0, 4.0];
    assert_eq!(find_closest_index(&l, 2.0), 2);
    assert_eq!(find_closest_index(&l, 2.4), 2);
    assert_eq!(find_closest_index(&l, 2.6), 3);
    assert_eq!(find_closest_index(&l, 9.0), 4);
    assert_eq!(find_closest_index(&l, -3.0), 0);
    // A tie keeps the first closest value the search visited (here 2.0 at index 2).
    assert_eq!(find_closest_index(&l, 2.5), 2);
}

#[test]
fn identical_trajectories_have_zero_rpe_in_every_mode() {
    let t = straight(50, 0.05, 0.1);
    for preset in [Preset::Evo, Preset::Tum] {
        for (delta, unit) in [
            (1.0, DeltaUnit::Frames),
            (3.0, DeltaUnit::Frames),
            (0.5, DeltaUnit::Seconds),
            (0.2, DeltaUnit::Metres),
        ] {
            let r = rpe(
                &t,
                &t,
                &RpeOptions {
                    delta,
                    unit,
                    ..RpeOptions::for_preset(preset)
                },
            )
            .unwrap();
            assert!(
                r.trans_m.max < 1e-9 && r.rot_deg.max < 1e-5,
                "{preset} {delta} {unit}"
            );
        }
    }
}

#[test]
fn constant_scale_drift_gives_known_per_frame_error() {
    // The estimate moves 10 % too far each frame along x: per-frame error 0.1 * step.
    let gt = straight(30, 0.05, 0.1);
    let est = Trajectory::from_parts(
        gt.stamps_s().to_vec(),
        gt.poses()
            .iter()
            .map(|p| {
                let mut q = *p;
                q.translation.vector.x *= 1.1;
                q
            })
            .collect(),
    )
    .unwrap();
    let r = rpe(&gt, &est, &RpeOptions::for_preset(Preset::Evo)).unwrap();
    assert_eq!(r.trans_m.count, 29);
    // Expressed in the rotated frame the error vector keeps its length.
    assert_relative_eq!(r.trans_m.mean, 0.005, epsilon = 1e-12);
    assert_relative_eq!(r.rot_deg.max, 0.0, epsilon = 1e-9);
    // Consecutive pairs every 5 frames see 5 times the error.
    let r = rpe(
        &gt,
        &est,
        &RpeOptions {
            delta: 5.0,
            ..RpeOptions::for_preset(Preset::Evo)
        },
    )
    .unwrap();
    assert_eq!(r.trans_m.count, 5);
    assert_relative_eq!(r.trans_m.mean, 0.025, epsilon = 1e-12);
    // All pairs 5 frames apart.
    let r = rpe(
        &gt,
        &est,
        &RpeOptions {
            delta: 5.0,
            all_pairs: true,
            ..RpeOptions::for_preset(Preset::Evo)
        },
    )
    .unwrap();
    assert_eq!(r.trans_m.count, 25);
    // Sim(3) alignment removes the scale error only partly (it is anisotropic); SE(3)
    // alignment changes nothing.
    let se3 = rpe(
        &gt,
        &est,
        &RpeOptions {
            align: Align::Se3,
            ..RpeOptions::for_preset(Preset::Evo)
        },
    )
    .unwrap();
    assert_relative_eq!(se3.trans_m.mean, 0.005, epsilon = 1e-9);
}

#[test]
fn rotation_error_in_degrees_and_chordal() {
    // Ground truth keeps its orientation; the estimate turns 0.01 rad about x per frame.
    let gt = straight(20, 0.05, 0.1);
    let gt = Trajectory::from_parts(
        gt.stamps_s().to_vec(),
        gt.poses()
            .iter()
            .map(|p| Isometry3::from_parts(p.translation, UnitQuaternion::identity()))
            .collect(),
    )
    .unwrap();
    let est = Trajectory::from_parts(
        gt.stamps_s().to_vec(),
        gt.poses()
            .iter()
            .enumerate()
            .map(|(i, p)| {
                Isometry3::from_parts(
                    p.translation,
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.01 * i as f64),
                )
            })
            .collect(),
    )
    .unwrap();
    for preset in [Preset::Evo, Preset::Tum] {
        let r = rpe(
            &gt,
            &est,
            &RpeOptions {
                delta: 1.0,
                unit: DeltaUnit::Frames,
                ..RpeOptions::for_preset(preset)
            },
        )
        .unwrap();
        assert_relative_eq!(r.rot_deg.median, 0.01f64.to_degrees(), epsilon = 1e-6);
        assert_relative_eq!(
            r.rot_chordal.median,
            2.0 * 2f64.sqrt() * 0.005f64.sin(),
            epsilon = 1e-9
        );
    }
}

#[test]
fn tum_drops_pairs_ending_on_the_last_pose_and_far_gt() {
    let gt = straight(10, 0.05, 0.1);
    let r = rpe(
        &gt,
        &gt,
        &RpeOptions {
            delta: 1.0,
            unit: DeltaUnit::Frames,
            ..RpeOptions::for_preset(Preset::Tum)
        },
    )
    .unwrap();
    // Pairs (i, i+1) for i = 0..7: the pair (8, 9) ends on the last pose and (9, 9) too,
    // and the tool drops both.
    assert_eq!(r.trans_m.count, 8);
}

#[test]
fn invalid_options_and_empty_results_are_errors() {
    let t = straight(10, 0.05, 0.1);
    let base = RpeOptions::for_preset(Preset::Evo);
    for bad in [
        RpeOptions { delta: 0.0, ..base },
        RpeOptions { delta: 1.5, ..base },
        RpeOptions {
            rel_delta_tol: -1.0,
            ..base
        },
        RpeOptions {
            all_pairs: true,
            ..RpeOptions::for_preset(Preset::Tum)
        },
    ] {
        assert!(
            matches!(rpe(&t, &t, &bad), Err(EvalError::InvalidOption { .. })),
            "{bad:?}"
        );
    }
    let e = rpe(
        &t,
        &t,
        &RpeOptions {
            delta: 100.0,
            ..base
        },
    )
    .unwrap_err();
    assert!(matches!(e, EvalError::NoRelativePairs { .. }), "{e}");
    let e = rpe(
        &t,
        &t,
        &RpeOptions {
            delta: 100.0,
            unit: DeltaUnit::Metres,
            ..base
        },
    )
    .unwrap_err();
    assert!(matches!(e, EvalError::NoRelativePairs { .. }), "{e}");
}
