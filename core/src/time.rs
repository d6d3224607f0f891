//! Timestamps and associating two streams of them.
//!
//! Times are `f64` seconds (any epoch; TUM uses Unix time). MCAP and ROS use integer
//! nanoseconds: see [`nanos_from_seconds`] and [`seconds_from_nanos`].
//!
//! Two association rules are used in the field, and both are reproduced exactly here:
//!
//! * [`associate_greedy`]: the TUM benchmark's `associate.py` (and `evaluate_ate.py`):
//!   consider every pair with `|a - (b + offset)| < max_diff`, take pairs in order of
//!   increasing time difference, each stamp at most once (one-to-one).
//! * [`associate_nearest`]: evo's `associate_trajectories`: every stamp of the shorter
//!   stream takes the nearest stamp of the longer one if within `max_diff` (inclusive); a
//!   stamp of the longer stream may be used more than once.

use std::cmp::Ordering;

/// Converts seconds to integer nanoseconds (rounded to nearest).
pub fn nanos_from_seconds(t_s: f64) -> u64 {
    (t_s * 1e9).round().max(0.0) as u64
}

/// Converts integer nanoseconds to seconds.
pub fn seconds_from_nanos(t_ns: u64) -> f64 {
    (t_ns / 1_000_000_000) as f64 + (t_ns % 1_000_000_000) as f64 * 1e-9
}

/// One-to-one greedy association, exactly as TUM's `associate.py`.
///
/// `first` and `second` must be sorted ascending (not checked; unsorted input gives fewer
/// matches, never a panic). Returns index pairs `(i_first, i_second)` sorted by `first`'s
/// stamp, for which `|first[i] - (second[j] + offset_s)| < max_diff_s` (strict, as the tool),
/// chosen greedily by increasing time difference; ties are broken by the smaller first stamp,
/// then the smaller second stamp, as Python's tuple sort does.
pub fn associate_greedy(
    first: &[f64],
    second: &[f64],
    offset_s: f64,
    max_diff_s: f64,
) -> Vec<(usize, usize)> {
    // Candidate pairs within the window. `second` is sorted, so for each a the candidates
    // b satisfy a - max_diff < b + offset < a + max_diff; widen the search by one element on
    // each side and apply the tool's exact test to each.
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, &a) in first.iter().enumerate() {
        let lo = second.partition_point(|&b| b + offset_s <= a - max_diff_s);
        let mut j = lo.saturating_sub(1);
        while let Some(&b) = second.get(j) {
            let diff = (a - (b + offset_s)).abs();
            if diff < max_diff_s {
                candidates.push((diff, i, j));
            } else if b + offset_s > a {
                break;
            }
            j += 1;
        }
    }
    candidates.sort_by(|x, y| {
        x.0.total_cmp(&y.0)
            .then_with(|| cmp_stamp(first, x.1, y.1))
            .then_with(|| cmp_stamp(second, x.2, y.2))
    });
    let mut used_first = vec![false; first.len()];
    let mut used_second = vec![false; second.len()];
    let mut matches = Vec::new();
    for (_, i, j) in candidates {
        if let (Some(ui), Some(uj)) = (used_first.get(i), used_second.get(j)) {
            if !*ui && !*uj {
                used_first[i] = true;
                used_second[j] = true;
                matches.push((i, j));
            }
        }
    }
    matches.sort_by(|x, y| cmp_stamp(first, x.0, y.0).then_with(|| cmp_stamp(second, x.1, y.1)));
    matches
}

fn cmp_stamp(stamps: &[f64], a: usize, b: usize) -> Ordering {
    match (stamps.get(a), stamps.get(b)) {
        (Some(x), Some(y)) => x.total_cmp(y),
        _ => a.cmp(&b),
    }
}

/// Nearest-neighbour association, exactly as evo's `matching_time_indices` on sorted
/// stamps.
///
/// For each stamp `s` of `short` (in order), finds the nearest stamp of `long + offset_s`; the
/// pair is kept if the difference is `<= max_diff_s`. On a tie the earlier stamp of `long`
/// wins. Returns `(i_short, i_long)` pairs in `short`'s order. `long` must be sorted
/// ascending (the caller checks); `short` need not be.
pub fn associate_nearest(
    short: &[f64],
    long: &[f64],
    offset_s: f64,
    max_diff_s: f64,
) -> Vec<(usize, usize)> {
    let (Some(&first), Some(&last)) = (long.first(), long.last()) else {
        return Vec::new();
    };
    let (first, last) = (first + offset_s, last + offset_s);
    let mut pairs = Vec::new();
    for (i, &s) in short.iter().enumerate() {
        if s < first - max_diff_s || s > last + max_diff_s {
            continue;
        }
        // Insertion index with side="right": first element strictly greater than s.
        let mut idx = long.partition_point(|&b| b + offset_s <= s);
        if idx >= long.len() {
            idx = long.len() - 1;
        }
        let Some(&ub) = long.get(idx) else { continue };
        let diff_ub = ub + offset_s - s;
        let diff_lb = match idx.checked_sub(1).and_then(|k| long.get(k)) {
            Some(&lb) => s - (lb + offset_s),
            None => f64::INFINITY,
        };
        if diff_ub <= max_diff_s && diff_ub < diff_lb {
            pairs.push((i, idx));
        } else if diff_lb <= max_diff_s && diff_lb <= diff_ub {
            pairs.push((i, idx - 1));
        }
    }
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The TUM tool's algorithm, written naively: all pairs, sort, greedy.
    fn greedy_reference(a: &[f64], b: &[f64], offset: f64, max_diff: f64) -> Vec<(usize, usize)> {
        let mut cand = Vec::new();
        for (i, &x) in a.iter().enumerate() {
            for (j, &y) in b.iter().enumerate() {
                let d = (x - (y + offset)).abs();
                if d < max_diff {
                    cand.push((d, x, y, i, j));
                }
            }
        }
        cand.sort_by(|p, q| {
            p.0.total_cmp(&q.0)
                .then(p.1.total_cmp(&q.1))
                .then(p.2.total_cmp(&q.2))
        });
        let (mut ua, mut ub) = (vec![false; a.len()], vec![false; b.len()]);
        let mut m = Vec::new();
        for (_, _, _, i, j) in cand {
            if !ua[i] && !ub[j] {
                ua[i] = true;
                ub[j] = true;
                m.push((i, j));
            }
        }
        m.sort();
        m
    }

    /// A small deterministic generator (no external crates needed for tests).
    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    fn stamps(seed: &mut u64, n: usize, step: f64) -> Vec<f64> {
        let mut t = 1000.0;
        (0..n)
            .map(|_| {
                t += step * (0.2 + lcg(seed));
                (t * 1e4).round() / 1e4 // 0.1 ms quantisation makes ties happen
            })
            .collect::<Vec<_>>()
            .windows(2)
            .filter(|w| w[1] > w[0])
            .map(|w| w[1])
            .collect()
    }

    #[test]
    fn greedy_matches_the_naive_tum_algorithm() {
        let mut seed = 7;
        for round in 0..200 {
            let a = stamps(&mut seed, 40, 0.03);
            let b = stamps(&mut seed, 60, 0.02);
            let offset = if round % 3 == 0 { 0.013 } else { 0.0 };
            for max_diff in [0.005, 0.02, 0.1] {
                assert_eq!(
                    associate_greedy(&a, &b, offset, max_diff),
                    greedy_reference(&a, &b, offset, max_diff),
                    "round {round}, max_diff {max_diff}"
                );
            }
        }
    }

    #[test]
    fn greedy_is_one_to_one_and_strict() {
        let a = [1.0, 1.01];
        let b = [1.005];
        assert_eq!(associate_greedy(&a, &b, 0.0, 0.02), vec![(0, 0)]);
        assert!(associate_greedy(&[1.0], &[1.02], 0.0, 0.02).is_empty());
    }

    #[test]
    fn nearest_matches_evo_semantics() {
        let long = [0.0, 1.0, 2.0, 3.0];
        // Many-to-one is allowed; ties go to the earlier stamp; the bound is inclusive.
        let short = [0.9, 1.1, 1.5, 3.25, -0.25, 5.0];
        assert_eq!(
            associate_nearest(&short, &long, 0.0, 0.5),
            vec![(0, 1), (1, 1), (2, 1), (3, 3), (4, 0)]
        );
        assert_eq!(associate_nearest(&[1.4], &long, 0.5, 0.11), vec![(0, 1)]);
        assert!(associate_nearest(&[1.0], &[], 0.0, 1.0).is_empty());
    }

    #[test]
    fn nanosecond_conversions() {
        assert_eq!(nanos_from_seconds(1.5), 1_500_000_000);
        assert_eq!(
            seconds_from_nanos(1_341_841_873_273_820_000),
            1341841873.27382
        );
    }
}
