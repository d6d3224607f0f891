//! Pose-graph mode (paper 004's RGB-D SLAM v2 style): instead of optimizing points, each
//! new keyframe is tied to the keyframes it shares points with by a relative motion
//! estimated from their measurements of those points (Umeyama + RANSAC, refined), and only
//! the poses are optimized. Points are then re-placed from their observations, for the map
//! matching of later keyframes.

use crate::backend::Backend;
use crate::map::KeyframeId;
use crate::se3::left_from_right;
use crate::window::KeyframeEdge;
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeSet;
use stride_core::rng::{key, SplitMix64};
use stride_frontend::motion::{estimate, Correspondence, MotionParams};
use stride_frontend::{InlierTest, VoConfig};

/// Fewest shared points for a keyframe-to-keyframe estimate.
const MIN_SHARED: u32 = 20;
/// Most keyframes a new keyframe is tied to.
const MAX_LINKS: usize = 5;

impl Backend {
    /// Estimates the relative motion between keyframe `id` and each of the keyframes
    /// sharing the most points with it, and stores them as pose-pose edges.
    pub(crate) fn measure_pose_edges(&mut self, id: KeyframeId) {
        let Some(kf) = self.map.keyframe(id) else {
            return;
        };
        let vo = VoConfig::default();
        let params = MotionParams {
            test: InlierTest::Mahalanobis { chi2: 11.34 },
            ..MotionParams::from_config(&vo)
        };
        let mut edges = Vec::new();
        for (other, _) in kf.covisible(MIN_SHARED).into_iter().take(MAX_LINKS) {
            let Some(okf) = self.map.keyframe(other) else {
                continue;
            };
            let corrs: Vec<Correspondence> = kf
                .features
                .iter()
                .filter_map(|f| {
                    let pid = f.point?;
                    let current = f.measurement?;
                    let reference = okf
                        .features
                        .iter()
                        .find(|g| g.point == Some(pid))?
                        .measurement?;
                    Some(Correspondence { reference, current })
                })
                .collect();
            let mut rng = SplitMix64::new(key(&[other, id]));
            let Some(e) = estimate(&corrs, &params, &mut rng) else {
                continue;
            };
            let a = left_from_right(&e.ref_from_cur);
            let info = a.transpose() * e.information * a;
            edges.push(KeyframeEdge {
                from: other,
                to: id,
                from_from_to: e.ref_from_cur,
                information: (info + info.transpose()) * 0.5,
                kind: crate::window::EdgeKind::Covisible,
            });
        }
        self.pose_edges.extend(edges);
    }

    /// Re-places the points of keyframes `free` at the information-weighted mean of their
    /// observations under the current poses.
    pub(crate) fn place_points(&mut self, free: &[KeyframeId]) {
        let mut points = BTreeSet::new();
        for &k in free {
            if let Some(kf) = self.map.keyframe(k) {
                points.extend(kf.points());
            }
        }
        let model = Matrix3::identity() * self.config.model_noise_m.powi(2);
        for pid in points {
            let Some(p) = self.map.point(pid) else {
                continue;
            };
            let (mut info, mut acc) = (Matrix3::zeros(), Vector3::zeros());
            for o in &p.observations {
                let Some(kf) = self.map.keyframe(o.keyframe) else {
                    continue;
                };
                let Some(m) = kf.features.get(o.feature).and_then(|f| f.measurement) else {
                    continue;
                };
                let Some(w) = (m.cov + model).try_inverse() else {
                    continue;
                };
                let r = kf.world_from_camera.rotation.to_rotation_matrix();
                let w_world = r.matrix() * w * r.matrix().transpose();
                info += w_world;
                acc += w_world * (kf.world_from_camera * m.p).coords;
            }
            if let Some(cov) = info.try_inverse() {
                self.map
                    .set_position(pid, nalgebra::Point3::from(cov * acc));
            }
        }
    }
}
