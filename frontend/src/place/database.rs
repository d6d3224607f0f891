//! An inverted index of keyframes' bags of words.

use super::BowVector;
use std::collections::BTreeMap;

/// A keyframe found by [`PlaceDatabase::query`], with its similarity to the query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaceMatch {
    /// The keyframe's identifier, as given to [`PlaceDatabase::add`].
    pub id: u64,
    /// L1 similarity with the query, in `[0, 1]`.
    pub score: f32,
}

/// Keyframes' bags of words, indexed by word (each word lists the keyframes holding it and
/// their weights), so a query touches only keyframes that share a word with it.
#[derive(Debug, Clone, Default)]
pub struct PlaceDatabase {
    /// Per word: `(keyframe, weight)` in insertion order.
    postings: BTreeMap<u32, Vec<(u64, f32)>>,
    /// Each keyframe's vector, to remove it.
    entries: BTreeMap<u64, BowVector>,
}

impl PlaceDatabase {
    /// An empty database.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of keyframes held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// No keyframe held.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Keyframe `id`'s bag of words, when held.
    pub fn get(&self, id: u64) -> Option<&BowVector> {
        self.entries.get(&id)
    }

    /// Adds keyframe `id` (replacing an earlier vector of the same id).
    pub fn add(&mut self, id: u64, bow: BowVector) {
        self.remove(id);
        for &(w, v) in bow.entries() {
            self.postings.entry(w).or_default().push((id, v));
        }
        self.entries.insert(id, bow);
    }

    /// Removes keyframe `id` (a culled keyframe); nothing when it is not held.
    pub fn remove(&mut self, id: u64) {
        let Some(bow) = self.entries.remove(&id) else {
            return;
        };
        for &(w, _) in bow.entries() {
            if let Some(list) = self.postings.get_mut(&w) {
                list.retain(|&(k, _)| k != id);
                if list.is_empty() {
                    self.postings.remove(&w);
                }
            }
        }
    }

    /// The keyframes most similar to `bow` that `accept` lets through, at most `max`, best
    /// first (ties by identifier), each with a score above zero. Deterministic: scores are
    /// summed in word order.
    pub fn query(
        &self,
        bow: &BowVector,
        max: usize,
        accept: impl Fn(u64) -> bool,
    ) -> Vec<PlaceMatch> {
        let mut scores: BTreeMap<u64, f32> = BTreeMap::new();
        for &(w, v) in bow.entries() {
            for &(id, weight) in self.postings.get(&w).map_or(&[][..], |l| l.as_slice()) {
                *scores.entry(id).or_default() += v.min(weight);
            }
        }
        let mut ranked: Vec<PlaceMatch> = scores
            .into_iter()
            .filter(|&(id, s)| s > 0.0 && accept(id))
            .map(|(id, score)| PlaceMatch { id, score })
            .collect();
        ranked.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.id.cmp(&b.id)));
        ranked.truncate(max);
        ranked
    }
}
