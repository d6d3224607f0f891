//! A saved keyframe's place features ([`stride_frontend::PlaceFeature`]) as the map file
//! holds them (format version 2, [`crate::map_file`]): column by column, so that a
//! keyframe's thousand features take a few arrays instead of a thousand objects.
//!
//! `place_features` of a keyframe: `px` (`[column, row]` per feature, px), `p_camera_m`
//! (`[x, y, z]` per feature, m, the keyframe's camera frame), `cov_camera_m2` (the upper
//! triangle `[xx, xy, xz, yy, yz, zz]` per feature, m^2), all f32, and `descriptors` (ORB,
//! 64 hex digits per feature, concatenated). Reading checks that the columns agree in
//! length, that every number is finite, every point in front of the camera and every
//! variance positive.

use crate::map_file::{hex, unhex};
use serde::{Deserialize, Serialize};
use stride_frontend::{PackedFeature, PlaceFeature};

/// One keyframe's place features, column by column (see the module documentation).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PlaceFeaturesDto {
    px: Vec<f32>,
    p_camera_m: Vec<f32>,
    cov_camera_m2: Vec<f32>,
    descriptors: String,
}

impl PlaceFeaturesDto {
    /// The columns of `features` (points and covariances rounded to f32).
    pub(crate) fn of(features: &[PlaceFeature]) -> Self {
        let mut dto = Self::default();
        for f in features.iter().map(PackedFeature::new) {
            dto.px.extend(f.px);
            dto.p_camera_m.extend(f.p_camera_m);
            dto.cov_camera_m2.extend(f.cov_upper_m2);
            dto.descriptors.push_str(&hex(&f.descriptor));
        }
        dto
    }

    /// The features back, checked (see the module documentation); the error says which
    /// feature of keyframe `kf` is wrong.
    pub(crate) fn features(&self, kf: u64) -> Result<Vec<PlaceFeature>, String> {
        let n = self.px.len() / 2;
        if self.px.len() != 2 * n
            || self.p_camera_m.len() != 3 * n
            || self.cov_camera_m2.len() != 6 * n
            || self.descriptors.len() != 64 * n
        {
            return Err(format!(
                "keyframe {kf}: place feature columns disagree in length ({} px, {} p_camera_m, {} cov_camera_m2 numbers, {} descriptor digits)",
                self.px.len(),
                self.p_camera_m.len(),
                self.cov_camera_m2.len(),
                self.descriptors.len()
            ));
        }
        let columns = self
            .px
            .chunks_exact(2)
            .zip(self.p_camera_m.chunks_exact(3))
            .zip(self.cov_camera_m2.chunks_exact(6));
        columns
            .enumerate()
            .map(|(i, ((px, p), c))| {
                let bad = |what: &str| format!("keyframe {kf} place feature {i}: {what}");
                let all = px.iter().chain(p).chain(c);
                if !all.clone().all(|v| v.is_finite()) {
                    return Err(bad("a number is not finite"));
                }
                if p[2] <= 0.0 || c[0] <= 0.0 || c[3] <= 0.0 || c[5] <= 0.0 {
                    return Err(bad("point behind the camera or variance not positive"));
                }
                let digits = self.descriptors.get(64 * i..64 * (i + 1)).unwrap_or("");
                let descriptor = unhex(digits)
                    .ok_or_else(|| bad(&format!("descriptor {digits:?} is not 64 hex digits")))?;
                Ok(PackedFeature {
                    px: [px[0], px[1]],
                    descriptor,
                    p_camera_m: [p[0], p[1], p[2]],
                    cov_upper_m2: [c[0], c[1], c[2], c[3], c[4], c[5]],
                }
                .feature())
            })
            .collect()
    }
}
