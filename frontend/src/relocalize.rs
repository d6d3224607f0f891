//! Relocalization by appearance: a frame that neither Lucas-Kanade nor the recent keyframes
//! ([`crate::recovery`]) can place is looked up among every keyframe the run may come back
//! to, and tracking resumes in the same map instead of at a guessed pose.
//!
//! The odometry remembers a saved map's keyframes ([`VisualOdometry::start_in_map`]) and
//! this run's own: one keyframe whenever the camera has moved 0.15 m or turned 15 degrees
//! since the last one kept (the recent keyframes' spacing), at most
//! `relocalization_keyframes` of them (the oldest forgotten first). This run's are
//! remembered by their place features (up to 1,000 multi-scale ORB features detected in
//! the keyframe, with depth, kept in f32: about 75 KB each): corners detected where they
//! are, which a later view finds again, unlike the tracking's corners, described where
//! Lucas-Kanade carried them (a frame jumping back to a place the run passed matched 43 of
//! those at most, and 98 inliers of place features). A saved map's keyframes hold their
//! mapped features (the tracking's corners) and, from format version 2 on, their place
//! features. Each has a bag of words ([`crate::place`], the shipped vocabulary). A query
//! frame's ORB features (multi-scale, plus, with a saved map, its tracking corners
//! described as the map's are) give its own bag; the [`SHORTLIST`] keyframes with the best
//! scores are matched by descriptor, and RANSAC runs on the [`RELOCALIZATION_CANDIDATES`]
//! with the most matches, as for recovery but with more support required ([`MIN_INLIERS`],
//! a third of the matches). A saved map small enough to fit the shortlist is thus searched
//! exhaustively.
//!
//! The run's own keyframes are placed by the odometry's poses: a relocalized frame is put
//! where the odometry had put that place, so the jump it makes is consistent with the
//! trajectory up to the drift accumulated since, which the back end's loop closure then
//! corrects. The keyframe made of a relocalized frame is linked to the keyframe it was
//! found against, by the pose measured against it (not to the previous keyframe, which
//! would state that drift as a measurement): the back end puts it where its corrected map
//! has that place.

use crate::error::FrontendError;
use crate::features::OrbDescriptor;
use crate::klt::Pyramid;
use crate::motion::{ransac, Correspondence, MotionParams};
use crate::orb::{match_points, orb_points, OrbPoint, MAX_HAMMING, RATIO};
use crate::points::{measure, ShutterMotion};
use crate::recovery::{
    estimate_against, keep_best, orb_motion_params, Anchor, AnchorKeyframe, Recovered, SPACING_M,
    SPACING_RAD,
};
use crate::result::{OdometryLink, PackedFeature, TrackingStatus};
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, UnitQuaternion};
use opencv::core::Point2f;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use stride_core::frame::RgbdFrame;
use stride_core::image::GrayImage;

use crate::place::{PlaceDatabase, Vocabulary};

/// Keyframes with the best bag-of-words scores that are matched by descriptor.
pub const SHORTLIST: usize = 20;
/// Keyframes of the shortlist tried with RANSAC: those with the most descriptor matches.
pub const RELOCALIZATION_CANDIDATES: usize = 5;
/// Fewest RANSAC inliers of a relocalization (or `recovery_min_inliers` when larger), and
/// they must be a third of the matches: a place is searched anywhere, so it needs more
/// support than a recovery against the last keyframes (as loop closure's 30).
pub const MIN_INLIERS: usize = 30;
/// A weakly tracked frame's pose (fewer than [`crate::VoConfig::keyframe_min_inliers`]
/// tracking inliers) is replaced by one from ORB matches with more than this many times
/// its inliers. The two counts are not alike: ORB poses assume at least 5 mm of noise
/// ([`crate::recovery::ORB_MIN_MODEL_NOISE_M`]), the tracks 2 mm, and a sub-pixel track
/// is the more accurate measurement. With 2 (before the ORB floor), teddy_200 at every 10th
/// frame took frame 10 from ORB matches on 2 of 5 seeds (8.4-8.5 mm against 4.1-4.5);
/// with 3: seeds 1-5 4.3 mm, every 20th frame 8.4 -> 6.7 mm (live 19.2 -> 8.0).
pub const WEAK_REPLACED_BY_INLIER_RATIO: usize = 3;
/// The Hamming bound of a lost frame's last chance at recovery, tried after relocalization
/// and the depth alignment from its tracks' pose (`VisualOdometry::search_by_appearance`):
/// ORB-SLAM's looser bound. After a second or more of dropped frames the views differ by
/// 0.4-0.6 m and 25-35 degrees and few matches pass the usual bounds (teddy_200 with 1.25 s
/// dropped at 1 s: 8 at most, against 144 with these, 32 of them inliers); RANSAC, with
/// its 2,000 draws and the same inlier count required, sorts out the rest.
pub const LOST_MAX_HAMMING: u32 = 100;
/// Lowe's ratio of a lost frame's last chance at recovery (see [`LOST_MAX_HAMMING`]).
pub const LOST_RATIO: f64 = 0.95;
/// Fewest tracks of a frame lost after dropped frames that must agree on a pose for it to
/// start the depth alignment (`VisualOdometry::search_by_appearance`): too few to place
/// the frame, enough for a start nearer than the motion model's extrapolation.
pub const WEAK_GUESS_MIN_INLIERS: usize = 6;
/// The overlap (a fraction of the frame's depth samples paired with the keyframe's surface)
/// a depth alignment started at the tracks' pose must reach, below the alignment's own 0.4:
/// the tracks and the depth agree, two cues where a start at the motion model's guess has
/// one. After a second and a half of dropped frames the camera has moved about 0.45 m and
/// the views share a third of their surface or less.
pub const WEAK_GUESS_MIN_PAIRED_FRACTION: f64 = 0.3;

/// The keyframes relocalization searches (see the module documentation).
pub(crate) struct PlaceMemory {
    vocabulary: Arc<Vocabulary>,
    database: PlaceDatabase,
    keyframes: BTreeMap<u64, AnchorKeyframe>,
    /// This run's keyframes kept, oldest first.
    own: VecDeque<u64>,
    /// The pose of the last one.
    last_own: Option<Isometry3<f64>>,
    /// A saved map's keyframes were added: the first frame must be relocalized in them.
    pub(crate) saved_map: bool,
}

impl PlaceMemory {
    /// Empty, with the shipped vocabulary.
    pub(crate) fn new() -> Result<Self, FrontendError> {
        Ok(Self {
            vocabulary: Vocabulary::shipped()?,
            database: PlaceDatabase::new(),
            keyframes: BTreeMap::new(),
            own: VecDeque::new(),
            last_own: None,
            saved_map: false,
        })
    }

    /// Keyframes held.
    pub(crate) fn len(&self) -> usize {
        self.keyframes.len()
    }

    fn insert(&mut self, kf: AnchorKeyframe) {
        let descriptors: Vec<OrbDescriptor> = kf.points.iter().map(|p| p.descriptor).collect();
        self.database
            .add(kf.id, self.vocabulary.transform(&descriptors));
        self.keyframes.insert(kf.id, kf);
    }

    /// Adds a saved map's keyframes.
    pub(crate) fn add_saved_map(&mut self, anchors: Vec<Anchor>) {
        self.saved_map |= !anchors.is_empty();
        for a in anchors {
            self.insert(AnchorKeyframe::from(a));
        }
    }

    /// Where a run starts whose first frame the saved map could not place: at the saved
    /// map's newest keyframe (a run often goes on where the last one ended), as a predicted
    /// link to it (no information, no inliers) and its `world_from_camera`.
    /// `None` without a saved map, or once this run has keyframes of its own.
    pub(crate) fn guess_in_saved_map(&self) -> Option<(OdometryLink, Isometry3<f64>)> {
        if !self.saved_map || !self.own.is_empty() {
            return None;
        }
        let (&id, kf) = self.keyframes.last_key_value()?;
        let link = OdometryLink {
            previous_id: id,
            previous_from_this: Isometry3::identity(),
            information: nalgebra::Matrix6::zeros(),
            inliers: 0,
        };
        Some((link, kf.world_from_camera))
    }

    /// Whether a keyframe at `world_from_kf` would be remembered: it is far enough from the
    /// last one kept ([`SPACING_M`], [`SPACING_RAD`]), or none is kept yet.
    pub(crate) fn wants(&self, world_from_kf: &Isometry3<f64>) -> bool {
        self.last_own.is_none_or(|last| {
            let step = last.inverse() * world_from_kf;
            step.translation.vector.norm() >= SPACING_M || step.rotation.angle() >= SPACING_RAD
        })
    }

    /// Remembers one of this run's keyframes by its ORB points with depth (its place
    /// features: corners detected where they are, which a later view of the place finds
    /// again far more often than the tracking's corners, described where Lucas-Kanade
    /// carried them) when [`Self::wants`] it, forgetting the oldest beyond `cap`.
    pub(crate) fn remember(
        &mut self,
        id: u64,
        world_from_kf: Isometry3<f64>,
        points: Vec<OrbPoint>,
        cap: usize,
    ) {
        if !self.wants(&world_from_kf) {
            return;
        }
        self.insert(AnchorKeyframe {
            id,
            world_from_camera: world_from_kf,
            points: points
                .iter()
                .map(|p| PackedFeature::new(&p.into()))
                .collect(),
        });
        self.own.push_back(id);
        self.last_own = Some(world_from_kf);
        while self.own.len() > cap {
            if let Some(old) = self.own.pop_front() {
                self.keyframes.remove(&old);
                self.database.remove(old);
            }
        }
    }

    /// The keyframes to try for `query`, most descriptor matches first (ties by identifier),
    /// with their match counts: the [`SHORTLIST`] best by bag of words, then the
    /// [`RELOCALIZATION_CANDIDATES`] best of those by matches, each with its features as
    /// the matcher takes them.
    fn candidates(&self, query: &[OrbPoint]) -> Vec<(usize, &AnchorKeyframe, Vec<OrbPoint>)> {
        let descriptors: Vec<OrbDescriptor> = query.iter().map(|p| p.descriptor).collect();
        let bow = self.vocabulary.transform(&descriptors);
        let mut ranked: Vec<(usize, &AnchorKeyframe, Vec<OrbPoint>)> = self
            .database
            .query(&bow, SHORTLIST, |_| true)
            .iter()
            .filter_map(|m| self.keyframes.get(&m.id))
            .map(|kf| {
                let points = kf.orb_points();
                (match_points(query, &points).len(), kf, points)
            })
            .collect();
        ranked.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.id.cmp(&b.1.id)));
        ranked.truncate(RELOCALIZATION_CANDIDATES);
        ranked
    }
}

/// What a lost or weakly tracked frame's search starts from: its predicted pose
/// (`world_from_pred`), its tracks' correspondences with world points, and the gyroscope's
/// rotation since the previous frame (`None` when it measured none).
pub(crate) type Guesses<'a> = (
    &'a Isometry3<f64>,
    &'a [Correspondence],
    Option<&'a UnitQuaternion<f64>>,
);

impl VisualOdometry {
    /// Looks for the pose of a frame that tracking lost (`lost`) or kept with only
    /// `inliers` inliers: recovery against the recent keyframes (a weak estimate is replaced
    /// only by one with [`WEAK_REPLACED_BY_INLIER_RATIO`] times its inliers), then, for a
    /// lost frame, relocalization among the remembered keyframes, the depth alignment from
    /// where the frame's few tracks agree (after dropped frames), recovery within looser
    /// bounds (after dropped frames, also near the rough poses too few matches give:
    /// `crate::guided`), the depth alignment with the newest keyframe from the predicted
    /// pose `world_from_pred`, and (after dropped frames) the depth search. After dropped
    /// frames a pose from ORB matches is checked against the frame's depth
    /// (`checked_orb_pose`). A pose whose rotation from the previous frame
    /// disagrees with `gyroscope` (the gyroscope's rotation over the same interval, `None`
    /// when it measured none) is refused and the next way tried, as tracking's estimates
    /// are: a gyroscope measures the turn across a gap better than a few ORB matches
    /// between distant views do. A recovered pose that is a step no camera makes from a
    /// tracked previous frame is refused too (`held_to_step_bounds`). `None` when none
    /// finds it.
    pub(crate) fn search_by_appearance(
        &mut self,
        frame: &RgbdFrame,
        pyr: &Pyramid,
        gray_img: &GrayImage,
        (lost, inliers): (bool, usize),
        (world_from_pred, tracked, gyroscope): Guesses,
    ) -> Result<Option<(Recovered, TrackingStatus)>, FrontendError> {
        let at_least = WEAK_REPLACED_BY_INLIER_RATIO * inliers;
        let across_gap = self
            .motion_model
            .across_gap(self.prev_t, frame.t_s)
            .is_some();
        let recovered = self.recover(frame, pyr, at_least, (MAX_HAMMING, RATIO), None)?;
        let found = (recovered, TrackingStatus::Recovered);
        if let Some(r) = self.checked_orb_pose(frame, found, gyroscope, across_gap) {
            return Ok(Some(r));
        }
        if !lost {
            return Ok(None);
        }
        if self.config.relocalization_keyframes.is_some() && self.places.len() > 0 {
            match self.relocalize(frame, pyr, gray_img) {
                Ok(r) => {
                    let found = (Some(r), TrackingStatus::Relocalized);
                    if let Some(r) = self.checked_orb_pose(frame, found, gyroscope, across_gap) {
                        return Ok(Some(r));
                    }
                }
                Err(FrontendError::NotLocalized { most_matches, .. }) => {
                    tracing::debug!(
                        "frame {}: not relocalized ({most_matches} matches at most)",
                        frame.index
                    );
                }
                Err(e) => return Err(e),
            }
        }
        // After dropped frames, the depth alignment starts where the frame's few tracks
        // agree, if they do (the motion model's extrapolation over the gap can be far off).
        let after_gap = self.config.depth_alignment && across_gap;
        let mut params = MotionParams::from_config(&self.config);
        params.min_inliers = WEAK_GUESS_MIN_INLIERS;
        let weak = after_gap
            .then(|| ransac(tracked, &params, &mut self.rng))
            .flatten()
            .map(|(pose, ..)| pose);
        let aligned =
            weak.and_then(|w| self.align_depth(frame, &w, Some(WEAK_GUESS_MIN_PAIRED_FRACTION)));
        if let Some(r) = self.held_to_gyroscope(aligned, gyroscope) {
            return Ok(Some((r, TrackingStatus::DepthAligned)));
        }
        // The last chances: ORB matches within looser bounds (and after dropped frames, near
        // the rough pose too few of them give), then the depth alignment from the motion
        // model's guess (for an unbroken run of frames, a good start).
        let guided = across_gap.then_some(crate::guided::MIN_ROUGH_INLIERS);
        let bounds = (LOST_MAX_HAMMING, LOST_RATIO);
        let recovered = self.recover(frame, pyr, at_least, bounds, guided)?;
        let found = (recovered, TrackingStatus::Recovered);
        if let Some(r) = self.checked_orb_pose(frame, found, gyroscope, across_gap) {
            return Ok(Some(r));
        }
        let aligned = self.align_depth(frame, world_from_pred, None);
        if let Some(r) = self.held_to_gyroscope(aligned, gyroscope) {
            return Ok(Some((r, TrackingStatus::DepthAligned)));
        }
        // After dropped frames the guess can be beyond the alignment's reach: many starts.
        let searched = after_gap
            .then(|| self.search_depth(frame, world_from_pred))
            .flatten();
        Ok(self
            .held_to_gyroscope(searched, gyroscope)
            .map(|r| (r, TrackingStatus::DepthAligned)))
    }

    /// A pose from ORB matches (`found`, with the status it earns) held, when recovery
    /// found it, to the step bounds ([`Self::held_to_step_bounds`]), then to `gyroscope`
    /// ([`Self::held_to_gyroscope`]) and, for the first frame after dropped frames
    /// (`across_gap`), checked against the frame's depth
    /// ([`VisualOdometry::checked_by_depth`]): the depth's pose (with the matches that hold
    /// there as tracks), if it moves the pose too far and the gyroscope does not disagree
    /// with it, with status `DepthAligned`.
    fn checked_orb_pose(
        &mut self,
        frame: &RgbdFrame,
        (found, status): (Option<Recovered>, TrackingStatus),
        gyroscope: Option<&UnitQuaternion<f64>>,
        across_gap: bool,
    ) -> Option<(Recovered, TrackingStatus)> {
        let found = match status {
            TrackingStatus::Recovered => self.held_to_step_bounds(frame, found),
            _ => found,
        };
        let r = self.held_to_gyroscope(found, gyroscope)?;
        let by_depth = across_gap
            .then(|| self.checked_by_depth(frame, &r))
            .flatten();
        match self.held_to_gyroscope(by_depth, gyroscope) {
            Some(d) => Some((d, TrackingStatus::DepthAligned)),
            None => Some((r, status)),
        }
    }

    /// `found`, unless its step from the previous frame is one no camera makes
    /// ([`crate::motion_model::MotionModel::refuses_search`]): refused, logged and counted
    /// ([`VisualOdometry::recoveries_refused`]). On teddy_200 blurred to 25 px (peers'
    /// injector) with `fb_max_error_px` at 1.5-2 px, frame 184 (seeds 2 and 7) was
    /// recovered from 31 ORB inliers 0.34 m from frame 183, and bundle adjustment kept it:
    /// ATE 76 and 58 mm; refused, 8.2 and 9.1 mm.
    fn held_to_step_bounds(
        &mut self,
        frame: &RgbdFrame,
        found: Option<Recovered>,
    ) -> Option<Recovered> {
        let r = found?;
        let prev_from_cur = self.world_from_prev.inverse() * r.world_from_cur;
        let cfg = &self.config;
        if !(self.motion_model).refuses_search(self.prev_t, frame.t_s, &prev_from_cur, cfg) {
            return Some(r);
        }
        tracing::debug!(
            "frame {}: recovery against keyframe {} refused, {:.3} m from the previous \
             frame in {:.3} s",
            frame.index,
            r.matched_keyframe,
            prev_from_cur.translation.vector.norm(),
            frame.t_s - self.prev_t
        );
        None
    }

    /// Poses that recovery found and refused because the step from the previous frame,
    /// whose pose tracking had estimated, was longer or faster than any camera makes
    /// (`max_step_translation_m`, `max_step_rotation_deg`, `max_speed_m_s`), frames apart
    /// with none dropped between. The frame then went on to the next way of placing it.
    pub fn recoveries_refused(&self) -> usize {
        self.motion_model.refused_searches
    }

    /// `found`, unless its rotation from the previous frame disagrees with `gyroscope`
    /// (see [`VisualOdometry::disagrees_with_gyroscope`], which counts the refusal).
    fn held_to_gyroscope(
        &mut self,
        found: Option<Recovered>,
        gyroscope: Option<&UnitQuaternion<f64>>,
    ) -> Option<Recovered> {
        let r = found?;
        let prev_from_cur = self.world_from_prev.inverse() * r.world_from_cur;
        (!self.disagrees_with_gyroscope(&prev_from_cur, gyroscope)).then_some(r)
    }

    /// Looks for the current frame's pose among the remembered keyframes (see the module
    /// documentation). [`FrontendError::NotLocalized`], saying what was found, when no
    /// candidate gives [`MIN_INLIERS`] (or `recovery_min_inliers`, if larger) inliers that
    /// are a third of its matches.
    pub(crate) fn relocalize(
        &mut self,
        frame: &RgbdFrame,
        pyr: &Pyramid,
        gray_img: &GrayImage,
    ) -> Result<Recovered, FrontendError> {
        let (camera, config) = (&self.camera, &self.config);
        let still = ShutterMotion::default();
        let mut query = orb_points(
            &mut self.recent.orb,
            &pyr.gray,
            &frame.depth_m,
            camera,
            &still,
            config,
        )?;
        // A saved map's keyframes hold their mapped features, the tracking's corners with
        // ORB descriptors at full resolution: the same corners of this frame match them
        // best. This run's keyframes hold place features, as the query's ORB points.
        let corners = if self.places.saved_map {
            self.detector.detect(&pyr.gray, &[], config)?
        } else {
            Vec::new()
        };
        let pts: Vec<Point2f> = corners.iter().map(|c| c.px).collect();
        let descriptors = self.detector.describe(&pyr.gray, gray_img, &pts)?;
        for (px, d) in pts.iter().zip(descriptors) {
            let m = measure(&frame.depth_m, camera, (px.x, px.y), &still, config);
            if let (Some(descriptor), Some(p_camera)) = (d, m) {
                query.push(OrbPoint {
                    px: *px,
                    descriptor,
                    p_camera,
                });
            }
        }
        let params = orb_motion_params(config, config.recovery_min_inliers.max(MIN_INLIERS));
        let mut best = None;
        let most_matches = {
            let ranked = self.places.candidates(&query);
            for (_, a, points) in &ranked {
                let found = estimate_against(
                    &query,
                    points,
                    &a.world_from_camera,
                    &params,
                    config.refine_iterations,
                    &mut self.rng,
                );
                // A place found anywhere must be clearly supported: a third of the matches.
                let found = found.filter(|(e, pairs)| 3 * e.inlier_count >= pairs.len());
                keep_best(
                    &mut best,
                    found.map(|(e, p)| (e, p, (a.id, a.world_from_camera))),
                );
            }
            ranked.first().map_or(0, |r| r.0)
        };
        match best {
            Some((e, pairs, matched)) => Ok(self.recovered(&query, e, &pairs, matched)),
            None => Err(FrontendError::NotLocalized {
                index: frame.index,
                t_s: frame.t_s,
                keyframes: self.places.len(),
                features: query.len(),
                most_matches,
                min_inliers: self.config.recovery_min_inliers.max(MIN_INLIERS),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::points::Measurement;
    use nalgebra::{Matrix3, Point3};

    fn points(seed: u8) -> Vec<OrbPoint> {
        (0..50u8)
            .map(|i| OrbPoint {
                px: Point2f::new(f32::from(i), 0.0),
                descriptor: [i.wrapping_mul(seed); 32],
                p_camera: Measurement {
                    p: Point3::new(0.0, 0.0, 1.0),
                    cov: Matrix3::identity() * 1e-6,
                },
            })
            .collect()
    }

    fn at(x: f64) -> Isometry3<f64> {
        Isometry3::translation(x, 0.0, 0.0)
    }

    #[test]
    fn keyframes_are_remembered_apart_and_the_oldest_forgotten_beyond_the_cap() {
        let mut m = PlaceMemory::new().unwrap();
        assert!(m.wants(&at(0.0)));
        // 0.06 m apart: one kept per 0.15 m (every third, 0.18 m apart).
        for k in 0..10u64 {
            m.remember(k, at(0.06 * k as f64), points(3), 100);
        }
        let kept: Vec<u64> = m.keyframes.keys().copied().collect();
        assert_eq!(kept, vec![0, 3, 6, 9]);
        assert!(!m.wants(&at(0.6)) && m.wants(&at(0.7)));
        // A cap of 2 forgets the oldest, in the database too.
        m.remember(10, at(1.0), points(5), 2);
        assert_eq!(m.keyframes.keys().copied().collect::<Vec<_>>(), vec![9, 10]);
        assert_eq!(m.database.len(), 2);
        assert!(!m.saved_map);
        assert_eq!(m.keyframes[&10].points.len(), 50);
    }
}
