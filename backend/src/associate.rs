//! Associating a new keyframe's features with map points: through their tracks, then by
//! ORB matching near the predicted projections of the local map.

use crate::backend::Backend;
use crate::map::{KeyframeId, MapPoint, PointId};
use crate::matching::match_points;
use nalgebra::Matrix6;
use std::collections::BTreeSet;

impl Backend {
    /// Associates features whose track already has a map point (the tracks of the previous
    /// keyframe, which saw every track the odometry still follows), each pair gated by its
    /// 3-D Mahalanobis distance under the predicted pose. Returns the associations and the
    /// pose's covariance.
    pub(crate) fn associate_tracks(
        &mut self,
        id: KeyframeId,
        pose_cov: Matrix6<f64>,
    ) -> (usize, Matrix6<f64>) {
        let by_track = &self.tracks;
        let Some(kf) = self.map.keyframe(id) else {
            return (0, pose_cov);
        };
        let candidates: Vec<(usize, PointId)> = kf
            .features
            .iter()
            .enumerate()
            .filter(|(_, f)| f.measurement.is_some())
            .filter_map(|(i, f)| Some((i, *by_track.get(&f.track_id)?)))
            .collect();
        let Some(kf) = self.map.keyframe(id) else {
            return (0, pose_cov);
        };
        let camera_from_world = kf.world_from_camera.inverse();
        let r_cw = camera_from_world.rotation.to_rotation_matrix().into_inner();
        // The prediction's own uncertainty widens the gate: a frontend pose is exact only
        // relative to its own points.
        let pose_var = pose_cov.fixed_view::<3, 3>(0, 0).trace() / 3.0;
        let gate = self.config.matching.chi2_gate;
        let model = self.config.matching.model_noise_m.powi(2) + pose_var.max(0.0);
        let pairs: Vec<(usize, PointId)> = candidates
            .iter()
            .filter_map(|&(i, pid)| {
                let m = kf.features.get(i)?.measurement?;
                let p = self.map.point(pid)?;
                let q = camera_from_world * p.p_world;
                let cov_p = p
                    .covariance()
                    .map_or(nalgebra::Matrix3::zeros(), |c| r_cw * c * r_cw.transpose());
                let s = m.cov + cov_p + nalgebra::Matrix3::identity() * model;
                let r = m.p - q;
                let chi2 = r.dot(&(s.try_inverse()? * r));
                (chi2 <= gate).then_some((i, pid))
            })
            .collect();
        (self.observe(id, &pairs, false), pose_cov)
    }

    /// Records the associations `(feature, point)` of keyframe `id`; returns how many took.
    /// `projected`: whether the points' `visible` counters were already counted (ORB
    /// matching counts every point it projects into the image).
    fn observe(&mut self, id: KeyframeId, pairs: &[(usize, PointId)], projected: bool) -> usize {
        let mut n = 0;
        for &(f, pid) in pairs {
            if self.map.add_observation(pid, id, f) {
                if let Some(p) = self.map.point_mut(pid) {
                    p.visible += u32::from(!projected);
                    p.found += 1;
                }
                n += 1;
            }
        }
        n
    }

    /// The keyframes whose points are matched into keyframe `id`: the previous keyframe's
    /// covisible ones, and those near the predicted pose; only those of its own piece in a
    /// run that started in a saved map by a guess (`Backend::guessed_start`).
    fn local_map(&self, id: KeyframeId, previous: Option<KeyframeId>) -> BTreeSet<KeyframeId> {
        let mut set = self.local_map_all(id, previous);
        if let Some(start) = self.guessed_start.filter(|&s| id >= s) {
            set.retain(|&k| k >= start);
        }
        set
    }

    /// [`Self::local_map`] wherever the keyframe is.
    fn local_map_all(&self, id: KeyframeId, previous: Option<KeyframeId>) -> BTreeSet<KeyframeId> {
        let mut set = BTreeSet::new();
        if let Some(prev) = previous.and_then(|p| self.map.keyframe(p)) {
            set.insert(prev.id);
            set.extend(
                prev.covisible(1)
                    .into_iter()
                    .take(self.config.local_map_keyframes)
                    .map(|(k, _)| k),
            );
        }
        set.extend(self.map.nearby(
            id,
            self.config.nearby_radius_m,
            self.config.nearby_angle_deg,
            self.config.local_map_keyframes,
            |_| true,
        ));
        set
    }

    /// ORB matching of the features of keyframe `id` against the local map's points that
    /// it does not see yet. A feature without a point takes the one it matches; a feature
    /// whose track already has a point that turns out to be a duplicate of the matched one
    /// (the same physical point, mapped twice because it was not recognised when its track
    /// began) has the two fused, keeping the one seen by more keyframes. Returns the new
    /// associations and the fusions.
    pub(crate) fn match_local_map(
        &mut self,
        id: KeyframeId,
        previous: Option<KeyframeId>,
        pose_cov: &Matrix6<f64>,
    ) -> (usize, usize) {
        let local = self.local_map(id, previous);
        let Some(kf) = self.map.keyframe(id) else {
            return (0, 0);
        };
        let seen: BTreeSet<PointId> = kf.points().collect();
        let mut cand_ids: BTreeSet<PointId> = BTreeSet::new();
        for k in &local {
            if let Some(other) = self.map.keyframe(*k) {
                cand_ids.extend(other.points().filter(|p| !seen.contains(p)));
            }
        }
        let candidates: Vec<(PointId, &MapPoint)> = cand_ids
            .iter()
            .filter_map(|&p| Some((p, self.map.point(p)?)))
            .collect();
        let eligible: Vec<usize> = kf
            .features
            .iter()
            .enumerate()
            .filter(|(_, f)| f.measurement.is_some() && f.descriptor.is_some())
            .map(|(i, _)| i)
            .collect();
        let (matches, visible) = match_points(
            &self.camera,
            &kf.world_from_camera,
            pose_cov,
            &kf.features,
            &eligible,
            &candidates,
            &self.config.matching,
        );
        for p in visible {
            if let Some(mp) = self.map.point_mut(p) {
                mp.visible += 1;
            }
        }
        let mut pairs = Vec::new();
        let mut fused = 0;
        for m in &matches {
            let current = self
                .map
                .keyframe(id)
                .and_then(|kf| kf.features.get(m.feature))
                .and_then(|f| f.point);
            match current {
                None => pairs.push((m.feature, m.point)),
                Some(p) if p != m.point => {
                    let count = |q| self.map.point(q).map_or(0, |mp| mp.observations.len());
                    let (keep, drop) = if (count(m.point), std::cmp::Reverse(m.point))
                        >= (count(p), std::cmp::Reverse(p))
                    {
                        (m.point, p)
                    } else {
                        (p, m.point)
                    };
                    if self.map.point(keep).is_some() && self.map.point(drop).is_some() {
                        self.map.merge_points(keep, drop);
                        fused += 1;
                    }
                }
                Some(_) => {}
            }
        }
        (self.observe(id, &pairs, true), fused)
    }
}
