//! The persistent map: keyframes with their features and poses, 3-D points with their
//! observations, and the covisibility between keyframes (how many points two keyframes
//! share).
//!
//! Invariants kept by every method: an observation `(keyframe, feature)` of a point is
//! listed in the point and named by the keyframe's feature (`Feature::point`), and in no
//! other point; covisibility counts equal the points two keyframes share; a point without
//! observations does not exist. Maps iterate in identifier order (`BTreeMap`), so that
//! every pass over them is deterministic.

use crate::se3::point_is_finite;
use nalgebra::{Isometry3, Matrix3, Matrix6, Point2, Point3};
use std::collections::BTreeMap;
use stride_frontend::features::OrbDescriptor;
use stride_frontend::points::Measurement;

/// Identifier of a keyframe (the frontend's [`stride_frontend::KeyframeInfo::id`]).
pub type KeyframeId = u64;
/// Identifier of a map point.
pub type PointId = u64;

/// A keypoint of a keyframe.
#[derive(Debug, Clone, PartialEq)]
pub struct Feature {
    /// The frontend's track identifier.
    pub track_id: u64,
    /// Pixel position (distorted image coordinates).
    pub px: Point2<f32>,
    /// The point measured with the keyframe's depth (camera frame, m and m^2).
    pub measurement: Option<Measurement>,
    /// ORB descriptor.
    pub descriptor: Option<OrbDescriptor>,
    /// The map point this feature observes.
    pub point: Option<PointId>,
}

/// The odometry's link from a keyframe to the one before it.
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryEdge {
    /// The previous keyframe.
    pub previous: KeyframeId,
    /// `previous_from_this` (m).
    pub previous_from_this: Isometry3<f64>,
    /// Information of the error of [`crate::ba::problem::pose_error`] (translation, then
    /// rotation).
    pub information: Matrix6<f64>,
    /// Whether the optimizer uses it: when the keyframe re-observes too few map points.
    pub active: bool,
}

/// A keyframe.
#[derive(Debug, Clone, PartialEq)]
pub struct Keyframe {
    /// Identifier.
    pub id: KeyframeId,
    /// Index of its frame in the sequence.
    pub frame_index: usize,
    /// Time (s).
    pub t_s: f64,
    /// `world_from_camera` (m), as optimized.
    pub world_from_camera: Isometry3<f64>,
    /// Its keypoints.
    pub features: Vec<Feature>,
    /// Shared points with each other keyframe (only non-zero counts).
    pub covisibility: BTreeMap<KeyframeId, u32>,
    /// The odometry's link to the previous keyframe.
    pub odometry: Option<OdometryEdge>,
}

impl Keyframe {
    /// The points this keyframe observes, in feature order.
    pub fn points(&self) -> impl Iterator<Item = PointId> + '_ {
        self.features.iter().filter_map(|f| f.point)
    }

    /// Keyframes sharing at least `min_shared` points with this one, most shared first
    /// (ties by identifier).
    pub fn covisible(&self, min_shared: u32) -> Vec<(KeyframeId, u32)> {
        let mut v: Vec<(KeyframeId, u32)> = self
            .covisibility
            .iter()
            .filter(|(_, &n)| n >= min_shared)
            .map(|(&k, &n)| (k, n))
            .collect();
        v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        v
    }
}

/// An observation of a point: a keyframe and the index of its feature.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Observation {
    /// The keyframe.
    pub keyframe: KeyframeId,
    /// Index into its features.
    pub feature: usize,
}

/// A 3-D point feature of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapPoint {
    /// Position in the world frame (m).
    pub p_world: Point3<f64>,
    /// Sum of its observations' information matrices rotated into the world frame
    /// (1/m^2); its inverse approximates the point's covariance.
    pub information_world: Matrix3<f64>,
    /// A descriptor for matching: the latest observation's.
    pub descriptor: Option<OrbDescriptor>,
    /// Observations, sorted by keyframe.
    pub observations: Vec<Observation>,
    /// Times the point was projected into a new keyframe for matching, and times it was
    /// matched or tracked there (ORB-SLAM's found ratio, for culling).
    pub visible: u32,
    /// See `visible`.
    pub found: u32,
    /// The keyframe that created it.
    pub created_by: KeyframeId,
}

impl MapPoint {
    /// The point's covariance in the world frame (m^2), when its information is invertible.
    pub fn covariance(&self) -> Option<Matrix3<f64>> {
        self.information_world.try_inverse()
    }
}

/// A keyframe removed from the map, remembered so that frames referring to it keep a pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Culled {
    /// The keyframe its pose is kept relative to (possibly culled itself later).
    pub parent: KeyframeId,
    /// `parent_from_culled` (m).
    pub parent_from_this: Isometry3<f64>,
}

/// The map. See the module documentation for its invariants.
#[derive(Debug, Clone, Default)]
pub struct Map {
    keyframes: BTreeMap<KeyframeId, Keyframe>,
    points: BTreeMap<PointId, MapPoint>,
    culled: BTreeMap<KeyframeId, Culled>,
    next_point: PointId,
}

/// The rotation of `world_from_camera` applied to a camera-frame information matrix.
fn info_to_world(world_from_camera: &Isometry3<f64>, info: &Matrix3<f64>) -> Matrix3<f64> {
    let r = world_from_camera.rotation.to_rotation_matrix();
    r.matrix() * info * r.matrix().transpose()
}

impl Map {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Keyframes, by identifier.
    pub fn keyframes(&self) -> &BTreeMap<KeyframeId, Keyframe> {
        &self.keyframes
    }

    /// Points, by identifier.
    pub fn points(&self) -> &BTreeMap<PointId, MapPoint> {
        &self.points
    }

    /// A keyframe.
    pub fn keyframe(&self, id: KeyframeId) -> Option<&Keyframe> {
        self.keyframes.get(&id)
    }

    /// A point.
    pub fn point(&self, id: PointId) -> Option<&MapPoint> {
        self.points.get(&id)
    }

    /// Keyframes (other than `id`) passing `keep` within `radius_m` of keyframe `id`'s
    /// position and looking within `max_angle_deg` of its optical axis, nearest first (ties
    /// by identifier), at most `take`.
    pub fn nearby(
        &self,
        id: KeyframeId,
        radius_m: f64,
        max_angle_deg: f64,
        take: usize,
        keep: impl Fn(&Keyframe) -> bool,
    ) -> Vec<KeyframeId> {
        let Some(kf) = self.keyframe(id) else {
            return Vec::new();
        };
        let forward = |k: &Keyframe| k.world_from_camera.rotation * nalgebra::Vector3::z();
        let (t, fwd) = (kf.world_from_camera.translation.vector, forward(kf));
        let cos_max = max_angle_deg.to_radians().cos();
        let mut near: Vec<(f64, KeyframeId)> = self
            .keyframes
            .values()
            .filter(|k| k.id != id && keep(k))
            .filter_map(|k| {
                let d = (k.world_from_camera.translation.vector - t).norm();
                (d <= radius_m && forward(k).dot(&fwd) >= cos_max).then_some((d, k.id))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.into_iter().take(take).map(|(_, k)| k).collect()
    }

    /// Culled keyframes and where their poses are kept.
    pub fn culled(&self) -> &BTreeMap<KeyframeId, Culled> {
        &self.culled
    }

    /// Adds a keyframe (its features' `point` fields are cleared; use
    /// [`Map::add_observation`]). Replaces nothing: an existing identifier is refused.
    pub fn insert_keyframe(&mut self, mut kf: Keyframe) -> bool {
        if self.keyframes.contains_key(&kf.id) || self.culled.contains_key(&kf.id) {
            return false;
        }
        for f in &mut kf.features {
            f.point = None;
        }
        kf.covisibility.clear();
        self.keyframes.insert(kf.id, kf);
        true
    }

    /// Sets a keyframe's pose.
    pub fn set_pose(&mut self, id: KeyframeId, world_from_camera: Isometry3<f64>) {
        if let Some(kf) = self.keyframes.get_mut(&id) {
            kf.world_from_camera = world_from_camera;
        }
    }

    /// Sets a point's position.
    pub fn set_position(&mut self, id: PointId, p_world: Point3<f64>) {
        if let Some(p) = self.points.get_mut(&id) {
            if point_is_finite(&p_world) {
                p.p_world = p_world;
            }
        }
    }

    /// A mutable point, for its counters.
    pub fn point_mut(&mut self, id: PointId) -> Option<&mut MapPoint> {
        self.points.get_mut(&id)
    }

    /// A mutable keyframe's odometry edge.
    pub fn odometry_mut(&mut self, id: KeyframeId) -> Option<&mut OdometryEdge> {
        self.keyframes.get_mut(&id)?.odometry.as_mut()
    }

    /// Creates a point from a keyframe's feature measurement (placed with the keyframe's
    /// pose) and returns its identifier; `None` if the feature has no measurement or
    /// already observes a point.
    pub fn create_point(&mut self, kf_id: KeyframeId, feature: usize) -> Option<PointId> {
        let kf = self.keyframes.get(&kf_id)?;
        let f = kf.features.get(feature)?;
        if f.point.is_some() {
            return None;
        }
        let m = f.measurement?;
        let p_world = kf.world_from_camera * m.p;
        if !point_is_finite(&p_world) {
            return None;
        }
        let id = self.next_point;
        self.next_point += 1;
        self.points.insert(
            id,
            MapPoint {
                p_world,
                information_world: Matrix3::zeros(),
                descriptor: None,
                observations: Vec::new(),
                visible: 1,
                found: 1,
                created_by: kf_id,
            },
        );
        self.add_observation(id, kf_id, feature).then_some(id)
    }

    /// Records that `feature` of keyframe `kf_id` observes point `point`. Refused (false)
    /// when the feature has no measurement or already observes a point, or the keyframe
    /// already observes this point.
    pub fn add_observation(&mut self, point: PointId, kf_id: KeyframeId, feature: usize) -> bool {
        let (Some(kf), Some(p)) = (self.keyframes.get(&kf_id), self.points.get(&point)) else {
            return false;
        };
        let Some(f) = kf.features.get(feature) else {
            return false;
        };
        let Some(m) = f.measurement else {
            return false;
        };
        if f.point.is_some() || p.observations.iter().any(|o| o.keyframe == kf_id) {
            return false;
        }
        let Some(info) = m.cov.try_inverse() else {
            return false;
        };
        let info_w = info_to_world(&kf.world_from_camera, &info);
        let descriptor = f.descriptor;
        let others: Vec<KeyframeId> = p.observations.iter().map(|o| o.keyframe).collect();
        for &o in &others {
            if let Some(k) = self.keyframes.get_mut(&o) {
                *k.covisibility.entry(kf_id).or_insert(0) += 1;
            }
        }
        if let Some(kf) = self.keyframes.get_mut(&kf_id) {
            for &o in &others {
                *kf.covisibility.entry(o).or_insert(0) += 1;
            }
            if let Some(f) = kf.features.get_mut(feature) {
                f.point = Some(point);
            }
        }
        if let Some(p) = self.points.get_mut(&point) {
            let obs = Observation {
                keyframe: kf_id,
                feature,
            };
            let at = p.observations.partition_point(|o| *o < obs);
            p.observations.insert(at, obs);
            p.information_world += info_w;
            if descriptor.is_some() {
                p.descriptor = descriptor;
            }
        }
        true
    }

    /// Removes the observation of `point` by keyframe `kf_id`; the point goes when it has no
    /// observation left.
    pub fn remove_observation(&mut self, point: PointId, kf_id: KeyframeId) {
        let Some(p) = self.points.get_mut(&point) else {
            return;
        };
        let Some(pos) = p.observations.iter().position(|o| o.keyframe == kf_id) else {
            return;
        };
        let obs = p.observations.remove(pos);
        let others: Vec<KeyframeId> = p.observations.iter().map(|o| o.keyframe).collect();
        let empty = others.is_empty();
        if let Some(kf) = self.keyframes.get(&kf_id) {
            let info = kf
                .features
                .get(obs.feature)
                .and_then(|f| f.measurement)
                .and_then(|m| m.cov.try_inverse())
                .map(|i| info_to_world(&kf.world_from_camera, &i));
            if let (Some(info), Some(p)) = (info, self.points.get_mut(&point)) {
                p.information_world -= info;
            }
        }
        let decrement = |k: &mut Keyframe, other: KeyframeId| {
            if let Some(n) = k.covisibility.get_mut(&other) {
                *n = n.saturating_sub(1);
                if *n == 0 {
                    k.covisibility.remove(&other);
                }
            }
        };
        for &o in &others {
            if let Some(k) = self.keyframes.get_mut(&o) {
                decrement(k, kf_id);
            }
        }
        if let Some(kf) = self.keyframes.get_mut(&kf_id) {
            for &o in &others {
                decrement(kf, o);
            }
            if let Some(f) = kf.features.get_mut(obs.feature) {
                f.point = None;
            }
        }
        if empty {
            self.points.remove(&point);
        }
    }

    /// Removes a point and all its observations.
    pub fn remove_point(&mut self, point: PointId) {
        let kfs: Vec<KeyframeId> = self
            .points
            .get(&point)
            .map(|p| p.observations.iter().map(|o| o.keyframe).collect())
            .unwrap_or_default();
        for k in kfs {
            self.remove_observation(point, k);
        }
        self.points.remove(&point);
    }

    /// Moves every observation of `drop` to `keep` (where `keep`'s keyframe does not already
    /// observe it) and removes `drop`: two points found to be the same.
    pub fn merge_points(&mut self, keep: PointId, drop: PointId) {
        if keep == drop || !self.points.contains_key(&keep) {
            return;
        }
        let Some(obs) = self.points.get(&drop).map(|p| p.observations.clone()) else {
            return;
        };
        self.remove_point(drop);
        for o in obs {
            self.add_observation(keep, o.keyframe, o.feature);
        }
    }

    /// Drops the features of keyframe `id` that observe no point, renumbering the
    /// observations of the others (their order is kept). Meant for keyframes older than the
    /// local window: nothing gives their features a point any more, and those features are
    /// most of a keyframe's memory (a 10,000-frame run kept 644,000 of which 37,000 had a
    /// point). Returns how many were dropped.
    pub fn drop_unmapped_features(&mut self, id: KeyframeId) -> usize {
        let Some(kf) = self.keyframes.get_mut(&id) else {
            return 0;
        };
        let all = std::mem::take(&mut kf.features);
        let before = all.len();
        let mut renumbered = Vec::new();
        let mut kept = Vec::with_capacity(all.iter().filter(|f| f.point.is_some()).count());
        for (old, f) in all.into_iter().enumerate() {
            if let Some(p) = f.point {
                renumbered.push((p, old, kept.len()));
                kept.push(f);
            }
        }
        let dropped = before - kept.len();
        kf.features = kept;
        for (p, old, new) in renumbered {
            let Some(mp) = self.points.get_mut(&p) else {
                continue;
            };
            for o in mp
                .observations
                .iter_mut()
                .filter(|o| o.keyframe == id && o.feature == old)
            {
                o.feature = new;
            }
        }
        dropped
    }

    /// Removes the keyframes `ids` outright (not culled: nothing is kept relative to them),
    /// with their observations; points left without one go too, and a remaining keyframe's
    /// odometry edge to a removed one is dropped. Returns the points removed. For a map
    /// to be saved without the pieces of a run that were placed only by a guess.
    pub fn remove_keyframes(&mut self, ids: &std::collections::BTreeSet<KeyframeId>) -> usize {
        let before = self.points.len();
        for &id in ids {
            let points: Vec<PointId> = self
                .keyframes
                .get(&id)
                .map(|kf| kf.points().collect())
                .unwrap_or_default();
            for p in points {
                self.remove_observation(p, id);
            }
            self.keyframes.remove(&id);
        }
        for k in self.keyframes.values_mut() {
            if k.odometry
                .as_ref()
                .is_some_and(|e| ids.contains(&e.previous))
            {
                k.odometry = None;
            }
        }
        before.saturating_sub(self.points.len())
    }

    /// Removes a keyframe and its observations; frames that refer to it keep their pose
    /// relative to `parent` (which must exist).
    pub fn cull_keyframe(&mut self, id: KeyframeId, parent: KeyframeId) -> bool {
        let (Some(kf), Some(par)) = (self.keyframes.get(&id), self.keyframes.get(&parent)) else {
            return false;
        };
        if id == parent {
            return false;
        }
        let parent_from_this = par.world_from_camera.inverse() * kf.world_from_camera;
        let points: Vec<PointId> = kf.points().collect();
        for p in points {
            self.remove_observation(p, id);
        }
        // A later keyframe whose odometry edge pointed here now points at the parent.
        let odometry = self.keyframes.get(&id).and_then(|k| k.odometry.clone());
        for k in self.keyframes.values_mut() {
            if let Some(e) = k.odometry.as_mut().filter(|e| e.previous == id) {
                match &odometry {
                    Some(o) if o.previous != k.id => {
                        e.previous = o.previous;
                        e.previous_from_this = o.previous_from_this * e.previous_from_this;
                    }
                    _ => k.odometry = None,
                }
            }
        }
        self.keyframes.remove(&id);
        self.culled.insert(
            id,
            Culled {
                parent,
                parent_from_this,
            },
        );
        true
    }

    /// The live keyframe a keyframe's pose is kept relative to, and `live_from_this`: the
    /// keyframe itself (identity) while it lives, its chain of parents once culled.
    pub fn live_ancestor(&self, id: KeyframeId) -> Option<(KeyframeId, Isometry3<f64>)> {
        let mut id = id;
        let mut from_this = Isometry3::identity();
        for _ in 0..=self.culled.len() {
            if self.keyframes.contains_key(&id) {
                return Some((id, from_this));
            }
            let c = self.culled.get(&id)?;
            from_this = c.parent_from_this * from_this;
            id = c.parent;
        }
        None
    }

    /// The pose of any keyframe ever inserted: a live one's, or a culled one's through its
    /// chain of parents.
    pub fn pose_of(&self, id: KeyframeId) -> Option<Isometry3<f64>> {
        let (live, live_from_this) = self.live_ancestor(id)?;
        Some(self.keyframes.get(&live)?.world_from_camera * live_from_this)
    }
}

#[cfg(test)]
#[path = "map_tests.rs"]
mod tests;
