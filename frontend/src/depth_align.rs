//! Depth alignment: the pose of a frame from its depth image alone, for the frames whose
//! colour image the features cannot follow.
//!
//! Motion blur smears the colour image over the exposure, while a structured-light or
//! time-of-flight depth image of the same instant stays sharp (paper 004's blurred runs
//! lose track in colour, not in geometry). When Lucas-Kanade, the recovery by ORB and the
//! relocalization all fail, the odometry aligns the frame's depth with the last keyframe's
//! by projective point-to-plane ICP (Chen and Medioni; KinectFusion's projective data
//! association), started at the constant-velocity prediction:
//!
//! - every 8th, then every 4th pixel of the frame with depth is a sample `p_cur`;
//! - each iteration moves it into the world with the current estimate, projects it into the
//!   keyframe, and pairs it with the keyframe's point at that pixel and its normal (from the
//!   points two pixels either side; none across a depth edge);
//! - a pair is kept when the two points are within the level's distance (coarse, then fine);
//!   its residual is the distance along the normal, weighted by both depths' noise (the
//!   PrimeSense model) and a Huber kernel;
//! - Gauss-Newton over a left perturbation of `world_from_camera` (translation, rotation).
//!
//! The result is refused (the frame stays lost) when too few samples pair up, when the
//! residual stays large, or when the geometry does not fix every direction (a bare floor or
//! wall leaves the motion along it free: the smallest eigenvalue of the normalised
//! information is checked).

use nalgebra::{Isometry3, Matrix6, Point2, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use nalgebra::{SymmetricEigen, Vector6};
use stride_core::camera::PinholeCamera;
use stride_core::image::DepthImage;
use stride_core::plane::Plane;
use stride_core::robust::huber_weight;
use stride_core::uncertainty::PrimeSenseModel;

/// One level of the alignment: samples every `stride` pixels, pairs closer than
/// `max_distance_m`, `iterations` Gauss-Newton steps. Coarse first: the prediction can be a
/// few centimetres off after a lost frame.
#[derive(Debug, Clone, Copy)]
struct Level {
    stride: u32,
    max_distance_m: f64,
    iterations: usize,
}

/// The levels, coarse to fine.
const LEVELS: [Level; 3] = [
    Level {
        stride: 8,
        max_distance_m: 0.10,
        iterations: 8,
    },
    Level {
        stride: 4,
        max_distance_m: 0.04,
        iterations: 6,
    },
    Level {
        stride: 4,
        max_distance_m: 0.015,
        iterations: 4,
    },
];

/// Two coarser levels ahead of [`LEVELS`], for a start that may be 0.1-0.2 m and several
/// degrees from the pose ([`align_coarse`]): sparser samples paired within 40, then 20 cm.
const WIDE_LEVELS: [Level; 2] = [
    Level {
        stride: 16,
        max_distance_m: 0.40,
        iterations: 10,
    },
    Level {
        stride: 8,
        max_distance_m: 0.20,
        iterations: 8,
    },
];

/// Pixels either side of a keyframe pixel whose points give its normal.
const NORMAL_STEP_PX: u32 = 2;

/// Damping of the Gauss-Newton steps, relative to the information's largest diagonal entry.
const DAMPING: f64 = 1e-6;

/// Huber threshold of a pair's residual (standard deviations).
const HUBER_K: f64 = 2.0;

/// Fewest pairs at the finest level for the pose to be accepted.
const MIN_PAIRS: usize = 1_500;

/// Smallest share of the finest level's samples that must pair up (overlap).
const MIN_PAIRED_FRACTION: f64 = 0.4;

/// Largest weighted RMS residual at the finest level (standard deviations).
const MAX_RMS_SIGMAS: f64 = 2.5;

/// Smallest eigenvalue of the information matrix per pair, rotation scaled by 1 m, relative
/// to the largest: below it a direction of motion is not fixed by the geometry.
const MIN_CONDITION: f64 = 2e-3;

/// The sampled residuals of neighbouring pixels are not independent (the depth camera's
/// errors are correlated over its speckle windows): the information handed on counts one
/// in this many pairs.
const INFORMATION_SHARE: f64 = 1.0 / 16.0;

/// The pose found by [`align`].
#[derive(Debug, Clone, PartialEq)]
pub struct DepthAlignment {
    /// The frame's `world_from_camera` (m).
    pub world_from_cur: Isometry3<f64>,
    /// Pairs at the finest level.
    pub pairs: usize,
    /// Samples at the finest level (pixels with depth).
    pub samples: usize,
    /// Samples at the finest level that land on the keyframe's surface (inside its image,
    /// on a depth, off its depth edges), paired or not: `pairs` is close to it when the
    /// views agree wherever they overlap, however little that is.
    pub on_surface: usize,
    /// Weighted RMS residual at the finest level (standard deviations of the depth noise).
    pub rms_sigmas: f64,
    /// Smallest eigenvalue of the normalised information relative to the largest.
    pub condition: f64,
    /// Information matrix of the pose (left, world-frame perturbation, translation then
    /// rotation; 1/m², 1/rad²), deflated for correlated samples.
    pub information: Matrix6<f64>,
}

/// Why a depth alignment was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum DepthAlignError {
    /// Too few samples of the frame paired with the keyframe's surface.
    #[error("{pairs} of {samples} depth samples paired with the keyframe's surface")]
    Overlap {
        /// Pairs.
        pairs: usize,
        /// Samples with depth.
        samples: usize,
    },

    /// The surfaces do not agree after the alignment.
    #[error("residual {rms_sigmas:.2} standard deviations after alignment")]
    Residual {
        /// Weighted RMS residual (standard deviations).
        rms_sigmas: f64,
    },
    /// The geometry leaves a direction of motion free (a plane, a corridor).
    #[error("degenerate geometry: information condition {condition:.1e}")]
    Degenerate {
        /// Smallest over largest eigenvalue of the normalised information.
        condition: f64,
    },
}

/// What the alignment reads of one image: its depth with the camera and noise model.
pub struct DepthView<'a> {
    /// The depth image (m along the optical axis; 0 where none).
    pub depth_m: &'a DepthImage,
    /// Its `world_from_camera` (m); the current frame's is the starting guess.
    pub world_from_camera: Isometry3<f64>,
}

/// The settings of an alignment that come from the odometry's configuration.
#[derive(Debug, Clone, Copy)]
pub struct DepthAlignParams {
    /// Depth range used (m).
    pub min_depth_m: f64,
    /// See `min_depth_m`.
    pub max_depth_m: f64,
    /// Relative depth jump that marks an edge (no normal across it).
    pub depth_edge_rel: f64,
    /// The depth noise model.
    pub noise: PrimeSenseModel,
    /// Fewest samples paired with the keyframe's surface, as a fraction of the samples
    /// with depth: below it the alignment is refused.
    pub min_paired_fraction: f64,
}

impl DepthAlignParams {
    /// The odometry's depth range, edge test and noise model.
    pub fn from_config(c: &crate::VoConfig) -> Self {
        Self {
            min_depth_m: c.min_depth_m,
            max_depth_m: c.max_depth_m,
            depth_edge_rel: c.depth_edge_rel,
            noise: c.uncertainty,
            min_paired_fraction: MIN_PAIRED_FRACTION,
        }
    }

    /// Whether a depth (m) is a measurement within the range used.
    fn in_range(&self, d_m: f64) -> bool {
        d_m.is_finite() && d_m >= self.min_depth_m && d_m <= self.max_depth_m
    }
}

/// Aligns `current`'s depth with `keyframe`'s, starting at `current.world_from_camera`
/// (see the module documentation).
pub fn align(
    keyframe: &DepthView<'_>,
    current: &DepthView<'_>,
    camera: &PinholeCamera,
    params: &DepthAlignParams,
) -> Result<DepthAlignment, DepthAlignError> {
    let (world_from_cur, last) = iterate(keyframe, current, camera, params, LEVELS);
    accept(world_from_cur, &last, params)
}

/// Two levels coarser than [`align`]'s, alone and unchecked (every 16th pixel paired within
/// 40 cm, then every 8th within 20 cm), so that a start 0.1-0.2 m and several degrees from
/// the pose reaches it: where they leave the frame (`world_from_camera`) and how many of its
/// samples paired with the keyframe's surface at the last iteration. A search over many
/// starts ([`crate::depth_search`]) ranks them by it and goes on with [`align`] from there.
pub fn align_coarse(
    keyframe: &DepthView<'_>,
    current: &DepthView<'_>,
    camera: &PinholeCamera,
    params: &DepthAlignParams,
) -> (Isometry3<f64>, usize) {
    let (world_from_cur, last) = iterate(keyframe, current, camera, params, WIDE_LEVELS);
    (world_from_cur, last.pairs)
}

/// The Gauss-Newton iterations over `levels`, coarse to fine, from
/// `current.world_from_camera`: the pose reached and the last iteration's system.
fn iterate(
    keyframe: &DepthView<'_>,
    current: &DepthView<'_>,
    camera: &PinholeCamera,
    params: &DepthAlignParams,
    levels: impl IntoIterator<Item = Level>,
) -> (Isometry3<f64>, Normal) {
    let kf_from_world = keyframe.world_from_camera.inverse();
    let mut world_from_cur = current.world_from_camera;
    let mut last = Normal::default();
    let mut sampled: Option<(u32, Vec<Point3<f64>>)> = None;
    let rays = Rays::new(camera);
    for level in levels {
        if sampled.as_ref().map(|s| s.0) != Some(level.stride) {
            let points = samples(current.depth_m, &rays, level.stride, params);
            sampled = Some((level.stride, points));
        }
        let samples = sampled.as_ref().map_or(&[][..], |s| &s.1[..]);
        for _ in 0..level.iterations {
            let eq = normal_equations(
                samples,
                keyframe,
                &kf_from_world,
                &world_from_cur,
                &rays,
                level.max_distance_m,
                params,
            );
            // A little damping keeps a direction the geometry leaves free from taking a
            // wild step (it is refused below, by the condition).
            let damping = DAMPING * eq.h.diagonal().max();
            let damped = eq.h + Matrix6::identity() * damping;
            let Some(delta) = damped.cholesky().map(|c| c.solve(&(-eq.g))) else {
                last = eq;
                break;
            };
            world_from_cur = about(&world_from_cur.translation.vector, &delta) * world_from_cur;
            last = eq;
            if delta.fixed_rows::<3>(0).norm() < 1e-5 && delta.fixed_rows::<3>(3).norm() < 1e-5 {
                break;
            }
        }
    }
    (world_from_cur, last)
}

/// The pose `world_from_cur` with its last system `last`, or why it is refused (overlap,
/// residual, conditioning).
fn accept(
    world_from_cur: Isometry3<f64>,
    last: &Normal,
    params: &DepthAlignParams,
) -> Result<DepthAlignment, DepthAlignError> {
    let (pairs, samples) = (last.pairs, last.samples);
    if pairs < MIN_PAIRS || (pairs as f64) < params.min_paired_fraction * samples as f64 {
        return Err(DepthAlignError::Overlap { pairs, samples });
    }

    let rms_sigmas = (last.cost / pairs as f64).sqrt();
    if rms_sigmas > MAX_RMS_SIGMAS {
        return Err(DepthAlignError::Residual { rms_sigmas });
    }
    let condition = condition(&last.h);
    if condition < MIN_CONDITION {
        return Err(DepthAlignError::Degenerate { condition });
    }
    Ok(DepthAlignment {
        world_from_cur,
        pairs,
        samples,
        on_surface: last.on_surface,
        rms_sigmas,
        condition,
        information: at_origin(&last.h, &world_from_cur.translation.vector) * INFORMATION_SHARE,
    })
}

/// The frame's samples: points (camera frame, m) every `stride` pixels with depth in range.
fn samples(
    depth_m: &DepthImage,
    rays: &Rays<'_>,
    stride: u32,
    params: &DepthAlignParams,
) -> Vec<Point3<f64>> {
    let (w, h) = (depth_m.width(), depth_m.height());
    let mut out = Vec::with_capacity(((w / stride + 1) * (h / stride + 1)) as usize);
    for v in (stride / 2..h).step_by(stride as usize) {
        for u in (stride / 2..w).step_by(stride as usize) {
            let d = f64::from(depth_m.get(u, v).unwrap_or(0.0));
            if params.in_range(d) {
                out.push(rays.unproject(u, v, d));
            }
        }
    }
    out
}

/// The camera's rays through whole pixels, for [`PinholeCamera::unproject`]'s numbers at a
/// fraction of its cost: without distortion a ray's `X/Z` depends on the column alone and
/// its `Y/Z` on the row alone, so one division per column and per row, made once per
/// alignment, serves every lookup (each iteration unprojects five keyframe pixels per
/// sample: under blur, with a weak keyframe's five depth links, the unprojection's
/// divisions took a third of the SLAM's time). With distortion, or off the tables, each
/// lookup asks the camera, as before. The same arithmetic either way: the same bits.
/// (`stride_mapping`'s ray table is the other way round: f32, for distorted cameras, one
/// row at a time for its vectorised input stage; these must stay bit-exact.)
struct Rays<'a> {
    camera: &'a PinholeCamera,
    /// `X/Z` by column and `Y/Z` by row; empty with distortion.
    x_by_column: Vec<f64>,
    y_by_row: Vec<f64>,
}

impl<'a> Rays<'a> {
    fn new(camera: &'a PinholeCamera) -> Self {
        let separable = camera.distortion().is_none();
        let ray = |u: u32, v: u32| camera.normalized_from_pixel(&pixel(u, v));
        let (x_by_column, y_by_row) = if separable {
            let xs = (0..camera.width()).map(|u| ray(u, 0).x).collect();
            (xs, (0..camera.height()).map(|v| ray(0, v).y).collect())
        } else {
            (Vec::new(), Vec::new())
        };
        Self {
            camera,
            x_by_column,
            y_by_row,
        }
    }

    /// The camera-frame point (m) at pixel `(u, v)` with depth `depth_m` (m, along the
    /// optical axis).
    fn unproject(&self, u: u32, v: u32, depth_m: f64) -> Point3<f64> {
        match (
            self.x_by_column.get(u as usize),
            self.y_by_row.get(v as usize),
        ) {
            (Some(&x), Some(&y)) => Point3::new(x * depth_m, y * depth_m, depth_m),
            _ => self.camera.unproject(&pixel(u, v), depth_m),
        }
    }
}

/// The centre of whole pixel `(u, v)`.
fn pixel(u: u32, v: u32) -> Point2<f64> {
    Point2::new(f64::from(u), f64::from(v))
}

/// The Gauss-Newton system of one iteration and what it was built from.
#[derive(Debug, Clone, Default)]
struct Normal {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    /// Sum of the weighted squared residuals (in standard deviations).
    cost: f64,
    pairs: usize,
    samples: usize,
    /// Samples that found the keyframe's surface where they project, paired or not.
    on_surface: usize,
}

/// Pairs every sample with the keyframe's surface under `world_from_cur` and sums the
/// point-to-plane system.
fn normal_equations(
    samples: &[Point3<f64>],
    keyframe: &DepthView<'_>,
    kf_from_world: &Isometry3<f64>,
    world_from_cur: &Isometry3<f64>,
    rays: &Rays<'_>,
    max_distance_m: f64,
    params: &DepthAlignParams,
) -> Normal {
    let mut n = Normal {
        samples: samples.len(),
        ..Normal::default()
    };
    let world_from_kf = &keyframe.world_from_camera;
    let centre = world_from_cur.translation.vector;
    for p_cur in samples {
        let p_world = world_from_cur * p_cur;
        let p_kf = kf_from_world * p_world;
        let Some((q_kf, normal_kf)) = surface(keyframe.depth_m, rays, &p_kf, params) else {
            continue;
        };
        n.on_surface += 1;
        let q_world = world_from_kf * q_kf;
        let normal = world_from_kf.rotation * normal_kf;
        let diff = p_world - q_world;
        if diff.norm() > max_distance_m {
            continue;
        }
        let sigma =
            (params.noise.sigma_d(p_cur.z).powi(2) + params.noise.sigma_d(q_kf.z).powi(2)).sqrt();
        let r = normal.dot(&diff) / sigma;
        let huber = huber_weight(r * r, Some(HUBER_K * HUBER_K));
        let mut j = Vector6::zeros();
        j.fixed_rows_mut::<3>(0).copy_from(&(normal / sigma));
        j.fixed_rows_mut::<3>(3)
            .copy_from(&((p_world.coords - centre).cross(&normal) / sigma));
        n.h += huber * j * j.transpose();
        n.g += huber * r * j;
        n.cost += huber * r * r;
        n.pairs += 1;
    }
    n
}

/// The keyframe's point (camera frame, m) at the pixel where `p_kf` projects, and the unit
/// normal of its tangent plane facing the camera; none off the image, without depth, or across a depth edge.
fn surface(
    depth_m: &DepthImage,
    rays: &Rays<'_>,
    p_kf: &Point3<f64>,
    params: &DepthAlignParams,
) -> Option<(Point3<f64>, Vector3<f64>)> {
    if p_kf.z <= 0.0 {
        return None;
    }
    let camera = rays.camera;
    let px = camera.project(p_kf)?;
    let (u, v) = (px.x.round(), px.y.round());
    let s = f64::from(NORMAL_STEP_PX);
    if u < s || v < s || u + s >= f64::from(camera.width()) || v + s >= f64::from(camera.height()) {
        return None;
    }
    let (u, v) = (u as u32, v as u32);
    let point = |du: i64, dv: i64| -> Option<(Point3<f64>, f64)> {
        let (x, y) = ((i64::from(u) + du) as u32, (i64::from(v) + dv) as u32);
        let d = f64::from(depth_m.get(x, y)?);
        params.in_range(d).then(|| (rays.unproject(x, y, d), d))
    };
    let step = i64::from(NORMAL_STEP_PX);
    let (centre, d) = point(0, 0)?;
    let mut around = [Point3::origin(); 4];
    for (slot, (du, dv)) in around
        .iter_mut()
        .zip([(-step, 0), (step, 0), (0, -step), (0, step)])
    {
        let (p, dn) = point(du, dv)?;
        if (dn - d).abs() > params.depth_edge_rel * d * f64::from(NORMAL_STEP_PX) {
            return None;
        }
        *slot = p;
    }
    let [left, right, up, down] = around;
    let normal = Unit::try_new((right - left).cross(&(down - up)), 0.0)?;
    let tangent = Plane {
        normal,
        offset_m: normal.dot(&centre.coords),
    };
    Some((
        centre,
        tangent.facing(&Point3::origin()).normal.into_inner(),
    ))
}

/// The world-frame pose change of a perturbation `(translation, rotation vector)` whose
/// rotation turns about `centre` (the camera's position, so that the rotation's Jacobian
/// does not grow with the distance from the world's origin).
fn about(centre: &Vector3<f64>, delta: &Vector6<f64>) -> Isometry3<f64> {
    let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(delta[3], delta[4], delta[5]));
    let translation = Vector3::new(delta[0], delta[1], delta[2]) + centre - rotation * centre;
    Isometry3::from_parts(Translation3::from(translation), rotation)
}

/// The information `h` of a perturbation about `centre` expressed for one about the world's
/// origin (the odometry's convention): `δ_origin = A δ_centre` with `A = [I, [c]x; 0, I]`,
/// so `H_origin = A^-T H A^-1`.
fn at_origin(h: &Matrix6<f64>, centre: &Vector3<f64>) -> Matrix6<f64> {
    let mut a_inv = Matrix6::identity();
    a_inv
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(-centre.cross_matrix()));
    a_inv.transpose() * h * a_inv
}

/// Smallest over largest eigenvalue of the information (rotation in radians times 1 m, so
/// that both blocks are in m⁻²).
fn condition(h: &Matrix6<f64>) -> f64 {
    let e = SymmetricEigen::new(*h).eigenvalues;
    let (min, max) = e.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &x| {
        (lo.min(x), hi.max(x))
    });
    if max > 0.0 {
        min / max
    } else {
        0.0
    }
}

#[cfg(test)]
#[path = "depth_align_tests.rs"]
mod tests;
