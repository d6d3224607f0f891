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
