//! `stride bench place`: place recognition by bags of words on a real sequence: recall
//! against exhaustive descriptor matching, and the query time on a database of 1,000
//! keyframes against exhaustive matching over the same keyframes.

use super::median;
use anyhow::{bail, Result};
use clap::Args;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;
use stride_datasets::tum::{AssociationOptions, TumSequence};
use stride_frontend::features::{gray_mat, match_descriptors, OrbDescriptor};
use stride_frontend::orb::{PlaceExtractor, MAX_HAMMING, RATIO};
use stride_frontend::place::{BowVector, PlaceDatabase, Vocabulary};
use stride_frontend::VoConfig;

#[derive(Debug, Args)]
pub struct PlaceBenchArgs {
    /// Sequence folder (TUM layout).
    #[arg(long)]
    dataset: PathBuf,
    /// Keyframes in the speed database (the sequence's images in turn, each a keyframe).
    #[arg(long, default_value_t = 1000)]
    keyframes: usize,
    /// Candidates a query returns (recall is counted within them).
    #[arg(long, default_value_t = 5)]
    top: usize,
    /// Images closer in time than this (s) to the query are not candidates, so that recall
    /// is about places seen from elsewhere, not the previous frame.
    #[arg(long, default_value_t = 1.0)]
    exclude_s: f64,
    /// Exhaustive matching's best image counts as a true place when it has at least this
    /// many matches.
    #[arg(long, default_value_t = 30)]
    min_matches: usize,
    /// A vocabulary file (`stride vocab`) instead of the shipped one.
    #[arg(long)]
    vocabulary: Option<PathBuf>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

pub fn bench_place(a: PlaceBenchArgs) -> Result<()> {
    let seq = TumSequence::open(&a.dataset, None, AssociationOptions::default())?;
    if seq.len() < 2 || a.keyframes == 0 || a.top == 0 {
        bail!("need a sequence of at least 2 frames, --keyframes and --top above 0");
    }
    let vocabulary = match &a.vocabulary {
        Some(path) => Vocabulary::from_bytes(&std::fs::read(path)?)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?,
        None => Vocabulary::embedded()?,
    };
    // Each image described as keyframes are (their place features), which is what
    // relocalization and loop closure look up.
    let vo = VoConfig::default();
    let mut extractor = PlaceExtractor::new()?;
    let camera = seq.camera.camera;
    let pb = crate::cli::progress_bar(seq.len(), "describing", !a.json);
    let (mut times, mut descriptors, mut bows, mut transform_ms) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for i in 0..seq.len() {
        let frame = seq.load_frame(i)?;
        let gray = gray_mat(&frame.rgb.to_gray())?;
        let d: Vec<OrbDescriptor> = extractor.descriptors(&gray, &frame.depth_m, &camera, &vo)?;
        let t = Instant::now();
        bows.push(vocabulary.transform(&d));
        transform_ms.push(t.elapsed().as_secs_f64() * 1e3);
        descriptors.push(d);
        times.push(frame.t_s);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let n = seq.len();

    // Recall against exhaustive matching, every image a query against the images at
    // least `exclude_s` away in time.
    let mut db = PlaceDatabase::new();
    for (i, b) in bows.iter().enumerate() {
        db.add(i as u64, b.clone());
    }
    let (mut queries, mut hit1, mut hitk, mut verified, mut exhaustive_ms) =
        (0usize, 0usize, 0usize, 0usize, vec![]);
    let mut chance = 0.0;
    let pb = crate::cli::progress_bar(n, "recall", !a.json);
    for q in 0..n {
        let far = |j: usize| (times[j] - times[q]).abs() >= a.exclude_s;
        let t = Instant::now();
        let matches: Vec<usize> = (0..n)
            .map(|j| match far(j) {
                true => {
                    match_descriptors(&descriptors[q], &descriptors[j], MAX_HAMMING, RATIO).len()
                }
                false => 0,
            })
            .collect();
        let best = (0..n)
            .filter(|&j| far(j))
            .map(|j| (matches[j], j))
            .max_by(|x, y| x.0.cmp(&y.0).then(y.1.cmp(&x.1)));
        exhaustive_ms.push(t.elapsed().as_secs_f64() * 1e3);
        pb.inc(1);
        let Some((most, best)) = best.filter(|b| b.0 >= a.min_matches) else {
            continue;
        };
        let found = db.query(&bows[q], a.top, |id| far(id as usize));
        queries += 1;
        hit1 += usize::from(found.first().is_some_and(|m| m.id as usize == best));
        hitk += usize::from(found.iter().any(|m| m.id as usize == best));
        verified += usize::from(
            found
                .iter()
                .any(|m| matches[m.id as usize] >= a.min_matches),
        );
        let (good, all) = (0..n).filter(|&j| far(j)).fold((0.0, 0.0), |(g, t), j| {
            (
                g + f64::from(u8::from(matches[j] >= a.min_matches)),
                t + 1.0,
            )
        });
        chance += 1.0 - (1.0 - good / all).powi(a.top as i32);
        tracing::debug!("query {q}: exhaustive best {best} ({most} matches), bow {found:?}");
    }
    pb.finish_and_clear();
    if queries == 0 {
        bail!(
            "no image has a place {} s away with {} matches",
            a.exclude_s,
            a.min_matches
        );
    }

    // Speed on `keyframes` keyframes: the images in turn.
    let mut big = PlaceDatabase::new();
    for k in 0..a.keyframes {
        big.add(k as u64, bows[k % n].clone());
    }
    let mut query_ms = Vec::with_capacity(n);
    for b in &bows {
        let t = Instant::now();
        let found = big.query(b, a.top, |_| true);
        query_ms.push(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(found);
    }
    let per_image_ms = median(exhaustive_ms) / (n as f64 - 1.0);
    let exhaustive_big_ms = per_image_ms * a.keyframes as f64;
    let (tm, qm) = (median(transform_ms), median(query_ms));
    let words: Vec<f64> = bows.iter().map(|b: &BowVector| b.len() as f64).collect();
    let r = json!({
        "dataset": a.dataset.display().to_string(),
        "images": n,
        "vocabulary_words": vocabulary.word_count(),
        "descriptors_per_image_median": median(descriptors.iter().map(|d| d.len() as f64).collect()),
        "words_per_image_median": median(words),
        "recall": {
            "queries": queries,
            "exclude_s": a.exclude_s,
            "min_matches": a.min_matches,
            "top": a.top,
            "at_1": hit1 as f64 / queries as f64,
            "at_top": hitk as f64 / queries as f64,
            "verifiable_at_top": verified as f64 / queries as f64,
            "verifiable_at_top_by_chance": chance / queries as f64,
        },
        "speed": {
            "keyframes": a.keyframes,
            "transform_ms_median": tm,
            "query_ms_median": qm,
            "place_recognition_ms_median": tm + qm,
            "exhaustive_ms_per_keyframe_median": per_image_ms,
            "exhaustive_ms_estimated": exhaustive_big_ms,
            "speedup": exhaustive_big_ms / (tm + qm),
        },
    });
    if a.json {
        crate::outln!("{r}")?;
    } else {
        crate::outln!(
            "{} images, {} words: exhaustive best found at 1 {:.2}, in the top {} {:.2}; a candidate with >= {} matches in the top {} {:.2} (by chance {:.2}; {} queries with such a place >= {} s away)",
            n, vocabulary.word_count(), hit1 as f64 / queries as f64, a.top, hitk as f64 / queries as f64,
            a.min_matches, a.top, verified as f64 / queries as f64, chance / queries as f64, queries, a.exclude_s
        )?;
        crate::outln!(
            "{} keyframes: transform {:.3} ms + query {:.3} ms (medians); exhaustive matching {:.3} ms per keyframe, {:.0} ms for all ({:.0}x)",
            a.keyframes, tm, qm, per_image_ms, exhaustive_big_ms, exhaustive_big_ms / (tm + qm)
        )?;
    }
    Ok(())
}
