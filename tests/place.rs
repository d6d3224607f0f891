//! Place recognition on real frames: `stride bench place` on teddy_200 (the shipped
//! vocabulary was trained on the synthetic lab only); and `stride vocab` makes the same
//! vocabulary every time.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

mod common;

use common::{data, num, run_json};

#[test]
fn bags_of_words_rank_verifiable_places_above_chance() {
    let Some(teddy) = data("tum/rgbd_dataset_freiburg3_teddy_200") else {
        return;
    };
    let teddy = teddy.display().to_string();
    let r = run_json(&[
        "bench",
        "place",
        "--dataset",
        &teddy,
        "--keyframes",
        "1000",
        "--min-matches",
        "15",
        "--json",
    ]);
    let recall = &r["recall"];
    let (found, chance) = (
        num(recall, "verifiable_at_top"),
        num(recall, "verifiable_at_top_by_chance"),
    );
    // Measured: 0.66 against 0.32 by chance over 184 queries, images described by their
    // place features as keyframes are (0.45 against 0.23 over 165 by the tracking's corners).
    assert!(num(recall, "queries") >= 100.0, "{r}");
    assert!(
        found > 1.5 * chance,
        "{found} against {chance} by chance: {r}"
    );
}

#[test]
fn vocabularies_are_remade_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let make = |name: &str| {
        let out = tmp.path().join(name);
        common::run_ok(&[
            "vocab",
            "--out",
            out.to_str().unwrap(),
            "--scenes",
            "2",
            "--images-per-scene",
            "2",
            "--branching",
            "4",
            "--depth",
            "3",
            "-q",
        ]);
        std::fs::read(out).unwrap()
    };
    let (a, b) = (make("a.bin"), make("b.bin"));
    assert_eq!(a, b, "two trainings differ");
    let v = stride_frontend::place::Vocabulary::from_bytes(&a).unwrap();
    assert_eq!((v.branching(), v.depth()), (4, 3));
    assert!(v.word_count() > 16, "{} words", v.word_count());
}
