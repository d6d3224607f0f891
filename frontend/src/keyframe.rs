//! Keyframes of the odometry and the tracks' world points: deciding when a frame becomes a
//! keyframe (waiting out a jolt the gyroscope shows), making one (new corners in empty
//! grid cells, ORB descriptors, the features a back end maps) and fusing inlier
//! observations into the points.

use crate::error::FrontendError;
use crate::features::Detector;
use crate::klt::Pyramid;
use crate::orb::orb_points;
use crate::points::{measure, Measurement};
use crate::result::{KeyframeFeature, KeyframeInfo, OdometryLink, PlaceFeature, TrackingStatus};
use crate::vo::VisualOdometry;
use nalgebra::{Isometry3, Matrix3, Point2};
use opencv::core::Point2f;
use std::collections::VecDeque;
use stride_core::frame::RgbdFrame;
use stride_core::image::GrayImage;

/// Frames whose angular rate a frame is compared with ([`Jolts`]).
const JOLT_FRAMES: usize = 8;

/// The recent frames' angular rates from the gyroscope, to tell a jolt of the gait (a
/// foot's impact, which blurs the frame and drops its tracks) from the walk's sway, and how
/// many keyframes waited for the jolt to pass.
#[derive(Debug, Clone, Default)]
pub(crate) struct Jolts {
    recent: VecDeque<f64>,
    /// Keyframes that track losses asked for on a jolted frame and that waited.
    pub(crate) deferred: usize,
}

impl Jolts {
    /// Records the camera's angular rate at a frame (rad/s; `None` without a gyroscope);
    /// whether it is above `ratio` times the median of the previous [`JOLT_FRAMES`]
    /// frames' (never before there are that many, without a rate, or with `ratio` 0).
    fn jolted(&mut self, rate_rad_s: Option<f64>, ratio: f64) -> bool {
        let Some(now) = rate_rad_s.filter(|_| ratio > 0.0) else {
            return false;
        };
        let mut sorted: Vec<f64> = self.recent.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied();
        self.recent.push_back(now);
        if self.recent.len() > JOLT_FRAMES {
            self.recent.pop_front();
        }
        sorted.len() == JOLT_FRAMES && median.is_some_and(|m| now > ratio * m)
    }
}

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
    /// Whether the frame at `t_s` becomes a keyframe: when it was not tracked, keeps fewer
    /// than `keyframe_min_inliers` inliers, has moved or turned beyond the keyframe bounds,
    /// or keeps fewer than `redetect_fraction` of the keyframe's tracks. The last waits
    /// while the gyroscope says the frame was jolted (`keyframe_jolt_ratio`): a foot's
    /// impact that blurs one frame also drops tracks, and a keyframe made there would
    /// detect its corners and measure its points in the blurriest image.
    pub(crate) fn keyframe_due(
        &mut self,
        (status, inliers, tracked): (TrackingStatus, usize, usize),
        kf_from_cur: &Isometry3<f64>,
        t_s: f64,
    ) -> bool {
        let rate = self.gyroscope_rate(t_s);
        let cfg = &self.config;
        let jolted = self.jolts.jolted(rate, cfg.keyframe_jolt_ratio);
        let must = status != TrackingStatus::Tracked
            || inliers < cfg.keyframe_min_inliers
            || kf_from_cur.translation.vector.norm() > cfg.keyframe_max_translation_m
            || kf_from_cur.rotation.angle().to_degrees() > cfg.keyframe_max_rotation_deg;
        let tracks_lost = (tracked as f64) < cfg.redetect_fraction * self.kf_tracks as f64;
        if tracks_lost && jolted && !must {
            self.jolts.deferred += 1;
            return false;
        }
        must || tracks_lost
    }

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
        // Before this keyframe joins the recent ones: the links are to those before it.
        let depth_links = odometry
            .as_ref()
            .map(|o| self.depth_links(frame, o))
            .unwrap_or_default();
        // Measured at the frame's time, as the tracks are (recovery computes its own, for
        // a still camera, when it needs them). Relocalization remembers a keyframe by them
        // too, so they are detected for such a keyframe even without a back end.
        let remembered = self
            .config
            .relocalization_keyframes
            .filter(|_| self.places.wants(world_from_cur));
        let place_points = if self.config.place_features || remembered.is_some() {
            orb_points(
                &mut self.recent.place_orb,
                &pyr.gray,
                &frame.depth_m,
                &self.camera,
                &self.shutter,
                &self.config,
            )?
        } else {
            Vec::new()
        };
        let place_features = if self.config.place_features {
            place_points.iter().map(PlaceFeature::from).collect()
        } else {
            Vec::new()
        };
        if let Some(cap) = remembered {
            self.places.remember(id, *world_from_cur, place_points, cap);
        }
        if let Some(keep) = self.config.recovery_keyframes {
            let linked = !depth_links.is_empty();
            (self.recent).push(id, pyr, &frame.depth_m, (*world_from_cur, linked), keep);
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
        self.kf_tracks = tracks.len();
        self.tracks = tracks;
        Ok(KeyframeInfo {
            id,
            features,
            place_features,
            odometry,
            depth_links,
        })
    }

    /// Re-aligns tracks with their keyframe appearance (see [`crate::klt::realign`]), one
    /// Lucas-Kanade call per origin keyframe; drops the tracks that do not re-align.
    pub(crate) fn realign(
        &self,
        tracks: Vec<Track>,
        current: &Pyramid,
        max_correction_px: f32,
    ) -> Result<Vec<Track>, FrontendError> {
        let mut out = Vec::with_capacity(tracks.len());
        for (k, kf_pyr) in &self.kf_pyramids {
            let group: Vec<&Track> = tracks.iter().filter(|t| t.origin_kf == *k).collect();
            if group.is_empty() {
                continue;
            }
            let origins: Vec<Point2f> = group.iter().map(|t| t.origin_px).collect();
            let tracked: Vec<Point2f> = group.iter().map(|t| t.px).collect();
            let refined = crate::klt::realign(
                kf_pyr,
                current,
                &origins,
                &tracked,
                max_correction_px,
                &self.config,
            )?;
            for (t, r) in group.into_iter().zip(refined) {
                if let Some(px) = r {
                    out.push(Track { px, ..t.clone() });
                }
            }
        }
        // Keep the frame-to-frame order (by track id) so that results do not depend on the
        // grouping.
        out.sort_by_key(|t| t.id);
        Ok(out)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A foot's impact (2 rad/s among frames at 0.1-0.3 rad/s) is a jolt once eight frames
    /// have been seen; the sway is not, nor is anything without a gyroscope or with the
    /// ratio 0.
    #[test]
    fn an_impact_among_the_sway_is_a_jolt() {
        let mut j = Jolts::default();
        let sway = [0.1, 0.2, 0.3, 0.15, 0.25, 0.1, 0.2, 0.3];
        assert!(!j.jolted(Some(2.0), 3.0), "no history yet");
        let mut j = Jolts::default();
        for r in sway {
            assert!(!j.jolted(Some(r), 3.0));
        }
        assert!(j.jolted(Some(2.0), 3.0), "the impact");
        assert!(!j.jolted(Some(0.4), 3.0), "the sway after it");
        assert!(!j.jolted(None, 3.0) && !j.jolted(Some(5.0), 0.0));
    }
}
