//! The pieces of a run whose placement relative to one another rests only on a guess, as a
//! union-find over frames and keyframes. A lost frame (its pose predicted) starts a piece,
//! and so does a relocalized one (placed against the keyframe it was found against, not the
//! frames before it). Two pieces join when a frame of one is recovered or relocalized
//! against a keyframe of the other, or when something ties two of their keyframes (a loop,
//! shared points). Piece 0 holds the world's origin: the first frame's, or, in a saved map,
//! the map's keyframes (numbered before the run's own).
//!
//! The same bookkeeping serves the live status of each frame (`Slam`, as the back end's
//! loops arrive) and the final accounting of a run (`RunOutput`, with the final map's
//! shared points too).

use crate::pipeline::FrameStatus;
use std::collections::HashMap;

/// Union-find over the pieces of a run (see the module documentation).
#[derive(Debug, Clone)]
pub(crate) struct Pieces {
    /// Each piece's parent; a root is its own.
    parent: Vec<usize>,
    /// The piece each keyframe of the run was made in.
    of_keyframe: HashMap<u64, usize>,
    /// The run's first keyframe: identifiers below it are a saved map's (piece 0).
    first_own: Option<u64>,
}

impl Pieces {
    /// No frame yet: piece 0 only.
    pub(crate) fn new() -> Self {
        Self {
            parent: vec![0],
            of_keyframe: HashMap::new(),
            first_own: None,
        }
    }

    /// Records the next frame: its status, the keyframe a recovered or relocalized frame
    /// was matched against, and its own keyframe identifier when it became one. Returns
    /// the piece it was made in (see [`Pieces::root`] for the piece it is in now).
    pub(crate) fn frame(
        &mut self,
        status: FrameStatus,
        matched: Option<u64>,
        keyframe: Option<u64>,
    ) -> usize {
        if matches!(status, FrameStatus::Lost | FrameStatus::Relocalized) {
            self.parent.push(self.parent.len());
        }
        let current = self.parent.len() - 1;
        if let Some(k) = keyframe {
            self.first_own.get_or_insert(k);
        }
        if let Some(s) = matched.and_then(|k| self.piece_of(k)) {
            self.join(current, s);
        }
        if let Some(k) = keyframe {
            self.of_keyframe.insert(k, current);
        }
        current
    }

    /// Ties the pieces of keyframes `a` and `b` (a loop between them, or shared points);
    /// nothing when either is unknown.
    pub(crate) fn tie(&mut self, a: u64, b: u64) {
        if let (Some(a), Some(b)) = (self.piece_of(a), self.piece_of(b)) {
            self.join(a, b);
        }
    }

    /// The piece that `piece` belongs to now: the earliest of those joined to it.
    pub(crate) fn root(&self, mut piece: usize) -> usize {
        while let Some(&p) = self.parent.get(piece).filter(|&&p| p != piece) {
            piece = p;
        }
        piece
    }

    /// The piece keyframe `k` is in now: the one it was made in, or 0 for a keyframe
    /// numbered before the run's own (a saved map's); `None` for an unknown one.
    pub(crate) fn keyframe_piece(&self, k: u64) -> Option<usize> {
        self.piece_of(k).map(|p| self.root(p))
    }

    fn piece_of(&self, k: u64) -> Option<usize> {
        self.of_keyframe
            .get(&k)
            .copied()
            .or_else(|| self.first_own.filter(|&f| k < f).map(|_| 0))
    }

    fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.root(a), self.root(b));
        if let Some(p) = self.parent.get_mut(ra.max(rb)) {
            *p = ra.min(rb);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run in a saved map (keyframes 0-9) that starts by a guess, is lost once, and is
    /// joined back piece by piece.
    #[test]
    fn pieces_start_at_guesses_and_join_by_matches_and_ties() {
        let mut p = Pieces::new();
        let start = p.frame(FrameStatus::Lost, None, Some(10));
        p.frame(FrameStatus::Tracked, None, None);
        assert_ne!(p.root(start), 0, "a guessed start is apart from the map");
        let lost = p.frame(FrameStatus::Lost, None, Some(11));
        assert_ne!(p.root(lost), p.root(start));
        // Recovered against the start's keyframe: the lost piece joins the start's.
        let rec = p.frame(FrameStatus::Recovered, Some(10), None);
        assert_eq!(p.root(rec), p.root(start));
        // Relocalized against a saved keyframe: a new piece, in the map at once.
        let reloc = p.frame(FrameStatus::Relocalized, Some(3), Some(12));
        assert_eq!(p.root(reloc), 0);
        assert_ne!(p.root(start), 0, "the frames before it are not tied to it");
        // A loop between the start's keyframe and a saved one joins the rest.
        p.tie(11, 5);
        assert_eq!((p.root(start), p.root(lost)), (0, 0));
        assert_eq!(p.keyframe_piece(4), Some(0), "a saved keyframe");
        assert_eq!(p.keyframe_piece(99), None, "unknown");
    }
}
