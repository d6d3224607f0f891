//! The structured-light stripe sensor of paper 003 (a camera and a laser-sheet emitter,
//! section 3.1) simulated in the synthetic world, its returns written as scans in the light
//! plane.
//!
//! The emitter's sheet is traced as a fan of rays in the light plane; a lit point the
//! camera sees (nothing between them) is projected into the image, its stripe row gets the
//! detector's noise, and eq. 1 turns the pixel back into the measured point, exactly as the
//! real sensor measures. Each measured point becomes a return of a scan whose frame is the
//! light plane's: origin at the emitter, x along the sheet's central direction, y along the
//! camera's x axis, so that the scan log and the map take stripe data as they take a
//! scanner's (beams binned by their measured angle, `beams` of them across the fan).

use super::scanner::Cylinder;
use super::scene::Scene;
use nalgebra::{Isometry3, Matrix3, Rotation3, UnitQuaternion, Vector3};
use stride_core::range_sensor::StripeSensor;
use stride_core::rng::{hash_normal_fast, key, mix64};
use stride_core::scan::Scan;

/// The simulated stripe sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StripeSim {
    /// The sensor (eq. 1's parameters).
    pub sensor: StripeSensor,
    /// Standard deviation of the stripe's detected row (px).
    pub row_sigma_px: f64,
    /// Rays of the sheet's fan, and beams of the written scans.
    pub beams: usize,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for StripeSim {
    /// Paper 003's Ragno prototype: b = 120 mm, beta = 45 degrees, tau_c = 28.14 degrees,
    /// gamma_c = 38.8 degrees, a VGA image; the stripe row found to 0.5 px.
    fn default() -> Self {
        Self {
            sensor: StripeSensor::ragno(),
            row_sigma_px: 0.5,
            beams: 320,
            seed: 1,
        }
    }
}

/// Paper 003's Ragno: the camera 17.4 cm above the ground.
pub const RAGNO_CAMERA_HEIGHT_M: f64 = 0.174;
/// Paper 003's Ragno: the sensor tilted down by 10 degrees.
pub const RAGNO_TILT_RAD: f64 = 10.0 * std::f64::consts::PI / 180.0;

/// `world_from_camera` (paper 003's camera axes: x lateral, y towards the camera from the
/// emitter, i.e. down, z the optical axis) of a camera at `(x, y, height_m)` looking along
/// +x, pitched down by `tilt_rad`.
pub fn stripe_camera_pose(x: f64, y: f64, height_m: f64, tilt_rad: f64) -> Isometry3<f64> {
    // Camera axes in the world before the tilt: x_c -> -y, y_c -> -z, z_c -> +x.
    let base = Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, 1.0, //
        -1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0,
    ));
    let tilt = Rotation3::from_axis_angle(&Vector3::y_axis(), tilt_rad);
    Isometry3::from_parts(
        Vector3::new(x, y, height_m).into(),
        UnitQuaternion::from_rotation_matrix(&(tilt * base)),
    )
}

impl StripeSim {
    /// Scan `k` of the camera at `world_from_camera`, at time `t_s`.
    pub fn scan(
        &self,
        scene: &Scene,
        cylinders: &[Cylinder],
        world_from_camera: &Isometry3<f64>,
        t_s: f64,
        k: u64,
    ) -> Scan {
        let s = &self.sensor;
        let plane = s.camera_from_plane();
        let world_from_plane = world_from_camera * plane;
        let fan = s.gamma_c_rad * 1.2;
        let n = self.beams.max(2);
        let inc = 2.0 * fan / (n - 1) as f64;
        let mut ranges = vec![f64::NAN; n];
        let emitter = world_from_plane.translation.vector;
        let camera = world_from_camera.translation.vector;
        let scan_key = key(&[self.seed, k, 0x57A1]);
        let trace = |o: Vector3<f64>, d: Vector3<f64>, t_max: f64| {
            super::scanner::ScannerSim::first_hit(scene, cylinders, o, d, t_max)
        };
        // Several rays per beam, so that every beam's bin receives a measured point.
        let rays = n * 3;
        for j in 0..rays {
            let phi = -fan + 2.0 * fan * j as f64 / (rays - 1) as f64;
            let d = world_from_plane.rotation * Vector3::new(phi.cos(), phi.sin(), 0.0);
            let Some(t) = trace(emitter, d, 2.0) else {
                continue;
            };
            let lit = emitter + d * t;
            // Visible from the camera: nothing in between.
            let to = lit - camera;
            let dist = to.norm();
            if trace(camera, to / dist, dist + 0.01).is_none_or(|h| h < dist - 0.002) {
                continue;
            }
            let p_c = world_from_camera.rotation.inverse() * to;
            if p_c.z <= 1e-6 {
                continue;
            }
            let Some((u, v)) = s.pixel_of(&p_c.into()) else {
                continue;
            };
            if !(0.0..s.cols_px).contains(&u) || !(0.0..s.rows_px).contains(&v) {
                continue;
            }
            let noise = hash_normal_fast(mix64(
                scan_key ^ (j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            ));
            let Some(measured) = s.point(u, v + self.row_sigma_px * noise) else {
                continue;
            };
            let p = plane.inverse() * measured;
            let angle = p.y.atan2(p.x);
            let bin = ((angle + fan) / inc).round();
            if bin < 0.0 || bin >= n as f64 {
                continue;
            }
            if let Some(r) = ranges.get_mut(bin as usize) {
                let range = p.x.hypot(p.y);
                if r.is_nan() || range < *r {
                    *r = range;
                }
            }
        }
        Scan {
            t_s,
            world_from_sensor: world_from_plane,
            angle_min_rad: -fan,
            angle_increment_rad: inc,
            ranges,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::terrain::HeightField;
    use stride_core::grid::{Grid, GridGeometry};

    #[test]
    fn the_stripe_measures_the_floor_where_the_light_plane_meets_it() {
        let g = GridGeometry::covering(-1.0, -1.0, 2.0, 1.0, 0.01);
        let scene = Scene {
            terrain: HeightField::new(Grid::filled(g, 0.0)),
            boxes: Vec::new(),
            texture_seed: 1,
        };
        let sim = StripeSim {
            row_sigma_px: 0.0,
            ..StripeSim::default()
        };
        let pose = stripe_camera_pose(0.0, 0.0, RAGNO_CAMERA_HEIGHT_M, RAGNO_TILT_RAD);
        let scan = sim.scan(&scene, &[], &pose, 0.0, 0);
        let points: Vec<_> = (0..scan.ranges.len())
            .filter_map(|i| scan.p_world(i))
            .collect();
        assert!(points.len() > 100, "{} returns", points.len());
        // Noise-free: every point on the floor (the bins' angles move points by < 1 mm).
        assert!(
            points.iter().all(|p| p.z.abs() < 0.002),
            "{:?}",
            points.iter().map(|p| p.z).fold(0.0, f64::max)
        );
        // The sheet meets the floor ahead of the camera: the emitter is 0.12 m above it,
        // the sheet 10 + 45 degrees below the horizon.
        let ahead =
            (RAGNO_CAMERA_HEIGHT_M + 0.12 * RAGNO_TILT_RAD.cos()) / 55f64.to_radians().tan();
        let central = points.iter().map(|p| p.x).fold(f64::MAX, f64::min);
        assert!((central - ahead).abs() < 0.03, "{central} vs {ahead}");
    }
}
