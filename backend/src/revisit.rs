//! Revisit links: a new keyframe's depth aligned with the depth of an old keyframe whose
//! camera stood near it, and the relative pose kept as a pose-pose edge.
//!
//! A keyframe of a later pass over the same place re-observes few old map points by ORB
//! (its tracked corners are not where the old points were detected), so the passes are
//! tied only loosely through the features. Their depth images overlap much more: the
//! odometry's projective point-to-plane ICP ([`stride_frontend::depth_align`]) at half
//! resolution, started from the two keyframes' current poses, measures their relative pose
//! from the geometry. The edge joins the optimizations like the odometry's depth links,
//! for as long as both keyframes live.
//!
//! Memory: each keyframe keeps its depth at half resolution in quarter millimetres (2 bytes
//! per pixel: 0.15 MB at VGA), dropped when the keyframe is culled.

use crate::backend::Backend;
use crate::map::KeyframeId;
use nalgebra::Isometry3;
use std::collections::BTreeMap;
use stride_core::camera::PinholeCamera;
use stride_core::image::{DepthImage, Image};
use stride_core::pose::rotation_angle_rad;
use stride_frontend::depth_align::{align, DepthAlignParams, DepthView};

/// The revisit links' settings (`backend.revisit` in the configuration).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RevisitConfig {
    /// Whether new keyframes are aligned with old keyframes near them. A keyframe so tied
    /// is not searched for a loop: the link closes it. On teddy's pingpong (seed 1) the
    /// ATE over 1,000 frames falls from 8.35 to 7.49 mm, over 10,000 from 12.22 to 6.74.
    pub enabled: bool,
    /// Farthest an old keyframe's camera may stand from the new one's (m).
    pub max_distance_m: f64,
    /// Largest rotation between the two cameras (degrees).
    pub max_rotation_deg: f64,
    /// Fewest keyframes between the two: nearer ones are tied by the features already.
    pub min_keyframe_gap: u64,
    /// Fewest samples of the new keyframe paired with the old one's surface, as a
    /// fraction of those with depth (the overlap).
    pub min_paired_fraction: f64,
}

impl Default for RevisitConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_distance_m: 0.3,
            max_rotation_deg: 45.0,
            min_keyframe_gap: 20,
            min_paired_fraction: 0.3,
        }
    }
}

/// Largest correction of the new keyframe's pose relative to the old one that a link may
/// make (m, degrees): the reach of the alignment's coarsest pairing (10 cm).
const MAX_CORRECTION_M: f64 = 0.1;
/// See [`MAX_CORRECTION_M`].
const MAX_CORRECTION_DEG: f64 = 10.0;

/// Units of a kept depth image per metre: quarter millimetres (16.38 m at most; a farther
/// depth is kept as none). Their rounding (0.07 mm rms) is far below the sensor's noise.
const KEPT_UNITS_PER_M: f32 = 4000.0;

/// A depth image (m) in [`KEPT_UNITS_PER_M`]; 0 where none or out of range.
fn keep(depth_m: &DepthImage) -> Image<u16> {
    depth_m.map(|d| {
        let q = (d * KEPT_UNITS_PER_M).round();
        if q >= 1.0 && q <= f32::from(u16::MAX) {
            q as u16
        } else {
            0
        }
    })
}

/// The keyframes' depth images at half resolution ([`keep`]), with the camera that goes
/// with them.
pub(crate) struct Revisits {
    camera: PinholeCamera,
    depth: BTreeMap<KeyframeId, Image<u16>>,
}

impl Revisits {
    /// An empty store for `camera` (full resolution).
    pub(crate) fn new(camera: &PinholeCamera) -> Self {
        Self {
            camera: camera.scaled(0.5),
            depth: BTreeMap::new(),
        }
    }

    /// Forgets keyframe `id`'s depth.
    pub(crate) fn remove(&mut self, id: KeyframeId) {
        self.depth.remove(&id);
    }
}

/// `depth_m` at half resolution: each 2 x 2 block's mean when all four pixels have depth
/// within `edge_rel` of each other, else 0 (no depth), so that no sample mixes two
/// surfaces. Pixel centres move as [`PinholeCamera::scaled`] assumes.
fn half_resolution(depth_m: &DepthImage, edge_rel: f32) -> DepthImage {
    let (w, h) = (depth_m.width() / 2, depth_m.height() / 2);
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let px = [
                depth_m.get(2 * x, 2 * y),
                depth_m.get(2 * x + 1, 2 * y),
                depth_m.get(2 * x, 2 * y + 1),
                depth_m.get(2 * x + 1, 2 * y + 1),
            ];
            let (mut lo, mut hi, mut sum) = (f32::INFINITY, 0.0f32, 0.0f32);
            for d in px.iter().map(|d| d.unwrap_or(0.0)) {
                lo = if d < lo { d } else { lo };
                hi = if d > hi { d } else { hi };
                sum += d;
            }
            let ok = lo > 0.0 && lo.is_finite() && hi <= lo * (1.0 + edge_rel);
            out.push(if ok { sum / 4.0 } else { 0.0 });
        }
    }
    // The size is w x h by construction.
    DepthImage::from_vec(w, h, out).unwrap_or_else(|_| DepthImage::filled(w, h, 0.0))
}

/// Whether the alignment moved the new keyframe relative to the old one (from `start` to
/// `aligned`, both `old_from_new`) by no more than the alignment can reach; a larger
/// correction is the ICP settling on a look-alike surface (steps, a corridor), not a
/// revisit. The reason when not.
fn within_reach(start: &Isometry3<f64>, aligned: &Isometry3<f64>) -> Result<(), String> {
    let moved = start.inverse() * aligned;
    let (m, deg) = (
        moved.translation.vector.norm(),
        rotation_angle_rad(&moved.rotation).to_degrees(),
    );
    if m > MAX_CORRECTION_M || deg > MAX_CORRECTION_DEG {
        Err(format!(
            "it would move the keyframe {m:.3} m and {deg:.1} degrees"
        ))
    } else {
        Ok(())
    }
}

impl Backend {
    /// Keeps keyframe `id`'s depth, and ties it to the old keyframe nearest to it (within
    /// the configured distance, rotation and keyframe gap) by aligning their depths;
    /// whether an edge was added.
    pub(crate) fn add_revisit_edge(
        &mut self,
        id: KeyframeId,
        depth_m: Option<&DepthImage>,
    ) -> bool {
        let cfg = self.config.revisit;
        let Some(depth_m) = depth_m.filter(|_| cfg.enabled) else {
            return false;
        };
        let vo = stride_frontend::VoConfig::default();
        let half = half_resolution(depth_m, vo.depth_edge_rel as f32);
        let Some(world_from_new) = self.map.pose_of(id) else {
            return false;
        };
        let nearest = self
            .revisits
            .depth
            .keys()
            .filter(|&&k| k + cfg.min_keyframe_gap <= id)
            .filter_map(|&k| Some((k, self.map.pose_of(k)?)))
            .map(|(k, p)| {
                let d = (p.translation.vector - world_from_new.translation.vector).norm();
                (k, p, d)
            })
            .filter(|(_, p, d)| {
                let turn = p.rotation.inverse() * world_from_new.rotation;
                *d <= cfg.max_distance_m
                    && rotation_angle_rad(&turn).to_degrees() <= cfg.max_rotation_deg
            })
            .min_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)));
        let mut added = false;
        if let Some((old, world_from_old, _)) = nearest {
            if let Some(old_depth) = self.revisits.depth.get(&old) {
                let old_depth = old_depth.map(|q| f32::from(q) / KEPT_UNITS_PER_M);
                // The odometry's default depth range and edge test; the back end's own
                // depth model.
                let params = DepthAlignParams {
                    min_paired_fraction: cfg.min_paired_fraction,
                    noise: self.config.depth_model,
                    ..DepthAlignParams::from_config(&vo)
                };
                // Both in the old keyframe's frame: the edge is relative.
                let old_from_new = world_from_old.inverse() * world_from_new;
                let result = align(
                    &DepthView {
                        depth_m: &old_depth,
                        world_from_camera: Isometry3::identity(),
                    },
                    &DepthView {
                        depth_m: &half,
                        world_from_camera: old_from_new,
                    },
                    &self.revisits.camera,
                    &params,
                );
                let checked = result
                    .map_err(|e| e.to_string())
                    .and_then(|a| within_reach(&old_from_new, &a.world_from_cur).map(|()| a));
                match checked {
                    Ok(a) => {
                        added = self.add_measured_edge(
                            (old, id, crate::window::EdgeKind::Revisit),
                            a.world_from_cur,
                            &a.world_from_cur,
                            &a.information,
                        );
                    }
                    Err(e) => tracing::debug!("keyframe {id}: no revisit link to {old}: {e}"),
                }
            }
        }
        self.revisits.depth.insert(id, keep(&half));
        added
    }
}

#[cfg(test)]
#[path = "revisit_tests.rs"]
mod tests;
