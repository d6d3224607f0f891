//! Turning part of the map into an optimization problem and the result back into the map:
//! the local window (the newest keyframe and those sharing the most points with it, free;
//! the other keyframes that see their points, fixed) and the final optimization's span.

use crate::ba::problem::point_error;
use crate::ba::{PointEdge, PointVar, PoseEdge, PoseVar, Problem};
use crate::config::BackendConfig;
use crate::map::{KeyframeId, Map, PointId};
use nalgebra::{Matrix3, Matrix6};
use std::collections::{BTreeMap, BTreeSet};

/// A problem built from the map, with the map identifiers of its variables and edges.
pub(crate) struct MapProblem {
    pub(crate) problem: Problem,
    pub(crate) keyframes: Vec<KeyframeId>,
    pub(crate) points: Vec<PointId>,
    /// For each point edge, the point and the keyframe observing it.
    pub(crate) observations: Vec<(PointId, KeyframeId)>,
}

/// A pose-pose edge between two keyframes, in map identifiers.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct KeyframeEdge {
    pub(crate) from: KeyframeId,
    pub(crate) to: KeyframeId,
    pub(crate) from_from_to: nalgebra::Isometry3<f64>,
    pub(crate) information: Matrix6<f64>,
    /// What measured it: the final optimization caps the reach of revisit links.
    pub(crate) kind: EdgeKind,
}

/// Where a pose-pose edge comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum EdgeKind {
    /// The odometry's relative pose, or a weak keyframe's depth link to the previous one.
    Odometry,
    /// The relative pose of two covisible keyframes from the points they share (the
    /// pose-graph back end).
    Covisible,
    /// A verified loop closure: the final optimization spreads it over the whole span.
    Loop,
    /// A revisit link to a keyframe of an earlier pass (`[backend.revisit]`): the final
    /// optimization frees only the newest `final_revisit_link_keyframes` for it.
    Revisit,
}

/// The free keyframes of a local optimization around `newest`: itself and the keyframes
/// sharing the most points with it (then its odometry predecessor, so that a keyframe that
/// re-observes nothing stays tied to the map).
pub(crate) fn local_window(map: &Map, newest: KeyframeId, cfg: &BackendConfig) -> Vec<KeyframeId> {
    let Some(kf) = map.keyframe(newest) else {
        return Vec::new();
    };
    let mut window = vec![newest];
    for (k, _) in kf.covisible(1) {
        if window.len() >= cfg.window_keyframes {
            break;
        }
        window.push(k);
    }
    if let Some(prev) = kf.odometry.as_ref().map(|e| e.previous) {
        if !window.contains(&prev) && map.keyframe(prev).is_some() {
            window.push(prev);
        }
    }
    window
}

/// The keyframes the final optimization frees. Where links tie keyframes (loops, revisit
/// and depth links in `pose_edges`, the odometry of a keyframe that re-observed too
/// little), every keyframe from the oldest one linked (at most the newest
/// `final_max_keyframes`; a revisit link reaches back at most the newest
/// `final_revisit_link_keyframes`): local windows, chosen by shared points, do not optimize
/// linked keyframes together, and this spreads what the links say. Where shared points
/// alone tie them, the newest keyframe's local window, the only keyframes local
/// optimizations have not settled: freeing every keyframe there lets the depth's correlated
/// errors bend the whole trajectory, worse than the live poses on real sequences
/// (docs/slam-measured.md, "The final optimization"). Empty with fewer than two keyframes.
pub(crate) fn final_free(
    map: &Map,
    pose_edges: &[KeyframeEdge],
    cfg: &BackendConfig,
) -> Vec<KeyframeId> {
    let all: Vec<KeyframeId> = map.keyframes().keys().copied().collect();
    let Some(&last) = all.last().filter(|_| all.len() >= 2) else {
        return Vec::new();
    };
    let active_odometry = map.keyframes().values().filter_map(|kf| {
        let e = kf.odometry.as_ref()?;
        e.active.then_some(e.previous)
    });
    // A revisit link reaches back at most `final_revisit_link_keyframes`.
    let revisit_from = all
        .get(all.len().saturating_sub(cfg.final_revisit_link_keyframes))
        .copied()
        .unwrap_or(last);
    let linked_from = pose_edges
        .iter()
        .map(|e| {
            let oldest = e.from.min(e.to);
            if e.kind == EdgeKind::Revisit {
                oldest.max(revisit_from)
            } else {
                oldest
            }
        })
        .chain(active_odometry)
        .min();
    match linked_from {
        Some(from) => {
            let span = all.get(all.len().saturating_sub(cfg.final_max_keyframes)..);
            span.unwrap_or(&all)
                .iter()
                .copied()
                .filter(|&k| k >= from)
                .collect()
        }
        None => local_window(map, last, cfg),
    }
}

/// The covariance (m^2, camera frame) added to a measurement at `p_camera` so that its depth
/// standard deviation is `depth_noise_scale` times the sensor model's: the model's depth
/// term is `sigma_d^2 (p/z)(p/z)^T`, so `(k^2 - 1)` times it is added.
fn depth_inflation(p_camera: &nalgebra::Point3<f64>, cfg: &BackendConfig) -> Matrix3<f64> {
    let ray = p_camera.coords / p_camera.z.max(1e-3);
    let sd = cfg.depth_model.sigma_d(p_camera.z);
    let k2 = cfg.depth_noise_scale * cfg.depth_noise_scale;
    ray * ray.transpose() * ((k2 - 1.0).max(0.0) * sd * sd)
}

/// Builds the problem over `free` keyframes: with points (bundle adjustment) the points
/// they observe that at least two keyframes see, every observation of those points by the
/// free keyframes and by up to `max_fixed` other keyframes (most observations first, held
/// fixed); the odometry edges that are active and the `extra` pose edges between keyframes
/// of the problem. `gauge` keyframes are held fixed even when listed as free.
pub(crate) fn build(
    map: &Map,
    free: &[KeyframeId],
    gauge: &BTreeSet<KeyframeId>,
    with_points: bool,
    extra: &[KeyframeEdge],
    max_fixed: usize,
    cfg: &BackendConfig,
) -> MapProblem {
    let free_set: BTreeSet<KeyframeId> = free.iter().copied().collect();
    let mut point_set: BTreeSet<PointId> = BTreeSet::new();
    if with_points {
        for &k in free {
            if let Some(kf) = map.keyframe(k) {
                point_set.extend(
                    kf.points()
                        .filter(|p| map.point(*p).is_some_and(|mp| mp.observations.len() >= 2)),
                );
            }
        }
    }
    // Fixed keyframes: observers of the points outside the window, most observations first,
    // and the other ends of pose edges.
    let mut outside: BTreeMap<KeyframeId, usize> = BTreeMap::new();
    for p in &point_set {
        for o in map.point(*p).map_or(&[][..], |mp| &mp.observations) {
            if !free_set.contains(&o.keyframe) {
                *outside.entry(o.keyframe).or_insert(0) += 1;
            }
        }
    }
    let mut ranked: Vec<(KeyframeId, usize)> = outside.into_iter().collect();
    ranked.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut fixed: BTreeSet<KeyframeId> =
        ranked.into_iter().take(max_fixed).map(|(k, _)| k).collect();
    let mut pose_edges: Vec<KeyframeEdge> = Vec::new();
    for &k in free {
        let Some(kf) = map.keyframe(k) else {
            continue;
        };
        let Some(e) = kf.odometry.as_ref() else {
            continue;
        };
        // A keyframe that sees few of the problem's points keeps its odometry link, whether
        // or not it had few re-observations when it was made (outliers and culling remove
        // observations later), so that no free pose is left unconstrained.
        let seen = kf.points().filter(|p| point_set.contains(p)).count();
        if (e.active || seen < cfg.min_reobserved) && map.keyframe(e.previous).is_some() {
            pose_edges.push(KeyframeEdge {
                from: e.previous,
                to: k,
                from_from_to: e.previous_from_this,
                information: e.information,
                kind: EdgeKind::Odometry,
            });
        }
    }
    pose_edges.extend(
        extra
            .iter()
            .filter(|e| free_set.contains(&e.from) || free_set.contains(&e.to))
            .cloned(),
    );
    for e in &pose_edges {
        for end in [e.from, e.to] {
            if !free_set.contains(&end) && map.keyframe(end).is_some() {
                fixed.insert(end);
            }
        }
    }
    let keyframes: Vec<KeyframeId> = free_set.iter().chain(fixed.iter()).copied().collect();
    let index: BTreeMap<KeyframeId, usize> =
        keyframes.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let mut problem = Problem::default();
    for &k in &keyframes {
        if let Some(kf) = map.keyframe(k) {
            problem.poses.push(PoseVar {
                world_from_camera: kf.world_from_camera,
                fixed: !free_set.contains(&k) || gauge.contains(&k),
            });
        }
    }
    let points: Vec<PointId> = point_set.into_iter().collect();
    let model = Matrix3::identity() * cfg.model_noise_m * cfg.model_noise_m;
    let mut observations = Vec::new();
    for (j, &pid) in points.iter().enumerate() {
        let Some(mp) = map.point(pid) else { continue };
        problem.points.push(PointVar {
            p_world: mp.p_world,
        });
        for o in &mp.observations {
            let (Some(&i), Some(m)) = (
                index.get(&o.keyframe),
                map.keyframe(o.keyframe)
                    .and_then(|kf| kf.features.get(o.feature))
                    .and_then(|f| f.measurement),
            ) else {
                continue;
            };
            let Some(information) = (m.cov + model + depth_inflation(&m.p, cfg)).try_inverse()
            else {
                continue;
            };
            problem.point_edges.push(PointEdge {
                pose: i,
                point: j,
                p_camera: m.p,
                information,
            });
            observations.push((pid, o.keyframe));
        }
    }
    for e in pose_edges {
        if let (Some(&from), Some(&to)) = (index.get(&e.from), index.get(&e.to)) {
            problem.pose_edges.push(PoseEdge {
                from,
                to,
                from_from_to: e.from_from_to,
                information: e.information,
            });
        }
    }
    // A free pose that nothing constrains would move freely: hold it.
    let mut constrained = vec![false; problem.poses.len()];
    for e in &problem.point_edges {
        if let Some(c) = constrained.get_mut(e.pose) {
            *c = true;
        }
    }
    for e in &problem.pose_edges {
        for end in [e.from, e.to] {
            if let Some(c) = constrained.get_mut(end) {
                *c = true;
            }
        }
    }
    for (v, c) in problem.poses.iter_mut().zip(constrained) {
        v.fixed |= !c;
    }
    MapProblem {
        problem,
        keyframes,
        points,
        observations,
    }
}

impl MapProblem {
    /// Writes the optimized free poses and the points back into the map.
    pub(crate) fn write_back(&self, map: &mut Map) {
        for (k, v) in self.keyframes.iter().zip(&self.problem.poses) {
            if !v.fixed {
                map.set_pose(*k, v.world_from_camera);
            }
        }
        for (p, v) in self.points.iter().zip(&self.problem.points) {
            map.set_position(*p, v.p_world);
        }
    }

    /// Observations whose squared Mahalanobis distance exceeds `chi2` at the current
    /// estimate.
    pub(crate) fn outliers(&self, chi2: f64) -> Vec<(PointId, KeyframeId)> {
        let p = &self.problem;
        p.point_edges
            .iter()
            .zip(&self.observations)
            .filter(|(e, _)| {
                let (Some(pose), Some(pt)) = (p.poses.get(e.pose), p.points.get(e.point)) else {
                    return false;
                };
                let r = point_error(&pose.world_from_camera, &pt.p_world, &e.p_camera);
                let d = r.dot(&(e.information * r));
                d.is_nan() || d > chi2
            })
            .map(|(_, o)| *o)
            .collect()
    }
}
