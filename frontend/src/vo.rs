//! Frame-to-map RGB-D visual odometry (PUT SLAM's front end, paper 004 section 3.1).
//!
//! Every tracked keypoint carries a 3-D point in the world frame with a covariance, created
//! from its first depth measurement and refined by fusing (information-weighted) each later
//! inlier observation. Every new frame:
//!
//! 1. predicts its pose with a constant-velocity model, and from it where each point should
//!    appear, which seeds pyramidal Lucas-Kanade (robust to the fast, shaky motion of a
//!    walking robot), checked forward and backward;
//! 2. measures the tracked keypoints in 3-D from its depth image;
//! 3. estimates `world_from_camera` from the world-point/measurement pairs with Umeyama +
//!    RANSAC and refines it with the covariance-weighted 3-D error (paper 004, eq. 1 for one
//!    pose);
//! 4. fuses the inliers' measurements into their world points, and becomes a keyframe
//!    (detecting new corners in empty grid cells, describing them with ORB) when too many
//!    tracks were lost or it has moved far enough.
//!
//! Because each pose is estimated against points that persist as long as they are tracked,
//! drift only enters when new points are created. When a frame cannot be estimated (too few
//! inliers, an implausible jump, no depth), its pose is predicted with the constant-velocity
//! model, the frame is marked [`TrackingStatus::Lost`], and it becomes a keyframe so that
//! tracking resumes with the next frame. Poses are never NaN.

use crate::config::VoConfig;
use crate::error::FrontendError;
use crate::features::{Detector, OrbDescriptor};
use crate::klt::{track, Pyramid};
use crate::motion::{estimate, is_finite, Correspondence};
use crate::points::{measure, Measurement};
use nalgebra::{Isometry3, Matrix6, Point2, Translation3, UnitQuaternion};
use opencv::core::Point2f;
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::frame::RgbdFrame;
use stride_core::rng::SplitMix64;

/// How a frame's pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingStatus {
    /// The first frame: it defines the world frame.
    Initialized,
    /// Estimated from tracked 3-D points.
    Tracked,
    /// Not estimable: predicted by the constant-velocity model; tracking restarts here.
    Lost,
}

impl TrackingStatus {
    /// A short lowercase name for reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            TrackingStatus::Initialized => "initialized",
            TrackingStatus::Tracked => "tracked",
            TrackingStatus::Lost => "lost",
        }
    }
}

/// Time spent in each stage of one frame (s).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageTimes {
    /// Corner detection and ORB description (keyframes only).
    pub detect_s: f64,
    /// Grey conversion, pyramid, Lucas-Kanade both ways, 3-D measurement.
    pub track_s: f64,
    /// RANSAC.
    pub ransac_s: f64,
    /// Gauss-Newton refinement.
    pub refine_s: f64,
    /// The whole frame.
    pub total_s: f64,
}

/// A keypoint of a keyframe, for a back end's map.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeFeature {
    /// Track identifier (stable while the keypoint is tracked).
    pub id: u64,
    /// Pixel position (distorted image coordinates).
    pub px: Point2<f32>,
    /// 3-D point and covariance in the keyframe's camera frame, when depth was valid.
    pub point: Option<Measurement>,
    /// ORB descriptor, when computed and the point is not too close to the border.
    pub descriptor: Option<OrbDescriptor>,
}

/// What the odometry says about one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameResult {
    /// Frame index.
    pub index: usize,
    /// Frame time (s).
    pub t_s: f64,
    /// `world_from_camera`; the world frame is the first frame's camera frame.
    pub world_from_camera: Isometry3<f64>,
    /// How the pose was obtained.
    pub status: TrackingStatus,
    /// Whether this frame became a keyframe.
    pub keyframe: bool,
    /// Keypoints tracked into this frame.
    pub tracked: usize,
    /// Of them, with a valid 3-D point in this frame and in the keyframe.
    pub correspondences: usize,
    /// RANSAC inliers after refinement.
    pub inliers: usize,
    /// RANSAC iterations.
    pub ransac_iterations: usize,
    /// Information matrix of the keyframe-relative pose (zero when not estimated).
    pub information: Matrix6<f64>,
    /// Stage timings.
    pub timing: StageTimes,
    /// The keyframe's features, when this frame is a keyframe.
    pub keyframe_features: Option<Vec<KeyframeFeature>>,
}

/// A track's point in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct MapPoint {
    /// Position and covariance in the world frame.
    world: Measurement,
    /// Observations fused so far.
    observations: u32,
}

#[derive(Debug, Clone)]
struct Track {
    id: u64,
    px: Point2f,
    point: Option<MapPoint>,
    /// Keyframe where the track was detected, and its position there.
    origin_kf: u64,
    origin_px: Point2f,
}

/// One attempt at the pose: the tracks used, their pairs and the estimate.
struct Attempt {
    alive: Vec<(Track, Option<Measurement>)>,
    pairs: Vec<(usize, Correspondence)>,
    corrs: Vec<Correspondence>,
    estimate: Option<crate::motion::MotionEstimate>,
}

/// Observations fused into a map point at most; later ones only serve tracking (keeps the
/// point's covariance from collapsing on correlated errors).
const MAX_FUSED_OBSERVATIONS: u32 = 20;
/// Observations are fused with their covariance inflated by this factor, for the error of
/// the pose they are placed with.
const OBSERVATION_INFLATION: f64 = 2.0;

/// The visual odometry. Feed it frames in time order with [`VisualOdometry::process`].
pub struct VisualOdometry {
    config: VoConfig,
    camera: PinholeCamera,
    detector: Detector,
    prev: Option<std::rc::Rc<Pyramid>>,
    prev_t: f64,
    tracks: Vec<Track>,
    world_from_kf: Isometry3<f64>,
    world_from_prev: Isometry3<f64>,
    /// Last motion `prev_from_cur` over `dt` seconds.
    velocity: Option<(Isometry3<f64>, f64)>,
    /// Tracks when the current keyframe started.
    kf_tracks: usize,
    /// Pyramids of the keyframes that live tracks were detected in, by keyframe number.
    kf_pyramids: Vec<(u64, std::rc::Rc<Pyramid>)>,
    kf_count: u64,
    next_id: u64,
    rng: SplitMix64,
}

/// Scales a motion by `ratio` (translation linearly, rotation along its axis).
fn scale_motion(m: &Isometry3<f64>, ratio: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(m.translation.vector * ratio),
        UnitQuaternion::from_scaled_axis(m.rotation.scaled_axis() * ratio),
    )
}

impl VisualOdometry {
    /// A new odometry for a camera. Validates the configuration.
    pub fn new(camera: PinholeCamera, config: VoConfig) -> Result<Self, FrontendError> {
        if config.target_features < 20
            || config.min_inliers < 3
            || config.klt_window < 5
            || config.klt_levels < 0
        {
            return Err(FrontendError::Config(format!(
                "target_features {} (>= 20), min_inliers {} (>= 3), klt_window {} (>= 5), klt_levels {} (>= 0)",
                config.target_features, config.min_inliers, config.klt_window, config.klt_levels
            )));
        }
        Ok(Self {
            detector: Detector::new(&config)?,
            rng: SplitMix64::new(config.seed),
            config,
            camera,
            prev: None,
            prev_t: 0.0,
            tracks: Vec::new(),
            world_from_kf: Isometry3::identity(),
            world_from_prev: Isometry3::identity(),
            velocity: None,
            kf_tracks: 0,
            kf_pyramids: Vec::new(),
            kf_count: 0,
            next_id: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &VoConfig {
        &self.config
    }

    fn predicted_prev_from_cur(&self, t_s: f64) -> Isometry3<f64> {
        match self.velocity {
            Some((m, dt)) if dt > 0.0 => {
                scale_motion(&m, ((t_s - self.prev_t) / dt).clamp(0.0, 5.0))
            }
            _ => Isometry3::identity(),
        }
    }

    /// The pose predicted for time `t_s` by the constant-velocity model (for frames that
    /// could not even be loaded).
    pub fn predict(&self, t_s: f64) -> Isometry3<f64> {
        self.world_from_prev * self.predicted_prev_from_cur(t_s)
    }

    /// Processes the next frame.
    pub fn process(&mut self, frame: &RgbdFrame) -> Result<FrameResult, FrontendError> {
        let start = Instant::now();
        let (w, h) = (frame.rgb.width(), frame.rgb.height());
        if (w, h) != (self.camera.width, self.camera.height)
            || (frame.depth_m.width(), frame.depth_m.height()) != (w, h)
        {
            return Err(FrontendError::SizeMismatch {
                index: frame.index,
                width: w,
                height: h,
                camera_width: self.camera.width,
                camera_height: self.camera.height,
            });
        }
        let mut timing = StageTimes::default();
        let gray_img = frame.rgb.to_gray();
        let pyr = std::rc::Rc::new(Pyramid::new(&gray_img, &self.config)?);

        let Some(prev) = self.prev.take() else {
            // First frame: it defines the world.
            self.world_from_kf = Isometry3::identity();
            self.world_from_prev = Isometry3::identity();
            timing.track_s = start.elapsed().as_secs_f64();
            let t = Instant::now();
            let features = self.start_keyframe(frame, &pyr, &gray_img, &Isometry3::identity())?;
            timing.detect_s = t.elapsed().as_secs_f64();
            self.prev = Some(pyr);
            self.prev_t = frame.t_s;
            timing.total_s = start.elapsed().as_secs_f64();
            return Ok(FrameResult {
                index: frame.index,
                t_s: frame.t_s,
                world_from_camera: Isometry3::identity(),
                status: TrackingStatus::Initialized,
                keyframe: true,
                tracked: 0,
                correspondences: 0,
                inliers: 0,
                ransac_iterations: 0,
                information: Matrix6::zeros(),
                timing,
                keyframe_features: Some(features),
            });
        };

        // 1. Predict and track.
        let prev_from_pred = self.predicted_prev_from_cur(frame.t_s);
        let world_from_pred = self.world_from_prev * prev_from_pred;
        let pred_from_world = world_from_pred.inverse();
        let from: Vec<Point2f> = self.tracks.iter().map(|t| t.px).collect();
        let guesses: Vec<Point2f> = self
            .tracks
            .iter()
            .map(|t| {
                t.point
                    .and_then(|a| self.camera.project(&(pred_from_world * a.world.p)))
                    .filter(|p| self.camera.contains(p))
                    .map(|p| Point2f::new(p.x as f32, p.y as f32))
                    .unwrap_or(t.px)
            })
            .collect();
        let tracked = track(&prev, &pyr, &from, &guesses, &self.config)?;
        let candidates: Vec<(Track, crate::klt::Tracked)> = self
            .tracks
            .drain(..)
            .zip(tracked)
            .filter_map(|(t, p)| Some((t, p?)))
            .collect();
        timing.track_s = start.elapsed().as_secs_f64();

        // 2. Pose against the world points: strict tracks first, relaxed ones if needed.
        let cfg = self.config.clone();
        let mut attempt = self.attempt(
            frame,
            &pyr,
            &candidates,
            cfg.fb_max_error_px,
            cfg.realign_max_correction_px,
            &mut timing,
        )?;
        let enough = |a: &Attempt| a.estimate.is_some() && a.corrs.len() >= 3 * cfg.min_inliers;
        if !enough(&attempt) {
            if let Some(relaxed) = cfg.relaxed_fb_max_error_px {
                let second = self.attempt(frame, &pyr, &candidates, relaxed, None, &mut timing)?;
                if second.estimate.as_ref().map_or(0, |e| e.inlier_count)
                    > attempt.estimate.as_ref().map_or(0, |e| e.inlier_count)
                {
                    attempt = second;
                }
            }
        }
        let Attempt {
            mut alive,
            pairs,
            corrs,
            estimate: est,
        } = attempt;

        // 3. Accept or fall back.
        let mut status = TrackingStatus::Tracked;
        let mut world_from_cur = world_from_pred;
        let (mut inliers, mut iterations, mut information) = (0, 0, Matrix6::zeros());
        match &est {
            Some(e) => {
                let candidate = e.ref_from_cur;
                let step = self.world_from_prev.inverse() * candidate;
                let plausible = is_finite(&candidate)
                    && step.translation.vector.norm() <= cfg.max_step_translation_m
                    && step.rotation.angle().to_degrees() <= cfg.max_step_rotation_deg;
                if plausible {
                    world_from_cur = candidate;
                    inliers = e.inlier_count;
                    iterations = e.iterations;
                    information = e.information;
                } else {
                    status = TrackingStatus::Lost;
                }
            }
            None => status = TrackingStatus::Lost,
        }
        if !is_finite(&world_from_cur) {
            world_from_cur = self.world_from_prev;
        }
        // Drop outlier tracks (they would poison the next estimates), fuse the inliers'
        // measurements into their points, give points to tracks that gained depth.
        if status == TrackingStatus::Tracked {
            let mut outlier = vec![false; alive.len()];
            if let Some(e) = &est {
                for ((i, _), &inl) in pairs.iter().zip(&e.inliers) {
                    if let Some(o) = outlier.get_mut(*i) {
                        *o = !inl;
                    }
                }
            }
            let mut k = 0;
            alive.retain(|_| {
                let keep = !outlier.get(k).copied().unwrap_or(false);
                k += 1;
                keep
            });
            let rot = world_from_cur.rotation.to_rotation_matrix();
            for (t, m) in alive.iter_mut() {
                let Some(m) = m else { continue };
                let obs = Measurement {
                    p: world_from_cur * m.p,
                    cov: rot.matrix() * m.cov * rot.matrix().transpose() * OBSERVATION_INFLATION,
                };
                t.point = Some(match t.point {
                    None => MapPoint {
                        world: obs,
                        observations: 1,
                    },
                    Some(mp) if mp.observations >= MAX_FUSED_OBSERVATIONS => mp,
                    Some(mp) => fuse(mp, obs),
                });
            }
        }

        // 4. Keyframe?
        let kf_from_cur = self.world_from_kf.inverse() * world_from_cur;
        let tracked_count = alive.len();
        let need_kf = status == TrackingStatus::Lost
            || inliers < cfg.keyframe_min_inliers
            || (tracked_count as f64) < cfg.redetect_fraction * self.kf_tracks as f64
            || kf_from_cur.translation.vector.norm() > cfg.keyframe_max_translation_m
            || kf_from_cur.rotation.angle().to_degrees() > cfg.keyframe_max_rotation_deg;
        let correspondences = corrs.len();
        let mut keyframe_features = None;
        self.tracks = alive.iter().map(|(t, _)| t.clone()).collect();
        if need_kf {
            self.world_from_kf = world_from_cur;
            let t_d = Instant::now();
            keyframe_features =
                Some(self.start_keyframe(frame, &pyr, &gray_img, &world_from_cur)?);
            timing.detect_s = t_d.elapsed().as_secs_f64();
        }

        // 5. Motion model.
        let dt = frame.t_s - self.prev_t;
        if status == TrackingStatus::Tracked && dt > 0.0 {
            self.velocity = Some((self.world_from_prev.inverse() * world_from_cur, dt));
        }
        self.world_from_prev = world_from_cur;
        self.prev = Some(pyr);
        self.prev_t = frame.t_s;
        timing.total_s = start.elapsed().as_secs_f64();
        Ok(FrameResult {
            index: frame.index,
            t_s: frame.t_s,
            world_from_camera: world_from_cur,
            status,
            keyframe: need_kf,
            tracked: tracked_count,
            correspondences,
            inliers,
            ransac_iterations: iterations,
            information,
            timing,
            keyframe_features,
        })
    }

    /// Tracks that pass `fb_max` (and re-alignment, when given), measured in 3-D, paired with
    /// their world points, and the motion estimated from them.
    #[allow(clippy::too_many_arguments)]
    fn attempt(
        &mut self,
        frame: &RgbdFrame,
        pyr: &Pyramid,
        candidates: &[(Track, crate::klt::Tracked)],
        fb_max: f32,
        realign: Option<f32>,
        timing: &mut StageTimes,
    ) -> Result<Attempt, FrontendError> {
        let t0 = Instant::now();
        let mut moved: Vec<Track> = candidates
            .iter()
            .filter(|(_, p)| p.fb_error_px <= fb_max)
            .map(|(t, p)| Track {
                px: p.px,
                ..t.clone()
            })
            .collect();
        if let Some(max_corr) = realign {
            moved = self.realign(moved, pyr, max_corr)?;
        }
        let alive: Vec<(Track, Option<Measurement>)> = moved
            .into_iter()
            .map(|t| {
                let m = measure(&frame.depth_m, &self.camera, t.px.x, t.px.y, &self.config);
                (t, m)
            })
            .collect();
        let pairs: Vec<(usize, Correspondence)> = alive
            .iter()
            .enumerate()
            .filter_map(|(i, (t, m))| {
                Some((
                    i,
                    Correspondence {
                        reference: t.point?.world,
                        current: (*m)?,
                    },
                ))
            })
            .collect();
        let corrs: Vec<Correspondence> = pairs.iter().map(|(_, c)| *c).collect();
        timing.track_s += t0.elapsed().as_secs_f64();
        let cfg = &self.config;
        let t_r = Instant::now();
        let params = crate::motion::MotionParams {
            refine_iterations: 0,
            ..crate::motion::MotionParams::from_config(cfg)
        };
        let est = estimate(&corrs, &params, &mut self.rng);
        timing.ransac_s += t_r.elapsed().as_secs_f64();
        let t_f = Instant::now();
        let est = est.map(|e| {
            let (pose, info, chi2) = crate::motion::refine(
                &corrs,
                &e.inliers,
                e.ref_from_cur,
                cfg.refine_iterations,
                cfg.model_noise_m,
            );
            crate::motion::MotionEstimate {
                ref_from_cur: pose,
                information: info,
                mean_chi2: chi2,
                ..e
            }
        });
        timing.refine_s += t_f.elapsed().as_secs_f64();
        Ok(Attempt {
            alive,
            pairs,
            corrs,
            estimate: est,
        })
    }

    /// Re-aligns tracks with their keyframe appearance (see [`crate::klt::realign`]), one
    /// Lucas-Kanade call per origin keyframe; drops the tracks that do not re-align.
    fn realign(
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

    /// Makes the current frame a keyframe: new corners fill the grid (their points placed in
    /// the world with the frame's pose), ORB describes every track.
    fn start_keyframe(
        &mut self,
        frame: &RgbdFrame,
        pyr: &std::rc::Rc<Pyramid>,
        gray_img: &stride_core::image::GrayImage,
        world_from_cur: &Isometry3<f64>,
    ) -> Result<Vec<KeyframeFeature>, FrontendError> {
        let mut tracks = std::mem::take(&mut self.tracks);
        let existing: Vec<Point2f> = tracks.iter().map(|t| t.px).collect();
        let corners = self.detector.detect(&pyr.gray, &existing, &self.config)?;
        let rot = world_from_cur.rotation.to_rotation_matrix();
        for c in corners {
            let point =
                measure(&frame.depth_m, &self.camera, c.px.x, c.px.y, &self.config).map(|m| {
                    MapPoint {
                        world: Measurement {
                            p: world_from_cur * m.p,
                            cov: rot.matrix() * m.cov * rot.matrix().transpose(),
                        },
                        observations: 1,
                    }
                });
            tracks.push(Track {
                id: self.next_id,
                px: c.px,
                point,
                origin_kf: self.kf_count,
                origin_px: c.px,
            });
            self.next_id += 1;
        }
        // Keep this keyframe's pyramid for re-alignment; forget those no track comes from.
        self.kf_pyramids
            .push((self.kf_count, std::rc::Rc::clone(pyr)));
        self.kf_count += 1;
        self.kf_pyramids
            .retain(|(k, _)| tracks.iter().any(|t| t.origin_kf == *k));
        let descriptors = if self.config.orb_descriptors {
            let pts: Vec<Point2f> = tracks.iter().map(|t| t.px).collect();
            self.detector.describe(&pyr.gray, gray_img, &pts)?
        } else {
            vec![None; tracks.len()]
        };
        let features = tracks
            .iter()
            .zip(descriptors)
            .map(|(t, d)| KeyframeFeature {
                id: t.id,
                px: Point2::new(t.px.x, t.px.y),
                point: t.point.map(|mp| Measurement {
                    p: world_from_cur.inverse() * mp.world.p,
                    cov: rot.matrix().transpose() * mp.world.cov * rot.matrix(),
                }),
                descriptor: d,
            })
            .collect();
        self.kf_tracks = tracks.len();
        self.tracks = tracks;
        Ok(features)
    }
}

/// Information-weighted fusion of an observation into a map point (a Kalman update with an
/// identity model).
fn fuse(mp: MapPoint, obs: Measurement) -> MapPoint {
    let s = mp.world.cov + obs.cov;
    let Some(s_inv) = s.try_inverse() else {
        return mp;
    };
    let k = mp.world.cov * s_inv;
    let p = mp.world.p + k * (obs.p - mp.world.p);
    let cov = (nalgebra::Matrix3::identity() - k) * mp.world.cov;
    let cov = (cov + cov.transpose()) * 0.5;
    if p.coords.iter().all(|v| v.is_finite()) && cov.iter().all(|v| v.is_finite()) {
        MapPoint {
            world: Measurement { p, cov },
            observations: mp.observations + 1,
        }
    } else {
        mp
    }
}
