//! The range of every parameter of [`VoConfig`], checked before a run starts.

use super::{InlierTest, VoConfig};
use crate::error::FrontendError;

impl VoConfig {
    /// Checks every parameter's range; the error names the first one out of range.
    pub fn validate(&self) -> Result<(), FrontendError> {
        fn check<T: PartialOrd + std::fmt::Display>(
            name: &'static str,
            value: T,
            ok: bool,
            allowed: &'static str,
        ) -> Result<(), FrontendError> {
            if ok {
                Ok(())
            } else {
                Err(FrontendError::Parameter {
                    name,
                    value: value.to_string(),
                    allowed,
                })
            }
        }
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let non_neg = |v: f64| v.is_finite() && v >= 0.0;
        let c = self;
        check(
            "target_features",
            c.target_features,
            (20..=20_000).contains(&c.target_features),
            "20 to 20000",
        )?;
        check(
            "grid_cols",
            c.grid_cols,
            (1..=64).contains(&c.grid_cols),
            "1 to 64",
        )?;
        check(
            "grid_rows",
            c.grid_rows,
            (1..=64).contains(&c.grid_rows),
            "1 to 64",
        )?;
        check(
            "fast_threshold",
            c.fast_threshold,
            (1..=255).contains(&c.fast_threshold),
            "1 to 255",
        )?;
        check(
            "min_fast_threshold",
            c.min_fast_threshold,
            (1..=c.fast_threshold).contains(&c.min_fast_threshold),
            "1 to fast_threshold",
        )?;
        check(
            "min_feature_distance_px",
            c.min_feature_distance_px,
            pos(f64::from(c.min_feature_distance_px)),
            "positive (px)",
        )?;
        check(
            "max_gyroscope_disagreement_deg",
            c.max_gyroscope_disagreement_deg,
            c.max_gyroscope_disagreement_deg >= 0.0 && c.max_gyroscope_disagreement_deg.is_finite(),
            "0 (off), or finite and positive (deg)",
        )?;
        check(
            "keyframe_jolt_ratio",
            c.keyframe_jolt_ratio,
            c.keyframe_jolt_ratio == 0.0
                || (c.keyframe_jolt_ratio > 1.0 && c.keyframe_jolt_ratio.is_finite()),
            "0 (off), or finite and above 1",
        )?;
        check(
            "redetect_fraction",
            c.redetect_fraction,
            c.redetect_fraction > 0.0 && c.redetect_fraction <= 1.0,
            "within (0, 1]",
        )?;
        check(
            "klt_window",
            c.klt_window,
            (5..=101).contains(&c.klt_window),
            "5 to 101 (px)",
        )?;
        check(
            "klt_levels",
            c.klt_levels,
            (0..=8).contains(&c.klt_levels),
            "0 to 8",
        )?;
        check(
            "klt_iterations",
            c.klt_iterations,
            (1..=1000).contains(&c.klt_iterations),
            "1 to 1000",
        )?;
        check(
            "fb_max_error_px",
            c.fb_max_error_px,
            pos(f64::from(c.fb_max_error_px)),
            "positive (px)",
        )?;
        if let Some(r) = c.relaxed_fb_max_error_px {
            check(
                "relaxed_fb_max_error_px",
                r,
                r.is_finite() && r >= c.fb_max_error_px,
                "at least fb_max_error_px (px), or false",
            )?;
        }
        if let Some(r) = c.realign_max_correction_px {
            check(
                "realign_max_correction_px",
                r,
                pos(f64::from(r)),
                "positive (px), or false",
            )?;
        }
        check(
            "min_depth_m",
            c.min_depth_m,
            pos(c.min_depth_m),
            "positive (m)",
        )?;
        check(
            "max_depth_m",
            c.max_depth_m,
            c.max_depth_m.is_finite() && c.max_depth_m > c.min_depth_m,
            "above min_depth_m (m)",
        )?;
        check(
            "depth_edge_rel",
            c.depth_edge_rel,
            non_neg(c.depth_edge_rel),
            "0 or more",
        )?;
        check(
            "occluded_sigma_px",
            c.occluded_sigma_px,
            non_neg(c.occluded_sigma_px) && c.occluded_sigma_px <= 100.0,
            "0 to 100 (px)",
        )?;
        let u = &c.uncertainty;
        check(
            "uncertainty.var_u_px2",
            u.var_u_px2,
            non_neg(u.var_u_px2),
            "0 or more (px^2)",
        )?;
        check(
            "uncertainty.var_v_px2",
            u.var_v_px2,
            non_neg(u.var_v_px2),
            "0 or more (px^2)",
        )?;
        check(
            "uncertainty.min_sigma_d_m",
            u.min_sigma_d_m,
            non_neg(u.min_sigma_d_m),
            "0 or more (m)",
        )?;
        match c.inlier_test {
            InlierTest::Mahalanobis { chi2 } => {
                check("inlier_test.chi2", chi2, pos(chi2), "positive")?
            }
            InlierTest::Euclidean { max_m } => {
                check("inlier_test.max_m", max_m, pos(max_m), "positive (m)")?
            }
        }
        check(
            "model_noise_m",
            c.model_noise_m,
            non_neg(c.model_noise_m),
            "0 or more (m)",
        )?;
        check(
            "ransac_confidence",
            c.ransac_confidence,
            c.ransac_confidence > 0.0 && c.ransac_confidence < 1.0,
            "within (0, 1)",
        )?;
        check(
            "ransac_max_iterations",
            c.ransac_max_iterations,
            c.ransac_max_iterations >= 1,
            "1 or more",
        )?;
        check(
            "ransac_min_iterations",
            c.ransac_min_iterations,
            c.ransac_min_iterations <= c.ransac_max_iterations,
            "0 to ransac_max_iterations",
        )?;
        check(
            "min_inliers",
            c.min_inliers,
            c.min_inliers >= 3,
            "3 or more",
        )?;
        check(
            "keyframe_min_inliers",
            c.keyframe_min_inliers,
            c.keyframe_min_inliers >= 3,
            "3 or more",
        )?;
        check(
            "keyframe_max_translation_m",
            c.keyframe_max_translation_m,
            pos(c.keyframe_max_translation_m),
            "positive (m)",
        )?;
        check(
            "keyframe_max_rotation_deg",
            c.keyframe_max_rotation_deg,
            pos(c.keyframe_max_rotation_deg),
            "positive (deg)",
        )?;
        check(
            "max_step_translation_m",
            c.max_step_translation_m,
            pos(c.max_step_translation_m),
            "positive (m)",
        )?;
        check(
            "max_speed_m_s",
            c.max_speed_m_s,
            pos(c.max_speed_m_s),
            "positive (m/s)",
        )?;
        check(
            "max_step_rotation_deg",
            c.max_step_rotation_deg,
            pos(c.max_step_rotation_deg),
            "positive (deg)",
        )?;
        if let Some(k) = c.recovery_keyframes {
            check(
                "recovery_keyframes",
                k,
                (1..=20).contains(&k),
                "1 to 20 (or false: no recovery)",
            )?;
        }
        if let Some(k) = c.relocalization_keyframes {
            check(
                "relocalization_keyframes",
                k,
                (1..=100_000).contains(&k),
                "1 to 100000 (or false: no relocalization within a run)",
            )?;
        }
        check(
            "recovery_min_inliers",
            c.recovery_min_inliers,
            c.recovery_min_inliers >= c.min_inliers.max(3),
            "at least min_inliers",
        )?;
        check(
            "rolling_shutter_s",
            c.rolling_shutter_s,
            (0.0..=0.1).contains(&c.rolling_shutter_s),
            "0 to 0.1 (s)",
        )?;
        check(
            "rolling_shutter_passes",
            c.rolling_shutter_passes,
            c.rolling_shutter_passes <= 5,
            "0 to 5",
        )?;
        check(
            "exposure_s",
            c.exposure_s,
            (0.0..=0.5).contains(&c.exposure_s),
            "0 to 0.5 (s)",
        )?;
        Ok(())
    }
}
