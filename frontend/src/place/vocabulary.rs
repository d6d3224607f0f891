//! A vocabulary of binary words: a tree of ORB descriptors (Galvez-Lopez and Tardos's
//! DBoW2 idea) that quantises a descriptor into a word by descending to the nearest child
//! at each level, and weighs each word by its inverse document frequency.
//!
//! Invariants of a [`Vocabulary`] (checked when one is read from bytes):
//! - node 0 is the root; a node's children are contiguous (`first_child ..
//!   first_child + children`) and come after it, so descending always ends;
//! - a node without children is a leaf and carries a word; inner nodes carry none;
//! - words are numbered `0 .. word_count()` and each has a finite, non-negative idf.

use super::{BowVector, PlaceError};
use crate::features::{hamming, OrbDescriptor};
use std::collections::BTreeMap;
use stride_core::rng::SplitMix64;

/// First bytes of a vocabulary file.
const MAGIC: &[u8; 8] = b"STRDVOC\0";
/// Version of the file format this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// Marks an inner node's word.
const NO_WORD: u32 = u32::MAX;
/// Bytes per node in the file: descriptor, first child, child count, word.
const NODE_BYTES: usize = 32 + 4 + 4 + 4;
/// Rounds of k-majority per node at most (assignments usually settle in fewer).
const MAX_ROUNDS: usize = 10;

/// One node of the tree.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Node {
    /// The cluster's centre (the bitwise majority of its members).
    descriptor: OrbDescriptor,
    /// Index of the first child in `nodes`.
    first_child: u32,
    /// Number of children (0 for a leaf).
    children: u32,
    /// The leaf's word, [`NO_WORD`] for an inner node.
    word: u32,
}

/// A tree of binary words with their idf weights (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct Vocabulary {
    branching: u32,
    depth: u32,
    nodes: Vec<Node>,
    idf: Vec<f32>,
}

impl Vocabulary {
    /// Trains a vocabulary on the descriptors of a set of images (one `Vec` per image):
    /// hierarchical k-majority clustering, `branching` children per node (k-means++
    /// seeding from `seed`), `depth` levels below the root; a cluster with no more
    /// members than `branching` gives each distinct member its own leaf. Each word's idf
    /// is `ln(images / images containing the word)`. Deterministic for a given input.
    pub fn train(
        images: &[Vec<OrbDescriptor>],
        branching: u32,
        depth: u32,
        seed: u64,
    ) -> Result<Self, PlaceError> {
        if !(2..=64).contains(&branching) || !(1..=8).contains(&depth) {
            return Err(PlaceError::Training(format!(
                "branching {branching} must be in 2..=64 and depth {depth} in 1..=8"
            )));
        }
        let all: Vec<OrbDescriptor> = images.iter().flatten().copied().collect();
        if all.len() < branching as usize {
            return Err(PlaceError::Training(format!(
                "{} descriptors are fewer than the branching factor {branching}",
                all.len()
            )));
        }
        let mut rng = SplitMix64::new(seed);
        let root = Node {
            descriptor: [0; 32],
            first_child: 0,
            children: 0,
            word: NO_WORD,
        };
        let mut nodes = vec![root];
        // Breadth first: (node, its members, its level).
        let mut queue = std::collections::VecDeque::from([(0usize, all, 0u32)]);
        while let Some((node, members, level)) = queue.pop_front() {
            if level == depth || members.len() <= 1 {
                continue;
            }
            let clusters = if members.len() <= branching as usize {
                distinct(&members)
            } else {
                k_majority(&members, branching as usize, &mut rng)
            };
            if clusters.len() <= 1 && level > 0 {
                continue;
            }
            let first = nodes.len();
            for (centre, m) in clusters {
                nodes.push(Node {
                    descriptor: centre,
                    first_child: 0,
                    children: 0,
                    word: NO_WORD,
                });
                queue.push_back((nodes.len() - 1, m, level + 1));
            }
            let children = (nodes.len() - first) as u32;
            if let Some(n) = nodes.get_mut(node) {
                n.first_child = first as u32;
                n.children = children;
            }
        }
        let mut words = 0u32;
        for n in nodes.iter_mut().skip(1).filter(|n| n.children == 0) {
            n.word = words;
            words += 1;
        }
        let mut vocabulary = Self {
            branching,
            depth,
            nodes,
            idf: vec![0.0; words as usize],
        };
        let mut containing = vec![0u32; words as usize];
        for image in images {
            let mut seen: Vec<u32> = image.iter().map(|d| vocabulary.word(d)).collect();
            seen.sort_unstable();
            seen.dedup();
            for w in seen {
                if let Some(c) = containing.get_mut(w as usize) {
                    *c += 1;
                }
            }
        }
        let n_images = images.len().max(1) as f64;
        for (idf, &c) in vocabulary.idf.iter_mut().zip(&containing) {
            *idf = (n_images / f64::from(c.max(1))).ln() as f32;
        }
        Ok(vocabulary)
    }

    /// Children per node as trained.
    pub fn branching(&self) -> u32 {
        self.branching
    }

    /// Levels below the root as trained.
    pub fn depth(&self) -> u32 {
        self.depth
    }

    /// Number of words (leaves).
    pub fn word_count(&self) -> usize {
        self.idf.len()
    }

    /// The word of a descriptor: the leaf reached by descending to the nearest child (by
    /// Hamming distance, the first on a tie) from the root.
    pub fn word(&self, d: &OrbDescriptor) -> u32 {
        let mut node = self.nodes.first();
        while let Some(n) = node.filter(|n| n.children > 0) {
            let first = n.first_child as usize;
            let children = self.nodes.get(first..first + n.children as usize);
            node = children.and_then(|c| c.iter().min_by_key(|c| hamming(&c.descriptor, d)));
        }
        node.map_or(0, |n| n.word)
    }

    /// The image's bag of words: term frequency times idf per word, normalised to a unit
    /// L1 norm (empty when no word has weight).
    pub fn transform(&self, descriptors: &[OrbDescriptor]) -> BowVector {
        let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
        for d in descriptors {
            *counts.entry(self.word(d)).or_default() += 1;
        }
        let weights: Vec<(u32, f32)> = counts
            .into_iter()
            .map(|(w, c)| {
                (
                    w,
                    c as f32 * self.idf.get(w as usize).copied().unwrap_or(0.0),
                )
            })
            .filter(|&(_, v)| v > 0.0)
            .collect();
        let total: f32 = weights.iter().map(|w| w.1).sum();
        BowVector::from_sorted(weights.into_iter().map(|(w, v)| (w, v / total)).collect())
    }

    /// The vocabulary in its file format (see [`Vocabulary::from_bytes`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(32 + self.nodes.len() * NODE_BYTES + 4 * self.idf.len());
        out.extend_from_slice(MAGIC);
        for v in [
            FORMAT_VERSION,
            self.branching,
            self.depth,
            self.nodes.len() as u32,
            self.idf.len() as u32,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for n in &self.nodes {
            out.extend_from_slice(&n.descriptor);
            for v in [n.first_child, n.children, n.word] {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        for idf in &self.idf {
            out.extend_from_slice(&idf.to_le_bytes());
        }
        let sum = fnv1a64(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Reads a vocabulary file: the magic `STRDVOC\0`, then little-endian u32 format
    /// version, branching, depth, node count and word count; each node's 32-byte
    /// descriptor, first child, child count and word (`u32::MAX` for inner nodes); each
    /// word's idf (f32); an FNV-1a 64 checksum of everything before it. Every invariant of
    /// the module documentation is checked; a violation is a [`PlaceError::Format`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, PlaceError> {
        let bad = |what: String| PlaceError::Format(what);
        let body_len = bytes
            .len()
            .checked_sub(8)
            .ok_or_else(|| bad("shorter than its checksum".into()))?;
        let (body, sum) = bytes.split_at(body_len);
        if body.get(..8) != Some(MAGIC.as_slice()) {
            return Err(bad("not a stride vocabulary (wrong magic bytes)".into()));
        }
        let mut r = Reader { bytes: body, at: 8 };
        let version = r.u32()?;
        if version != FORMAT_VERSION {
            return Err(bad(format!(
                "format version {version}, this build reads {FORMAT_VERSION}"
            )));
        }
        let expected = u64::from_le_bytes(sum.try_into().map_err(|_| bad("checksum".into()))?);
        if fnv1a64(body) != expected {
            return Err(bad("checksum mismatch (the file is corrupt)".into()));
        }
        let (branching, depth, n_nodes, n_words) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        let need = 28 + n_nodes as usize * NODE_BYTES + 4 * n_words as usize;
        if body.len() != need {
            return Err(bad(format!(
                "{} bytes where {n_nodes} nodes and {n_words} words need {need}",
                body.len()
            )));
        }
        let mut nodes = Vec::with_capacity(n_nodes as usize);
        for _ in 0..n_nodes {
            let descriptor = r.descriptor()?;
            let (first_child, children, word) = (r.u32()?, r.u32()?, r.u32()?);
            nodes.push(Node {
                descriptor,
                first_child,
                children,
                word,
            });
        }
        let idf = (0..n_words)
            .map(|_| r.f32())
            .collect::<Result<Vec<_>, _>>()?;
        let vocabulary = Self {
            branching,
            depth,
            nodes,
            idf,
        };
        vocabulary.check().map_err(bad)?;
        Ok(vocabulary)
    }

    /// The invariants of the module documentation.
    fn check(&self) -> Result<(), String> {
        if self.nodes.is_empty() {
            return Err("no root node".into());
        }
        let mut words_seen = vec![false; self.idf.len()];
        for (i, n) in self.nodes.iter().enumerate() {
            let end = n.first_child as usize + n.children as usize;
            if n.children > 0 && (n.first_child as usize <= i || end > self.nodes.len()) {
                return Err(format!("node {i}'s children are out of order or range"));
            }
            match (n.children, n.word) {
                (0, w) if i > 0 => match words_seen.get_mut(w as usize) {
                    Some(seen) if !*seen => *seen = true,
                    _ => return Err(format!("leaf {i} has word {w}, out of range or repeated")),
                },
                (c, w) if c > 0 && w != NO_WORD => {
                    return Err(format!("inner node {i} carries word {w}"))
                }
                _ => {}
            }
        }
        if let Some(w) = words_seen.iter().position(|s| !s) {
            return Err(format!("word {w} belongs to no leaf"));
        }
        if let Some(w) = self.idf.iter().position(|v| !v.is_finite() || *v < 0.0) {
            return Err(format!(
                "word {w}'s idf is not a finite non-negative number"
            ));
        }
        Ok(())
    }
}

/// The distinct descriptors among `members`, each its own cluster.
fn distinct(members: &[OrbDescriptor]) -> Vec<(OrbDescriptor, Vec<OrbDescriptor>)> {
    let mut sorted = members.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    sorted.into_iter().map(|d| (d, vec![d])).collect()
}

/// k-majority clustering of `members` (more than `k` of them): k-means++ seeds, then rounds
/// of assignment to the nearest centre and bitwise-majority centres until the assignment
/// settles or [`MAX_ROUNDS`] pass. Empty clusters are dropped.
fn k_majority(
    members: &[OrbDescriptor],
    k: usize,
    rng: &mut SplitMix64,
) -> Vec<(OrbDescriptor, Vec<OrbDescriptor>)> {
    let mut centres: Vec<OrbDescriptor> = Vec::with_capacity(k);
    if let Some(first) = members.get(rng.below(members.len())) {
        centres.push(*first);
    }
    let mut nearest: Vec<u32> = members
        .iter()
        .map(|d| centres.first().map_or(256, |c| hamming(c, d)))
        .collect();
    while centres.len() < k {
        // The next seed with probability proportional to the squared distance.
        let total: f64 = nearest.iter().map(|&d| f64::from(d * d)).sum();
        if total <= 0.0 {
            break;
        }
        let mut target = rng.uniform() * total;
        let mut pick = members.len() - 1;
        for (i, &d) in nearest.iter().enumerate() {
            target -= f64::from(d * d);
            if target <= 0.0 {
                pick = i;
                break;
            }
        }
        let Some(c) = members.get(pick).copied() else {
            break;
        };
        for (n, d) in nearest.iter_mut().zip(members) {
            *n = (*n).min(hamming(&c, d));
        }
        centres.push(c);
    }
    let mut assignment = vec![usize::MAX; members.len()];
    for _ in 0..MAX_ROUNDS {
        let mut changed = false;
        for (a, d) in assignment.iter_mut().zip(members) {
            let best = (0..centres.len())
                .min_by_key(|&c| centres.get(c).map_or(u32::MAX, |c| hamming(c, d)))
                .unwrap_or(0);
            changed |= *a != best;
            *a = best;
        }
        if !changed {
            break;
        }
        // One pass: each member's bits counted into its cluster.
        let mut ones = vec![[0u32; 256]; centres.len()];
        let mut sizes = vec![0u32; centres.len()];
        for (&a, d) in assignment.iter().zip(members) {
            if let (Some(counts), Some(n)) = (ones.get_mut(a), sizes.get_mut(a)) {
                *n += 1;
                for (bit, count) in counts.iter_mut().enumerate() {
                    *count += u32::from(d.get(bit / 8).is_some_and(|b| b >> (bit % 8) & 1 == 1));
                }
            }
        }
        for ((centre, counts), &n) in centres.iter_mut().zip(&ones).zip(&sizes) {
            if n == 0 {
                continue;
            }
            let mut majority = [0u8; 32];
            for (bit, &count) in counts.iter().enumerate() {
                if 2 * count > n {
                    if let Some(b) = majority.get_mut(bit / 8) {
                        *b |= 1 << (bit % 8);
                    }
                }
            }
            *centre = majority;
        }
    }
    let mut clusters: Vec<(OrbDescriptor, Vec<OrbDescriptor>)> =
        centres.iter().map(|c| (*c, Vec::new())).collect();
    for (&a, d) in assignment.iter().zip(members) {
        if let Some((_, m)) = clusters.get_mut(a) {
            m.push(*d);
        }
    }
    clusters.retain(|(_, m)| !m.is_empty());
    clusters
}

/// FNV-1a, 64 bits: the file's checksum.
fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Little-endian reads from a byte slice, each failing with a format error at its end.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], PlaceError> {
        let s = self
            .bytes
            .get(self.at..self.at + N)
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or_else(|| PlaceError::Format(format!("truncated at byte {}", self.at)))?;
        self.at += N;
        Ok(s)
    }

    fn u32(&mut self) -> Result<u32, PlaceError> {
        self.take::<4>().map(u32::from_le_bytes)
    }

    fn f32(&mut self) -> Result<f32, PlaceError> {
        self.take::<4>().map(f32::from_le_bytes)
    }

    fn descriptor(&mut self) -> Result<OrbDescriptor, PlaceError> {
        self.take::<32>()
    }
}
