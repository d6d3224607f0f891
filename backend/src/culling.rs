//! Keeping the map bounded: points seen by too few keyframes, or rarely found where they
//! should be visible, and keyframes whose points other keyframes already see.

use crate::backend::Backend;
use crate::map::{KeyframeId, PointId};

/// A point projected into this many keyframes and found in fewer than a quarter of them is
/// unreliable (ORB-SLAM's found ratio).
const MIN_VISIBLE_FOR_RATIO: u32 = 4;
const MIN_FOUND_RATIO: f64 = 0.25;

impl Backend {
    /// Removes points seen by fewer than two keyframes once `point_grace_keyframes` have
    /// passed since their creation, and points rarely found where they should be visible.
    /// Returns how many were removed.
    pub(crate) fn cull_points(&mut self, newest: KeyframeId) -> usize {
        let grace = self.config.point_grace_keyframes;
        let doomed: Vec<PointId> = self
            .map
            .points()
            .iter()
            .filter(|(_, p)| {
                let old = newest.saturating_sub(p.created_by) >= grace;
                let unreliable = p.visible >= MIN_VISIBLE_FOR_RATIO
                    && f64::from(p.found) < MIN_FOUND_RATIO * f64::from(p.visible);
                (old && p.observations.len() < 2) || unreliable
            })
            .map(|(&id, _)| id)
            .collect();
        for &p in &doomed {
            self.map.remove_point(p);
        }
        doomed.len()
    }

    /// Removes the window's redundant keyframes: those (other than the first) with at least
    /// `redundant_fraction` of their points seen by `redundant_observers` other keyframes.
    /// The newest is one of them when it adds nothing. Each keeps its pose relative to its
    /// neighbour in time (see below). Returns how many were removed.
    pub(crate) fn cull_keyframes(&mut self, window: &[KeyframeId]) -> usize {
        let mut removed = 0;
        for &k in window {
            if Some(k) == self.first {
                continue;
            }
            let Some(kf) = self.map.keyframe(k) else {
                continue;
            };
            let mut total = 0usize;
            let mut redundant = 0usize;
            for p in kf.points() {
                total += 1;
                let others = self
                    .map
                    .point(p)
                    .map_or(0, |mp| mp.observations.len().saturating_sub(1));
                if others >= self.config.redundant_observers {
                    redundant += 1;
                }
            }
            if total == 0 || (redundant as f64) < self.config.redundant_fraction * total as f64 {
                continue;
            }
            // Its pose stays relative to its neighbour in time, not to the keyframe sharing
            // the most points (which may come from another pass over the place, with drift
            // of its own that later corrections move differently).
            let Some(parent) = self
                .map
                .keyframes()
                .range(..k)
                .next_back()
                .or_else(|| self.map.keyframes().range(k + 1..).next())
                .map(|(&p, _)| p)
            else {
                continue;
            };
            if self.map.cull_keyframe(k, parent) {
                self.pose_edges.retain(|e| e.from != k && e.to != k);
                removed += 1;
            }
        }
        removed
    }
}
