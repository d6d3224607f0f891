//! Aligning a sensor frame to the map before it is integrated: the height offset and the
//! tilt (rotation about the two horizontal axes through the sensor) that best lay the
//! frame's points on the map's established cells.
//!
//! Why: an elevation map is most sensitive to the pose's errors that a height field can
//! see. A SLAM whose orientation is off by 0.4 degrees places floor points 2 m away 1.4 cm
//! too high or too low, and a map fused from such views is rough where the surface is
//! flat. Those three degrees of freedom (z, roll, pitch) are exactly the ones the map
//! itself measures well, so each view is laid onto the map built so far, as a scan is
//! registered to a map. x, y and yaw are left to the SLAM (a height field constrains them
//! only at relief).
//!
//! The solve is weighted least squares on the height residuals `h_cell - z_point`, with
//! weights `1 / (var_cell + var_point)` (the point's height variance from the sensor
//! model, as the map uses it) and a Huber loss; points more than
//! [`AlignConfig::outlier_m`] off (step edges, objects not yet in the map, flying pixels)
//! are left out. Linearised about the current pose, a rotation `w = (wx, wy, 0)` about the
//! sensor's position `c` moves a point `p` up by `wx (p_y - c_y) - wy (p_x - c_x)`; the
//! solve is repeated [`AlignConfig::iterations`] times with the exact rigid correction.

use crate::input::{Cloud, DepthPixel, HeightModel, SensorFrame};
use crate::stack::StackMapper;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use stride_core::robust::huber_weight;

/// Parameters of the alignment of a frame to the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlignConfig {
    /// Every this many pixels of every this many rows of a depth image (or every this many
    /// points of a cloud) are used (1: all).
    pub stride: usize,
    /// Fewest points on established cells for a solve.
    pub min_points: usize,
    /// Only measurements nearer than this (m, along the optical axis) are used: the depth
    /// of a structured-light sensor is least biased near it.
    pub max_depth_m: f64,
    /// A point farther than this from its cell's height is left out (m).
    pub outlier_m: f64,
    /// Huber threshold, in standard deviations of the residual.
    pub huber_sigmas: f64,
    /// Linearise-and-solve rounds.
    pub iterations: usize,
    /// Fraction of the correction found that is applied (0 to 1).
    pub gain: f64,
    /// A correction that shifts by more than this (m) ...
    pub max_shift_m: f64,
    /// ... or tilts by more than this (rad) is refused (the frame is integrated unaligned).
    pub max_tilt_rad: f64,
}

impl Default for AlignConfig {
    /// A 320 x 240 view sampled every 3rd pixel of every 3rd row (about 8,500 points), 3
    /// rounds, points 5 cm off left out, 0.7 of a correction applied, corrections up to
    /// 5 cm and 2 degrees.
    fn default() -> Self {
        Self {
            stride: 3,
            min_points: 1000,
            max_depth_m: 4.5,
            outlier_m: 0.05,
            huber_sigmas: 2.0,
            iterations: 3,
            gain: 0.7,
            max_shift_m: 0.05,
            max_tilt_rad: 2f64.to_radians(),
        }
    }
}

impl AlignConfig {
    /// Checks every value; the error names the field.
    pub fn validate(&self) -> Result<(), crate::MappingError> {
        let bad = |name: &'static str, value: f64, reason: &'static str| {
            Err(crate::MappingError::Parameter {
                name,
                value,
                reason,
            })
        };
        if !(1..=64).contains(&self.stride) {
            return bad("stride", self.stride as f64, "must be 1 to 64");
        }
        if self.min_points < 3 {
            return bad("min_points", self.min_points as f64, "must be 3 or more");
        }
        if !(1..=20).contains(&self.iterations) {
            return bad("iterations", self.iterations as f64, "must be 1 to 20");
        }
        if !(0.0..=1.0).contains(&self.gain) {
            return bad("gain", self.gain, "must be 0 to 1");
        }
        for (name, v) in [
            ("max_depth_m", self.max_depth_m),
            ("outlier_m", self.outlier_m),
            ("huber_sigmas", self.huber_sigmas),
            ("max_shift_m", self.max_shift_m),
            ("max_tilt_rad", self.max_tilt_rad),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, v, "must be positive and finite");
            }
        }
        Ok(())
    }
}

/// A correction found by [`StackMapper::align`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// `corrected_from_map`: applied on the left of `map_from_sensor`.
    pub correction: Isometry3<f64>,
    /// Its vertical shift at the sensor (m).
    pub shift_m: f64,
    /// Its tilt (rad).
    pub tilt_rad: f64,
    /// Points on established cells within [`AlignConfig::outlier_m`] at the correction
    /// applied.
    pub points: usize,
    /// Weighted RMS of the height residuals before and after the correction applied (m).
    pub rms_before_m: f64,
    /// See `rms_before_m`.
    pub rms_after_m: f64,
}

/// What [`StackMapper::align`] found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlignOutcome {
    /// A correction within the limits.
    Aligned(Alignment),
    /// Fewer than [`AlignConfig::min_points`] points on established cells (the number
    /// found): nothing to align to yet.
    TooFewPoints(usize),
    /// A correction beyond [`AlignConfig::max_shift_m`] or [`AlignConfig::max_tilt_rad`].
    TooLarge(Alignment),
    /// Enough points, but they do not fix a tilt (all on one line): the normal equations
    /// are singular.
    Degenerate,
}

/// One point of a frame for the solve: its map-frame position at the frame's pose (m) and
/// its height variance (m²).
struct Sample {
    p_map: Point3<f64>,
    var_m2: f64,
}

impl StackMapper {
    /// The correction that lays `frame` on the map's established cells (see the module
    /// documentation). The map is not changed (only the ray table the update shares is
    /// brought up to date for the frame's camera).
    pub fn align(&mut self, frame: &SensorFrame<'_>, cfg: &AlignConfig) -> AlignOutcome {
        if let Cloud::Depth { camera, .. } = frame.cloud() {
            self.prepare_rays(camera);
        }
        self.align_prepared(frame, cfg)
    }

    /// [`StackMapper::align`] of each frame, against the map as it is (none is integrated),
    /// the frames spread over the threads.
    pub fn align_each(
        &mut self,
        frames: &[SensorFrame<'_>],
        cfg: &AlignConfig,
    ) -> Vec<AlignOutcome> {
        let camera = frames.iter().find_map(|f| match f.cloud() {
            Cloud::Depth { camera, .. } => Some(camera),
            Cloud::Points { .. } => None,
        });
        if let Some(camera) = camera {
            self.prepare_rays(camera);
        }
        let mapper = &*self;
        frames
            .par_iter()
            .map(|f| mapper.align_prepared(f, cfg))
            .collect()
    }

    /// [`StackMapper::align`] once the ray table is prepared (a frame of another camera
    /// builds its own).
    fn align_prepared(&self, frame: &SensorFrame<'_>, cfg: &AlignConfig) -> AlignOutcome {
        let samples = samples(self, frame, cfg);
        let centre = frame.map_from_sensor.translation.vector;
        let mut correction = Isometry3::identity();
        let mut rms_before = f64::NAN;
        let mut last = (0, f64::NAN);
        for round in 0..cfg.iterations {
            let Some(step) = solve(self, &samples, &correction, &centre, cfg) else {
                return AlignOutcome::Degenerate;
            };
            if step.points < cfg.min_points {
                return AlignOutcome::TooFewPoints(step.points);
            }
            if round == 0 {
                rms_before = step.rms_m;
            }
            let [dz, wx, wy] = step.delta;
            // About the sensor's position as corrected so far (as `solve` linearised).
            let c = (correction * Point3::from(centre)).coords;
            let rot = UnitQuaternion::from_scaled_axis(Vector3::new(wx, wy, 0.0));
            let about_c =
                Translation3::from(c + Vector3::new(0.0, 0.0, dz)) * rot * Translation3::from(-c);
            correction = about_c * correction;
            last = (step.points, step.rms_m);
        }
        // Only `gain` of it is applied: the rest is left to the SLAM.
        let c = Point3::from(centre);
        let dz = (correction * c).z - c.z;
        let rot = UnitQuaternion::identity().slerp(&correction.rotation, cfg.gain);
        correction = Translation3::from(c.coords + Vector3::new(0.0, 0.0, cfg.gain * dz))
            * rot
            * Translation3::from(-c.coords);
        // The residual after the last update, for the report.
        let after = solve(self, &samples, &correction, &centre, cfg);
        let moved = correction * Point3::from(centre);
        let a = Alignment {
            correction,
            shift_m: moved.z - centre.z,
            tilt_rad: (correction.rotation * Vector3::z()).angle(&Vector3::z()),
            points: after.as_ref().map_or(last.0, |s| s.points),
            rms_before_m: rms_before,
            rms_after_m: after.map_or(last.1, |s| s.rms_m),
        };
        if a.shift_m.abs() > cfg.max_shift_m || a.tilt_rad > cfg.max_tilt_rad {
            AlignOutcome::TooLarge(a)
        } else {
            AlignOutcome::Aligned(a)
        }
    }
}

/// The frame's usable points in the map frame at its pose, every `stride`-th one.
fn samples(mapper: &StackMapper, frame: &SensorFrame<'_>, cfg: &AlignConfig) -> Vec<Sample> {
    let stride = cfg.stride;
    let pose = frame.map_from_sensor;
    let r3 = pose.rotation.inverse() * Vector3::z();
    let mut out = Vec::new();
    match frame.cloud() {
        Cloud::Depth { depth_m, camera } => {
            let (prepared, sensor) = mapper.prepared_rays(camera);
            let mut own = crate::input::RayCache::default();
            let rays = match prepared {
                Some(r) => r,
                None => own.rays(camera),
            };
            let (lo, hi) = sensor.range_m();
            let hi = hi.min(cfg.max_depth_m);
            let mut row = Vec::new();
            // A steep face's pixels are left out: the map holds them behind the face
            // (`crate::steep`), the view as measured, and neither is the height of the
            // cell they land in.
            let steep = (mapper.config().steep_push_sigmas > 0.0)
                .then(|| crate::steep::SteepTest::new(camera, &r3));
            for v in (0..depth_m.height()).step_by(stride) {
                rays.row(v as usize, depth_m.width() as usize, &mut row);
                for u in (0..depth_m.width()).step_by(stride) {
                    let Some(d) = depth_m.get(u, v).map(f64::from) else {
                        continue;
                    };
                    let Some(&(xn, yn)) = row.get(u as usize) else {
                        continue;
                    };
                    if !(d >= lo && d <= hi)
                        || steep
                            .as_ref()
                            .is_some_and(|t| t.at(depth_m, u as usize, v as usize))
                    {
                        continue;
                    }
                    let px = DepthPixel {
                        u: f64::from(u),
                        v: f64::from(v),
                        xn,
                        yn,
                        d_m: d,
                    };
                    out.push(Sample {
                        p_map: pose * Point3::new(xn * d, yn * d, d),
                        var_m2: sensor.pixel_variance(camera, &px, &r3),
                    });
                }
            }
        }
        Cloud::Points {
            points,
            covariances,
        } => {
            let sensor = &mapper.config().sensor;
            let (lo, hi) = sensor.range_m();
            let hi = hi.min(cfg.max_depth_m);
            for (p, cov) in points.iter().zip(covariances).step_by(stride) {
                if !(p.z >= lo && p.z <= hi) {
                    continue;
                }
                let cov: &Matrix3<f64> = cov;
                out.push(Sample {
                    p_map: pose * p,
                    var_m2: sensor.point_variance(p, cov, &r3),
                });
            }
        }
    }
    out.retain(|s| s.p_map.coords.iter().all(|v| v.is_finite()) && s.var_m2 > 0.0);
    out
}

/// One round's solution: the update `[dz, wx, wy]`, the points used and their weighted RMS
/// residual (m) at the correction given.
struct Step {
    delta: [f64; 3],
    points: usize,
    rms_m: f64,
}

/// One Gauss-Newton round about `correction`; `None` when the normal equations are singular.
fn solve(
    mapper: &StackMapper,
    samples: &[Sample],
    correction: &Isometry3<f64>,
    centre: &Vector3<f64>,
    cfg: &AlignConfig,
) -> Option<Step> {
    let c = correction * Point3::from(*centre);
    let (mut ata, mut atb) = (Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
    let (mut n, mut swr2, mut sw) = (0usize, 0.0, 0.0);
    for s in samples {
        let p = correction * s.p_map;
        let Some((h, var_cell)) = mapper.established_height(p.x, p.y) else {
            continue;
        };
        let r = f64::from(h) - p.z;
        if r.abs() > cfg.outlier_m {
            continue;
        }
        let var = s.var_m2 + f64::from(var_cell);
        // Huber: full weight within huber_sigmas standard deviations, then falling as 1/|r|.
        let w = huber_weight(r * r / var, Some(cfg.huber_sigmas * cfg.huber_sigmas)) / var;
        let j = Vector3::new(1.0, p.y - c.y, -(p.x - c.x));
        ata += w * j * j.transpose();
        atb += w * r * j;
        n += 1;
        swr2 += w * r * r;
        sw += w;
    }
    if n < 3 {
        return Some(Step {
            delta: [0.0; 3],
            points: n,
            rms_m: f64::NAN,
        });
    }
    let x = ata.cholesky()?.solve(&atb);
    Some(Step {
        delta: [x.x, x.y, x.z],
        points: n,
        rms_m: (swr2 / sw).sqrt(),
    })
}

#[cfg(test)]
#[path = "align_tests.rs"]
mod tests;
