//! The rasterised renderer against the marched reference on the same scenes: the terrain it
//! finds must be the same surface, so depth and colour agree within the sensor's noise.
//! Full-size frames (640x480, the size the speed target is about), few of them.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is a failure report

use stride_datasets::synth::motion::{Gait, MotionConfig};
use stride_datasets::synth::render::Visibility;
use stride_datasets::synth::{Synth, SynthConfig, TerrainSource};

/// How two renders of one frame differ.
#[derive(Debug)]
struct Agreement {
    /// Pixels where exactly one renderer hit something, over all pixels.
    hit_mismatch: f64,
    /// Pixels hit by both whose true z-depth differs by more than 1 mm, over those pixels.
    depth_over_1mm: f64,
    /// Largest true z-depth difference over pixels hit by both, excluding the worst 0.1 % (m).
    depth_p999_m: f64,
    /// Mean absolute difference of the sensor's colour values (DN, all channels).
    color_mean_dn: f64,
    /// Sensor depth (raw units) identical, over all pixels.
    raw_depth_identical: f64,
}

fn compare(cfg: SynthConfig, frames: &[usize]) -> Vec<Agreement> {
    let synth = Synth::new(cfg).unwrap();
    let renderer = synth.renderer();
    frames
        .iter()
        .map(|&i| {
            let a = synth.render_frame_with(&renderer, i, Visibility::Marched);
            let b = synth.render_frame_with(&renderer, i, Visibility::Rasterized);
            let n = a.depth_true_m.len() as f64;
            let (mut mismatch, mut both, mut over) = (0usize, 0usize, 0usize);
            let mut diffs = Vec::new();
            for (&za, &zb) in a.depth_true_m.iter().zip(&b.depth_true_m) {
                match (za > 0.0, zb > 0.0) {
                    (true, true) => {
                        both += 1;
                        let d = f64::from((za - zb).abs());
                        over += usize::from(d > 1e-3);
                        diffs.push(d);
                    }
                    (false, false) => {}
                    _ => mismatch += 1,
                }
            }
            diffs.sort_by(f64::total_cmp);
            let p999 = diffs
                .get((diffs.len() as f64 * 0.999) as usize)
                .copied()
                .unwrap_or(0.0);
            let color: f64 = a
                .rgb
                .as_slice()
                .iter()
                .zip(b.rgb.as_slice())
                .map(|(p, q)| {
                    (0..3)
                        .map(|c| (f64::from(p[c]) - f64::from(q[c])).abs())
                        .sum::<f64>()
                })
                .sum::<f64>()
                / (3.0 * n);
            let raw_same = a
                .depth_raw
                .as_slice()
                .iter()
                .zip(b.depth_raw.as_slice())
                .filter(|(p, q)| p == q)
                .count() as f64
                / n;
            Agreement {
                hit_mismatch: mismatch as f64 / n,
                depth_over_1mm: over as f64 / both.max(1) as f64,
                depth_p999_m: p999,
                color_mean_dn: color,
                raw_depth_identical: raw_same,
            }
        })
        .collect()
}

fn assert_agree(label: &str, results: &[Agreement]) {
    for (k, r) in results.iter().enumerate() {
        eprintln!("{label} frame {k}: {r:?}");
        assert!(r.hit_mismatch < 1e-3, "{label} frame {k}: {r:?}");
        assert!(r.depth_over_1mm < 1e-3, "{label} frame {k}: {r:?}");
        assert!(r.depth_p999_m < 1e-3, "{label} frame {k}: {r:?}");
        assert!(r.color_mean_dn < 0.1, "{label} frame {k}: {r:?}");
        assert!(r.raw_depth_identical > 0.999, "{label} frame {k}: {r:?}");
    }
}

#[test]
fn rasterised_frames_match_the_marched_reference_with_objects_and_rolling_shutter() {
    // The lab's default: mixed terrain, objects and walls, tripod gait with blur, a 20 ms
    // rolling shutter (per-band poses in the rasteriser).
    let cfg = SynthConfig {
        frames: 40,
        motion: MotionConfig {
            speed_m_s: 0.15,
            ..MotionConfig::default()
        },
        ..SynthConfig::default()
    };
    assert_agree("tripod", &compare(cfg, &[0, 23]));
}

#[test]
fn rasterised_frames_match_the_marched_reference_on_steps_with_a_global_shutter() {
    // Sharp steps (the bilinear patches straddling them are steep) and a global shutter.
    let mut cfg = SynthConfig {
        frames: 30,
        terrain: TerrainSource::Procedural {
            name: "steps".into(),
            resolution_m: 0.02,
        },
        motion: MotionConfig {
            gait: Gait::Crawl,
            ..MotionConfig::default()
        },
        blur: false,
        ..SynthConfig::default()
    };
    cfg.camera.rolling_shutter_s = 0.0;
    assert_agree("steps", &compare(cfg, &[0, 29]));
}
