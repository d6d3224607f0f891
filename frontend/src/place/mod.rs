//! Place recognition by appearance: which earlier keyframes look like this image?
//!
//! A keyframe's ORB descriptors are quantised by a [`Vocabulary`] (a tree of binary words
//! trained offline on the synthetic lab's images and shipped with the project, see
//! [`Vocabulary::embedded`]) into a [`BowVector`] (tf-idf weights, unit L1 norm). A
//! [`PlaceDatabase`] keeps the keyframes' vectors in an inverted index and ranks them
//! against a query by the L1 similarity of DBoW2 (Galvez-Lopez and Tardos 2012),
//! `1 - |a - b|_1 / 2`, which for unit-L1 non-negative vectors is the sum over shared
//! words of the smaller weight: 1 for identical images, 0 for images sharing no word.
//!
//! Why words and not a global image descriptor: they match the ORB features the map
//! already stores (no second descriptor per keyframe), they tolerate the large viewpoint
//! changes of a relocalization (local features move, words stay), and the inverted index
//! answers a query over 1,000 keyframes in well under a millisecond (`stride bench place`).
//! A candidate is only a candidate: callers verify it geometrically (RGB-D RANSAC).

mod database;
mod vocabulary;

pub use database::{PlaceDatabase, PlaceMatch};
pub use vocabulary::{Vocabulary, FORMAT_VERSION};

/// The vocabulary shipped with the project (`frontend/assets/orb_vocabulary.bin`), made by
/// `stride vocab` (see that command for how it was trained).
const EMBEDDED: &[u8] = include_bytes!("../../assets/orb_vocabulary.bin");

impl Vocabulary {
    /// The vocabulary shipped with the project, read and checked.
    pub fn embedded() -> Result<Self, PlaceError> {
        Self::from_bytes(EMBEDDED)
    }

    /// The shipped vocabulary, read once per process and shared.
    pub fn shipped() -> Result<std::sync::Arc<Self>, PlaceError> {
        static SHIPPED: std::sync::OnceLock<Result<std::sync::Arc<Vocabulary>, PlaceError>> =
            std::sync::OnceLock::new();
        SHIPPED
            .get_or_init(|| Self::embedded().map(std::sync::Arc::new))
            .clone()
    }
}

/// Why a vocabulary could not be trained or read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlaceError {
    /// The training input or parameters cannot make a vocabulary.
    #[error("cannot train a vocabulary: {0}")]
    Training(String),
    /// The bytes are not a valid vocabulary file.
    #[error("invalid vocabulary file: {0}")]
    Format(String),
}

/// An image's bag of words: `(word, weight)` pairs sorted by word, weights positive and
/// summing to 1 (or empty).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BowVector {
    entries: Vec<(u32, f32)>,
}

impl BowVector {
    /// A vector from pairs already sorted by word without repeats.
    fn from_sorted(entries: Vec<(u32, f32)>) -> Self {
        Self { entries }
    }

    /// The `(word, weight)` pairs, sorted by word.
    pub fn entries(&self) -> &[(u32, f32)] {
        &self.entries
    }

    /// Number of distinct words.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// No word at all.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The L1 similarity in `[0, 1]` (see the module documentation).
    pub fn score(&self, other: &BowVector) -> f32 {
        let (mut a, mut b) = (
            self.entries.iter().peekable(),
            other.entries.iter().peekable(),
        );
        let mut s = 0.0;
        while let (Some(&&(wa, va)), Some(&&(wb, vb))) = (a.peek(), b.peek()) {
            match wa.cmp(&wb) {
                std::cmp::Ordering::Less => {
                    a.next();
                }
                std::cmp::Ordering::Greater => {
                    b.next();
                }
                std::cmp::Ordering::Equal => {
                    s += va.min(vb);
                    a.next();
                    b.next();
                }
            }
        }
        s
    }
}

#[cfg(test)]
#[path = "place_tests.rs"]
mod tests;
