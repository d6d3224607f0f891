//! Every parameter of the back end, with its default, unit and reason.

use crate::error::BackendError;
use crate::loop_closure::LoopParams;
use crate::matching::MatchParams;
use crate::revisit::RevisitConfig;
use stride_core::uncertainty::PrimeSenseModel;

/// What the back end optimizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BackendMode {
    /// Bundle adjustment of keyframe poses and 3-D points (paper 004, eq. 1).
    BundleAdjustment,
    /// A pose graph: keyframe poses only, tied by relative motions estimated between
    /// keyframes that share points (the RGB-D SLAM v2 style of paper 004's comparison).
    PoseGraph,
}

impl BackendMode {
    /// A short lowercase name for reports (`ba`, `pose-graph`).
    pub fn as_str(&self) -> &'static str {
        match self {
            BackendMode::BundleAdjustment => "ba",
            BackendMode::PoseGraph => "pose-graph",
        }
    }
}

/// Parameters of [`crate::Backend`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackendConfig {
    /// Bundle adjustment or pose graph.
    pub mode: BackendMode,
    /// Keyframes optimized online: the newest and those sharing the most points with it.
    /// Keyframes outside the window that see its points are held fixed.
    pub window_keyframes: usize,
    /// Most fixed keyframes in a local optimization (those sharing the most points).
    pub max_fixed_keyframes: usize,
    /// Levenberg-Marquardt iterations of a local optimization.
    pub local_iterations: usize,
    /// A local optimization runs on every this-many-th keyframe (1: every keyframe). 2
    /// halves the back end's work for 10-20 % more frames/s on two cores; on teddy_200 the
    /// ATE moved within its spread under small perturbations (4.40 -> 4.23 mm; every 5th
    /// frame 5.66 -> 6.10 mm). The final optimization is unaffected.
    pub optimize_every_keyframes: usize,
    /// Iterations of the full optimization at the end of a run.
    pub final_iterations: usize,
    /// When a new keyframe re-observes fewer map points than this, its odometry link joins
    /// the optimization as a pose-pose edge (paper 004, section 3.1).
    pub min_reobserved: usize,
    /// Isotropic standard deviation (m) added to every measured point's covariance: what
    /// the PrimeSense model leaves out (tracking error on real texture, colour/depth
    /// misregistration, rolling shutter).
    pub model_noise_m: f64,
    /// The depth model the frontend's covariances come from (paper 000, eq. 12).
    pub depth_model: PrimeSenseModel,
    /// The optimizer trusts depth this many times less than the model says (its standard
    /// deviation is scaled): Kinect-class depth errors are correlated in space and time
    /// (disparity quantization, per-pixel bias), so repeated observations do not average
    /// them out as the model assumes. Measured on teddy_200 (five seeds, ATE): 1 gives
    /// 5.3 mm, 2 gives 4.8, 3 gives 4.8, 6 gives 5.2. 1 when the frontend's covariances
    /// already carry the factor (stride's SLAM defaults, whose odometry takes 3 times the
    /// sensor's depth noise), so that it applies once.
    pub depth_noise_scale: f64,
    /// Standard deviations (m, rad) of an odometry link whose pose was predicted, not
    /// estimated (the frontend lost track): weak, but it keeps the map connected.
    pub predicted_link_sigma: (f64, f64),
    /// Huber threshold on a pose-point edge's squared Mahalanobis distance (3 degrees of
    /// freedom; 7.815 is the 95 % quantile).
    pub huber_chi2: f64,
    /// Observations whose squared Mahalanobis distance exceeds this after an optimization
    /// are removed as outliers.
    pub outlier_chi2: f64,
    /// Keyframes whose points are matched into a new keyframe: its covisible keyframes, up
    /// to this many (most shared first) ...
    pub local_map_keyframes: usize,
    /// ... and keyframes within this distance (m) ...
    pub nearby_radius_m: f64,
    /// ... looking within this angle (degrees) of the predicted pose's direction.
    pub nearby_angle_deg: f64,
    /// ORB map matching.
    pub matching: MatchParams,
    /// Loop closure (bundle-adjustment mode only).
    pub loop_closure: LoopParams,
    /// Revisit links: new keyframes tied to old ones near them by their depth.
    pub revisit: RevisitConfig,
    /// A keyframe is redundant (culled) when this fraction of its points is seen by at
    /// least `redundant_observers` other keyframes.
    pub redundant_fraction: f64,
    /// See `redundant_fraction`.
    pub redundant_observers: usize,
    /// Points seen by fewer than two keyframes are dropped this many keyframes after their
    /// creation.
    pub point_grace_keyframes: u64,
    /// The final optimization frees at most this many keyframes (the newest); the others
    /// that see their points are held fixed. Bounds its time and memory on long runs.
    pub final_max_keyframes: usize,
    /// A revisit link (which ties a keyframe to one of an earlier pass) is spread by the
    /// final optimization over at most this many of the newest keyframes; the older ones
    /// stay where the local windows left them (docs/slam-measured.md, "The final optimization's
    /// span"). A loop closure and a weak keyframe's depth link free the whole span (up to
    /// `final_max_keyframes`).
    pub final_revisit_link_keyframes: usize,
    /// The map keeps at most this many keyframes: beyond it, the most redundant of those
    /// older than the final optimization's span (`final_max_keyframes`; most of their
    /// points seen by others, the oldest first on a tie) are culled with their poses kept,
    /// so that walking over the same place for hours does not grow the map. Must exceed
    /// `final_max_keyframes`: the older keyframes it keeps anchor the final optimization.
    pub max_keyframes: usize,
    /// A keyframe is culled once it has settled (`window_keyframes + point_grace_keyframes`
    /// keyframes later) when an older keyframe stands within this distance of it (m): a
    /// later pass over a place keeps the keyframes of the first instead of adding its own
    /// (docs/slam-gaps.md, "Revisits keep the map flat"). 0: never. Bundle-adjustment mode only.
    pub revisit_cull_radius_m: f64,
    /// ... looking within this angle of it (degrees), and at least `revisit.min_keyframe_gap`
    /// keyframes older (an earlier pass, as for the revisit links).
    pub revisit_cull_angle_deg: f64,
}

impl Default for BackendConfig {
    fn default() -> Self {
        Self {
            mode: BackendMode::BundleAdjustment,
            window_keyframes: 6,
            max_fixed_keyframes: 20,
            local_iterations: 5,
            optimize_every_keyframes: 1,
            final_iterations: 20,
            min_reobserved: 30,
            model_noise_m: 0.002,
            depth_model: PrimeSenseModel::default(),
            depth_noise_scale: 3.0,
            predicted_link_sigma: (0.05, 0.05),
            huber_chi2: 7.815,
            outlier_chi2: 16.27,
            local_map_keyframes: 20,
            nearby_radius_m: 1.0,
            nearby_angle_deg: 45.0,
            matching: MatchParams::default(),
            loop_closure: LoopParams::default(),
            revisit: RevisitConfig::default(),
            redundant_fraction: 0.9,
            redundant_observers: 3,
            point_grace_keyframes: 3,
            final_max_keyframes: 300,
            final_revisit_link_keyframes: 30,
            max_keyframes: 400,
            revisit_cull_radius_m: 0.1,
            revisit_cull_angle_deg: 15.0,
        }
    }
}

impl BackendConfig {
    /// Checks every parameter's range.
    pub fn validate(&self) -> Result<(), BackendError> {
        let bad = |name: &'static str, value: String, allowed: &'static str| {
            Err(BackendError::Config {
                name,
                value,
                allowed,
            })
        };
        if self.window_keyframes < 2 {
            return bad(
                "window_keyframes",
                self.window_keyframes.to_string(),
                ">= 2",
            );
        }
        if self.optimize_every_keyframes == 0 {
            return bad("optimize_every_keyframes", "0".into(), ">= 1");
        }
        if self.local_iterations == 0 {
            return bad("local_iterations", "0".into(), ">= 1");
        }
        if self.final_max_keyframes < 2 {
            return bad(
                "final_max_keyframes",
                self.final_max_keyframes.to_string(),
                ">= 2",
            );
        }
        if self.final_revisit_link_keyframes < 2 {
            return bad(
                "final_revisit_link_keyframes",
                self.final_revisit_link_keyframes.to_string(),
                ">= 2",
            );
        }
        if !(self.model_noise_m >= 0.0 && self.model_noise_m.is_finite()) {
            return bad(
                "model_noise_m",
                self.model_noise_m.to_string(),
                "finite, >= 0 m",
            );
        }
        if !(self.depth_noise_scale >= 1.0 && self.depth_noise_scale.is_finite()) {
            return bad(
                "depth_noise_scale",
                self.depth_noise_scale.to_string(),
                "finite, >= 1",
            );
        }
        let (t, r) = self.predicted_link_sigma;
        if !(t > 0.0 && r > 0.0 && t.is_finite() && r.is_finite()) {
            return bad(
                "predicted_link_sigma",
                format!("({t}, {r})"),
                "finite, > 0 (m, rad)",
            );
        }
        if !(self.huber_chi2 > 0.0 && self.outlier_chi2 > 0.0) {
            return bad(
                "huber_chi2/outlier_chi2",
                format!("{}/{}", self.huber_chi2, self.outlier_chi2),
                "> 0",
            );
        }
        if !(self.redundant_fraction > 0.0 && self.redundant_fraction <= 1.0) {
            return bad(
                "redundant_fraction",
                self.redundant_fraction.to_string(),
                "in (0, 1]",
            );
        }
        if self.max_keyframes <= self.final_max_keyframes {
            return bad(
                "max_keyframes",
                format!(
                    "{} (final_max_keyframes {})",
                    self.max_keyframes, self.final_max_keyframes
                ),
                "> final_max_keyframes",
            );
        }
        if !(self.revisit_cull_radius_m >= 0.0 && self.revisit_cull_radius_m.is_finite()) {
            return bad(
                "revisit_cull_radius_m",
                self.revisit_cull_radius_m.to_string(),
                ">= 0 (0: never)",
            );
        }
        if !(self.revisit_cull_angle_deg >= 0.0 && self.revisit_cull_angle_deg <= 180.0) {
            return bad(
                "revisit_cull_angle_deg",
                self.revisit_cull_angle_deg.to_string(),
                "in [0, 180]",
            );
        }
        let m = &self.matching;
        if !(m.min_radius_px > 0.0
            && m.max_radius_px >= m.min_radius_px
            && m.ratio > 0.0
            && m.ratio <= 1.0)
        {
            return bad(
                "matching",
                format!("{m:?}"),
                "0 < min_radius_px <= max_radius_px, 0 < ratio <= 1",
            );
        }
        let l = &self.loop_closure;
        if !(l.search_radius_m > 0.0
            && l.candidates >= 1
            && l.min_inliers >= 6
            && l.appearance_candidates <= 100
            && (1..=100).contains(&l.matched_candidates))
        {
            return bad(
                "loop_closure",
                format!("{l:?}"),
                "search_radius_m > 0, candidates >= 1, min_inliers >= 6, \
                 appearance_candidates <= 100, matched_candidates 1 to 100",
            );
        }
        let r = &self.revisit;
        if !(r.max_distance_m > 0.0
            && r.max_distance_m.is_finite()
            && r.max_rotation_deg > 0.0
            && r.max_rotation_deg <= 180.0
            && r.min_paired_fraction > 0.0
            && r.min_paired_fraction <= 1.0)
        {
            return bad(
                "revisit",
                format!("{r:?}"),
                "max_distance_m > 0, 0 < max_rotation_deg <= 180, 0 < min_paired_fraction <= 1",
            );
        }
        Ok(())
    }
}
