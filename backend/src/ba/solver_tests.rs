//! Tests of the solver: convergence on noise-free data, statistical consistency on noisy
//! data (NEES), a pose graph with a known solution, and failures that must not corrupt the
//! estimate.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;
use crate::ba::problem::{linearize_point, linearize_pose, PointEdge, PointVar, PoseEdge, PoseVar};
use crate::se3::{is_finite, point_is_finite, retract};
use nalgebra::{DMatrix, DVector, Translation3, UnitQuaternion};
use nalgebra::{Isometry3, Point3};
use stride_core::rng::SplitMix64;

/// Cameras on an arc looking at a cloud of points, with anisotropic (depth-heavy)
/// measurement covariances like the PrimeSense model's.
struct Scene {
    poses: Vec<Isometry3<f64>>,
    points: Vec<Point3<f64>>,
}

fn scene(n_poses: usize, n_points: usize, rng: &mut SplitMix64) -> Scene {
    let poses = (0..n_poses)
        .map(|i| {
            let a = i as f64 * 0.08;
            Isometry3::from_parts(
                Translation3::new(0.3 * a.sin(), 0.02 * i as f64, -0.3 * (1.0 - a.cos())),
                UnitQuaternion::from_euler_angles(0.01 * i as f64, -a, 0.005 * i as f64),
            )
        })
        .collect();
    let points = (0..n_points)
        .map(|_| {
            Point3::new(
                rng.range(-1.0, 1.0),
                rng.range(-0.7, 0.7),
                rng.range(1.5, 3.0),
            )
        })
        .collect();
    Scene { poses, points }
}

/// A depth-heavy covariance (m^2) in the camera frame for a point at depth `z`.
fn sensor_cov(z: f64) -> Matrix3<f64> {
    let lateral = (0.002 * z).powi(2);
    Matrix3::from_diagonal(&Vector3::new(lateral, lateral, (0.006 * z * z).powi(2)))
}

/// Observations of every point by every camera that sees it in front (z > 0.5 m), with
/// noise drawn from each measurement's covariance (`noise = false`: exact).
fn problem(s: &Scene, noise: bool, rng: &mut SplitMix64) -> Problem {
    let mut p = Problem {
        poses: s
            .poses
            .iter()
            .enumerate()
            .map(|(i, t)| PoseVar {
                world_from_camera: *t,
                fixed: i == 0,
            })
            .collect(),
        points: s
            .points
            .iter()
            .map(|&p_world| PointVar { p_world })
            .collect(),
        ..Problem::default()
    };
    for (i, t) in s.poses.iter().enumerate() {
        for (j, pw) in s.points.iter().enumerate() {
            let q = t.inverse_transform_point(pw);
            if q.z < 0.5 {
                continue;
            }
            let cov = sensor_cov(q.z);
            let chol = cov.cholesky().unwrap().l();
            let z = if noise {
                q + chol * Vector3::new(rng.normal(), rng.normal(), rng.normal())
            } else {
                q
            };
            p.point_edges.push(PointEdge {
                pose: i,
                point: j,
                p_camera: z,
                information: cov.try_inverse().unwrap(),
            });
        }
    }
    p
}

fn perturb(p: &mut Problem, rng: &mut SplitMix64, trans_m: f64, rot_rad: f64, point_m: f64) {
    for v in p.poses.iter_mut().filter(|v| !v.fixed) {
        let d = Vector6::new(
            rng.normal() * trans_m,
            rng.normal() * trans_m,
            rng.normal() * trans_m,
            rng.normal() * rot_rad,
            rng.normal() * rot_rad,
            rng.normal() * rot_rad,
        );
        v.world_from_camera = retract(&v.world_from_camera, &d);
    }
    for v in &mut p.points {
        v.p_world += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * point_m;
    }
}

fn plain() -> SolverOptions {
    SolverOptions {
        max_iterations: 30,
        point_huber_chi2: None,
        pose_huber_chi2: None,
        function_tolerance: 1e-12,
        ..SolverOptions::default()
    }
}

#[test]
fn noise_free_problem_converges_to_the_truth() {
    let mut rng = SplitMix64::new(1);
    let s = scene(8, 150, &mut rng);
    let mut p = problem(&s, false, &mut rng);
    perturb(&mut p, &mut rng, 0.03, 0.03, 0.05);
    let report = solve(&mut p, &plain()).unwrap();
    assert!(report.accepted >= 2, "{report:?}");
    assert!(
        report.final_cost < 1e-12 * report.initial_cost.max(1.0),
        "{report:?}"
    );
    for (v, t) in p.poses.iter().zip(&s.poses) {
        let err = t.inverse() * v.world_from_camera;
        assert!(err.translation.vector.norm() < 1e-7, "{err}");
        assert!(err.rotation.angle() < 1e-7);
    }
    for (v, t) in p.points.iter().zip(&s.points) {
        assert!((v.p_world - t).norm() < 1e-7);
    }
}

/// The stacked whitened Jacobian of all edges with respect to the free variables (dense;
/// an independent path to the normal equations, for the covariance).
fn dense_information(p: &Problem) -> DMatrix<f64> {
    let free: Vec<usize> = (0..p.poses.len()).filter(|&i| !p.poses[i].fixed).collect();
    let col_of_pose = |i: usize| free.iter().position(|&f| f == i).map(|k| 6 * k);
    let n = 6 * free.len() + 3 * p.points.len();
    let mut h = DMatrix::zeros(n, n);
    for e in &p.point_edges {
        let l = linearize_point(
            &p.poses[e.pose].world_from_camera,
            &p.points[e.point].p_world,
            &e.p_camera,
        );
        let mut j = DMatrix::zeros(3, n);
        if let Some(c) = col_of_pose(e.pose) {
            j.view_mut((0, c), (3, 6)).copy_from(&l.j_pose);
        }
        let c = 6 * free.len() + 3 * e.point;
        j.view_mut((0, c), (3, 3)).copy_from(&l.j_point);
        let w = DMatrix::from_iterator(3, 3, e.information.iter().copied());
        h += j.transpose() * w * &j;
    }
    for e in &p.pose_edges {
        let (_, ji, jk) = linearize_pose(
            &p.poses[e.from].world_from_camera,
            &p.poses[e.to].world_from_camera,
            &e.from_from_to,
        );
        let mut j = DMatrix::zeros(6, n);
        if let Some(c) = col_of_pose(e.from) {
            j.view_mut((0, c), (6, 6)).copy_from(&ji);
        }
        if let Some(c) = col_of_pose(e.to) {
            j.view_mut((0, c), (6, 6)).copy_from(&jk);
        }
        let w = DMatrix::from_iterator(6, 6, e.information.iter().copied());
        h += j.transpose() * w * &j;
    }
    h
}

#[test]
fn noisy_problems_give_errors_consistent_with_their_covariance() {
    // Normalized estimation error squared over all free variables: its mean over trials is
    // the number of degrees of freedom when the estimator is consistent.
    let mut rng = SplitMix64::new(7);
    let s = scene(4, 25, &mut rng);
    let trials = 150;
    let mut nees_sum = 0.0;
    let mut dof = 0;
    for _ in 0..trials {
        let mut p = problem(&s, true, &mut rng);
        perturb(&mut p, &mut rng, 0.005, 0.005, 0.01);
        solve(&mut p, &plain()).unwrap();
        let free: Vec<usize> = (0..p.poses.len()).filter(|&i| !p.poses[i].fixed).collect();
        let mut err = DVector::zeros(6 * free.len() + 3 * p.points.len());
        for (k, &i) in free.iter().enumerate() {
            // The estimate's deviation from the truth, in the retraction's tangent space.
            let d = s.poses[i].inverse() * p.poses[i].world_from_camera;
            let w = d.rotation.scaled_axis();
            err.rows_mut(6 * k, 6).copy_from(&Vector6::new(
                d.translation.x,
                d.translation.y,
                d.translation.z,
                w.x,
                w.y,
                w.z,
            ));
        }
        for (j, v) in p.points.iter().enumerate() {
            err.rows_mut(6 * free.len() + 3 * j, 3)
                .copy_from(&(v.p_world - s.points[j]));
        }
        let h = dense_information(&p);
        nees_sum += (err.transpose() * h * &err)[(0, 0)];
        dof = err.len();
    }
    let mean = nees_sum / trials as f64;
    // The chi-square mean has standard deviation sqrt(2 dof / trials) (~1.0 here).
    let tol = 4.0 * (2.0 * dof as f64 / trials as f64).sqrt();
    assert!(
        (mean - dof as f64).abs() < tol,
        "mean NEES {mean:.2} over {trials} trials, expected {dof} +- {tol:.2}"
    );
}

#[test]
fn a_pose_graph_alone_reaches_its_known_solution() {
    // Four poses along a rotated line: three odometry edges of +1 m along local x and a
    // loop edge saying the last is +2.7 m from the first. With equal information the least
    // squares solution spreads the 0.3 m disagreement evenly: 0.925, 1.85, 2.775.
    let r0 = UnitQuaternion::from_euler_angles(0.2, -0.4, 1.0);
    let at = |x: f64| Isometry3::from_parts(Translation3::from(r0 * Vector3::new(x, 0.0, 0.0)), r0);
    let step =
        |x: f64| Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity());
    let mut p = Problem {
        poses: [0.0, 1.3, 1.7, 3.4]
            .iter()
            .enumerate()
            .map(|(i, &x)| PoseVar {
                world_from_camera: at(x),
                fixed: i == 0,
            })
            .collect(),
        ..Problem::default()
    };
    let info = Matrix6::from_diagonal(&Vector6::new(100.0, 100.0, 100.0, 1e4, 1e4, 1e4));
    for (from, to, x) in [(0, 1, 1.0), (1, 2, 1.0), (2, 3, 1.0), (0, 3, 2.7)] {
        p.pose_edges.push(PoseEdge {
            from,
            to,
            from_from_to: step(x),
            information: info,
        });
    }
    let report = solve(&mut p, &plain()).unwrap();
    for (v, x) in p.poses.iter().zip([0.0, 0.925, 1.85, 2.775]) {
        let err = at(x).inverse() * v.world_from_camera;
        assert!(
            err.translation.vector.norm() < 1e-9,
            "{x}: {err} ({report:?})"
        );
        assert!(err.rotation.angle() < 1e-9);
    }
    assert!((report.final_cost - 4.0 * 100.0 * 0.075f64.powi(2)).abs() < 1e-9);
}

#[test]
fn a_diverging_problem_is_rejected_without_corrupting_the_estimate() {
    // A camera 170 degrees off with a wrong, very confident observation set: steps that
    // raise the cost are rejected; whatever happens, the poses stay finite and the cost
    // never rises.
    let mut rng = SplitMix64::new(3);
    let s = scene(3, 40, &mut rng);
    let mut p = problem(&s, true, &mut rng);
    if let Some(v) = p.poses.get_mut(2) {
        v.world_from_camera *=
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 170f64.to_radians());
    }
    for e in &mut p.point_edges {
        e.information *= 1e12;
    }
    let before = p.clone();
    let report = solve(&mut p, &SolverOptions::default()).unwrap();
    assert!(report.final_cost <= report.initial_cost, "{report:?}");
    assert!(p.poses.iter().all(|v| is_finite(&v.world_from_camera)));
    assert!(p.points.iter().all(|v| point_is_finite(&v.p_world)));
    if report.accepted == 0 {
        assert_eq!(p, before, "no accepted step: the estimate is unchanged");
    }
}

#[test]
fn non_finite_input_is_an_error_and_changes_nothing() {
    let mut rng = SplitMix64::new(5);
    let s = scene(3, 20, &mut rng);
    let mut p = problem(&s, false, &mut rng);
    p.point_edges[4].p_camera.x = f64::NAN;
    let before = format!("{p:?}"); // NaN != NaN: compare the printed values
    assert!(solve(&mut p, &SolverOptions::default()).is_err());
    assert!(format!("{p:?}") == before, "the problem changed");
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let mut rng = SplitMix64::new(11);
    let s = scene(6, 300, &mut rng);
    let mut base = problem(&s, true, &mut rng);
    perturb(&mut base, &mut rng, 0.01, 0.01, 0.02);
    let run = |threads: usize| {
        let mut p = base.clone();
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| solve(&mut p, &SolverOptions::default()).unwrap());
        p
    };
    assert_eq!(run(1), run(3));
}
