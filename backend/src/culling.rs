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
    /// The newest is one of them when it adds nothing. Returns how many were removed.
    pub(crate) fn cull_keyframes(&mut self, window: &[KeyframeId]) -> usize {
        let mut removed = 0;
        for &k in window {
            if Some(k) == self.first {
                continue;
            }
            let fraction = self.redundancy(k);
            if fraction >= self.config.redundant_fraction && self.cull_into_neighbour(k) {
                removed += 1;
            }
        }
        removed
    }

    /// Culls the keyframe that has just settled (`window_keyframes + point_grace_keyframes`
    /// before `newest`: the local optimizations are done with it and its new points have had
    /// their grace) when it stands where an older keyframe of the same piece already stands:
    /// one at least `revisit.min_keyframe_gap` keyframes older (an earlier pass), within
    /// `revisit_cull_radius_m` and `revisit_cull_angle_deg` of it. Its pose is kept relative
    /// to that keyframe, as the local optimizations left the two (tied by the old points it
    /// re-observed), and its frames follow; so passing the same place again does not grow
    /// the map. Kept relative to its neighbour in time instead, a later pass's keyframes
    /// culled one after another would hang in a chain from the last one kept, and every
    /// correction of that one would swing the whole chain (docs/slam-gaps.md, "Revisits keep the
    /// map flat"). Returns how many were removed (0 or 1). Bundle-adjustment mode only: the
    /// pose graph, whose edges join covisible keyframes, lost accuracy without the later
    /// passes' keyframes.
    pub(crate) fn cull_revisit(&mut self, newest: KeyframeId) -> usize {
        let cfg = &self.config;
        if cfg.mode == crate::config::BackendMode::PoseGraph {
            return 0;
        }
        let settled = cfg.window_keyframes as u64 + cfg.point_grace_keyframes;
        let Some(k) = newest.checked_sub(settled) else {
            return 0;
        };
        if cfg.revisit_cull_radius_m <= 0.0 || Some(k) == self.first {
            return 0;
        }
        let gap = cfg.revisit.min_keyframe_gap;
        // Not across the start of a piece placed by a guess: the two may still be moved
        // apart when the pieces join.
        let starts = &self.piece_starts;
        let older = self.map.nearby(
            k,
            cfg.revisit_cull_radius_m,
            cfg.revisit_cull_angle_deg,
            1,
            |o| o.id.saturating_add(gap) < k && starts.range(o.id + 1..=k).next().is_none(),
        );
        older
            .first()
            .map_or(0, |&o| usize::from(self.remove_keyframe(k, o)))
    }

    /// Keeps the map within `max_keyframes`: culls the most redundant keyframes older than
    /// the final optimization's span (the oldest first among equally redundant ones) until
    /// it fits. The final optimization would hold them fixed anyway, so each keeps its pose
    /// as it is (it is culled into the first keyframe, the gauge, which never moves).
    /// Returns how many were removed.
    pub(crate) fn cull_to_budget(&mut self) -> usize {
        let keyframes = self.map.keyframes();
        let excess = keyframes.len().saturating_sub(self.config.max_keyframes);
        let Some(first) = self.first.filter(|_| excess > 0) else {
            return 0;
        };
        let settled = keyframes
            .len()
            .saturating_sub(self.config.final_max_keyframes);
        let mut ranked: Vec<(f64, KeyframeId)> = keyframes
            .keys()
            .take(settled)
            .filter(|&&k| k != first)
            .map(|&k| (self.redundancy(k), k))
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut removed = 0;
        for (_, k) in ranked.into_iter().take(excess) {
            if self.remove_keyframe(k, first) {
                removed += 1;
            }
        }
        removed
    }

    /// The fraction of keyframe `k`'s points that `redundant_observers` other keyframes
    /// see (0 for a keyframe without points, or unknown).
    fn redundancy(&self, k: KeyframeId) -> f64 {
        let Some(kf) = self.map.keyframe(k) else {
            return 0.0;
        };
        let (mut total, mut redundant) = (0usize, 0usize);
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
        if total == 0 {
            0.0
        } else {
            redundant as f64 / total as f64
        }
    }

    /// Culls keyframe `k`, keeping its pose relative to its neighbour in time, not to the
    /// keyframe sharing the most points (which may come from another pass over the place,
    /// with drift of its own that later corrections move differently): the previous one,
    /// or the next when a piece of the map placed by a guess starts between the previous
    /// one and `k` (a pose kept relative to the other piece would miss the piece's
    /// correction when the two join). False when it has no such neighbour or could not be
    /// culled.
    fn cull_into_neighbour(&mut self, k: KeyframeId) -> bool {
        let starts_between =
            |a: KeyframeId, b: KeyframeId| self.piece_starts.range(a + 1..=b).next().is_some();
        let keyframes = self.map.keyframes();
        let previous = keyframes
            .range(..k)
            .next_back()
            .map(|(&p, _)| p)
            .filter(|&p| !starts_between(p, k));
        let next = || {
            keyframes
                .range(k + 1..)
                .next()
                .map(|(&n, _)| n)
                .filter(|&n| !starts_between(k, n))
        };
        let Some(parent) = previous.or_else(next) else {
            return false;
        };
        self.remove_keyframe(k, parent)
    }

    /// Culls keyframe `k` from the map (its frames kept relative to `parent`), with its pose
    /// edges and its entry in the place database. False when the map refused.
    fn remove_keyframe(&mut self, k: KeyframeId, parent: KeyframeId) -> bool {
        if !self.map.cull_keyframe(k, parent) {
            return false;
        }
        self.pose_edges.retain(|e| e.from != k && e.to != k);
        self.places.forget(k);
        self.revisits.remove(k);
        true
    }
}

#[cfg(test)]
#[path = "culling_tests.rs"]
mod tests;
