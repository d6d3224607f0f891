//! Keyframes of the odometry and the tracks' world points: making a keyframe (new corners
//! in empty grid cells, ORB descriptors, the features a back end maps) and fusing inlier
//! observations into the points.

use crate::error::FrontendError;
use crate::features::Detector;
use crate::klt::Pyramid;
use crate::points::{measure, Measurement};
use crate::result::{KeyframeFeature, KeyframeInfo, OdometryLink};
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, Matrix3, Point2};
use opencv::core::Point2f;
use stride_core::frame::RgbdFrame;
use stride_core::image::GrayImage;

/// A track's 3-D point in the odometry's world frame (not to be confused with a back end's
/// map points, which outlive tracks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TrackPoint {
    /// Position and covariance in the world frame (m, m^2).
    pub(crate) world: Measurement,
    /// Observations fused so far.
    pub(crate) observations: u32,
}

/// A keypoint followed from frame to frame.
#[derive(Debug, Clone)]
pub(crate) struct Track {
    pub(crate) id: u64,
    pub(crate) px: Point2f,
    pub(crate) point: Option<TrackPoint>,
    /// Keyframe where the track was detected, and its position there.
    pub(crate) origin_kf: u64,
    pub(crate) origin_px: Point2f,
}

/// Observations fused into a track's point at most; later ones only serve tracking (keeps
/// the point's covariance from collapsing on correlated errors).
const MAX_FUSED_OBSERVATIONS: u32 = 20;
/// Observations are fused with their covariance inflated by this factor, for the error of
/// the pose they are placed with.
const OBSERVATION_INFLATION: f64 = 2.0;

/// Rotates a covariance from frame `a` into frame `b` with `b_from_a`'s rotation.
pub(crate) fn rotate_cov(b_from_a: &Isometry3<f64>, cov: &Matrix3<f64>) -> Matrix3<f64> {
    let r = b_from_a.rotation.to_rotation_matrix();
    r.matrix() * cov * r.matrix().transpose()
}

impl VisualOdometry {
    /// Fuses each inlier's measurement in the current frame into its track's point (or
    /// gives the track a point if it had none).
    pub(crate) fn fuse_observations(
        alive: &mut [(Track, Option<Measurement>)],
        world_from_cur: &Isometry3<f64>,
    ) {
        for (t, m) in alive.iter_mut() {
            let Some(m) = m else { continue };
            let obs = Measurement {
                p: world_from_cur * m.p,
                cov: rotate_cov(world_from_cur, &m.cov) * OBSERVATION_INFLATION,
            };
            t.point = Some(match t.point {
                None => TrackPoint {
                    world: obs,
                    observations: 1,
                },
                Some(mp) if mp.observations >= MAX_FUSED_OBSERVATIONS => mp,
                Some(mp) => fuse(mp, obs),
            });
        }
    }

    /// Makes the current frame a keyframe: new corners fill the grid (their points placed
    /// in the world with the frame's pose), ORB describes every track. `measured` holds the
    /// current frame's measurement of each live track (same order as the tracks).
    pub(crate) fn start_keyframe(
        &mut self,
        frame: &RgbdFrame,
        pyr: &std::rc::Rc<Pyramid>,
        gray_img: &GrayImage,
        world_from_cur: &Isometry3<f64>,
        measured: Vec<Option<Measurement>>,
        odometry: Option<OdometryLink>,
    ) -> Result<KeyframeInfo, FrontendError> {
        let id = self.kf_count;
        let mut tracks = std::mem::take(&mut self.tracks);
        let mut measured = measured;
        measured.resize(tracks.len(), None);
        let existing: Vec<Point2f> = tracks.iter().map(|t| t.px).collect();
        let corners = Detector::detect(&mut self.detector, &pyr.gray, &existing, &self.config)?;
        for c in corners {
            let m = measure(
                &frame.depth_m,
                &self.camera,
                (c.px.x, c.px.y),
                &self.shutter,
                &self.config,
            );
            let point = m.map(|m| TrackPoint {
                world: Measurement {
                    p: world_from_cur * m.p,
                    cov: rotate_cov(world_from_cur, &m.cov),
                },
                observations: 1,
            });
            tracks.push(Track {
                id: self.next_id,
                px: c.px,
                point,
                origin_kf: id,
                origin_px: c.px,
            });
            measured.push(m);
            self.next_id += 1;
        }
        // Keep this keyframe's pyramid for re-alignment; forget those no track comes from.
        self.kf_pyramids.push((id, std::rc::Rc::clone(pyr)));
        self.kf_pyramids
            .retain(|(k, _)| tracks.iter().any(|t| t.origin_kf == *k));
        self.kf_count += 1;
        self.world_from_kf = *world_from_cur;
        let descriptors = if self.config.orb_descriptors {
            let pts: Vec<Point2f> = tracks.iter().map(|t| t.px).collect();
            self.detector.describe(&pyr.gray, gray_img, &pts)?
        } else {
            vec![None; tracks.len()]
        };
        // Before this keyframe joins the recent ones: the link is to the one before it.
        let depth = odometry.as_ref().and_then(|o| self.depth_link(frame, o));
        if let Some(keep) = self.config.recovery_keyframes {
            self.recent
                .push(id, pyr, &frame.depth_m, *world_from_cur, keep);
        }
        let features = tracks
            .iter()
            .zip(descriptors)
            .zip(measured)
            .map(|((t, d), m)| KeyframeFeature {
                track_id: t.id,
                px: Point2::new(t.px.x, t.px.y),
                measurement: m,
                descriptor: d,
            })
            .collect::<Vec<_>>();
        if let Some(cap) = self.config.relocalization_keyframes {
            self.places.remember(id, *world_from_cur, &features, cap);
        }
        self.kf_tracks = tracks.len();
        self.tracks = tracks;
        Ok(KeyframeInfo {
            id,
            features,
            odometry,
            depth,
        })
    }
}

/// Information-weighted fusion of an observation into a track's point (a Kalman update
/// with an identity model).
fn fuse(mp: TrackPoint, obs: Measurement) -> TrackPoint {
    let s = mp.world.cov + obs.cov;
    let Some(s_inv) = s.try_inverse() else {
        return mp;
    };
    let k = mp.world.cov * s_inv;
    let p = mp.world.p + k * (obs.p - mp.world.p);
    let cov = (Matrix3::identity() - k) * mp.world.cov;
    let cov = (cov + cov.transpose()) * 0.5;
    if p.coords.iter().all(|v| v.is_finite()) && cov.iter().all(|v| v.is_finite()) {
        TrackPoint {
            world: Measurement { p, cov },
            observations: mp.observations + 1,
        }
    } else {
        mp
    }
}
