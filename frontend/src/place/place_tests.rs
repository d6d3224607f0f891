#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;
use crate::features::OrbDescriptor;
use stride_core::rng::SplitMix64;

/// `n` descriptors near each of `centres` (each bit flipped with probability 0.05).
fn blobs(centres: &[OrbDescriptor], n: usize, rng: &mut SplitMix64) -> Vec<OrbDescriptor> {
    let mut out = Vec::new();
    for c in centres {
        for _ in 0..n {
            let mut d = *c;
            for byte in d.iter_mut() {
                for bit in 0..8 {
                    if rng.uniform() < 0.05 {
                        *byte ^= 1 << bit;
                    }
                }
            }
            out.push(d);
        }
    }
    out
}

fn random_descriptor(rng: &mut SplitMix64) -> OrbDescriptor {
    let mut d = [0u8; 32];
    for b in d.iter_mut() {
        *b = (rng.next_u64() & 0xff) as u8;
    }
    d
}

/// Images of 20 "places", each showing 30 of 600 clustered patterns.
fn places(rng: &mut SplitMix64) -> (Vec<OrbDescriptor>, Vec<Vec<OrbDescriptor>>) {
    let patterns: Vec<OrbDescriptor> = (0..600).map(|_| random_descriptor(rng)).collect();
    let images = (0..20)
        .map(|p| blobs(&patterns[p * 30..(p + 1) * 30], 3, rng))
        .collect();
    (patterns, images)
}

fn trained() -> (Vocabulary, Vec<OrbDescriptor>, Vec<Vec<OrbDescriptor>>) {
    let mut rng = SplitMix64::new(7);
    let (patterns, images) = places(&mut rng);
    let v = Vocabulary::train(&images, 8, 4, 3).unwrap();
    (v, patterns, images)
}

#[test]
fn noisy_copies_of_a_pattern_share_its_word_and_patterns_get_their_own() {
    // 100 patterns seen 10 times each with noise, a tree of about 100 words.
    let mut rng = SplitMix64::new(5);
    let patterns: Vec<OrbDescriptor> = (0..100).map(|_| random_descriptor(&mut rng)).collect();
    let images: Vec<Vec<OrbDescriptor>> = patterns
        .chunks(10)
        .map(|c| blobs(c, 10, &mut rng))
        .collect();
    let v = Vocabulary::train(&images, 10, 2, 3).unwrap();
    assert!(v.word_count() <= 100, "{} words", v.word_count());
    let words: Vec<u32> = patterns.iter().map(|p| v.word(p)).collect();
    let mut distinct = words.clone();
    distinct.sort_unstable();
    distinct.dedup();
    assert!(
        distinct.len() >= 70,
        "{} distinct words of 100",
        distinct.len()
    );
    let fresh = blobs(&patterns, 5, &mut rng);
    let kept = fresh
        .chunks(5)
        .zip(&words)
        .map(|(copies, &w)| copies.iter().filter(|c| v.word(c) == w).count())
        .sum::<usize>();
    assert!(
        kept >= 400,
        "{kept} of 500 fresh copies share their pattern's word"
    );
}

#[test]
fn training_is_deterministic_and_rejects_bad_parameters() {
    let mut rng = SplitMix64::new(7);
    let (_, images) = places(&mut rng);
    let a = Vocabulary::train(&images, 8, 3, 3).unwrap();
    let b = Vocabulary::train(&images, 8, 3, 3).unwrap();
    assert_eq!(a, b);
    assert!(matches!(
        Vocabulary::train(&images, 1, 3, 3),
        Err(PlaceError::Training(_))
    ));
    assert!(matches!(
        Vocabulary::train(&[vec![[0; 32]]], 8, 3, 3),
        Err(PlaceError::Training(_))
    ));
}

#[test]
fn bags_of_words_are_unit_l1_and_score_an_image_highest_against_itself() {
    let (v, _, images) = trained();
    let bows: Vec<BowVector> = images.iter().map(|i| v.transform(i)).collect();
    for b in &bows {
        let sum: f32 = b.entries().iter().map(|e| e.1).sum();
        assert!((sum - 1.0).abs() < 1e-5, "L1 norm {sum}");
        assert!(b.entries().windows(2).all(|w| w[0].0 < w[1].0));
        assert!((b.score(b) - 1.0).abs() < 1e-5);
    }
    assert!(bows[0].score(&bows[1]) < 0.2);
    assert_eq!(BowVector::default().score(&bows[0]), 0.0);
}

#[test]
fn the_database_finds_the_place_of_a_new_view_and_forgets_removed_keyframes() {
    let (v, patterns, images) = trained();
    let mut db = PlaceDatabase::new();
    for (i, img) in images.iter().enumerate() {
        db.add(i as u64, v.transform(img));
    }
    assert_eq!(db.len(), 20);
    // A new view of place 7: two thirds of its patterns, fresh noise, plus clutter.
    let mut rng = SplitMix64::new(99);
    let mut view = blobs(&patterns[7 * 30..7 * 30 + 20], 1, &mut rng);
    view.extend((0..10).map(|_| random_descriptor(&mut rng)));
    let query = v.transform(&view);
    let found = db.query(&query, 3, |_| true);
    assert_eq!(found[0].id, 7, "{found:?}");
    assert!(found[0].score > 2.0 * found.get(1).map_or(0.0, |m| m.score));
    // The filter and removal.
    assert!(db.query(&query, 3, |id| id != 7).iter().all(|m| m.id != 7));
    db.remove(7);
    assert_eq!(db.len(), 19);
    assert!(db.query(&query, 20, |_| true).iter().all(|m| m.id != 7));
    // Re-adding replaces.
    db.add(3, v.transform(&images[7]));
    assert_eq!(db.len(), 19);
    assert_eq!(db.query(&query, 1, |_| true)[0].id, 3);
}

#[test]
fn files_round_trip_and_corruption_is_a_clear_error() {
    let (v, _, _) = trained();
    let bytes = v.to_bytes();
    assert_eq!(Vocabulary::from_bytes(&bytes).unwrap(), v);
    let err = |b: &[u8]| match Vocabulary::from_bytes(b) {
        Err(PlaceError::Format(m)) => m,
        other => panic!("expected a format error, got {other:?}"),
    };
    assert!(err(&bytes[..bytes.len() - 1]).contains("checksum"));
    let mut flipped = bytes.clone();
    flipped[100] ^= 1;
    assert!(err(&flipped).contains("corrupt"));
    let mut version = bytes.clone();
    version[8] = 9;
    assert!(err(&version).contains("version 9"));
    assert!(err(b"short").contains("checksum"));
    assert!(err(b"not a vocabulary at all").contains("magic"));
}

#[test]
fn the_embedded_vocabulary_loads() {
    let v = Vocabulary::embedded().unwrap();
    assert_eq!((v.branching(), v.depth()), (6, 5));
    assert!(v.word_count() > 5_000, "{} words", v.word_count());
}
