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
//!    beyond the radius is found too. In a piece of the map placed by a guess (after a lost
//!    frame, until a loop joins it), every keyframe before the piece, however recent.
//! 2. Appearance: of those, the [`LoopParams::matched_candidates`] with the best
//!    bag-of-words scores are matched by unguided ORB matching of the keyframes' place
//!    features ([`stride_frontend::PlaceFeature`]: multi-scale ORB detected in each
//!    keyframe, whose descriptors, unlike those of tracked corners, repeat from pass to
//!    pass; a keyframe without them uses its mapped features): Hamming bound, Lowe's ratio,
//!    one claim per feature. The candidate with the most matches is verified.
//! 3. Geometry: RANSAC over the 3-D/3-D pairs (the two keyframes' measurements), refined:
//!    the new keyframe's pose relative to the old one, with at least
//!    [`LoopParams::min_inliers`] inliers and a third of the matches.
//! 4. Correction: a pose graph over the keyframes after the candidate (consecutive keyframes
//!    and those tied by depth, revisit or earlier loop links held at their current relative
//!    poses, weighted by their information; the loop by the verified pose), the older ones
//!    held fixed; points move with the keyframe that made them. The loop stays as a
//!    pose-pose edge; a joined piece's guessed link takes the corrected relative pose.
//! 5. Fusion: the keyframe's features are matched again against the map around the
//!    corrected pose (a point of its own that matches an old one is merged into it), and the
//!    local window is optimized again.
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
use stride_frontend::{InlierTest, PackedFeature, PlaceFeature};

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
    /// Of all the candidates above, those with the best bag-of-words scores are matched
    /// feature by feature (about 2 ms each), at most this many (with appearance search on).
    pub matched_candidates: usize,
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
            matched_candidates: 2,
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
    /// Points of the keyframe fused with old ones by the matching after the correction.
    pub fused: usize,
}

/// Standard deviations (m, rad) of a consecutive-keyframe link without odometry
/// information: 1 cm and 1 degree.
const DEFAULT_LINK_SIGMA: (f64, f64) = (0.01, 0.017_453_292_519_943_295);

/// A verified loop: the old keyframe, the match and inlier counts, the new keyframe's pose
/// relative to the old one and in the world (through the old one's pose), and its
/// information (left perturbation in the old camera's frame, as RANSAC gives it, and in
/// the optimizer's tangent space).
struct Verified {
    matched: KeyframeId,
    matches: usize,
    inliers: usize,
    world_from_new: Isometry3<f64>,
    matched_from_new: Isometry3<f64>,
    information_left: Matrix6<f64>,
    information: Matrix6<f64>,
}

/// The keyframes' place features and bags of words (see
/// [`LoopParams::appearance_candidates`]).
pub(crate) struct Places {
    vocabulary: Option<std::sync::Arc<Vocabulary>>,
    database: PlaceDatabase,
    /// Each live keyframe's place features (none kept when loop closure is off).
    features: BTreeMap<KeyframeId, Vec<PackedFeature>>,
    keep_features: bool,
}

impl Places {
    /// Forgets keyframe `id` (culled from the map).
    pub(crate) fn forget(&mut self, id: KeyframeId) {
        self.database.remove(id);
        self.features.remove(&id);
    }

    /// Keeps keyframe `id`'s place features (when loop closure is on).
    pub(crate) fn keep(&mut self, id: KeyframeId, features: &[PlaceFeature]) {
        if self.keep_features && !features.is_empty() {
            self.features
                .insert(id, features.iter().map(PackedFeature::new).collect());
        }
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
            features: BTreeMap::new(),
            keep_features: params.enabled,
        })
    }
}

impl Backend {
    /// The place features of the map's keyframes (those kept: none when loop closure is
    /// off), by keyframe: what a saved map carries for relocalization and loop closure in a
    /// later run. Their points and covariances come back in f32 precision.
    pub fn place_features(&self) -> BTreeMap<KeyframeId, Vec<PlaceFeature>> {
        self.places
            .features
            .iter()
            .filter(|(id, _)| self.map.keyframe(**id).is_some())
            .map(|(&id, f)| (id, f.iter().map(PackedFeature::feature).collect()))
            .collect()
    }

    /// Keyframe `k`'s features for matching keyframe against keyframe, with their points in
    /// its camera frame: its place features, or for a keyframe without them (from a saved
    /// map) its mapped features.
    fn matchable_features(&self, k: KeyframeId) -> Vec<([u8; 32], Measurement)> {
        if let Some(f) = self.places.features.get(&k) {
            return f.iter().map(|p| (p.descriptor, p.measurement())).collect();
        }
        self.map.keyframe(k).map_or_else(Vec::new, |kf| {
            kf.features
                .iter()
                .filter(|f| f.point.is_some())
                .filter_map(|f| Some((f.descriptor?, f.measurement?)))
                .collect()
        })
    }

    /// Adds keyframe `id`'s bag of words (of its place features) to the place database
    /// (culling removes it again); nothing when appearance search is off.
    pub(crate) fn index_place(&mut self, id: KeyframeId) {
        let features = self.matchable_features(id);
        self.index_features(id, &features);
    }

    /// [`Backend::index_place`] with keyframe `id`'s features already at hand.
    fn index_features(&mut self, id: KeyframeId, features: &[([u8; 32], Measurement)]) {
        let Places {
            vocabulary,
            database,
            ..
        } = &mut self.places;
        if let Some(v) = vocabulary {
            let descriptors: Vec<[u8; 32]> = features.iter().map(|f| f.0).collect();
            database.add(id, v.transform(&descriptors));
        }
    }

    /// Looks for a loop at keyframe `id` and closes it (see the module documentation),
    /// unless it is `tied` to an old place already (a revisit link or a loop within the last
    /// `window_keyframes` keyframes) and not in a piece placed by a guess. Returns what was done,
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
        let query = self.matchable_features(id);
        self.index_features(id, &query);
        if tied && self.unjoined_from.is_none() {
            // Tied to an old place already: the loop is closed, and a pose graph would only
            // pull against what bundle adjustment holds (measured on teddy's 5,000-frame
            // pingpong: 142 such loops, ATE 8.7 against 6.8 mm).
            return Ok(None);
        }
        let Some(verified) = self.find_loop(id, &query, &params) else {
            return Ok(None);
        };
        let before = self.map.pose_of(id).unwrap_or(verified.world_from_new);
        let moved = self.correct_loop(id, &verified)?;
        // A loop with a keyframe before the piece the new one is in joins the two, and the
        // guess that placed each piece since replaces its link by where the join put it:
        // a keyframe whose only tie is that link would otherwise go back to the guess.
        if let Some(start) = self.unjoined_from.filter(|&s| verified.matched < s) {
            let starts: Vec<KeyframeId> = self.piece_starts.range(start..=id).copied().collect();
            for s in starts {
                let relative = self
                    .map
                    .keyframe(s)
                    .and_then(|k| k.odometry.as_ref())
                    .and_then(|e| {
                        Some(self.map.pose_of(e.previous)?.inverse() * self.map.pose_of(s)?)
                    });
                if let (Some(r), Some(e)) = (relative, self.map.odometry_mut(s)) {
                    e.previous_from_this = r;
                }
            }
            self.unjoined_from = None;
            self.guessed_start = None;
        }
        let step = before.inverse() * verified.world_from_new;
        // The loop stays as an edge, and the keyframe's features are matched again against
        // the map around its corrected pose: the points mapped twice are fused. The final
        // optimization spreads it over the whole span (not `EdgeKind::Revisit`: capped, the
        // demo's lap lost 0.71 -> 0.84 mm).
        self.add_measured_edge(
            (verified.matched, id, crate::window::EdgeKind::Loop),
            verified.matched_from_new,
            &verified.matched_from_new,
            &verified.information_left,
        );
        let pose_cov = verified
            .information
            .try_inverse()
            .unwrap_or_else(|| Matrix6::identity() * 1e-4);
        let (reobserved, fused) = self.match_local_map(id, None, &pose_cov);
        let window = crate::window::local_window(&self.map, id, &self.config);
        self.optimize(&window, self.config.local_iterations)?;
        tracing::debug!(
            "keyframe {id}: loop closed with keyframe {} ({} inliers of {} matches), moved {:.1} mm, {reobserved} map points re-observed, {fused} fused",
            verified.matched,
            verified.inliers,
            verified.matches,
            step.translation.vector.norm() * 1e3
        );
        Ok(Some(LoopReport {
            matched: verified.matched,
            matches: verified.matches,
            inliers: verified.inliers,
            correction_m: step.translation.vector.norm(),
            correction_rad: step.rotation.angle(),
            moved_keyframes: moved,
            fused,
        }))
    }

    /// Steps 1-3: the old keyframe keyframe `id` sees again, verified.
    /// `query`: keyframe `id`'s features ([`Backend::matchable_features`]).
    fn find_loop(
        &self,
        id: KeyframeId,
        query: &[([u8; 32], Measurement)],
        params: &crate::LoopParams,
    ) -> Option<Verified> {
        let kf = self.map.keyframe(id)?;
        // Old keyframes already tied to this one (by tracks or the local map's matching)
        // are no loop to close.
        let tied = |k: KeyframeId| {
            kf.covisibility.get(&k).copied().unwrap_or(0) >= params.connected_points
        };
        // In a piece placed by a guess, every keyframe before the piece is a candidate,
        // however recent: the piece may start right after the place it should join.
        let old = |k: KeyframeId| match self.unjoined_from {
            Some(start) if start <= id => k < start && !tied(k),
            _ => k + params.min_age_keyframes <= id && !tied(k),
        };
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
            // Only the candidates that look most alike are matched feature by feature.
            let score = |k: KeyframeId| {
                self.places
                    .database
                    .get(k)
                    .map_or(0.0, |other| bow.score(other))
            };
            let mut ranked: Vec<(f32, KeyframeId)> = near.iter().map(|&k| (score(k), k)).collect();
            ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            near = ranked
                .into_iter()
                .take(params.matched_candidates)
                .map(|(_, k)| k)
                .collect();
        }
        // Keyframe against keyframe, by their place features.
        let query_desc: Vec<[u8; 32]> = query.iter().map(|q| q.0).collect();
        let m = &self.config.matching;
        let mut best: Option<(KeyframeId, Vec<(Measurement, Measurement)>)> = None;
        for &c in &near {
            let reference = self.matchable_features(c);
            let ref_desc: Vec<[u8; 32]> = reference.iter().map(|r| r.0).collect();
            let pairs: Vec<(Measurement, Measurement)> =
                match_descriptors(&query_desc, &ref_desc, m.max_hamming, m.ratio)
                    .into_iter()
                    .filter_map(|(qi, ri)| Some((reference.get(ri)?.1, query.get(qi)?.1)))
                    .collect();
            if best.as_ref().is_none_or(|(_, b)| pairs.len() > b.len()) {
                best = Some((c, pairs));
            }
        }
        let (matched, pairs) = best.filter(|(_, p)| p.len() >= params.min_inliers)?;
        let corrs: Vec<Correspondence> = pairs
            .iter()
            .map(|&(reference, current)| Correspondence { reference, current })
            .collect();
        let ransac = MotionParams {
            test: InlierTest::Mahalanobis { chi2: 11.34 },
            max_iterations: 1000,
            min_inliers: params.min_inliers,
            model_noise_m: self
                .config
                .model_noise_m
                .max(stride_frontend::recovery::ORB_MIN_MODEL_NOISE_M),
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
        let world_from_matched = self.map.pose_of(matched)?;
        Some(Verified {
            matched,
            matches: pairs.len(),
            inliers: e.inlier_count,
            world_from_new: world_from_matched * e.ref_from_cur,
            matched_from_new: e.ref_from_cur,
            information_left: e.information,
            // A right perturbation does not depend on the frame the pose is expressed from.
            information: tangent_information(&e.ref_from_cur, &e.information),
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
        // The links that tie keyframes beyond their neighbours (depth, revisits, earlier
        // loops) keep their current shape too, so that the correction goes where nothing
        // holds the keyframes yet.
        for e in &self.pose_edges {
            let (Some(&from), Some(&to)) = (index.get(&e.from), index.get(&e.to)) else {
                continue;
            };
            if let (Some(a), Some(b)) = (poses.get(from), poses.get(to)) {
                problem.pose_edges.push(PoseEdge {
                    from,
                    to,
                    from_from_to: a.inverse() * b,
                    information: e.information,
                });
            }
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
