//! The walking robot: a hexapod trunk following a path with a tripod or crawl (wave) gait.
//!
//! Frames: world (z up, origin at the start, x along the initial heading), trunk (x forward,
//! y left, z up), camera (x right, y down, z forward). The camera pose at any time is
//! `world_from_trunk(t) * trunk_from_camera`.
//!
//! The gait shapes the trunk's motion as paper 004 describes for Messor II: trunk heave,
//! pitch and roll oscillating at the gait frequency, velocity ripple at the step frequency,
//! and a damped vibration after each foot touchdown. A tripod gait (3 legs in stance, fast)
//! shakes much more than a crawl (wave) gait, which keeps five of six legs down. Amplitudes
//! grow with speed. The trunk also follows the terrain: its height and attitude come from a
//! plane through the terrain under its six feet.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::{PI, TAU};

/// The gait pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Gait {
    /// Two alternating tripods; 3 legs in stance (6 briefly at each switch). Fast, shaky.
    Tripod,
    /// Wave gait: one leg swings at a time; 5 legs in stance (6 briefly). Slow, smooth.
    Crawl,
}

/// The path the trunk follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PathKind {
    /// Straight ahead along +x.
    Straight,
    /// A square loop, counter-clockwise, turning on the spot at each corner (as the Messor II
    /// runs of paper 004, where ORB-SLAM2 lost track in the turns).
    Square,
    /// Turning on the spot, counter-clockwise.
    Turn,
}

/// How the robot moves.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MotionConfig {
    /// Gait pattern.
    pub gait: Gait,
    /// Commanded walking speed (m/s); turning on the spot uses `speed / TURN_RADIUS_M` rad/s.
    pub speed_m_s: f64,
    /// Path shape.
    pub path: PathKind,
    /// Side of the square path (m).
    pub square_side_m: f64,
    /// Height of the camera above the ground under the trunk (m).
    pub camera_height_m: f64,
    /// Downward tilt of the camera's optical axis from the horizontal (degrees).
    pub camera_tilt_deg: f64,
    /// Multiplies every gait-induced oscillation (1 = defaults after Messor II).
    pub shake: f64,
    /// Step-to-step variation of the touchdown vibrations: each touchdown's amplitude is
    /// scaled by a random factor in `[1 - v, 1 + v]` (real steps are not identical).
    pub variation: f64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        Self {
            gait: Gait::Tripod,
            speed_m_s: 0.1,
            path: PathKind::Straight,
            square_side_m: 1.5,
            camera_height_m: 0.4,
            camera_tilt_deg: 25.0,
            shake: 1.0,
            variation: 0.5,
        }
    }
}

/// Equivalent radius for turning on the spot (m): the feet's arc speed matches `speed`.
pub const TURN_RADIUS_M: f64 = 0.25;

/// Half length and half width of the foot polygon (m): feet at (±L, ±W) and (0, ±W).
const FOOT_HALF_LENGTH_M: f64 = 0.18;
const FOOT_HALF_WIDTH_M: f64 = 0.16;
/// Camera mount: ahead of and above the trunk centre (m).
const CAMERA_FORWARD_M: f64 = 0.15;
const CAMERA_ABOVE_TRUNK_M: f64 = 0.1;

/// The trunk state at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrunkState {
    /// `world_from_trunk` (metres).
    pub world_from_trunk: Isometry3<f64>,
    /// `world_from_camera` (metres).
    pub world_from_camera: Isometry3<f64>,
    /// Gait phase in `[0, 1)`.
    pub gait_phase: f64,
    /// Legs on the ground (3 or 6 for tripod, 5 or 6 for crawl).
    pub stance_legs: u8,
}

struct GaitParams {
    /// Distance the trunk advances per gait cycle (m).
    cycle_length_m: f64,
    /// Touchdown phases within a cycle and their swing start phases.
    touchdowns: &'static [f64],
    /// Step events per cycle (heave frequency multiplier).
    steps_per_cycle: f64,
    heave_m: f64,
    roll_rad: f64,
    pitch_rad: f64,
    yaw_rad: f64,
    ripple: f64,
    impact_rad: f64,
    impact_heave_m: f64,
    swing_fraction: f64,
}

fn params(g: Gait) -> GaitParams {
    match g {
        Gait::Tripod => GaitParams {
            cycle_length_m: 0.16,
            touchdowns: &[0.45, 0.95],
            steps_per_cycle: 2.0,
            heave_m: 0.006,
            roll_rad: 1.6f64.to_radians(),
            pitch_rad: 1.2f64.to_radians(),
            yaw_rad: 0.8f64.to_radians(),
            ripple: 0.25,
            impact_rad: 0.7f64.to_radians(),
            impact_heave_m: 0.003,
            swing_fraction: 0.45,
        },
        Gait::Crawl => GaitParams {
            cycle_length_m: 0.12,
            touchdowns: &[
                0.15,
                0.15 + 1.0 / 6.0,
                0.15 + 2.0 / 6.0,
                0.15 + 3.0 / 6.0,
                0.15 + 4.0 / 6.0,
                0.15 + 5.0 / 6.0,
            ],
            steps_per_cycle: 6.0,
            heave_m: 0.0015,
            roll_rad: 0.35f64.to_radians(),
            pitch_rad: 0.25f64.to_radians(),
            yaw_rad: 0.15f64.to_radians(),
            ripple: 0.06,
            impact_rad: 0.08f64.to_radians(),
            impact_heave_m: 0.0004,
            swing_fraction: 0.15,
        },
    }
}

/// Reference speed at which amplitudes are the nominal ones (Messor II's fast tripod, m/s).
const REFERENCE_SPEED_M_S: f64 = 0.15;

/// The robot's motion over time.
pub struct Motion {
    config: MotionConfig,
    seed: u64,
    p: GaitParams,
    trunk_from_camera: Isometry3<f64>,
    cycle_hz: f64,
}

impl Motion {
    /// The motion for a configuration (step variation drawn with seed 0).
    pub fn new(config: MotionConfig) -> Self {
        Self::with_seed(config, 0)
    }

    /// The motion for a configuration, with the step-to-step variation drawn from `seed`.
    pub fn with_seed(config: MotionConfig, seed: u64) -> Self {
        let p = params(config.gait);
        let tilt = config.camera_tilt_deg.to_radians();
        let (s, c) = tilt.sin_cos();
        // Columns: camera x (right), y (down), z (forward, tilted down) in the trunk frame.
        let r = Matrix3::from_columns(&[
            Vector3::new(0.0, -1.0, 0.0),
            Vector3::new(-s, 0.0, -c),
            Vector3::new(c, 0.0, -s),
        ]);
        let trunk_from_camera = Isometry3::from_parts(
            Translation3::new(CAMERA_FORWARD_M, 0.0, CAMERA_ABOVE_TRUNK_M),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
        );
        // Legs step even when turning on the spot: use the feet's speed.
        let feet_speed = config.speed_m_s.max(1e-3);
        let cycle_hz = feet_speed / p.cycle_length_m;
        Self {
            config,
            seed,
            p,
            trunk_from_camera,
            cycle_hz,
        }
    }

    /// Gait cycle frequency (Hz); steps (touchdowns) happen `steps_per_cycle` times faster.
    pub fn cycle_hz(&self) -> f64 {
        self.cycle_hz
    }

    /// Touchdown (step) frequency (Hz): the frequency of the strongest shake.
    pub fn step_hz(&self) -> f64 {
        self.cycle_hz * self.p.steps_per_cycle
    }

    /// The camera mount `trunk_from_camera`.
    pub fn trunk_from_camera(&self) -> Isometry3<f64> {
        self.trunk_from_camera
    }

    fn amplitude(&self) -> f64 {
        self.config.shake
            * (self.config.speed_m_s / REFERENCE_SPEED_M_S)
                .clamp(0.0, 2.0)
                .sqrt()
    }

    /// Progress along the schedule in "nominal seconds": time with velocity ripple at the
    /// step frequency, integrated in closed form.
    fn progress(&self, t: f64) -> f64 {
        let w = TAU * self.step_hz();
        let a = self.p.ripple * self.amplitude().min(1.5);
        // ∫ (1 - a cos(w τ)) dτ = t - a sin(w t) / w
        if w > 0.0 {
            t - a * (w * t).sin() / w
        } else {
            t
        }
    }

    /// Planar pose (x, y, yaw) after `u` nominal seconds.
    fn planar(&self, u: f64) -> (f64, f64, f64) {
        let v = self.config.speed_m_s;
        let omega = v / TURN_RADIUS_M;
        match self.config.path {
            PathKind::Straight => (v * u, 0.0, 0.0),
            PathKind::Turn => (0.0, 0.0, omega * u),
            PathKind::Square => {
                let side = self.config.square_side_m;
                let (t_walk, t_turn) = if v > 0.0 {
                    (side / v, (PI / 2.0) / omega)
                } else {
                    (f64::INFINITY, f64::INFINITY)
                };
                let period = t_walk + t_turn;
                let mut u = u.max(0.0);
                let (mut x, mut y, mut yaw) = (0.0f64, 0.0f64, 0.0f64);
                // Whole sides completed.
                let sides = if period.is_finite() {
                    (u / period).floor()
                } else {
                    0.0
                };
                for _ in 0..(sides as usize % 4) {
                    x += side * yaw.cos();
                    y += side * yaw.sin();
                    yaw += PI / 2.0;
                }
                yaw += (sides - (sides as usize % 4) as f64) * PI / 2.0; // full laps
                u -= sides * period;
                let walked = (u.min(t_walk)) * v;
                x += walked * yaw.cos();
                y += walked * yaw.sin();
                if u > t_walk {
                    yaw += omega * (u - t_walk);
                }
                (x, y, yaw)
            }
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MotionConfig {
        &self.config
    }

    /// The trunk and camera state at time `t` (s since the start) over a terrain given by
    /// `height_at(x, y)` (m, world z up).
    pub fn state(&self, t: f64, height_at: &dyn Fn(f64, f64) -> f64) -> TrunkState {
        let (x, y, yaw) = self.planar(self.progress(t));
        let phase = (self.cycle_hz * t).rem_euclid(1.0);
        let amp = self.amplitude();
        let p = &self.p;

        // Terrain under the feet: fit z = a + b dx + c dy over the six feet (trunk frame).
        let (sy, cy) = yaw.sin_cos();
        let feet = [
            (FOOT_HALF_LENGTH_M, FOOT_HALF_WIDTH_M),
            (0.0, FOOT_HALF_WIDTH_M + 0.03),
            (-FOOT_HALF_LENGTH_M, FOOT_HALF_WIDTH_M),
            (FOOT_HALF_LENGTH_M, -FOOT_HALF_WIDTH_M),
            (0.0, -FOOT_HALF_WIDTH_M - 0.03),
            (-FOOT_HALF_LENGTH_M, -FOOT_HALF_WIDTH_M),
        ];
        let (mut sz, mut sxz, mut syz, mut sxx, mut syy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (fx, fy) in feet {
            let wx = x + fx * cy - fy * sy;
            let wy = y + fx * sy + fy * cy;
            let h = height_at(wx, wy);
            sz += h;
            sxz += fx * h;
            syz += fy * h;
            sxx += fx * fx;
            syy += fy * fy;
        }
        let ground = sz / 6.0;
        let slope_x = sxz / sxx; // dz/dx in the trunk frame
        let slope_y = syz / syy;
        let terrain_pitch = -slope_x.atan(); // nose up on an up-slope: negative pitch about y (y left)
        let terrain_roll = slope_y.atan();

        // Gait oscillations.
        let w = TAU * phase;
        let mut heave = p.heave_m * amp * (p.steps_per_cycle * w).cos();
        let mut roll = p.roll_rad * amp * w.sin();
        let mut pitch = p.pitch_rad * amp * (p.steps_per_cycle * w + 0.7).sin();
        let yaw_wobble = p.yaw_rad * amp * (w + 0.3).sin();
        // Damped vibration after each touchdown (servo overload), ~9 Hz, 60 ms decay.
        for (k, &td) in p.touchdowns.iter().enumerate() {
            let since_phase = (phase - td).rem_euclid(1.0);
            let since_s = since_phase / self.cycle_hz;
            // Which touchdown this is (cycle number), for its random amplitude.
            let cycle = (self.cycle_hz * t - since_phase - td).round() as i64;
            let u = stride_core::rng::hash_uniform(stride_core::rng::key(&[
                self.seed,
                cycle as u64,
                k as u64,
            ]));
            let factor = 1.0 + self.config.variation * (2.0 * u - 1.0);
            let env = (-since_s / 0.06).exp() * amp * factor;
            let osc = (TAU * 9.0 * since_s).sin();
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            pitch += p.impact_rad * env * osc;
            roll += 0.6 * sign * p.impact_rad * env * (TAU * 9.0 * since_s + 0.5).sin();
            heave -= p.impact_heave_m * env * osc.abs();
        }
        let swinging = p
            .touchdowns
            .iter()
            .filter(|&&td| {
                let start = td - p.swing_fraction;
                (phase - start).rem_euclid(1.0) < p.swing_fraction
            })
            .count();
        let legs_per_group = if self.config.gait == Gait::Tripod {
            3
        } else {
            1
        };
        let stance_legs = (6 - swinging * legs_per_group) as u8;

        let trunk_z = ground + (self.config.camera_height_m - CAMERA_ABOVE_TRUNK_M) + heave;
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw + yaw_wobble)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), terrain_pitch + pitch)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), terrain_roll + roll);
        let world_from_trunk = Isometry3::from_parts(Translation3::new(x, y, trunk_z), rotation);
        TrunkState {
            world_from_trunk,
            world_from_camera: world_from_trunk * self.trunk_from_camera,
            gait_phase: phase,
            stance_legs,
        }
    }

    /// The planar path (x, y) sampled over `[0, duration_s]`, for placing scene objects.
    pub fn path_samples(&self, duration_s: f64, n: usize) -> Vec<(f64, f64)> {
        (0..=n)
            .map(|i| {
                let (x, y, _) = self.planar(self.progress(duration_s * i as f64 / n.max(1) as f64));
                (x, y)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn flat(_: f64, _: f64) -> f64 {
        0.0
    }

    #[test]
    fn camera_sits_at_the_configured_height_and_tilt() {
        let cfg = MotionConfig {
            shake: 0.0,
            ..MotionConfig::default()
        };
        let m = Motion::new(cfg);
        let s = m.state(0.0, &flat);
        let c = s.world_from_camera;
        assert_relative_eq!(c.translation.vector.z, 0.4, epsilon = 1e-9);
        // Optical axis points forward and 25 degrees down.
        let axis = c.rotation * Vector3::z();
        assert_relative_eq!(axis.z, -(25f64.to_radians().sin()), epsilon = 1e-9);
        assert!(axis.x > 0.9);
        // Image x points to the robot's right (-y in the world at yaw 0), image y down-ish.
        assert_relative_eq!((c.rotation * Vector3::x()).y, -1.0, epsilon = 1e-9);
        assert!((c.rotation * Vector3::y()).z < -0.8);
    }

    #[test]
    fn paths_cover_the_expected_ground() {
        let straight = Motion::new(MotionConfig {
            speed_m_s: 0.1,
            ..MotionConfig::default()
        });
        let x = straight
            .state(10.0, &flat)
            .world_from_trunk
            .translation
            .vector
            .x;
        assert!((x - 1.0).abs() < 0.01, "{x}");
        let sq = MotionConfig {
            path: PathKind::Square,
            speed_m_s: 0.1,
            square_side_m: 1.0,
            shake: 0.0,
            ..MotionConfig::default()
        };
        let m = Motion::new(sq);
        // One side (10 s) plus a quarter turn (pi/2 / 0.4 = 3.93 s) per corner: a lap is 55.7 s.
        let lap = 4.0 * (10.0 + (PI / 2.0) / 0.4);
        let p = m
            .state(lap + 0.01, &flat)
            .world_from_trunk
            .translation
            .vector;
        assert!(p.x.abs() < 0.01 && p.y.abs() < 0.01, "{p}");
        let half = m
            .state(2.0 * (10.0 + (PI / 2.0) / 0.4), &flat)
            .world_from_trunk
            .translation
            .vector;
        assert!(
            (half.x - 1.0).abs() < 0.01 && (half.y - 1.0).abs() < 0.01,
            "{half}"
        );
        let turn = Motion::new(MotionConfig {
            path: PathKind::Turn,
            ..MotionConfig::default()
        });
        assert!(
            turn.state(5.0, &flat)
                .world_from_trunk
                .translation
                .vector
                .xy()
                .norm()
                < 1e-9
        );
    }

    #[test]
    fn tripod_shakes_more_than_crawl_and_counts_legs() {
        let mk = |gait, speed| MotionConfig {
            gait,
            speed_m_s: speed,
            ..MotionConfig::default()
        };
        let rate = |cfg: MotionConfig| {
            let m = Motion::new(cfg);
            let dt = 1.0 / 200.0;
            (0..800)
                .map(|i| {
                    let a = m.state(i as f64 * dt, &flat).world_from_camera.rotation;
                    let b = m
                        .state((i + 1) as f64 * dt, &flat)
                        .world_from_camera
                        .rotation;
                    (a.inverse() * b).angle() / dt
                })
                .fold(0.0f64, f64::max)
        };
        let fast = rate(mk(Gait::Tripod, 0.15));
        let slow = rate(mk(Gait::Crawl, 0.05));
        assert!(
            fast > 4.0 * slow,
            "peak angular rates {fast} vs {slow} rad/s"
        );
        let m = Motion::new(mk(Gait::Tripod, 0.15));
        let legs: Vec<u8> = (0..100)
            .map(|i| m.state(i as f64 * 0.013, &flat).stance_legs)
            .collect();
        assert!(legs.iter().all(|&l| l == 3 || l == 6) && legs.contains(&3) && legs.contains(&6));
        let m = Motion::new(mk(Gait::Crawl, 0.05));
        let legs: Vec<u8> = (0..100)
            .map(|i| m.state(i as f64 * 0.05, &flat).stance_legs)
            .collect();
        assert!(legs.iter().all(|&l| l == 5 || l == 6) && legs.contains(&5));
    }

    #[test]
    fn trunk_follows_a_slope() {
        let slope = |x: f64, _: f64| 0.2 * x;
        let m = Motion::new(MotionConfig {
            shake: 0.0,
            ..MotionConfig::default()
        });
        let s = m.state(5.0, &slope);
        let fwd = s.world_from_trunk.rotation * Vector3::x();
        assert_relative_eq!(fwd.z / fwd.x, 0.2, epsilon = 1e-6);
    }
}
