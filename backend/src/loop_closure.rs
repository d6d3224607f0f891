//! Loop closure: a new keyframe that sees again a place mapped long before, but is not yet
//! tied to it, is matched against it, the match verified, the drift of the loop spread over
//! the keyframes since, and the twice-mapped points fused.
//!
//! Per keyframe, in bundle-adjustment mode:
//! 1. Candidates: keyframes older than [`LoopParams::min_age_keyframes`] that the new one
//!    is not tied to yet (it shares fewer than [`LoopParams::connected_points`] points with
//!    them): by position, the [`LoopParams::candidates`] nearest within
//!    [`LoopParams::search_radius_m`] looking the same way (within the local map's
//!    `nearby_angle_deg`); by appearance, wherever they are, the
//!    [`LoopParams::appearance_candidates`] whose bags of words score highest against the
//!    new keyframe's ([`stride_frontend::place`], the shipped vocabulary), so that drift
//!    beyond the radius is found too.
//! 2. Appearance: unguided ORB matching of the keyframe's features against each candidate's
//!    mapped features (Hamming bound, Lowe's ratio, one claim per feature); the candidate
//!    with the most matches is verified.
//! 3. Geometry: RANSAC over the 3-D/3-D pairs (the keyframe's measurements against the old
//!    points), refined; at least [`LoopParams::min_inliers`] inliers, a third of the matches.
//! 4. Correction: a pose graph over the keyframes after the candidate (consecutive keyframes
//!    tied by their current relative poses, weighted by their odometry information; the
//!    loop by the verified pose), the older ones held fixed; points move with the keyframe
//!    that made them.
//! 5. Fusion: the keyframe's inlier features observe the old points (a point of its own is
//!    merged into the old one), and the local window is optimized again.
//!
//! Deterministic: candidates in a fixed order, RANSAC seeded by the two keyframes.

use crate::ba::{solve, PoseEdge, PoseVar, Problem, SolverOptions};
use crate::backend::{diagonal_information, tangent_information, Backend};
use crate::config::BackendMode;
use crate::error::BackendError;
use crate::map::{KeyframeId, PointId};
use crate::se3::is_finite;
use nalgebra::{Isometry3, Matrix6};
use std::collections::BTreeMap;
use stride_core::rng::{key, SplitMix64};
use stride_frontend::features::match_descriptors;
use stride_frontend::motion::{estimate, Correspondence, MotionParams};
use stride_frontend::place::{PlaceDatabase, Vocabulary};
use stride_frontend::points::Measurement;
use stride_frontend::InlierTest;

/// Parameters of loop closure.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopParams {
    /// Look for loops at all.
    pub enabled: bool,
    /// A loop candidate is at least this many keyframes older than the new keyframe (the
    /// local map covers the recent ones).
    pub min_age_keyframes: u64,
    /// An old keyframe sharing at least this many points with the new one is already
    /// tied to it: not a candidate.
    pub connected_points: u32,
    /// Old keyframes farther than this from the new keyframe's current pose (m) are not
    /// candidates: the largest drift a loop can correct.
    pub search_radius_m: f64,
    /// Nearest old keyframes compared by appearance.
    pub candidates: usize,
    /// Fewest RANSAC inliers that verify a loop.
    pub min_inliers: usize,
    /// Old keyframes compared by appearance wherever they are (the best bag-of-words
    /// scores); 0 turns the appearance search off (the vocabulary is then not loaded).
    pub appearance_candidates: usize,
}

impl Default for LoopParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_age_keyframes: 20,
            connected_points: 20,
            search_radius_m: 2.0,
            candidates: 5,
            min_inliers: 30,
            appearance_candidates: 3,
        }
    }
}

/// A closed loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopReport {
    /// The old keyframe the new one was matched to.
    pub matched: KeyframeId,
    /// Descriptor matches with it, and RANSAC inliers among them.
    pub matches: usize,
    /// See `matches`.
    pub inliers: usize,
    /// How far the verified pose moved the new keyframe (m, rad).
    pub correction_m: f64,
    /// See `correction_m`.
    pub correction_rad: f64,
    /// Keyframes the pose graph moved.
    pub moved_keyframes: usize,
    /// Points fused with old ones, and observations added to old points.
    pub fused: usize,
}

/// Standard deviations (m, rad) of a consecutive-keyframe link without odometry
/// information: 1 cm and 1 degree.
const DEFAULT_LINK_SIGMA: (f64, f64) = (0.01, 0.017_453_292_519_943_295);

/// A verified loop: the old keyframe, the match count, the keyframe's pose by the old
/// points, its information, and the inlier pairs `(feature, old point)`.
struct Verified {
    matched: KeyframeId,
    matches: usize,
    world_from_new: Isometry3<f64>,
    information: Matrix6<f64>,
    pairs: Vec<(usize, PointId)>,
}

/// The keyframes' bags of words (see [`LoopParams::appearance_candidates`]).
pub(crate) struct Places {
    vocabulary: Option<std::sync::Arc<Vocabulary>>,
    database: PlaceDatabase,
}

impl Places {
    /// Forgets keyframe `id` (culled from the map).
    pub(crate) fn forget(&mut self, id: KeyframeId) {
        self.database.remove(id);
    }

    /// Loads the shipped vocabulary when loop closure looks by appearance.
    pub(crate) fn new(params: &LoopParams) -> Result<Self, BackendError> {
        let vocabulary = if params.enabled && params.appearance_candidates > 0 {
            Some(Vocabulary::shipped()?)
        } else {
            None
        };
        Ok(Self {
            vocabulary,
            database: PlaceDatabase::new(),
        })
    }
}

impl Backend {
    /// Adds keyframe `id`'s bag of words (its described features) to the place database
    /// (culling removes it again); nothing when appearance search is off.
    pub(crate) fn index_place(&mut self, id: KeyframeId) {
        let Places {
            vocabulary,
            database,
        } = &mut self.places;
        let (Some(v), Some(kf)) = (vocabulary, self.map.keyframe(id)) else {
            return;
        };
        let descriptors: Vec<[u8; 32]> = kf.features.iter().filter_map(|f| f.descriptor).collect();
        database.add(id, v.transform(&descriptors));
    }

    /// Looks for a loop at keyframe `id` and closes it (see the module documentation),
    /// unless a revisit link `tied` it to an old keyframe already. Returns what was done,
    /// or `None` when there was no loop to close.
    pub(crate) fn close_loop(
        &mut self,
        id: KeyframeId,
        tied: bool,
    ) -> Result<Option<LoopReport>, BackendError> {
        let params = self.config.loop_closure.clone();
        if !params.enabled || self.config.mode != BackendMode::BundleAdjustment {
            return Ok(None);
        }
        self.index_place(id);
        if tied {
            // A revisit link tied the keyframe to an old one already: the loop is closed,
            // and a pose graph without that link would pull against it.
            return Ok(None);
        }
        let Some(verified) = self.find_loop(id, &params) else {
            return Ok(None);
        };
        let before = self.map.pose_of(id).unwrap_or(verified.world_from_new);
        let moved = self.correct_loop(id, &verified)?;
        let step = before.inverse() * verified.world_from_new;
        let mut fused = 0;
        for &(feature, old) in &verified.pairs {
            let current = self
                .map
                .keyframe(id)
                .and_then(|k| k.features.get(feature))
                .and_then(|f| f.point);
            match current {
                Some(p) if p == old => {}
                Some(p) => {
                    self.map.merge_points(old, p);
                    fused += 1;
                }
                None => fused += usize::from(self.map.add_observation(old, id, feature)),
            }
        }
        let window = crate::window::local_window(&self.map, id, &self.config);
        self.optimize(&window, self.config.local_iterations)?;
        tracing::debug!(
            "keyframe {id}: loop closed with keyframe {} ({} inliers of {} matches), moved {:.1} mm",
            verified.matched,
            verified.pairs.len(),
            verified.matches,
            step.translation.vector.norm() * 1e3
        );
        Ok(Some(LoopReport {
            matched: verified.matched,
            matches: verified.matches,
            inliers: verified.pairs.len(),
            correction_m: step.translation.vector.norm(),
            correction_rad: step.rotation.angle(),
            moved_keyframes: moved,
            fused,
        }))
    }

    /// Steps 1-3: the old keyframe keyframe `id` sees again, verified.
    fn find_loop(&self, id: KeyframeId, params: &crate::LoopParams) -> Option<Verified> {
        let kf = self.map.keyframe(id)?;
        // Old keyframes already tied to this one (by tracks or the local map's matching)
        // are no loop to close.
        let tied = |k: KeyframeId| {
            kf.covisibility.get(&k).copied().unwrap_or(0) >= params.connected_points
        };
        let old = |k: KeyframeId| k + params.min_age_keyframes <= id && !tied(k);
        let mut near = self.map.nearby(
            id,
            params.search_radius_m,
            self.config.nearby_angle_deg,
            params.candidates,
            |k| old(k.id),
        );
        if let Some(bow) = self.places.database.get(id) {
            let alike = self
                .places
                .database
                .query(bow, params.appearance_candidates, |k| {
                    old(k) && !near.contains(&k) && self.map.keyframe(k).is_some()
                });
            near.extend(alike.iter().map(|m| m.id));
        }
        // The keyframe's features that can be matched: descriptor and measurement.
        let query: Vec<(usize, [u8; 32], Measurement)> = kf
            .features
            .iter()
            .enumerate()
            .filter_map(|(i, f)| Some((i, f.descriptor?, f.measurement?)))
            .collect();
        let query_desc: Vec<[u8; 32]> = query.iter().map(|q| q.1).collect();
        let m = &self.config.matching;
        let mut best: Option<(KeyframeId, Vec<(usize, PointId)>)> = None;
        for &c in &near {
            let Some(ckf) = self.map.keyframe(c) else {
                continue;
            };
            let reference: Vec<(PointId, [u8; 32])> = ckf
                .features
                .iter()
                .filter_map(|f| Some((f.point?, f.descriptor?)))
                .collect();
            let ref_desc: Vec<[u8; 32]> = reference.iter().map(|r| r.1).collect();
            let pairs: Vec<(usize, PointId)> =
                match_descriptors(&query_desc, &ref_desc, m.max_hamming, m.ratio)
                    .into_iter()
                    .filter_map(|(qi, ri)| Some((query.get(qi)?.0, reference.get(ri)?.0)))
                    .collect();
            if best.as_ref().is_none_or(|(_, b)| pairs.len() > b.len()) {
                best = Some((c, pairs));
            }
        }
        let (matched, pairs) = best.filter(|(_, p)| p.len() >= params.min_inliers)?;
        let corrs: Vec<Correspondence> = pairs
            .iter()
            .filter_map(|&(f, p)| {
                let current = kf.features.get(f)?.measurement?;
                let point = self.map.point(p)?;
                let cov = point
                    .covariance()
                    .filter(|c| c.iter().all(|v| v.is_finite()))?;
                Some(Correspondence {
                    reference: Measurement {
                        p: point.p_world,
                        cov,
                    },
                    current,
                })
            })
            .collect();
        let ransac = MotionParams {
            test: InlierTest::Mahalanobis { chi2: 11.34 },
            max_iterations: 1000,
            min_inliers: params.min_inliers,
            model_noise_m: self.config.model_noise_m.max(0.005),
            ..MotionParams::from_config(&stride_frontend::VoConfig::default())
        };
        let mut rng = SplitMix64::new(key(&[matched, id]));
        let e = estimate(&corrs, &ransac, &mut rng)?;
        if e.inlier_count < params.min_inliers
            || 3 * e.inlier_count < pairs.len()
            || !is_finite(&e.ref_from_cur)
        {
            return None;
        }
        let inliers = pairs
            .iter()
            .zip(&e.inliers)
            .filter(|(_, &ok)| ok)
            .map(|(p, _)| *p)
            .collect();
        Some(Verified {
            matched,
            matches: pairs.len(),
            world_from_new: e.ref_from_cur,
            information: tangent_information(&e.ref_from_cur, &e.information),
            pairs: inliers,
        })
    }

    /// Step 4: the pose graph over the keyframes after the matched one; returns how many
    /// keyframes it moved. Points move with the keyframe that made them (or, when that one
    /// was culled, their first observer).
    fn correct_loop(&mut self, id: KeyframeId, v: &Verified) -> Result<usize, BackendError> {
        let ids: Vec<KeyframeId> = self.map.keyframes().keys().copied().collect();
        let index: BTreeMap<KeyframeId, usize> =
            ids.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        let (Some(&matched), Some(&new)) = (index.get(&v.matched), index.get(&id)) else {
            return Ok(0);
        };
        let poses: Vec<Isometry3<f64>> = ids.iter().filter_map(|&k| self.map.pose_of(k)).collect();
        if poses.len() != ids.len() {
            return Ok(0);
        }
        let mut problem = Problem {
            poses: poses
                .iter()
                .zip(&ids)
                .map(|(p, &k)| PoseVar {
                    world_from_camera: *p,
                    fixed: k <= v.matched,
                })
                .collect(),
            ..Problem::default()
        };
        for (i, pair) in poses.windows(2).enumerate() {
            let [a, b] = pair else { continue };
            let information = ids
                .get(i + 1)
                .and_then(|&k| self.map.keyframe(k)?.odometry.as_ref())
                .map_or_else(
                    || diagonal_information(DEFAULT_LINK_SIGMA),
                    |e| e.information,
                );
            problem.pose_edges.push(PoseEdge {
                from: i,
                to: i + 1,
                from_from_to: a.inverse() * b,
                information,
            });
        }
        let world_from_matched = poses.get(matched).copied().unwrap_or_default();
        problem.pose_edges.push(PoseEdge {
            from: matched,
            to: new,
            from_from_to: world_from_matched.inverse() * v.world_from_new,
            information: v.information,
        });
        let opts = SolverOptions {
            max_iterations: 20,
            point_huber_chi2: None,
            pose_huber_chi2: None,
            ..SolverOptions::default()
        };
        solve(&mut problem, &opts)?;
        // Each moved keyframe's correction, then the points it made.
        let mut corrections: BTreeMap<KeyframeId, Isometry3<f64>> = BTreeMap::new();
        for ((&k, old), var) in ids.iter().zip(&poses).zip(&problem.poses) {
            if !var.fixed && is_finite(&var.world_from_camera) {
                corrections.insert(k, var.world_from_camera * old.inverse());
                self.map.set_pose(k, var.world_from_camera);
            }
        }
        let moved: Vec<(PointId, nalgebra::Point3<f64>)> = self
            .map
            .points()
            .iter()
            .filter_map(|(&pid, p)| {
                let owner = if self.map.keyframe(p.created_by).is_some() {
                    p.created_by
                } else {
                    p.observations.first()?.keyframe
                };
                Some((pid, corrections.get(&owner)? * p.p_world))
            })
            .collect();
        for (pid, p) in moved {
            self.map.set_position(pid, p);
        }
        Ok(corrections.len())
    }
}

#[cfg(test)]
#[path = "loop_closure_tests.rs"]
mod tests;
