//! Tests of `input`.

use super::*;
use approx::assert_relative_eq;
use nalgebra::{Translation3, UnitQuaternion};

#[test]
fn pixel_variance_equals_the_full_covariance_projected_on_z() {
    let cam = PinholeCamera::new(525.0, 520.0, 319.5, 239.5, 640, 480).unwrap();
    let model = PrimeSenseHeight::default();
    let t = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.4),
        UnitQuaternion::from_euler_angles(-2.0, 0.1, 0.3),
    );
    let rot = t.rotation.to_rotation_matrix();
    let r3 = Vector3::new(rot[(2, 0)], rot[(2, 1)], rot[(2, 2)]);
    for &(u, v, d) in &[(100.0, 50.0, 1.0), (600.0, 400.0, 3.0), (320.0, 240.0, 2.0)] {
        let xn = cam.normalized_from_pixel(&nalgebra::Point2::new(u, v));
        let fast = model.pixel_variance(
            &cam,
            &DepthPixel {
                u,
                v,
                xn: xn.x,
                yn: xn.y,
                d_m: d,
            },
            &r3,
        );
        let (p, cov) = model.model.point_and_covariance(&cam, u, v, d);
        let full = model.point_variance(&p, &cov, &r3);
        assert_relative_eq!(fast, full, max_relative = 1e-12);
    }
}

#[test]
fn bad_measurements_are_dropped_and_counted() {
    let cam = PinholeCamera::new(10.0, 10.0, 1.5, 1.5, 4, 4).unwrap();
    let mut depth = DepthImage::filled(4, 4, 1.0);
    *depth.get_mut(0, 0).unwrap() = 0.0;
    *depth.get_mut(1, 0).unwrap() = f32::NAN;
    *depth.get_mut(2, 0).unwrap() = f32::INFINITY;
    *depth.get_mut(3, 0).unwrap() = 9.0;
    let frame = SensorFrame::depth(&depth, &cam, Isometry3::identity(), 0.0).unwrap();
    let (pts, rej) = to_map_points(&frame, &PrimeSenseHeight::default());
    assert_eq!(pts.iter().filter(|p| p.is_some()).count(), 12);
    assert_eq!((rej.no_return, rej.non_finite, rej.out_of_range), (1, 2, 1));
    let nan_pose = SensorFrame {
        map_from_sensor: Isometry3::translation(f64::NAN, 0.0, 0.0),
        ..frame
    };
    let (pts, rej) = to_map_points(&nan_pose, &PrimeSenseHeight::default());
    assert!(pts.iter().all(|p| p.is_none()) && rej.bad_pose == 16);
    let points = [
        Point3::new(0.0, 0.0, 1.0),
        Point3::new(0.0, 0.0, 1.0),
        Point3::new(f64::NAN, 0.0, 1.0),
    ];
    let covs = [
        Matrix3::identity() * 1e-4,
        Matrix3::zeros(),
        Matrix3::identity(),
    ];
    let frame = SensorFrame::points(&points, &covs, Isometry3::identity(), 0.0).unwrap();
    let (pts, rej) = to_map_points(&frame, &PrimeSenseHeight::default());
    assert_eq!(pts.iter().filter(|p| p.is_some()).count(), 1);
    assert_eq!((rej.bad_variance, rej.non_finite), (1, 1));
}

#[test]
fn inconsistent_frames_cannot_be_built() {
    // A depth image of another size than its camera would be back-projected along the wrong
    // rays (or partly not at all): the frame is refused, naming both sizes.
    let cam = PinholeCamera::new(10.0, 10.0, 1.5, 1.5, 4, 4).unwrap();
    let depth = DepthImage::filled(5, 4, 1.0);
    let err = SensorFrame::depth(&depth, &cam, Isometry3::identity(), 0.0).unwrap_err();
    assert_eq!(
        err,
        crate::MappingError::DepthSize {
            width: 5,
            height: 4,
            camera_width: 4,
            camera_height: 4
        }
    );
    assert!(err.to_string().contains("5x4") && err.to_string().contains("4x4"));
    let points = [Point3::new(0.0, 0.0, 1.0); 3];
    let covs = [Matrix3::identity(); 2];
    let err = SensorFrame::points(&points, &covs, Isometry3::identity(), 0.0).unwrap_err();
    assert!(matches!(
        err,
        crate::MappingError::CovarianceCount {
            points: 3,
            covariances: 2
        }
    ));
}

/// The mappers' vectorised f32 input stage (`prepare_binned` on a depth image) keeps the
/// points, cells, heights, variances and rejection counts of the f64 path
/// (`filtered_map_points` binned one point at a time), for both sensor models.
#[test]
fn the_vectorised_input_stage_agrees_with_the_f64_path() {
    use crate::fankhauser::KinectNguyenHeight;
    use crate::window::Window;
    let cam = PinholeCamera::new(52.5, 52.0, 31.5, 23.5, 64, 48).unwrap();
    let mut depth = DepthImage::filled(64, 48, 0.0);
    for v in 0..48u32 {
        for u in 0..64u32 {
            // A tilted floor with a box in front of it (a depth jump), holes and bad values.
            let d = if (20..30).contains(&u) && (10..20).contains(&v) {
                0.9
            } else {
                1.2 + 0.02 * f64::from(v)
            };
            *depth.get_mut(u, v).unwrap() = d as f32;
        }
    }
    for (u, v, d) in [
        (0, 0, 0.0),
        (5, 5, f32::NAN),
        (6, 5, f32::INFINITY),
        (7, 5, 9.0),
        (8, 5, 0.1),
        // A sliver: nearer than the floor beside it, a hole on its other side.
        (40, 40, 0.0),
        (41, 40, 1.5),
    ] {
        *depth.get_mut(u, v).unwrap() = d;
    }
    let pose = Isometry3::from_parts(
        Translation3::new(12.3, -4.5, 0.5),
        UnitQuaternion::from_euler_angles(-2.0, 0.05, 0.4),
    );
    let frame = SensorFrame::depth(&depth, &cam, pose, 0.0).unwrap();
    // A small window that cuts the view, so that some points fall outside it.
    let mut window: Window<u8> = Window::new(60, 0.01, (0, 0));
    window.follow(&pose, 0.9, 0.0, |_, _| {});
    let binner = window.binner(7);
    let bands = 60usize.div_ceil(7);
    let edge = EdgeFilter::default();
    fn check<M: HeightModel>(
        model: &M,
        frame: &SensorFrame<'_>,
        binner: &crate::window::CellBinner,
        bands: usize,
        edge: &EdgeFilter,
    ) {
        let mut binned = Binned::default();
        let rej = prepare_binned(
            frame,
            model,
            &mut RayCache::default(),
            Binning {
                binner,
                centrality: true,
                smooth: true,
                faces: None,
            },
            bands,
            Some(edge),
            &mut binned,
        );
        let (pts, mut want) = filtered_map_points(frame, model, Some(edge));
        let mut expected: Vec<(u32, usize, f64, f64, f32)> = Vec::new();
        for p in &pts {
            match binner.locate(p.x, p.y) {
                Some((cell, band)) => {
                    expected.push((cell as u32, band, p.z, p.var, binner.centrality(p.x, p.y)))
                }
                None => want.outside_window += 1,
            }
        }
        assert_eq!(rej, want);
        assert!(want.depth_edge > 0 && want.outside_window > 0 && rej.no_return > 0);
        let got: Vec<(u32, usize, f32, f32, f32)> = (0..bands)
            .flat_map(|b| {
                binned
                    .band(b)
                    .map(move |c| (c.cell(), b, c.z_m, c.var_m2, c.centrality()))
            })
            .collect();
        expected.sort_by_key(|e| (e.1, e.0));
        let mut got_sorted = got.clone();
        got_sorted.sort_by_key(|g| (g.1, g.0));
        assert_eq!(got.len(), expected.len());
        for (g, e) in got_sorted.iter().zip(&expected) {
            assert!((0.0..=1.0).contains(&g.4), "centrality {}", g.4);
            assert_eq!((g.0, g.1), (e.0, e.1));
        }
        // Heights, variances and centralities per cell, compared as sums (order within a
        // cell may differ).
        let sum = |v: &mut dyn Iterator<Item = (u32, f64, f64, f64)>| {
            let mut m = std::collections::BTreeMap::new();
            for (c, z, var, cen) in v {
                let e = m.entry(c).or_insert((0.0, 0.0, 0.0, 0.0));
                e.0 += z;
                e.1 += var;
                e.2 += cen;
                e.3 += 1.0;
            }
            m
        };
        let a = sum(&mut got
            .iter()
            .map(|g| (g.0, f64::from(g.2), f64::from(g.3), f64::from(g.4))));
        let b = sum(&mut expected.iter().map(|e| (e.0, e.2, e.3, f64::from(e.4))));
        for ((ca, (za, va, qa, n)), (cb, (zb, vb, qb, _))) in a.iter().zip(&b) {
            assert_eq!(ca, cb);
            assert!((za - zb).abs() < 1e-5, "cell {ca}: heights {za} vs {zb}");
            assert_relative_eq!(*va, *vb, max_relative = 1e-4);
            // Stored to 1/127 (the eighth bit of the byte holds CellPoint::smooth).
            let tol = n / 254.0 + 1e-4;
            assert!(
                (qa - qb).abs() <= tol,
                "cell {ca}: centralities {qa} vs {qb}"
            );
        }
    }
    check(&PrimeSenseHeight::default(), &frame, &binner, bands, &edge);
    check(
        &KinectNguyenHeight::default(),
        &frame,
        &binner,
        bands,
        &edge,
    );
}

/// A pixel is smooth when its 5 x 5 neighbourhood (missing returns left out) spans no depth
/// jump: on two fronto-parallel planes (1.0 m left, 1.5 m right) with one hole, exactly the
/// kept pixels within two columns of the jump are not (the jump's far side is dropped by the
/// edge filter, two columns deep; the hole changes nothing); without the request, no point
/// is smooth.
#[test]
fn points_from_pixels_near_a_depth_jump_are_not_smooth() {
    use crate::window::Window;
    let cam = PinholeCamera::new(52.5, 52.0, 31.5, 23.5, 64, 48).unwrap();
    let mut depth = DepthImage::filled(64, 48, 1.0);
    for v in 0..48u32 {
        for u in 32..64u32 {
            *depth.get_mut(u, v).unwrap() = 1.5;
        }
    }
    *depth.get_mut(10, 10).unwrap() = 0.0;
    let pose = Isometry3::from_parts(
        Translation3::new(1.0, 2.0, 0.5),
        UnitQuaternion::from_euler_angles(-2.0, 0.05, 0.4),
    );
    let frame = SensorFrame::depth(&depth, &cam, pose, 0.0).unwrap();
    let mut window: Window<u8> = Window::new(400, 0.01, (0, 0));
    window.follow(&pose, 0.9, 0.0, |_, _| {});
    let binner = window.binner(50);
    let bands = 8;
    let count = |smooth: bool| {
        let mut binned = Binned::default();
        let rej = prepare_binned(
            &frame,
            &PrimeSenseHeight::default(),
            &mut RayCache::default(),
            Binning {
                binner: &binner,
                centrality: true,
                smooth,
                faces: None,
            },
            bands,
            Some(&EdgeFilter::default()),
            &mut binned,
        );
        let all: Vec<CellPoint> = (0..bands).flat_map(|b| binned.band(b).copied()).collect();
        (rej, all.len(), all.iter().filter(|p| p.smooth()).count())
    };
    let (rej, kept, smooth) = count(true);
    // The jump's far side loses its two columns nearest the jump (32 and 33) to the edge
    // filter's two rings.
    assert_eq!(
        (rej.outside_window, rej.depth_edge, rej.no_return),
        (0, 2 * 48, 1)
    );
    assert_eq!(kept, 64 * 48 - 2 * 48 - 1);
    // Columns 30 and 31 (near side), 48 pixels each.
    assert_eq!(kept - smooth, 2 * 48);
    assert_eq!(count(false).2, 0);
}

/// A mixed ("flying") pixel whose foreground partner across the edge returned nothing has no
/// nearer neighbour within one pixel, only within two: the edge filter's second ring drops
/// it. Foreground at 1 m (columns 0-30), a dropped column (31), the mixed pixel at 2 m (32),
/// background at 3 m (33 on); the first ring alone keeps it.
#[test]
fn a_mixed_pixel_beside_a_dropped_return_is_an_edge() {
    let (pts, rej) = columns_filtered(|u| match u {
        0..=30 => 1.0,
        31 => 0.0,
        32 => 2.0,
        _ => 3.0,
    });
    assert!(
        pts.iter().all(|p| (p.z - 2.0).abs() > 0.5),
        "the mixed pixel was kept"
    );
    // Columns 32 (mixed), 33 (beside it) and 34 (two pixels from it) go.
    assert_eq!((rej.depth_edge, rej.no_return), (3 * 48, 48));
    assert_eq!(pts.len(), 64 * 48 - 4 * 48);
}

/// A flying pixel beside the hole a foreground edge leaves (a structured-light sensor's
/// shadow, or dropped edge pixels), nearer than the background on its other side: no
/// nearer pixel lies within two, so the rings keep it; the sliver test drops it.
/// Foreground at 1 m (columns 0-20), no returns (21-27), the sliver at 1.5 m (28),
/// background at 3 m (29 on). The foreground's last column, beside the hole, stays.
#[test]
fn a_sliver_between_a_hole_and_a_farther_surface_is_an_edge() {
    let (pts, rej) = columns_filtered(|u| match u {
        0..=20 => 1.0,
        21..=27 => 0.0,
        28 => 1.5,
        _ => 3.0,
    });
    assert!(
        pts.iter().all(|p| (p.z - 1.5).abs() > 0.25),
        "the sliver was kept"
    );
    // The sliver (28) and the two background columns beside it (29, 30, the rings) go.
    assert_eq!((rej.depth_edge, rej.no_return), (3 * 48, 7 * 48));
    assert_eq!(pts.len(), 64 * 48 - 10 * 48);
    // Column 20, the foreground's edge beside the hole, is kept (z = 1 m).
    assert_eq!(
        pts.iter().filter(|p| (p.z - 1.0).abs() < 0.1).count(),
        21 * 48
    );
}

/// The points and rejections of the default edge filter on a 64 x 48 depth image whose
/// column `u` holds `depth_of(u)` (m) in every row, seen at the identity pose (a point's map
/// z is its depth).
fn columns_filtered(
    depth_of: impl Fn(u32) -> f32,
) -> (Vec<crate::input::HeightSample>, Rejections) {
    let cam = PinholeCamera::new(52.5, 52.0, 31.5, 23.5, 64, 48).unwrap();
    let mut depth = DepthImage::filled(64, 48, 0.0);
    for v in 0..48u32 {
        for u in 0..64u32 {
            *depth.get_mut(u, v).unwrap() = depth_of(u);
        }
    }
    let frame = SensorFrame::depth(&depth, &cam, Isometry3::identity(), 0.0).unwrap();
    filtered_map_points(
        &frame,
        &PrimeSenseHeight::default(),
        Some(&EdgeFilter::default()),
    )
}
