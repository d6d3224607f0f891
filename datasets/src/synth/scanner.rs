//! A tilted 2-D laser scanner (the Hokuyo URG-04LX of paper 003) simulated in the synthetic
//! world by ray casting, for the terrain mapper of issue 14.
//!
//! Each beam is traced along its axis and along four rays at the edge of its footprint
//! (half-angle [`ScannerSim::footprint_rad`], in and across the scan plane). Where those
//! ranges differ by more than an edge (a beam straddling a depth edge), the return is, with
//! probability [`ScannerSim::mixed_probability`], a *mixed* range: between the two surfaces,
//! or (a fraction [`ScannerSim::beyond_fraction`] of them, the URG's range-intensity
//! coupling) up to 15 cm beyond the far one; otherwise the axis's range. Every range gets
//! the maker's noise (10 mm up to 1 m, 1 % beyond) and the 1 mm resolution; with
//! [`ScannerSim::raw`], ranges are written as raw readings carrying the systematic error
//! that paper 003's eq. 4 corrects. Randomness is a pure function of (seed, scan, beam).

use super::scene::Scene;
use nalgebra::{Isometry3, Rotation3, Unit, Vector3};
use stride_core::range_sensor::UrgSensor;
use stride_core::rng::{hash_normal_fast, hash_uniform, key, mix64};
use stride_core::scan::Scan;

/// A vertical cylinder standing on the floor (the rail run's object).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cylinder {
    /// Axis position x, y (m).
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Radius (m).
    pub radius: f64,
    /// Bottom and top heights (m).
    pub z0: f64,
    /// See `z0`.
    pub z1: f64,
}

impl Cylinder {
    /// First hit of the unit ray `o + t d` with the side or the top, `t <= t_max`.
    pub fn intersect(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> Option<f64> {
        let mut best: Option<f64> = None;
        let (ox, oy) = (o[0] - self.x, o[1] - self.y);
        let a = d[0] * d[0] + d[1] * d[1];
        if a > 1e-12 {
            let b = ox * d[0] + oy * d[1];
            let c = ox * ox + oy * oy - self.radius * self.radius;
            let disc = b * b - a * c;
            if disc >= 0.0 {
                let t = (-b - disc.sqrt()) / a;
                let z = o[2] + t * d[2];
                if t > 1e-9 && t <= t_max && z >= self.z0 && z <= self.z1 {
                    best = Some(t);
                }
            }
        }
        if d[2].abs() > 1e-12 {
            let t = (self.z1 - o[2]) / d[2];
            let (x, y) = (ox + t * d[0], oy + t * d[1]);
            if t > 1e-9 && t <= t_max && x * x + y * y <= self.radius * self.radius {
                best = Some(best.map_or(t, |b: f64| b.min(t)));
            }
        }
        best
    }

    /// Whether `(x, y)` lies under the cylinder.
    pub fn covers(&self, x: f64, y: f64) -> bool {
        (x - self.x).powi(2) + (y - self.y).powi(2) <= self.radius * self.radius
    }
}

/// The simulated scanner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScannerSim {
    /// Beams, angles and range limits.
    pub sensor: UrgSensor,
    /// Half-angle of a beam's footprint (rad): a 6 mm spot at 1 m by default.
    pub footprint_rad: f64,
    /// Probability that a beam straddling a depth edge returns a mixed range.
    pub mixed_probability: f64,
    /// Of the mixed ranges, the share beyond the far surface.
    pub beyond_fraction: f64,
    /// Write raw readings (eq. 4's systematic error added) instead of metric ranges.
    pub raw: bool,
    /// Seed of the noise and of the mixed returns.
    pub seed: u64,
}

impl Default for ScannerSim {
    fn default() -> Self {
        Self {
            sensor: UrgSensor::default(),
            footprint_rad: 0.003,
            mixed_probability: 0.5,
            beyond_fraction: 0.3,
            raw: false,
            seed: 1,
        }
    }
}

/// A depth edge inside a footprint: the ranges differ by more than this (m) plus 5 %.
const EDGE_M: f64 = 0.02;

impl ScannerSim {
    /// The first hit (m) along the unit ray `o + t d`, of the scene and the cylinders.
    pub fn first_hit(
        scene: &Scene,
        cylinders: &[Cylinder],
        o: Vector3<f64>,
        d: Vector3<f64>,
        t_max: f64,
    ) -> Option<f64> {
        Self::trace(scene, cylinders, [o.x, o.y, o.z], d, t_max)
    }

    fn trace(
        scene: &Scene,
        cylinders: &[Cylinder],
        o: [f64; 3],
        d: Vector3<f64>,
        t_max: f64,
    ) -> Option<f64> {
        let d = [d.x, d.y, d.z];
        let mut best = scene.trace_ray(o, d, t_max).map(|h| h.t);
        for c in cylinders {
            if let Some(t) = c.intersect(o, d, best.unwrap_or(t_max)) {
                best = Some(t);
            }
        }
        best
    }

    /// Scan `k` from `world_from_sensor` at time `t_s`.
    pub fn scan(
        &self,
        scene: &Scene,
        cylinders: &[Cylinder],
        world_from_sensor: &Isometry3<f64>,
        t_s: f64,
        k: u64,
    ) -> Scan {
        self.scan_marked(scene, cylinders, world_from_sensor, t_s, k)
            .0
    }

    /// As [`Self::scan`], with the beams whose return is mixed (the truth a filter of mixed
    /// measurements is judged against).
    pub fn scan_marked(
        &self,
        scene: &Scene,
        cylinders: &[Cylinder],
        world_from_sensor: &Isometry3<f64>,
        t_s: f64,
        k: u64,
    ) -> (Scan, Vec<usize>) {
        let s = &self.sensor;
        let o = world_from_sensor.translation.vector;
        let o = [o.x, o.y, o.z];
        let scan_key = key(&[self.seed, k, 0x5CA7]);
        let mut mixed = Vec::new();
        let ranges = (0..s.beams)
            .map(|i| {
                let dir = s.beam_direction(i);
                let r = world_from_sensor.rotation;
                // The footprint: in the scan plane about z, across it about the beam's normal.
                let across = Unit::new_normalize(Vector3::z().cross(&dir));
                let rays = [
                    dir,
                    Rotation3::from_axis_angle(&Vector3::z_axis(), self.footprint_rad) * dir,
                    Rotation3::from_axis_angle(&Vector3::z_axis(), -self.footprint_rad) * dir,
                    Rotation3::from_axis_angle(&across, self.footprint_rad) * dir,
                    Rotation3::from_axis_angle(&across, -self.footprint_rad) * dir,
                ];
                let t_max = s.range_max_m * 1.2;
                let hits: Vec<Option<f64>> = rays
                    .iter()
                    .map(|d| Self::trace(scene, cylinders, o, r * d, t_max))
                    .collect();
                let bk = mix64(scan_key ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                let axis = hits.first().copied().flatten();
                let found: Vec<f64> = hits.iter().flatten().copied().collect();
                let (near, far) = found
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(a, b), &t| (a.min(t), b.max(t)));
                let straddles = found.len() < hits.len() || far - near > EDGE_M + 0.05 * near;
                let mut range = axis;
                let is_mixed =
                    straddles && !found.is_empty() && hash_uniform(bk ^ 1) < self.mixed_probability;
                if is_mixed {
                    let far = if found.len() < hits.len() {
                        s.range_max_m
                    } else {
                        far
                    };
                    range = Some(if hash_uniform(bk ^ 2) < self.beyond_fraction {
                        far + 0.15 * hash_uniform(bk ^ 3)
                    } else {
                        near + (far - near) * (0.1 + 0.8 * hash_uniform(bk ^ 3))
                    });
                }
                let Some(true_m) = range else {
                    return f64::NAN;
                };
                if is_mixed {
                    mixed.push(i);
                }
                let noisy = true_m + UrgSensor::range_sigma_m(true_m) * hash_normal_fast(bk ^ 4);
                if !(s.range_min_m..=s.range_max_m).contains(&noisy) {
                    return f64::NAN;
                }
                let mm = if self.raw {
                    match UrgSensor::raw_for_mm(noisy * 1000.0) {
                        Some(raw) => raw,
                        None => return f64::NAN,
                    }
                } else {
                    noisy * 1000.0
                };
                mm.round() / 1000.0
            })
            .collect::<Vec<f64>>();
        // A mixed return that fell out of range is no return.
        mixed.retain(|&i| ranges.get(i).is_some_and(|r| r.is_finite()));
        let scan = Scan {
            t_s,
            world_from_sensor: *world_from_sensor,
            angle_min_rad: s.angle_min_rad,
            angle_increment_rad: s.angle_increment_rad,
            ranges,
        };
        (scan, mixed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::terrain::HeightField;
    use nalgebra::UnitQuaternion;
    use stride_core::grid::{Grid, GridGeometry};

    fn flat_scene() -> Scene {
        let g = GridGeometry::covering(-1.0, -1.0, 3.0, 1.0, 0.02);
        Scene {
            terrain: HeightField::new(Grid::filled(g, 0.0)),
            boxes: Vec::new(),
            texture_seed: 1,
        }
    }

    #[test]
    fn a_flat_floor_is_scanned_at_the_right_ranges_and_a_cylinder_in_front() {
        let scene = flat_scene();
        let pose = Isometry3::from_parts(
            Vector3::new(0.0, 0.0, 0.26).into(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 35f64.to_radians()),
        );
        let sim = ScannerSim {
            mixed_probability: 0.0,
            ..ScannerSim::default()
        };
        let s = sim.scan(&scene, &[], &pose, 0.0, 0);
        let centre = s.ranges[341];
        let want = 0.26 / 35f64.to_radians().sin();
        assert!((centre - want).abs() < 0.04, "{centre} vs {want}");
        // Beams above the horizon see nothing.
        assert!(s.ranges[0].is_nan());
        // A cylinder in the central beam's way returns its side.
        let c = Cylinder {
            x: 0.25,
            y: 0.0,
            radius: 0.05,
            z0: 0.0,
            z1: 0.3,
        };
        let s2 = sim.scan(&scene, &[c], &pose, 0.0, 0);
        assert!(
            s2.ranges[341] < centre - 0.1,
            "{} vs {centre}",
            s2.ranges[341]
        );
        assert!(c.covers(0.25, 0.04) && !c.covers(0.25, 0.06));
        // Deterministic, and raw readings lie below the metric ones (eq. 4 adds).
        let bits = |s: &Scan| s.ranges.iter().map(|r| r.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&sim.scan(&scene, &[c], &pose, 0.0, 0)), bits(&s2));
        let raw = ScannerSim { raw: true, ..sim }.scan(&scene, &[], &pose, 0.0, 0);
        assert!(raw.ranges[341] < centre - 0.1);
    }
}

/// Paper 003's mounting on Messor: 0.26 m above the ground, tilted down 35 degrees.
pub const MESSOR_HEIGHT_M: f64 = 0.26;
/// See [`MESSOR_HEIGHT_M`].
pub const MESSOR_TILT_RAD: f64 = 35.0 * std::f64::consts::PI / 180.0;

/// `world_from_sensor` of a scanner at height `height_m` above `(x, y)`, looking along +x
/// tilted down by `tilt_rad`.
pub fn tilted_pose(x: f64, y: f64, height_m: f64, tilt_rad: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Vector3::new(x, y, height_m).into(),
        nalgebra::UnitQuaternion::from_axis_angle(&Vector3::y_axis(), tilt_rad),
    )
}

/// One object of the rail run, with its true size (m).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RailObject {
    /// Its name in reports.
    pub name: &'static str,
    /// Centre x, y (m).
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Extent along x (m; a cylinder's diameter).
    pub length_m: f64,
    /// Extent along y (m).
    pub width_m: f64,
    /// Height (m).
    pub height_m: f64,
}

/// The rail run of paper 003, section 6.1: a cart carrying the scanner moves along +x in
/// 10 mm steps over a flat floor with two boxes and a cylinder (sizes of the order of the
/// paper's Table 1).
pub struct RailRun {
    /// The scene (floor and boxes).
    pub scene: Scene,
    /// The cylinder.
    pub cylinders: Vec<Cylinder>,
    /// The objects' true sizes.
    pub objects: Vec<RailObject>,
}

impl RailRun {
    /// The scene.
    pub fn new() -> Self {
        use super::scene::SceneBox;
        use super::texture::Material;
        let g = stride_core::grid::GridGeometry::covering(-0.5, -1.0, 2.5, 1.0, 0.01);
        let terrain = super::terrain::HeightField::new(stride_core::grid::Grid::filled(g, 0.0));
        let objects = vec![
            RailObject {
                name: "box A",
                x: 0.9,
                y: 0.0,
                length_m: 0.154,
                width_m: 0.115,
                height_m: 0.103,
            },
            RailObject {
                name: "box B",
                x: 1.2,
                y: 0.16,
                length_m: 0.10,
                width_m: 0.12,
                height_m: 0.078,
            },
            RailObject {
                name: "cylinder",
                x: 1.25,
                y: -0.15,
                length_m: 0.08,
                width_m: 0.08,
                height_m: 0.12,
            },
        ];
        let boxes = objects
            .iter()
            .take(2)
            .enumerate()
            .map(|(i, o)| {
                SceneBox::new(
                    o.x,
                    o.y,
                    0.0,
                    o.height_m,
                    o.length_m / 2.0,
                    o.width_m / 2.0,
                    0.0,
                    Material::Object(i as u32),
                )
            })
            .collect();
        let cylinders = objects
            .iter()
            .skip(2)
            .map(|o| Cylinder {
                x: o.x,
                y: o.y,
                radius: o.length_m / 2.0,
                z0: 0.0,
                z1: o.height_m,
            })
            .collect();
        Self {
            scene: Scene {
                terrain,
                boxes,
                texture_seed: 1,
            },
            cylinders,
            objects,
        }
    }

    /// The scans, each with its mixed beams: the cart from x = 0 to 1.6 m in 10 mm steps
    /// (161 scans, 10 Hz).
    pub fn scans(&self, sim: &ScannerSim) -> Vec<(Scan, Vec<usize>)> {
        (0..=160)
            .map(|k| {
                let pose = tilted_pose(0.01 * k as f64, 0.0, MESSOR_HEIGHT_M, MESSOR_TILT_RAD);
                sim.scan_marked(
                    &self.scene,
                    &self.cylinders,
                    &pose,
                    0.1 * k as f64,
                    k as u64,
                )
            })
            .collect()
    }

    /// The scans of the laser-stripe camera on the same rail (Ragno's mounting: 0.174 m up,
    /// tilted 10 degrees), from x = 0.3 to 1.6 m in 10 mm steps, so that the sheet sweeps
    /// the objects as the scanner's beams do.
    pub fn stripe_scans(&self, sim: &super::stripe::StripeSim) -> Vec<Scan> {
        (0..=130)
            .map(|k| {
                let x = 0.3 + 0.01 * k as f64;
                let pose = super::stripe::stripe_camera_pose(
                    x,
                    0.0,
                    super::stripe::RAGNO_CAMERA_HEIGHT_M,
                    super::stripe::RAGNO_TILT_RAD,
                );
                sim.scan(
                    &self.scene,
                    &self.cylinders,
                    &pose,
                    0.1 * k as f64,
                    k as u64,
                )
            })
            .collect()
    }

    /// The true elevation (floor 0, the objects' tops), 5 mm cells over the run's area.
    pub fn truth(&self) -> stride_core::grid::Grid<f32> {
        let g = stride_core::grid::GridGeometry::covering(0.2, -0.6, 1.8, 0.6, 0.005);
        let mut grid = stride_core::grid::Grid::filled(g, 0.0f32);
        for r in 0..g.rows {
            for c in 0..g.cols {
                let (x, y) = g.center(r, c);
                let top = self
                    .objects
                    .iter()
                    .filter(|o| {
                        if o.name == "cylinder" {
                            (x - o.x).hypot(y - o.y) <= o.length_m / 2.0
                        } else {
                            (x - o.x).abs() <= o.length_m / 2.0
                                && (y - o.y).abs() <= o.width_m / 2.0
                        }
                    })
                    .map(|o| o.height_m)
                    .fold(0.0, f64::max);
                if let Some(v) = grid.get_mut(r, c) {
                    *v = top as f32;
                }
            }
        }
        grid
    }
}

impl Default for RailRun {
    fn default() -> Self {
        Self::new()
    }
}

/// Scans of a scanner mounted on the synthetic robot's trunk (`trunk_from_sensor`: 0.15 m
/// ahead of the trunk's origin, 0.1 m above, tilted down `tilt_rad`), `rate_hz` scans a
/// second for `duration_s`, each with its mixed beams.
pub fn walk_scans(
    synth: &super::Synth,
    sim: &ScannerSim,
    tilt_rad: f64,
    rate_hz: f64,
    duration_s: f64,
) -> Vec<(Scan, Vec<usize>)> {
    let trunk_from_sensor = tilted_pose(0.15, 0.0, 0.1, tilt_rad);
    let n = (duration_s * rate_hz).floor() as usize;
    (0..n)
        .map(|k| {
            let t = k as f64 / rate_hz;
            let pose = synth.state(t).world_from_trunk * trunk_from_sensor;
            sim.scan_marked(synth.scene(), &[], &pose, t, k as u64)
        })
        .collect()
}
