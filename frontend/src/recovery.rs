//! Wide-baseline recovery: a frame that Lucas-Kanade cannot follow (a dropped stretch of
//! frames, a jolt, a fast turn) is matched by appearance instead.
//!
//! The odometry keeps the last few keyframes' images, depth and poses. When tracking fails
//! or keeps fewer than `keyframe_min_inliers` inliers, multi-scale ORB features
//! ([`crate::orb`], computed for a keyframe only the first time it is needed) of the frame
//! and of each recent keyframe are matched, unguided, since the prediction is what failed:
//! each feature's nearest descriptor by Hamming distance, kept when close enough
//! ([`crate::orb::MAX_HAMMING`]), clearly better than the second nearest
//! ([`crate::orb::RATIO`]), and the only one claiming that keyframe feature.
//! RANSAC over the 3-D/3-D matches (the tracking's estimator, with more iterations for the
//! lower inlier ratio) gives the pose against the keyframe with the most inliers, and the
//! matched points, placed in the world by that keyframe, become the new keyframe's tracks:
//! tracking resumes on old points instead of starting afresh at a predicted pose.
//!
//! When the recent keyframes cannot place the frame either, [`crate::relocalize`] looks it
//! up among all the keyframes the run may come back to, by appearance; when that fails too,
//! its depth is aligned with the newest keyframe's ([`crate::depth_align`]).

use crate::depth_align::{align, DepthAlignParams, DepthAlignment, DepthView};
use crate::error::FrontendError;
use crate::features::OrbDescriptor;
use crate::keyframe::{rotate_cov, Track, TrackPoint};
use crate::klt::Pyramid;
use crate::motion::{polish, ransac, Correspondence, MotionEstimate, MotionParams};
use crate::orb::{
    match_points, match_points_within, orb_extractor, orb_points, OrbPoint, PLACE_LEVELS,
};
use crate::points::{Measurement, ShutterMotion};
use crate::vo::VisualOdometry;
use crate::VoConfig;
use crate::{PackedFeature, PlaceFeature};
use nalgebra::{Isometry3, Matrix6, Point2};
use opencv::core::Ptr;
use opencv::features2d::ORB;
use std::collections::VecDeque;
use std::rc::Rc;
use std::sync::Arc;
use stride_core::camera::PinholeCamera;
use stride_core::frame::RgbdFrame;
use stride_core::image::DepthImage;
use stride_core::rng::SplitMix64;

/// Kept keyframes are at least this far apart (m) ...
pub(crate) const SPACING_M: f64 = 0.15;
/// ... or this rotation apart (rad, 15 degrees), except the newest: a handful of them then
/// covers the last metre or so of the path, not the last few frames.
pub(crate) const SPACING_RAD: f64 = 0.26;
/// The newest keyframes whose depth is kept for the depth links at short baselines
/// ([`crate::depth_link`]), beside the spaced ones recovery keeps: under blur keyframes
/// come 1-2 cm apart, so these reach back 10-20 cm; each costs its depth image (1.2 MB at
/// VGA), shared with the spaced set where it belongs to both (teddy_200: peak RSS 153 ->
/// 164 MB). With 16 kept, teddy_200 at 25 px gave a mean 8.52 mm instead of 8.47 (seeds
/// 1-8).
pub(crate) const NEARBY_KEYFRAMES: usize = 10;

/// RANSAC iterations for the matches: their inlier ratio can be a quarter, where 300 (the
/// tracking default) finds a clean sample only about half of the time.
pub(crate) const RANSAC_ITERATIONS: usize = 2000;
/// The least isotropic noise (m) a pose from ORB matches assumes
/// ([`crate::VoConfig::model_noise_m`] when larger): an ORB corner found again from another
/// viewpoint, at another pyramid level, sits a pixel or more from where the first keyframe
/// saw it, which the 2 mm the tracking assumes for its sub-pixel tracks does not cover.
/// With 2 mm, teddy_200 at every 20th frame lost frame 160 on 4 of 5 RANSAC seeds (19 of
/// the 20 inliers needed); with 5 mm on none (ATE 6.9-8.9 mm; 6.1-8.1 mm once a weak
/// pose needed three times its inliers to be replaced). Loop closure uses the same.
pub const ORB_MIN_MODEL_NOISE_M: f64 = 0.005;

/// RANSAC settings for a pose from ORB matches (recovery, relocalization): `config`'s,
/// with [`RANSAC_ITERATIONS`] at most, [`ORB_MIN_MODEL_NOISE_M`] of noise at least and
/// `min_inliers` inliers.
pub(crate) fn orb_motion_params(config: &VoConfig, min_inliers: usize) -> MotionParams {
    MotionParams {
        max_iterations: RANSAC_ITERATIONS,
        min_inliers,
        model_noise_m: config.model_noise_m.max(ORB_MIN_MODEL_NOISE_M),
        ..MotionParams::from_config(config)
    }
}

/// A feature of a saved map's keyframe: one that observes a map point, or one of the
/// keyframe's place features.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorPoint {
    /// Pixel position in the keyframe (px).
    pub px: Point2<f32>,
    /// ORB descriptor.
    pub descriptor: OrbDescriptor,
    /// The map point (a place feature: its measured point) in the keyframe's camera frame
    /// (m), with the covariance of the keyframe's measurement of it (camera frame, m^2).
    pub p_camera: Measurement,
}

/// A keyframe of a saved map, as relocalization needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct Anchor {
    /// The map's identifier of the keyframe.
    pub id: u64,
    /// `world_from_camera` in the map's frame (m).
    pub world_from_camera: Isometry3<f64>,
    /// Its features that observe map points, then its place features.
    pub points: Vec<AnchorPoint>,
}

/// A remembered keyframe (a saved map's, or one of this run's) with its features, kept in
/// f32 ([`PackedFeature`]) since relocalization may hold thousands of them.
pub(crate) struct AnchorKeyframe {
    pub(crate) id: u64,
    pub(crate) world_from_camera: Isometry3<f64>,
    pub(crate) points: Vec<PackedFeature>,
}

impl AnchorKeyframe {
    /// Its features as the matcher takes them.
    pub(crate) fn orb_points(&self) -> Vec<OrbPoint> {
        self.points
            .iter()
            .map(|p| OrbPoint::from(p.feature()))
            .collect()
    }
}

impl From<Anchor> for AnchorKeyframe {
    fn from(a: Anchor) -> Self {
        Self {
            id: a.id,
            world_from_camera: a.world_from_camera,
            points: a
                .points
                .iter()
                .map(|p| {
                    PackedFeature::new(&PlaceFeature {
                        px: p.px,
                        descriptor: p.descriptor,
                        measurement: p.p_camera,
                    })
                })
                .collect(),
        }
    }
}

/// A recent keyframe as recovery needs it.
pub(crate) struct RecentKeyframe {
    /// Its identifier.
    pub(crate) id: u64,
    pyramid: Rc<Pyramid>,
    pub(crate) depth_m: Arc<DepthImage>,
    /// Its `world_from_camera`.
    pub(crate) world_from_kf: Isometry3<f64>,
    /// Its ORB points, computed the first time recovery needs them.
    pub(crate) points: Option<Vec<OrbPoint>>,
}

/// A keyframe's depth image and pose, as the depth links need them.
pub(crate) struct NearbyKeyframe {
    /// Its identifier.
    pub(crate) id: u64,
    /// Its depth image (m along the optical axis), shared with the spaced set.
    pub(crate) depth_m: Arc<DepthImage>,
    /// Its `world_from_camera`, as the odometry placed it.
    pub(crate) world_from_kf: Isometry3<f64>,
    /// Whether it was itself tied by depth links (a weak keyframe).
    pub(crate) linked: bool,
}

/// The most recent keyframes (oldest first) and the ORB extractor recovery uses.
pub(crate) struct RecentKeyframes {
    pub(crate) keyframes: VecDeque<RecentKeyframe>,
    /// The [`NEARBY_KEYFRAMES`] newest keyframes, spaced or not (oldest first).
    pub(crate) nearby: VecDeque<NearbyKeyframe>,
    pub(crate) orb: Ptr<ORB>,
    /// The extractor of keyframes' place features (fewer levels: every keyframe pays for
    /// it).
    pub(crate) place_orb: Ptr<ORB>,
}

impl RecentKeyframes {
    /// None yet.
    pub(crate) fn new() -> Result<Self, FrontendError> {
        Ok(Self {
            keyframes: VecDeque::new(),
            nearby: VecDeque::new(),
            orb: orb_extractor(8)?,
            place_orb: orb_extractor(PLACE_LEVELS)?,
        })
    }

    /// Adds keyframe `id` (sharing its pyramid, copying its depth), forgetting the oldest
    /// beyond `keep`. The previous newest is dropped if it is within the spacing
    /// ([`SPACING_M`], [`SPACING_RAD`]) of the one before it. The nearby ones keep the
    /// newest [`NEARBY_KEYFRAMES`], spaced or not.
    pub(crate) fn push(
        &mut self,
        id: u64,
        pyramid: &Rc<Pyramid>,
        depth_m: &DepthImage,
        (world_from_kf, linked): (Isometry3<f64>, bool),
        keep: usize,
    ) {
        let n = self.keyframes.len();
        if let (Some(a), Some(b)) = (
            n.checked_sub(2).and_then(|i| self.keyframes.get(i)),
            self.keyframes.back(),
        ) {
            let step = a.world_from_kf.inverse() * b.world_from_kf;
            if step.translation.vector.norm() < SPACING_M && step.rotation.angle() < SPACING_RAD {
                self.keyframes.pop_back();
            }
        }
        let depth_m = Arc::new(depth_m.clone());
        self.nearby.push_back(NearbyKeyframe {
            id,
            depth_m: Arc::clone(&depth_m),
            world_from_kf,
            linked,
        });
        while self.nearby.len() > NEARBY_KEYFRAMES {
            self.nearby.pop_front();
        }
        self.keyframes.push_back(RecentKeyframe {
            id,
            pyramid: Rc::clone(pyramid),
            depth_m,
            world_from_kf,
            points: None,
        });
        while self.keyframes.len() > keep {
            self.keyframes.pop_front();
        }
    }
}

/// A pose found by recovery.
#[derive(Debug)]
pub(crate) struct Recovered {
    pub(crate) world_from_cur: Isometry3<f64>,
    pub(crate) inliers: usize,
    pub(crate) iterations: usize,
    /// Information matrix of the pose (as [`MotionEstimate::information`]).
    pub(crate) information: Matrix6<f64>,
    /// Tracks of the inlier features, each carrying its matched world point, with the
    /// features' measurements in this frame.
    pub(crate) tracks: Vec<(Track, Option<Measurement>)>,
    /// Matches with the keyframe the pose was found against.
    pub(crate) matches: usize,
    /// That keyframe's identifier.
    pub(crate) matched_keyframe: u64,
    /// The frame's pose in that keyframe's camera frame (what was measured: the keyframe
    /// was placed in the world by the odometry when it was kept, with the drift of then).
    pub(crate) matched_from_cur: Isometry3<f64>,
}

impl Recovered {
    /// A frame placed by the depth alignment `a` with keyframe `kf_id` (at `world_from_kf`):
    /// no inliers and no tracks (the keyframe it starts detects new corners).
    pub(crate) fn by_depth(a: &DepthAlignment, kf_id: u64, world_from_kf: &Isometry3<f64>) -> Self {
        Self {
            world_from_cur: a.world_from_cur,
            inliers: 0,
            iterations: 0,
            information: a.information,
            tracks: Vec::new(),
            matches: 0,
            matched_keyframe: kf_id,
            matched_from_cur: world_from_kf.inverse() * a.world_from_cur,
        }
    }
}

/// The pose of a frame against one reference keyframe: the matches of `query` with the
/// keyframe's `points` (placed in the world by `world_from_kf`), RANSAC, polish. Returns the
/// estimate and the correspondences with their query indices.
pub(crate) fn estimate_against(
    query: &[OrbPoint],
    points: &[OrbPoint],
    world_from_kf: &Isometry3<f64>,
    params: &MotionParams,
    refine_iterations: usize,
    rng: &mut SplitMix64,
) -> Option<(MotionEstimate, Vec<(usize, Correspondence)>)> {
    let matches = match_points(query, points);
    estimate_from(
        query,
        points,
        matches,
        world_from_kf,
        params,
        refine_iterations,
        rng,
    )
}

/// [`estimate_against`] with the matches `(query, reference)` given.
pub(crate) fn estimate_from(
    query: &[OrbPoint],
    points: &[OrbPoint],
    matches: Vec<(usize, usize)>,
    world_from_kf: &Isometry3<f64>,
    params: &MotionParams,
    refine_iterations: usize,
    rng: &mut SplitMix64,
) -> Option<(MotionEstimate, Vec<(usize, Correspondence)>)> {
    let pairs: Vec<(usize, Correspondence)> = matches
        .into_iter()
        .filter_map(|(qi, ri)| {
            let (q, r) = (query.get(qi)?, points.get(ri)?);
            let reference = Measurement {
                p: world_from_kf * r.p_camera.p,
                cov: rotate_cov(world_from_kf, &r.p_camera.cov),
            };
            Some((
                qi,
                Correspondence {
                    reference,
                    current: q.p_camera,
                },
            ))
        })
        .collect();
    let corrs: Vec<Correspondence> = pairs.iter().map(|(_, c)| *c).collect();
    let (h, flags, it) = ransac(&corrs, params, rng)?;
    let e = polish(&corrs, h, flags, refine_iterations, params)?;
    Some((
        MotionEstimate {
            iterations: it,
            ..e
        },
        pairs,
    ))
}

/// An estimate, its matches, and the keyframe it was found against (identifier,
/// `world_from_camera`).
pub(crate) type Found = (
    MotionEstimate,
    Vec<(usize, Correspondence)>,
    (u64, Isometry3<f64>),
);

/// Keeps the estimate with more inliers (the earlier one on a tie).
pub(crate) fn keep_best(best: &mut Option<Found>, candidate: Option<Found>) {
    if let Some(c) = candidate {
        if best
            .as_ref()
            .is_none_or(|b| c.0.inlier_count > b.0.inlier_count)
        {
            *best = Some(c);
        }
    }
}

impl VisualOdometry {
    /// Looks for the current frame's pose by matching its ORB features against the recent
    /// keyframes' within `bounds` (`(max_hamming, ratio)`; usually
    /// [`crate::orb::MAX_HAMMING`] and [`crate::orb::RATIO`]); when none gives enough
    /// inliers and `guided` is given, near the rough poses that at least that many inliers
    /// give (`crate::guided`). `None` when recovery
    /// is off or no keyframe gives more than `at_least` (and `recovery_min_inliers`)
    /// inliers. The caller must start the new tracks' keyframe (`kf_count`).
    pub(crate) fn recover(
        &mut self,
        frame: &RgbdFrame,
        pyr: &Pyramid,
        at_least: usize,
        bounds: (u32, f64),
        guided: Option<usize>,
    ) -> Result<Option<Recovered>, FrontendError> {
        if self.config.recovery_keyframes.is_none() || self.recent.keyframes.is_empty() {
            return Ok(None);
        }
        let (camera, config) = (&self.camera, &self.config);
        let RecentKeyframes { keyframes, orb, .. } = &mut self.recent;
        let query = orb_points(
            orb,
            &pyr.gray,
            &frame.depth_m,
            camera,
            &self.shutter,
            config,
        )?;
        let params = orb_motion_params(config, config.recovery_min_inliers.max(at_least + 1));
        let (refine, rng) = (config.refine_iterations, &mut self.rng);
        let mut best = None;
        let mut all_matches = Vec::new();
        for kf in keyframes.iter_mut().rev() {
            if kf.points.is_none() {
                let still = ShutterMotion::default();
                let p = orb_points(orb, &kf.pyramid.gray, &kf.depth_m, camera, &still, config)?;
                kf.points = Some(p);
            }
            let points = kf.points.as_deref().unwrap_or(&[]);
            let matches = match_points_within(&query, points, bounds);
            let w = &kf.world_from_kf;
            // Kept for the guided search only.
            if guided.is_some() {
                all_matches.push(matches.clone());
            }
            let found = estimate_from(&query, points, matches, w, &params, refine, rng);
            keep_best(&mut best, found.map(|(e, p)| (e, p, (kf.id, *w))));
        }
        // None found, and `guided`: search near the rough poses too few inliers give.
        if let (None, Some(min_rough)) = (&best, guided) {
            let near = (&query[..], &*keyframes, all_matches);
            best = crate::guided::best_near(near, (config, camera), min_rough, rng);
        }
        Ok(best.map(|(e, pairs, matched)| self.recovered(&query, e, &pairs, matched)))
    }

    /// Places a lost frame by aligning its depth with the newest keyframe's
    /// ([`crate::depth_align`]), starting at `world_from_pred`, with the overlap it must
    /// reach (`min_paired_fraction`; the alignment's own bound when `None`). `None` when
    /// depth alignment is off, no keyframe's depth is kept, or the alignment is refused
    /// (logged). The frame keeps no track: the keyframe it starts detects new corners.
    pub(crate) fn align_depth(
        &mut self,
        frame: &RgbdFrame,
        world_from_pred: &Isometry3<f64>,
        min_paired_fraction: Option<f64>,
    ) -> Option<Recovered> {
        if !self.config.depth_alignment {
            return None;
        }
        let kf = self.recent.keyframes.back()?;
        let mut params = DepthAlignParams::from_config(&self.config);
        params.min_paired_fraction = min_paired_fraction.unwrap_or(params.min_paired_fraction);
        let a = self.align_with(frame, kf, kf.world_from_kf, *world_from_pred, &params)?;
        tracing::debug!(
            "frame {}: depth aligned with keyframe {} ({} of {} samples paired, rms {:.2} sigma, condition {:.1e})",
            frame.index, kf.id, a.pairs, a.samples, a.rms_sigmas, a.condition
        );
        Some(Recovered::by_depth(&a, kf.id, &kf.world_from_kf))
    }

    /// Aligns `frame`'s depth with recent keyframe `kf`'s ([`align_with_keyframe`]).
    pub(crate) fn align_with(
        &self,
        frame: &RgbdFrame,
        kf: &RecentKeyframe,
        world_from_kf: Isometry3<f64>,
        world_from_cur: Isometry3<f64>,
        params: &DepthAlignParams,
    ) -> Option<DepthAlignment> {
        let keyframe = (kf.id, &*kf.depth_m, world_from_kf);
        align_with_keyframe(&self.camera, frame, keyframe, world_from_cur, params)
    }

    /// The pose and the new tracks (the inliers, carrying their matched world points) of
    /// an estimate from [`estimate_against`].
    pub(crate) fn recovered(
        &mut self,
        query: &[OrbPoint],
        e: MotionEstimate,
        pairs: &[(usize, Correspondence)],
        (matched_keyframe, world_from_matched): (u64, Isometry3<f64>),
    ) -> Recovered {
        let keyframe = self.kf_count;
        let mut tracks = Vec::with_capacity(e.inlier_count);
        for ((qi, c), inlier) in pairs.iter().zip(&e.inliers) {
            let Some(q) = query.get(*qi).filter(|_| *inlier) else {
                continue;
            };
            tracks.push((
                Track {
                    id: self.next_id,
                    px: q.px,
                    point: Some(TrackPoint {
                        world: c.reference,
                        observations: 1,
                    }),
                    origin_kf: keyframe,
                    origin_px: q.px,
                },
                Some(q.p_camera),
            ));
            self.next_id += 1;
        }
        Recovered {
            world_from_cur: e.ref_from_cur,
            inliers: e.inlier_count,
            iterations: e.iterations,
            information: e.information,
            tracks,
            matches: pairs.len(),
            matched_keyframe,
            matched_from_cur: world_from_matched.inverse() * e.ref_from_cur,
        }
    }
}

/// Aligns `frame`'s depth with the depth of keyframe `kf_id` ([`crate::depth_align`]): the
/// keyframe at `world_from_kf`, the frame starting at `world_from_cur` (any common frame).
/// `None` when the alignment is refused (logged). Needs no odometry, so alignments with
/// several keyframes can run side by side.
pub(crate) fn align_with_keyframe(
    camera: &PinholeCamera,
    frame: &RgbdFrame,
    (kf_id, kf_depth_m, world_from_kf): (u64, &DepthImage, Isometry3<f64>),
    world_from_cur: Isometry3<f64>,
    params: &DepthAlignParams,
) -> Option<DepthAlignment> {
    let keyframe = DepthView {
        depth_m: kf_depth_m,
        world_from_camera: world_from_kf,
    };
    let current = DepthView {
        depth_m: &frame.depth_m,
        world_from_camera: world_from_cur,
    };
    align(&keyframe, &current, camera, params)
        .map_err(|e| {
            tracing::debug!(
                "frame {}: depth not aligned with keyframe {kf_id}: {e}",
                frame.index
            );
        })
        .ok()
}

#[cfg(test)]
#[path = "recovery_tests.rs"]
mod tests;
