//! Every parameter of the visual odometry, with its default and its unit.

use stride_core::uncertainty::PrimeSenseModel;

mod validate;

/// How RANSAC decides that a correspondence is an inlier.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum InlierTest {
    /// Squared Mahalanobis distance of the 3-D residual under both points' covariances
    /// (`r^T (Sigma_ref + R Sigma_cur R^T)^-1 r`) below this chi-square bound (3 degrees of
    /// freedom; 11.34 is the 99 % quantile).
    Mahalanobis {
        /// Bound on the squared Mahalanobis distance.
        chi2: f64,
    },
    /// Euclidean distance of the 3-D residual below this bound (m).
    Euclidean {
        /// Bound (m).
        max_m: f64,
    },
}

/// Parameters of [`crate::VisualOdometry`]. The defaults weigh measurements by the sensor
/// model with 2 cm of isotropic noise (the pose graph's odometry);
/// [`VoConfig::with_backend_noise_model`] gives the SLAM with bundle adjustment's
/// (`stride::Config::default`, with the back end's `depth_noise_scale` at 1) and
/// [`VoConfig::odometry_only`] those of the odometry alone.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VoConfig {
    /// Keypoints to keep tracked (about 500-1000).
    pub target_features: usize,
    /// Grid for spreading keypoints: columns.
    pub grid_cols: usize,
    /// Grid for spreading keypoints: rows.
    pub grid_rows: usize,
    /// FAST threshold (grey levels); lowered to `min_fast_threshold` where texture is weak.
    pub fast_threshold: i32,
    /// Lowest FAST threshold tried.
    pub min_fast_threshold: i32,
    /// Smallest distance between two keypoints (px).
    pub min_feature_distance_px: f32,
    /// Start a keyframe (and detect new keypoints in the empty grid cells) when fewer than
    /// this fraction of the last keyframe's tracks are still tracked. With a back end,
    /// frequent keyframes keep the grid full and give bundle adjustment more points and
    /// measurements: on teddy_200 (five seeds each) its ATE is 4.8 mm at 0.8, 6.5 mm at 0.7
    /// and 7.3 mm at 0.6. The odometry alone drifts more with more new points (14.0 mm at
    /// 0.8 against 11.5 mm at 0.6), so [`VoConfig::odometry_only`] keeps 0.6.
    pub redetect_fraction: f64,
    /// With a gyroscope, a keyframe that only track losses ask for waits while the
    /// camera's angular rate at the frame is above this many times the median of the
    /// previous 8 frames' (a foot's impact, which blurs the frame and drops its tracks);
    /// 0 never waits.
    pub keyframe_jolt_ratio: f64,
    /// Lucas-Kanade window side (px).
    pub klt_window: i32,
    /// Pyramid levels above the full image.
    pub klt_levels: i32,
    /// Lucas-Kanade iterations per level.
    pub klt_iterations: i32,
    /// Largest forward-backward tracking error kept (px).
    pub fb_max_error_px: f32,
    /// When too few tracks pass the strict checks (heavy or changing blur), a second attempt
    /// accepts forward-backward errors up to this (px) without re-alignment and lets RANSAC
    /// sort the tracks out. `None` disables the second attempt.
    #[serde(with = "stride_core::serde_opt")]
    pub relaxed_fb_max_error_px: Option<f32>,
    /// Re-align every track with its appearance in the keyframe where it was detected
    /// (removes frame-to-frame drift); tracks that move more than this are dropped (px).
    /// `None` disables the re-alignment.
    #[serde(with = "stride_core::serde_opt")]
    pub realign_max_correction_px: Option<f32>,
    /// Depth range used for 3-D points (m).
    pub min_depth_m: f64,
    /// Depth range used for 3-D points (m).
    pub max_depth_m: f64,
    /// A keypoint is on a depth edge (rejected) when a pixel of its 3x3 neighbourhood differs
    /// from its depth by more than this fraction of it, or lacks depth.
    pub depth_edge_rel: f64,
    /// Standard deviation (px, turned into m at the point's depth) added isotropically to
    /// the covariance of a point measured just behind an occluding edge (a pixel within half
    /// `klt_window` nearer by more than `depth_edge_rel`): its track may follow the edge
    /// instead of the point (`points::measure`). 0 turns the test off.
    pub occluded_sigma_px: f64,
    /// Uncertainty model of the 3-D points.
    pub uncertainty: PrimeSenseModel,
    /// Inlier test of RANSAC and of the final inlier set.
    pub inlier_test: InlierTest,
    /// Isotropic standard deviation (m) added to every correspondence's covariance: the
    /// errors the sensor model leaves out (tracking drift on real texture, rolling shutter,
    /// colour/depth misregistration). Without it, nearby points with millimetre covariances
    /// are rejected by the first few millimetres of such error and far, noisy points decide
    /// the pose. Median ATE over five RANSAC seeds on TUM fr3/teddy_200 (sharp / 15 px blur
    /// / 25 px blur): 0 m gives 0.047 / 0.045 / 0.086 m (118 frames lost), 0.005 m gives
    /// 0.016 / 0.023 / 0.017, 0.01 m 0.013 / 0.017 / 0.025, 0.02 m 0.015 / 0.016 / 0.019,
    /// 0.03 m 0.011 / 0.012 / 0.025.
    pub model_noise_m: f64,
    /// Probability of drawing at least one all-inlier sample (adaptive iteration count).
    pub ransac_confidence: f64,
    /// Most RANSAC iterations.
    pub ransac_max_iterations: usize,
    /// Fewest RANSAC iterations, whatever the adaptive count says. The adaptive count
    /// trusts the best inlier ratio found so far; on blurred frames a cluster of tracks
    /// that slid together agrees on a wrong motion, reaches 80 % of the correspondences in
    /// the first draws and stopped the search after about ten (teddy_200 blurred by 5 px,
    /// a frame after a dropped one: a 68 mm step where the truth is 21 mm, found on 70
    /// inliers; the right motion has 87). 100 draws took teddy_200's five starts from
    /// 6.24 to 5.71 mm and that blurred run from 7.96 to 6.62 mm, for 0.2-0.3 ms a frame
    /// (docs/slam-measured.md, "RANSAC draws at least 100 samples").
    pub ransac_min_iterations: usize,
    /// Fewest inliers for a motion estimate to be accepted.
    pub min_inliers: usize,
    /// Gauss-Newton iterations of the covariance-weighted refinement.
    pub refine_iterations: usize,
    /// Start a new keyframe when fewer inliers than this remain.
    pub keyframe_min_inliers: usize,
    /// Start a new keyframe beyond this distance from the current one (m).
    pub keyframe_max_translation_m: f64,
    /// Start a new keyframe beyond this rotation from the current one (degrees).
    pub keyframe_max_rotation_deg: f64,
    /// A frame-to-frame motion larger than this is rejected as a failure (m).
    pub max_step_translation_m: f64,
    /// ... and so is one faster than this (m/s) over the time since the previous frame: a
    /// camera on a robot does not jump 0.5 m in a frame interval, but a heavily blurred
    /// frame's tracks can slide together and agree on such a jump. 5 m/s is 0.17 m at 30
    /// Hz; across dropped frames `max_step_translation_m` bounds it.
    pub max_speed_m_s: f64,
    /// A frame-to-frame rotation larger than this is rejected as a failure (degrees).
    pub max_step_rotation_deg: f64,
    /// With a gyroscope that measured the rotation since the previous frame
    /// (`predict_gyroscope`), a motion estimate whose rotation differs from the
    /// gyroscope's by more than this (degrees) is rejected as a failure: a few tracks on
    /// one patch can trade rotation for translation, as after dropped frames in a turn.
    /// 0: never. The lab's estimates differ from its gyroscope by at most 0.12 degrees; a
    /// gyroscope whose bias integrates to more than this over a gap needs a larger bound.
    pub max_gyroscope_disagreement_deg: f64,
    /// Compute ORB descriptors of keyframe keypoints (for map matching by a back end).
    pub orb_descriptors: bool,
    /// Detect multi-scale ORB features in every keyframe for a back end's loop closure and
    /// saved maps ([`crate::result::KeyframeInfo::place_features`]; about 2 ms per
    /// keyframe). Relocalization detects them in the keyframes it remembers either way.
    pub place_features: bool,
    /// Wide-baseline recovery ([`crate::recovery`]): when Lucas-Kanade loses a frame, or
    /// keeps fewer than `keyframe_min_inliers` inliers, the frame's ORB features are matched
    /// against those of this many recent keyframes and its pose is estimated from the
    /// matches. `None` disables it. Each keyframe kept costs its depth image and pyramid
    /// (about 3 MB at 640x480).
    #[serde(with = "stride_core::serde_opt")]
    pub recovery_keyframes: Option<usize>,
    /// Fewest RANSAC inliers among the matches for a recovered pose to be accepted (it must
    /// also have more inliers than Lucas-Kanade's estimate).
    pub recovery_min_inliers: usize,
    /// Relocalization ([`crate::relocalize`]): a frame that tracking and recovery lost is
    /// looked up by appearance among this run's keyframes (one per 0.15 m or 15 degrees, at
    /// most this many, each remembered by its place features, about 75 KB) and a saved
    /// map's. `None` disables it within a run (a saved map is still searched for the first
    /// frame).
    #[serde(with = "stride_core::serde_opt")]
    pub relocalization_keyframes: Option<usize>,
    /// Depth alignment ([`crate::depth_align`]): a frame that tracking, recovery and
    /// relocalization all lose (a colour image too blurred to follow) is placed by aligning
    /// its depth image with the last keyframe's, from the constant-velocity prediction, and
    /// marked [`crate::TrackingStatus::DepthAligned`]. Needs `recovery_keyframes` (the last
    /// keyframe's depth is kept with them).
    pub depth_alignment: bool,
    /// After dropped frames, a frame that the depth alignment from the motion model's guess
    /// cannot place either is aligned from a grid of starts around the guess and placed by
    /// the best-paired result ([`crate::depth_search`]; about 0.4 s on two cores, once per
    /// such gap); and a pose from ORB matches for the first frame after dropped frames is
    /// checked against the frame's depth, which replaces it when they disagree by more
    /// than 5 cm or 3 degrees. Needs `depth_alignment`.
    pub depth_search: bool,
    /// Depth links between keyframes ([`crate::KeyframeInfo::depth_links`]): a new
    /// keyframe whose pose rests on fewer than `keyframe_depth_link_inliers` inliers (a wide
    /// baseline after dropped frames, a blurred image) has its depth image aligned with
    /// each recent keyframe's (the previous one and the older ones recovery keeps, up to
    /// `recovery_keyframes`, 0.15 m or 15 degrees apart; the previous one alone when the
    /// keyframe stands more than 5 cm or 5 degrees from it; [`crate::depth_align`], from
    /// the odometry's pose), and each relative pose found goes to a back end as a
    /// constraint beside the features' points. 0: never. Needs `recovery_keyframes`.
    pub keyframe_depth_link_inliers: usize,
    /// Rolling-shutter readout time of the colour camera, top row to bottom row (s); the
    /// frame's timestamp is the middle row's time. Keypoints are brought back to the frame's
    /// time by the camera's velocity (see [`crate::points::ShutterMotion`]). 0 for a global
    /// shutter.
    #[serde(skip)]
    pub rolling_shutter_s: f64,
    /// Exposure time of each colour row (s), 0 when unknown. With a rolling shutter and a
    /// gyroscope, a keypoint is taken to sit where the scene was on average over its row's
    /// exposure (a blurred image's features do), not at the row's mid-exposure instant.
    #[serde(skip)]
    pub exposure_s: f64,
    /// With a rolling shutter and a gyroscope ([`VisualOdometry::add_gyroscope`]), each
    /// colour row's rotation from the frame's time is integrated from the gyroscope over
    /// the readout (instead of the last frame interval's angular velocity) and averaged
    /// over the exposure when `exposure_s` is known (see `crate::gyro`).
    ///
    /// [`VisualOdometry::add_gyroscope`]: crate::VisualOdometry::add_gyroscope
    pub readout_gyroscope: bool,
    /// With a rolling shutter and an accelerometer of 200 Hz or more
    /// ([`VisualOdometry::add_accelerometer`]), each colour row's translation from the
    /// frame's time is integrated from it (the frame's velocity from the interval's
    /// displacement and the acceleration within it) instead of the last frame interval's
    /// mean velocity times the row's delay (see `crate::accel`).
    ///
    /// [`VisualOdometry::add_accelerometer`]: crate::VisualOdometry::add_accelerometer
    pub readout_accelerometer: bool,
    /// With a rolling shutter, how many times the tracks are measured again once the
    /// frame's motion is estimated (each time with the velocity of the last estimate) and
    /// the pose polished on them, without a new RANSAC. The first estimate rests on the
    /// predicted motion, which lags a foot's impact; each pass starts nearer the frame's
    /// own. 0: the tracks keep the predicted motion's measurement.
    pub rolling_shutter_passes: usize,
    /// With a gyroscope, the rotation predicted from one frame to the next (where
    /// Lucas-Kanade starts each track) is integrated from it instead of the last frame
    /// interval's (see `crate::gyro`).
    pub predict_gyroscope: bool,
    /// Seed of RANSAC's sampling.
    pub seed: u64,
}

impl VoConfig {
    /// This configuration with the back end's noise model for its measurements: 2 mm of
    /// isotropic noise, and depth trusted 3 times less than the sensor model says (its
    /// standard deviation scaled; the back end's `model_noise_m` and `depth_noise_scale`).
    /// The odometry alone takes it ([`VoConfig::odometry_only`]), and so does the SLAM with
    /// bundle adjustment (`stride::Config::default`, whose back end then leaves the depth as
    /// these covariances give it); the pose graph keeps [`VoConfig::default`].
    ///
    /// With the SLAM's 2 cm, the isotropic term swamps the sensor model (about 3 mm across
    /// the ray and 7 mm along it at 1.5 m), so the estimate weighs a point's depth as much as
    /// its pixel position, and the odometry's motions came out short: 1.1-1.7 % on
    /// teddy_200 (Sim(3) scale 1.011-1.017), rotations included. Measured 2026-11-27 (ATE
    /// rmse, mean over RANSAC seeds 1-3, mm), the odometry alone with it
    /// ([`VoConfig::odometry_only`]): teddy_200 9.7 -> 6.7, every 5th frame (seeds 1-5) 17.0
    /// -> 6.7, every 3rd 8.7 -> 8.4, every 10th 15.6 -> 4.5, a 1 s gap 30.0 -> 5.0, a
    /// 600-frame pingpong 18.2 -> 6.9, blurred along the motion by 5 px 29.5 -> 15.8 and by
    /// 25 px 32.7 -> 21.3; three synthetic walks 0.29 / 0.57 / 0.32 -> 0.17 / 0.37 / 0.25.
    /// The pose graph with it: teddy_200 10.5 -> 6.3, from frames 5, 10, 20, 30 11.8 / 15.1 /
    /// 13.3 / 9.7 -> 5.9 / 5.8 / 7.0 / 5.7, every 5th frame 14.5 -> 5.3, a 600-frame
    /// pingpong 13.5 -> 6.4, but blurred by 5 px 9.0 -> 25.7 (Sim(3) scale 0.97: too large)
    /// and by 25 px 19.9 -> 25.1. Bundle adjustment (with the back end's depth inflation at
    /// 1, so as not to apply it twice), final / live ATE: teddy_200 from frames 0, 5, 10,
    /// 20, 30 (seeds 1-3) 6.87 / 6.82 -> 6.24 / 5.67 in the mean (from frame 0 alone 4.5 /
    /// 5.4 -> 6.9 / 5.5), every 10th frame 5.1 / 11.2 -> 4.1 / 4.0, blurred by 25 px 19.2 /
    /// 19.8 -> 14.6 / 13.7, by 5 px (seeds 1-5) 8.0 / 7.8 -> 7.6 / 10.0, five synthetic
    /// walks 14-43 % lower.
    pub fn with_backend_noise_model(self) -> Self {
        let [k1, k2, k3, k4] = self.uncertainty.depth_sigma_coeffs;
        let k = BACKEND_DEPTH_NOISE_SCALE;
        Self {
            model_noise_m: BACKEND_MODEL_NOISE_M,
            uncertainty: PrimeSenseModel {
                depth_sigma_coeffs: [k1 * k, k2 * k, k3 * k, k4 * k],
                ..self.uncertainty
            },
            ..self
        }
    }

    /// The defaults for the odometry running alone, without a back end: keyframes (and new
    /// points) less often, which drifts less (see [`VoConfig::redetect_fraction`]), and the
    /// back end's noise model ([`VoConfig::with_backend_noise_model`]).
    pub fn odometry_only() -> Self {
        Self {
            redetect_fraction: 0.6,
            ..Self::default().with_backend_noise_model()
        }
    }
}

/// Isotropic noise (m) of [`VoConfig::with_backend_noise_model`]: the back end's
/// `model_noise_m`.
const BACKEND_MODEL_NOISE_M: f64 = 0.002;

/// How many times larger [`VoConfig::with_backend_noise_model`] takes the depth's standard
/// deviation than the sensor model's: the back end's `depth_noise_scale` (Kinect-class
/// depth errors are correlated in space and time, so repeated observations do not average
/// them out).
const BACKEND_DEPTH_NOISE_SCALE: f64 = 3.0;

impl Default for VoConfig {
    fn default() -> Self {
        Self {
            target_features: 600,
            grid_cols: 8,
            grid_rows: 6,
            fast_threshold: 20,
            min_fast_threshold: 7,
            min_feature_distance_px: 8.0,
            redetect_fraction: 0.8,
            keyframe_jolt_ratio: 3.0,
            klt_window: 13,
            klt_levels: 3,
            klt_iterations: 20,
            fb_max_error_px: 1.0,
            relaxed_fb_max_error_px: Some(3.0),
            realign_max_correction_px: Some(2.0),
            min_depth_m: 0.3,
            max_depth_m: 6.0,
            depth_edge_rel: 0.04,
            occluded_sigma_px: 12.0,
            uncertainty: PrimeSenseModel::default(),
            inlier_test: InlierTest::Mahalanobis { chi2: 11.34 },
            model_noise_m: 0.02,
            ransac_confidence: 0.999,
            ransac_max_iterations: 300,
            ransac_min_iterations: 100,
            min_inliers: 12,
            refine_iterations: 8,
            keyframe_min_inliers: 60,
            keyframe_max_translation_m: 0.3,
            keyframe_max_rotation_deg: 20.0,
            max_step_translation_m: 0.5,
            max_speed_m_s: 5.0,
            max_step_rotation_deg: 45.0,
            max_gyroscope_disagreement_deg: 1.0,
            orb_descriptors: true,
            place_features: true,
            recovery_keyframes: Some(5),
            recovery_min_inliers: 20,
            relocalization_keyframes: Some(2000),
            depth_alignment: true,
            depth_search: true,
            keyframe_depth_link_inliers: 60,
            rolling_shutter_s: 0.0,
            exposure_s: 0.0,
            readout_gyroscope: true,
            readout_accelerometer: true,
            rolling_shutter_passes: 2,
            predict_gyroscope: true,
            seed: 1,
        }
    }
}
