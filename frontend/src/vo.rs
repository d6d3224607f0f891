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
//! inliers, an implausible jump, no depth) or keeps few inliers, it is matched by appearance
//! against recent keyframes ([`crate::recovery`], [`TrackingStatus::Recovered`]), then among
//! all remembered ones, then placed by its depth ([`crate::depth_align`]); when all fail, its
//! pose is predicted with the constant-velocity model and it is [`TrackingStatus::Lost`].
//! Either way it becomes a keyframe so that tracking resumes. Poses are never NaN.

use crate::config::VoConfig;
use crate::error::FrontendError;
use crate::features::Detector;
use crate::keyframe::Track;
use crate::klt::{track, Pyramid};
use crate::motion::{
    is_finite, is_inlier, polish, ransac, Correspondence, MotionEstimate, MotionParams,
};
use crate::points::{measure, Measurement, ShutterMotion};
use crate::recovery::{Anchor, RecentKeyframes};
use crate::relocalize::PlaceMemory;
use crate::result::{FrameResult, OdometryLink, StageTimes, TrackingStatus};
use nalgebra::{Isometry3, Matrix6};
use opencv::core::Point2f;
use std::ops::ControlFlow::{self, Break, Continue};
use std::time::Instant;
use stride_core::camera::PinholeCamera;
use stride_core::frame::RgbdFrame;
use stride_core::image::GrayImage;
use stride_core::rng::SplitMix64;

/// One attempt at the pose: the tracks used, their pairs and the estimate.
struct Attempt {
    alive: Vec<(Track, Option<Measurement>)>,
    pairs: Vec<(usize, Correspondence)>,
    corrs: Vec<Correspondence>,
    estimate: Option<MotionEstimate>,
}

/// The visual odometry. Feed it frames in time order with [`VisualOdometry::process`].
pub struct VisualOdometry {
    pub(crate) config: VoConfig,
    pub(crate) camera: PinholeCamera,
    pub(crate) detector: Detector,
    prev: Option<std::rc::Rc<Pyramid>>,
    pub(crate) prev_t: f64,
    pub(crate) tracks: Vec<Track>,
    /// `world_from_camera` of the current keyframe.
    pub(crate) world_from_kf: Isometry3<f64>,
    /// `world_from_camera` of the previous frame.
    pub(crate) world_from_prev: Isometry3<f64>,
    /// The constant-velocity model.
    pub(crate) motion_model: crate::motion_model::MotionModel,
    /// Tracks when the current keyframe started.
    pub(crate) kf_tracks: usize,
    /// The recent frames' angular rates, for the keyframe decision.
    pub(crate) jolts: crate::keyframe::Jolts,

    /// Pyramids of the keyframes that live tracks were detected in, by keyframe number.
    pub(crate) kf_pyramids: Vec<(u64, std::rc::Rc<Pyramid>)>,
    /// The next keyframe's identifier (keyframes made so far, plus `kf_first`).
    pub(crate) kf_count: u64,
    /// The first keyframe's identifier (0, or after a saved map's).
    kf_first: u64,
    pub(crate) next_id: u64,
    pub(crate) rng: SplitMix64,
    /// ORB features of the recent keyframes, for the wide-baseline recovery.
    pub(crate) recent: RecentKeyframes,
    /// The camera's motion during this frame's readout (rolling shutter), and the
    /// gyroscope's samples for it.
    pub(crate) shutter: ShutterMotion,
    pub(crate) gyro: crate::gyro::Gyro,
    /// The accelerometer's samples and what they were used for (`crate::accel`).
    pub(crate) accel: crate::accel::Accel,
    /// The keyframes relocalization searches: a saved map's (the first frame is localized
    /// in them) and this run's.
    pub(crate) places: PlaceMemory,
}

impl VisualOdometry {
    /// A new odometry for a camera. Validates the configuration.
    pub fn new(camera: PinholeCamera, config: VoConfig) -> Result<Self, FrontendError> {
        config.validate()?;
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
            motion_model: Default::default(),
            kf_tracks: 0,
            jolts: Default::default(),
            kf_pyramids: Vec::new(),
            kf_count: 0,
            kf_first: 0,
            next_id: 0,
            recent: RecentKeyframes::new()?,
            shutter: ShutterMotion::default(),
            gyro: crate::gyro::Gyro::default(),
            accel: crate::accel::Accel::default(),
            places: PlaceMemory::new()?,
        })
    }

    /// Starts the run in a saved map instead of at the identity: the first frame is
    /// relocalized against the map's keyframes `anchors` (its frame becomes the world), and
    /// keyframes are numbered from `first_keyframe_id` on, after the map's. Call before the
    /// first frame. An empty `anchors` leaves the first frame defining the world.
    pub fn start_in_map(&mut self, anchors: Vec<Anchor>, first_keyframe_id: u64) {
        self.places.add_saved_map(anchors);
        if self.kf_count == self.kf_first {
            self.kf_count = first_keyframe_id;
            self.kf_first = first_keyframe_id;
        }
    }

    /// The configuration.
    pub fn config(&self) -> &VoConfig {
        &self.config
    }

    /// The camera the frames come from.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// The current keyframe's identifier and `world_from_camera` (none before the first
    /// frame).
    pub fn current_keyframe(&self) -> Option<(u64, Isometry3<f64>)> {
        (self.kf_count > self.kf_first).then(|| (self.kf_count - 1, self.world_from_kf))
    }

    /// The pose predicted for time `t_s` by the constant-velocity model (for frames that
    /// could not even be loaded).
    pub fn predict(&self, t_s: f64) -> Isometry3<f64> {
        self.world_from_prev * self.motion_model.prev_from_cur(self.prev_t, t_s)
    }

    /// The first frame: it defines the world, or, in a saved map, is relocalized in it.
    /// When that fails, it is put at the newest saved keyframe's pose (status
    /// [`TrackingStatus::Lost`]), its keyframe linked to that one by a predicted link
    /// (no information): a piece of the map placed by a guess, which a back end's loop
    /// closure joins to the saved map when one of its keyframes is recognised there.
    fn first_frame(
        &mut self,
        frame: &RgbdFrame,
        pyr: &std::rc::Rc<Pyramid>,
        gray_img: &GrayImage,
        start: Instant,
        mut timing: StageTimes,
    ) -> Result<FrameResult, FrontendError> {
        let (mut status, mut world_from_cur) = (TrackingStatus::Initialized, Isometry3::identity());
        let (mut inliers, mut iterations, mut correspondences) = (0, 0, 0);
        let mut information = Matrix6::zeros();
        let (mut measured, mut matched_keyframe, mut guessed) = (Vec::new(), None, None);
        if self.places.saved_map {
            let t = Instant::now();
            match self.relocalize(frame, pyr, gray_img) {
                Ok(r) => {
                    status = TrackingStatus::Relocalized;
                    world_from_cur = r.world_from_cur;
                    (inliers, iterations, information) = (r.inliers, r.iterations, r.information);
                    (correspondences, matched_keyframe) = (r.matches, Some(r.matched_keyframe));
                    (self.tracks, measured) = r.tracks.into_iter().unzip();
                }
                Err(e @ FrontendError::NotLocalized { .. }) => {
                    let (link, world_from_guess) = self.places.guess_in_saved_map().ok_or(e)?;
                    tracing::warn!(
                        "frame {}: not found in the saved map; the run starts a piece of \
                         its own at saved keyframe {}'s pose, joined to the map when a \
                         keyframe of it is recognised there",
                        frame.index,
                        link.previous_id
                    );
                    (status, world_from_cur, guessed) =
                        (TrackingStatus::Lost, world_from_guess, Some(link));
                }
                Err(e) => return Err(e),
            }
            timing.recover_s = t.elapsed().as_secs_f64();
        }
        self.world_from_prev = world_from_cur;
        self.motion_model.start(frame.t_s, world_from_cur);
        // No earlier frame gives a velocity, but a gyroscope gives the rotation during the
        // readout: the first keyframe's points, which anchor the map, get it too.
        self.shutter = self.readout_motion(None, frame.t_s, true);
        timing.track_s = start.elapsed().as_secs_f64();
        let t = Instant::now();
        let tracked = self.tracks.len();
        let info = self.start_keyframe(frame, pyr, gray_img, &world_from_cur, measured, guessed)?;
        timing.detect_s = t.elapsed().as_secs_f64();
        self.prev = Some(std::rc::Rc::clone(pyr));
        self.prev_t = frame.t_s;
        timing.total_s = start.elapsed().as_secs_f64();
        Ok(FrameResult {
            index: frame.index,
            t_s: frame.t_s,
            world_from_camera: world_from_cur,
            keyframe_id: info.id,
            keyframe_from_camera: Isometry3::identity(),
            status,
            matched_keyframe,
            keyframe: true,
            tracked,
            correspondences,
            inliers,
            ransac_iterations: iterations,
            information,
            timing,
            new_keyframe: Some(info),
        })
    }

    /// Processes the next frame.
    pub fn process(&mut self, frame: &RgbdFrame) -> Result<FrameResult, FrontendError> {
        let start = Instant::now();
        let (w, h) = (frame.rgb.width(), frame.rgb.height());
        if (w, h) != (self.camera.width(), self.camera.height())
            || (frame.depth_m.width(), frame.depth_m.height()) != (w, h)
        {
            return Err(FrontendError::SizeMismatch {
                index: frame.index,
                width: w,
                height: h,
                camera_width: self.camera.width(),
                camera_height: self.camera.height(),
            });
        }
        let mut timing = StageTimes::default();
        let gray_img = frame.rgb.to_gray();
        let pyr = std::rc::Rc::new(Pyramid::new(&gray_img, &self.config)?);

        let Some(prev) = self.prev.take() else {
            return self.first_frame(frame, &pyr, &gray_img, start, timing);
        };

        // 1. Predict and track.
        let (prev_from_pred, gyro) = self.predicted_with_gyroscope(frame.t_s);
        let gyro_rotation = gyro.then_some(prev_from_pred.rotation);
        let interval = (&prev_from_pred, frame.t_s - self.prev_t);
        self.shutter = self.readout_motion(Some(interval), frame.t_s, true);
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
                    && crate::motion_model::step_is_plausible(&step, frame.t_s - self.prev_t, &cfg)
                    && !self.disagrees_with_gyroscope(&step, gyro_rotation.as_ref());
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
        // 3b. Wide baseline: a lost or weakly tracked frame is matched by appearance.
        let (mut recovered_tracks, mut matched_keyframe) = (None, None);
        // A relocalization measures the frame against the keyframe it found: its link.
        let mut relocalized_link = None;
        let mut correspondences = corrs.len();
        if status == TrackingStatus::Lost || inliers < cfg.keyframe_min_inliers {
            let t_w = Instant::now();
            let lost = status == TrackingStatus::Lost;
            if let Some((r, how)) = self.search_by_appearance(
                frame,
                &pyr,
                &gray_img,
                (lost, inliers),
                (&world_from_pred, &corrs, gyro_rotation.as_ref()),
            )? {
                world_from_cur = r.world_from_cur;
                (inliers, iterations, information) = (r.inliers, r.iterations, r.information);
                status = how;
                recovered_tracks = Some(r.tracks);
                (correspondences, matched_keyframe) = (r.matches, Some(r.matched_keyframe));
                if how == TrackingStatus::Relocalized {
                    relocalized_link = Some((r.matched_keyframe, r.matched_from_cur));
                }
            }
            timing.recover_s = t_w.elapsed().as_secs_f64();
        }
        // After dropped frames a lost frame moves at the recent velocity (its rotation the
        // gyroscope's when that measured it).
        let gap = (status == TrackingStatus::Lost)
            .then(|| self.motion_model.across_gap(self.prev_t, frame.t_s))
            .flatten();
        if let Some(gap) = gap {
            let rotation = gyro_rotation.unwrap_or(gap.rotation);
            world_from_cur =
                self.world_from_prev * Isometry3::from_parts(gap.translation, rotation);
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
            Self::fuse_observations(&mut alive, &world_from_cur);
        }
        if let Some(tracks) = recovered_tracks {
            alive = tracks;
        }
        let estimated = status != TrackingStatus::Lost;

        // 4. Keyframe?
        let kf_from_cur = self.world_from_kf.inverse() * world_from_cur;
        let tracked_count = alive.len();
        let need_kf = self.keyframe_due((status, inliers, tracked_count), &kf_from_cur, frame.t_s);
        let mut new_keyframe = None;
        let (tracks, measured): (Vec<Track>, Vec<Option<Measurement>>) = alive.into_iter().unzip();
        self.tracks = tracks;
        if need_kf {
            // New points are measured with this frame's estimated motion.
            if estimated {
                let prev_from_cur = self.world_from_prev.inverse() * world_from_cur;
                let dt = frame.t_s - self.prev_t;
                self.shutter = self.readout_motion(Some((&prev_from_cur, dt)), frame.t_s, false);
            }
            // A relocalized keyframe is linked to the keyframe it was found against, as
            // measured: linked to the previous one, the link would state the odometry's
            // drift between the two as a measurement (the more inliers, the firmer).
            let (previous_id, previous_from_this) =
                relocalized_link.unwrap_or((self.kf_count.saturating_sub(1), kf_from_cur));
            let odometry = OdometryLink {
                previous_id,
                previous_from_this,
                information,
                inliers,
            };
            let t_d = Instant::now();
            new_keyframe = Some(self.start_keyframe(
                frame,
                &pyr,
                &gray_img,
                &world_from_cur,
                measured,
                Some(odometry),
            )?);
            timing.detect_s = t_d.elapsed().as_secs_f64();
        }
        let keyframe_id = self.kf_count.saturating_sub(1);
        let keyframe_from_camera = self.world_from_kf.inverse() * world_from_cur;

        // 5. Motion model. A relocalized frame's jump is a correction (or a kidnapping),
        // not a velocity: the model restarts from it and keeps the motion before.
        let prev_from_cur = self.world_from_prev.inverse() * world_from_cur;
        if status == TrackingStatus::Relocalized {
            self.motion_model.restart(frame.t_s, world_from_cur);
        } else {
            let estimated_pose = estimated.then_some(world_from_cur);
            (self.motion_model).record(self.prev_t, frame.t_s, prev_from_cur, estimated_pose);
        }
        self.world_from_prev = world_from_cur;
        self.prev = Some(pyr);
        self.prev_t = frame.t_s;
        timing.total_s = start.elapsed().as_secs_f64();
        Ok(FrameResult {
            index: frame.index,
            t_s: frame.t_s,
            world_from_camera: world_from_cur,
            keyframe_id,
            keyframe_from_camera,
            status,
            matched_keyframe,
            keyframe: need_kf,
            tracked: tracked_count,
            correspondences,
            inliers,
            ransac_iterations: iterations,
            information,
            timing,
            new_keyframe,
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
        let Attempt {
            alive,
            pairs,
            corrs,
            ..
        } = self.measure_tracks(frame, moved, &self.shutter);
        timing.track_s += t0.elapsed().as_secs_f64();
        let cfg = &self.config;
        let t_r = Instant::now();
        let params = MotionParams::from_config(cfg);
        let hypothesis = ransac(&corrs, &params, &mut self.rng);
        timing.ransac_s += t_r.elapsed().as_secs_f64();
        let t_f = Instant::now();
        let estimate = hypothesis.and_then(|(pose, inliers, iterations)| {
            let e = polish(&corrs, pose, inliers, cfg.refine_iterations, &params)?;
            Some(MotionEstimate { iterations, ..e })
        });
        let attempt = Attempt {
            alive,
            pairs,
            corrs,
            estimate,
        };
        let mut passes = 0..self.config.rolling_shutter_passes;
        let (Continue(attempt) | Break(attempt)) =
            passes.try_fold(attempt, |a, _| self.remeasure_rolling(frame, a, &params));
        timing.refine_s += t_f.elapsed().as_secs_f64();
        Ok(attempt)
    }

    /// Measures tracks in 3-D with `shutter` and pairs those with a world point: an attempt
    /// without an estimate yet.
    fn measure_tracks(
        &self,
        frame: &RgbdFrame,
        tracks: Vec<Track>,
        shutter: &ShutterMotion,
    ) -> Attempt {
        let depth = &frame.depth_m;
        let alive: Vec<(Track, Option<Measurement>)> = tracks
            .into_iter()
            .map(|t| {
                let m = measure(depth, &self.camera, (t.px.x, t.px.y), shutter, &self.config);
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
        let corrs = pairs.iter().map(|(_, c)| *c).collect();
        Attempt {
            alive,
            pairs,
            corrs,
            estimate: None,
        }
    }

    /// One pass of `rolling_shutter_passes`: the tracks, measured with a motion that lags a
    /// walking robot's shake, are measured again with the frame's estimated motion and the
    /// pose polished on them (no new RANSAC). `Break`: the attempt as it was, and no more
    /// passes (a global shutter, or this pass failed, as another would).
    fn remeasure_rolling(
        &mut self,
        frame: &RgbdFrame,
        first: Attempt,
        params: &MotionParams,
    ) -> ControlFlow<Attempt, Attempt> {
        let dt = frame.t_s - self.prev_t;
        let readout = self.config.rolling_shutter_s;
        let Some(e) = first
            .estimate
            .as_ref()
            .filter(|_| readout > 0.0 && dt > 0.0)
        else {
            return Break(first);
        };
        let prev_from_cur = self.world_from_prev.inverse() * e.ref_from_cur;
        let shutter = self.readout_motion(Some((&prev_from_cur, dt)), frame.t_s, false);
        let tracks = first.alive.iter().map(|(t, _)| t.clone()).collect();
        let again = self.measure_tracks(frame, tracks, &shutter);
        let flags = again
            .corrs
            .iter()
            .map(|c| is_inlier(c, &e.ref_from_cur, params.test, params.model_noise_m))
            .collect();
        let refine = self.config.refine_iterations;
        match polish(&again.corrs, e.ref_from_cur, flags, refine, params) {
            Some(mut second) => {
                self.shutter = shutter;
                second.iterations = e.iterations;
                let estimate = Some(second);
                Continue(Attempt { estimate, ..again })
            }
            None => Break(first),
        }
    }
}
