//! Tests of the depth alignment on synthetic depth images.

#![allow(clippy::unwrap_used, clippy::expect_used)]
use super::*;

/// The plane `normal . p = offset_m` (world frame, m).
fn plane(normal: Vector3<f64>, offset_m: f64) -> Plane {
    Plane {
        normal: Unit::new_normalize(normal),
        offset_m,
    }
}

fn camera() -> PinholeCamera {
    PinholeCamera::new(262.5, 262.5, 159.5, 119.5, 320, 240).unwrap()
}

/// The depth image a camera at `world_from_camera` sees of `planes` (the nearest hit
/// along each pixel's ray; 0 where none is hit within 8 m).
fn render(planes: &[Plane], world_from_camera: &Isometry3<f64>) -> DepthImage {
    let cam = camera();
    let mut depth = DepthImage::filled(cam.width(), cam.height(), 0.0);
    for v in 0..cam.height() {
        for u in 0..cam.width() {
            // The ray through the pixel, scaled to unit depth.
            let ray = cam.unproject(&Point2::new(f64::from(u), f64::from(v)), 1.0);
            let origin = world_from_camera.translation.vector;
            let dir = world_from_camera.rotation * ray.coords;
            let nearest = planes
                .iter()
                .filter_map(|p| {
                    let t = (p.offset_m - p.normal.dot(&origin)) / p.normal.dot(&dir);
                    (t.is_finite() && t > 0.0 && t < 8.0).then_some(t)
                })
                .fold(f64::INFINITY, f64::min);
            if nearest.is_finite() {
                *depth.get_mut(u, v).unwrap() = nearest as f32;
            }
        }
    }
    depth
}

fn params() -> DepthAlignParams {
    DepthAlignParams {
        min_depth_m: 0.3,
        max_depth_m: 6.0,
        depth_edge_rel: 0.04,
        noise: PrimeSenseModel::default(),
        min_paired_fraction: MIN_PAIRED_FRACTION,
    }
}

/// A room corner ahead of the camera: a floor 1 m below it (y down), a back wall 3 m
/// ahead and a side wall 1.2 m to the right; three normals fix every direction.
fn corner() -> Vec<Plane> {
    vec![
        plane(Vector3::y(), 1.0),
        plane(Vector3::z(), 3.0),
        plane(Vector3::new(1.0, 0.0, 0.2), 1.2),
    ]
}

/// [`align`] of `current` against `keyframe` (at the origin), from the origin.
fn align_from_origin(
    keyframe: &DepthImage,
    current: &DepthImage,
) -> Result<DepthAlignment, DepthAlignError> {
    let view = |depth_m| DepthView {
        depth_m,
        world_from_camera: Isometry3::identity(),
    };
    align(&view(keyframe), &view(current), &camera(), &params())
}

fn moved() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.03, -0.01, 0.05),
        UnitQuaternion::from_euler_angles(0.02, -0.035, 0.01),
    )
}

#[test]
fn a_frame_is_placed_from_a_prediction_centimetres_and_degrees_off() {
    let planes = corner();
    let kf_depth = render(&planes, &Isometry3::identity());
    let truth = moved();
    let cur_depth = render(&planes, &truth);
    // From where the keyframe was: the prediction is 6 cm and 2.4 degrees off.
    let a = align_from_origin(&kf_depth, &cur_depth).unwrap();
    let err = truth.inverse() * a.world_from_cur;
    assert!(
        err.translation.vector.norm() < 1e-3 && err.rotation.angle().to_degrees() < 0.05,
        "error {:?} ({} pairs, rms {}, condition {})",
        err,
        a.pairs,
        a.rms_sigmas,
        a.condition
    );
    assert!(a.rms_sigmas < 0.5, "{}", a.rms_sigmas);
    // Where the views agree, nearly every sample that lands on the keyframe's surface
    // lies on it.
    assert!(
        a.on_surface >= a.pairs && a.pairs as f64 >= 0.95 * a.on_surface as f64,
        "{} of {} on the surface",
        a.pairs,
        a.on_surface
    );
    // The information is symmetric, positive definite and in the world's convention.
    assert!((a.information - a.information.transpose()).norm() < 1e-6 * a.information.norm());
    assert!(a.information.cholesky().is_some());
}

#[test]
fn geometry_that_leaves_a_direction_free_is_refused() {
    // Floor and back wall only: sliding sideways (along both) changes nothing.
    let planes = vec![plane(Vector3::y(), 1.0), plane(Vector3::z(), 3.0)];
    let kf_depth = render(&planes, &Isometry3::identity());
    let cur_depth = render(&planes, &moved());
    let e = align_from_origin(&kf_depth, &cur_depth).unwrap_err();
    assert!(matches!(e, DepthAlignError::Degenerate { .. }), "{e}");
}

#[test]
fn a_frame_that_does_not_overlap_the_keyframe_is_refused() {
    let planes = corner();
    let kf_depth = render(&planes, &Isometry3::identity());
    // Turned 120 degrees away: it sees other walls (none here) than the keyframe did.
    let away = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 2.1, 0.0),
    );
    let cur_depth = render(
        &[plane(Vector3::y(), 1.0), plane(-Vector3::z(), 3.0)],
        &away,
    );
    let e = align_from_origin(&kf_depth, &cur_depth);
    assert!(e.is_err(), "{e:?}");
}

/// The alignment's ray tables give the camera's own unprojection, bit for bit, at every
/// whole pixel (so they change no result, only the time), and with lens distortion and
/// off the image they ask the camera.
#[test]
fn the_ray_tables_unproject_as_the_camera_does() {
    use stride_core::camera::BrownConrady;
    let plain = camera();
    let distorted = camera()
        .with_distortion(BrownConrady::from_array([0.26, -0.95, -0.005, 0.002, 1.16]))
        .unwrap();
    for cam in [plain, distorted] {
        let rays = Rays::new(&cam);
        for v in (0..cam.height() + 2).step_by(7) {
            for u in (0..cam.width() + 2).step_by(5) {
                let depth_m = 0.5 + f64::from(u + v) * 1e-3;
                let expected = cam.unproject(&Point2::new(f64::from(u), f64::from(v)), depth_m);
                assert_eq!(rays.unproject(u, v, depth_m), expected, "pixel ({u}, {v})");
            }
        }
    }
    assert_eq!(Rays::new(&plain).x_by_column.len(), 320);
    assert!(Rays::new(&distorted).x_by_column.is_empty());
}
