//! Matching guided by a rough pose: a keyframe's ORB points projected into the current
//! frame with a pose that few matches support, each matched to the current frame's ORB
//! points near where it lands (ORB-SLAM's search by projection).
//!
//! After a second or more of dropped frames the views differ by tens of centimetres and
//! degrees; matched by descriptor alone across the whole image, a keyframe and the frame
//! share 11-18 RANSAC inliers, too few to trust (teddy_200 with 1.5 s dropped at 1 s,
//! poses of 17 and 19 inliers accepted as they were: runs 41 and 12 mm off). Near the rough
//! pose's projections a looser descriptor bound is safe, since geometry has already
//! sorted the candidates, and the frame gains the matches that pin its pose down; RANSAC
//! then runs again on them.

use crate::config::VoConfig;
use crate::features::hamming;
use crate::motion::{Correspondence, MotionEstimate};
use crate::orb::OrbPoint;
use crate::recovery::{estimate_from, keep_best, orb_motion_params, Found, RecentKeyframe};
use crate::relocalize::MIN_INLIERS;
use nalgebra::Isometry3;
use std::collections::VecDeque;
use stride_core::camera::PinholeCamera;
use stride_core::rng::SplitMix64;

/// Fewest RANSAC inliers of the rough pose searched near.
pub(crate) const MIN_ROUGH_INLIERS: usize = 10;
/// Radius (px) around a keyframe point's projection within which the current frame's
/// points are candidates: a pose 1 degree off moves projections by about 9 px at VGA.
pub(crate) const RADIUS_PX: f64 = 10.0;
/// Largest Hamming distance (of 256 bits) of a guided match.
pub(crate) const MAX_HAMMING: u32 = 80;
/// The best candidate must be below this fraction of the second best's distance.
pub(crate) const RATIO: f64 = 0.9;

/// Matches `(query, reference)` between the current frame's points `query` and a
/// keyframe's `points` (in the keyframe's camera frame), searched near where the pose
/// `cur_from_kf` (the keyframe's camera frame into the current one) projects each
/// reference point. A query point keeps only its closest reference in descriptor space.
pub(crate) fn matches_near(
    query: &[OrbPoint],
    points: &[OrbPoint],
    cur_from_kf: &Isometry3<f64>,
    camera: &PinholeCamera,
) -> Vec<(usize, usize)> {
    // (reference, distance) kept per query point.
    let mut best: Vec<Option<(usize, u32)>> = vec![None; query.len()];
    for (ri, r) in points.iter().enumerate() {
        let Some(px) = camera.project(&(cur_from_kf * r.p_camera.p)) else {
            continue;
        };
        let (mut first, mut second): (Option<(usize, u32)>, u32) = (None, u32::MAX);
        for (qi, q) in query.iter().enumerate() {
            let (du, dv) = (f64::from(q.px.x) - px.x, f64::from(q.px.y) - px.y);
            if du * du + dv * dv > RADIUS_PX * RADIUS_PX {
                continue;
            }
            let d = hamming(&q.descriptor, &r.descriptor);
            match first {
                Some((_, fd)) if d >= fd => second = second.min(d),
                _ => {
                    second = first.map_or(second, |(_, fd)| fd);
                    first = Some((qi, d));
                }
            }
        }
        let Some((qi, d)) = first else { continue };
        if d > MAX_HAMMING || f64::from(d) >= RATIO * f64::from(second) {
            continue;
        }
        if let Some(slot) = best.get_mut(qi) {
            if slot.is_none_or(|(_, kept)| d < kept) {
                *slot = Some((ri, d));
            }
        }
    }
    best.iter()
        .enumerate()
        .filter_map(|(qi, b)| b.map(|(ri, _)| (qi, ri)))
        .collect()
}

/// The pose of the current frame from its `matches` `(query, reference)` with a keyframe's
/// `points` (the keyframe at `world_from_kf`): RANSAC over them for a rough pose with at
/// least `min_rough` inliers, then over the matches near where it projects the keyframe's
/// points ([`matches_near`]), which must give [`MIN_INLIERS`] inliers, a third of them.
pub(crate) fn estimate_near(
    (query, points, matches): (&[OrbPoint], &[OrbPoint], Vec<(usize, usize)>),
    world_from_kf: &Isometry3<f64>,
    (config, camera): (&VoConfig, &PinholeCamera),
    min_rough: usize,
    rng: &mut SplitMix64,
) -> Option<(MotionEstimate, Vec<(usize, Correspondence)>)> {
    let refine = config.refine_iterations;
    let rough_params = orb_motion_params(config, min_rough);
    let (rough, _) = estimate_from(
        query,
        points,
        matches,
        world_from_kf,
        &rough_params,
        refine,
        rng,
    )?;
    let cur_from_kf = rough.ref_from_cur.inverse() * world_from_kf;
    let near = matches_near(query, points, &cur_from_kf, camera);
    let params = orb_motion_params(config, MIN_INLIERS);
    estimate_from(query, points, near, world_from_kf, &params, refine, rng)
        .filter(|(e, pairs)| 3 * e.inlier_count >= pairs.len())
}

/// The current frame's ORB points, the recent keyframes (oldest first) and the frame's
/// matches `(query, reference)` with each (newest first).
pub(crate) type Searches<'a> = (
    &'a [OrbPoint],
    &'a VecDeque<RecentKeyframe>,
    Vec<Vec<(usize, usize)>>,
);

/// The best pose [`estimate_near`] gives against any of the recent `keyframes` (newest
/// first), given the current frame's ORB points `query` and its `matches` with each
/// keyframe (in the same order).
pub(crate) fn best_near(
    (query, keyframes, matches): Searches,
    (config, camera): (&VoConfig, &PinholeCamera),
    min_rough: usize,
    rng: &mut SplitMix64,
) -> Option<Found> {
    let mut best = None;
    for (kf, matches) in keyframes.iter().rev().zip(matches) {
        let points = kf.points.as_deref().unwrap_or(&[]);
        let w = &kf.world_from_kf;
        let found = estimate_near(
            (query, points, matches),
            w,
            (config, camera),
            min_rough,
            rng,
        );
        keep_best(&mut best, found.map(|(e, p)| (e, p, (kf.id, *w))));
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::points::Measurement;
    use nalgebra::{Matrix3, Point3, Translation3, UnitQuaternion};
    use opencv::core::Point2f;

    fn orb(px: (f64, f64), descriptor_byte: u8, p: Point3<f64>) -> OrbPoint {
        OrbPoint {
            px: Point2f::new(px.0 as f32, px.1 as f32),
            descriptor: [descriptor_byte; 32],
            p_camera: Measurement {
                p,
                cov: Matrix3::identity() * 1e-6,
            },
        }
    }

    #[test]
    fn matches_are_searched_near_the_projections_only() {
        let camera = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480).unwrap();
        let cur_from_kf = nalgebra::Isometry3::from_parts(
            Translation3::new(0.05, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.02, 0.0),
        );
        // Three keyframe points, each with its own descriptor.
        let refs: Vec<OrbPoint> = [
            (0.1, 0.0, 2.0, 0x0f),
            (-0.3, 0.2, 1.5, 0x33),
            (0.4, -0.2, 2.5, 0x55),
        ]
        .iter()
        .map(|&(x, y, z, d)| orb((0.0, 0.0), d, Point3::new(x, y, z)))
        .collect();
        let at = |r: &OrbPoint, dx: f64| {
            let px = camera.project(&(cur_from_kf * r.p_camera.p)).unwrap();
            (px.x + dx, px.y)
        };
        let query = vec![
            // The first point 4 px from its projection, its descriptor 32 bits off.
            orb(at(&refs[0], 4.0), 0x0f ^ 0x01, Point3::new(0.0, 0.0, 2.0)),
            // The second point's twin 25 px away: beyond the radius.
            orb(at(&refs[1], 25.0), 0x33, Point3::new(0.0, 0.0, 1.5)),
            // Near the third point's projection, a descriptor far from its own.
            orb(at(&refs[2], 2.0), 0xaa, Point3::new(0.0, 0.0, 2.5)),
        ];
        assert_eq!(
            matches_near(&query, &refs, &cur_from_kf, &camera),
            vec![(0, 0)]
        );
        // Two equally good candidates near one projection: ambiguous, neither kept.
        let twins = vec![query[0], query[0]];
        assert!(matches_near(&twins, &refs, &cur_from_kf, &camera).is_empty());
    }
}
