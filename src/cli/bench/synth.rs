//! `stride bench synth`: rendering speed of the synthetic generator, the rasterised
//! renderer against the marched reference in the same run.

use super::median;
use anyhow::{bail, Result};
use clap::Args;
use std::time::Instant;
use stride_datasets::synth::render::Visibility;

#[derive(Debug, Args)]
pub struct SynthBenchArgs {
    /// Frames rendered per configuration (the median is reported).
    #[arg(long, default_value_t = 15)]
    frames: usize,
    /// Walking speed (m/s) of the tripod gait used for the blurred frames.
    #[arg(long, default_value_t = 0.15)]
    speed: f64,
    /// Rolling-shutter readout (ms): the lab's default is 20, 0 is a global shutter.
    #[arg(long, default_value_t = 20.0)]
    rolling_shutter_ms: f64,
}

pub fn bench_synth(a: SynthBenchArgs) -> Result<()> {
    use stride_datasets::png_io::{encode_depth_u16, encode_rgb};
    use stride_datasets::synth::{motion::MotionConfig, Synth, SynthConfig};
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    crate::outln!(
        "synthetic rendering, 640x480, procedural 'mixed' terrain, tripod at {} m/s, rolling shutter {} ms; medians of {} frames, the two renderers alternating",
        a.speed,
        a.rolling_shutter_ms,
        a.frames
    )?;
    for blur in [false, true] {
        let mut config = SynthConfig {
            frames: a.frames,
            blur,
            motion: MotionConfig {
                speed_m_s: a.speed,
                ..MotionConfig::default()
            },
            ..SynthConfig::default()
        };
        config.camera.rolling_shutter_s = a.rolling_shutter_ms * 1e-3;
        let synth = Synth::new(config)?;
        let renderer = synth.renderer();
        // Render times (s) of each renderer; PNG encoding, sub-frames and rays marched by
        // the rasteriser (they do not depend on the renderer).
        let (mut marched_s, mut raster_s) = (Vec::new(), Vec::new());
        let (mut encode_s, mut subframes, mut rays_marched) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..a.frames {
            // Swap the order every frame, so neither pays for the other's cold caches.
            let order = if i % 2 == 0 {
                [Visibility::Marched, Visibility::Rasterized]
            } else {
                [Visibility::Rasterized, Visibility::Marched]
            };
            for vis in order {
                let f = synth.render_frame_with(&renderer, i, vis);
                if vis == Visibility::Marched {
                    marched_s.push(f.render_s);
                    continue;
                }
                let t = Instant::now();
                let _ = encode_rgb(&f.rgb);
                let _ = encode_depth_u16(&f.depth_raw);
                encode_s.push(t.elapsed().as_secs_f64());
                raster_s.push(f.render_s);
                subframes.push(f.info.subframes as f64);
                rays_marched.push(f.marched_rays as f64);
            }
        }
        let label = if blur { "with blur" } else { "no blur" };
        let (rm, rr) = (median(marched_s), median(raster_s));
        for (name, r) in [("marched", rm), ("rasterised", rr)] {
            crate::outln!(
                "{label:<10} {name:<11} render {:>7.1} ms/frame ({:>5.1} frames/s)",
                r * 1e3,
                1.0 / r
            )?;
        }
        crate::outln!(
            "{label:<10} rasterised / marched time {:.3} ({:.1}x faster); PNG encoding {:.1} ms/frame; sub-frames {:.0}; rays marched by the rasteriser {:.0} per frame (of the depth pass)",
            rr / rm,
            rm / rr,
            median(encode_s) * 1e3,
            median(subframes),
            median(rays_marched)
        )?;
    }
    Ok(())
}
