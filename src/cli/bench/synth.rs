//! `stride bench synth`: rendering speed of the synthetic generator.

use super::median;
use anyhow::{bail, Result};
use clap::Args;
use std::time::Instant;

#[derive(Debug, Args)]
pub struct SynthBenchArgs {
    /// Frames rendered per configuration (the median is reported).
    #[arg(long, default_value_t = 15)]
    frames: usize,
    /// Walking speed (m/s) of the tripod gait used for the blurred frames.
    #[arg(long, default_value_t = 0.15)]
    speed: f64,
}

pub fn bench_synth(a: SynthBenchArgs) -> Result<()> {
    use stride_datasets::png_io::{encode_depth_u16, encode_rgb};
    use stride_datasets::synth::{motion::MotionConfig, Synth, SynthConfig};
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    crate::outln!("synthetic rendering, 640x480, procedural 'mixed' terrain, tripod at {} m/s; medians of {} frames", a.speed, a.frames)?;
    for blur in [false, true] {
        let config = SynthConfig {
            frames: a.frames,
            blur,
            motion: MotionConfig {
                speed_m_s: a.speed,
                ..MotionConfig::default()
            },
            ..SynthConfig::default()
        };
        let synth = Synth::new(config)?;
        let renderer = synth.renderer();
        let (mut render, mut encode, mut sub) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..a.frames {
            let f = synth.render_frame(&renderer, i);
            let t = Instant::now();
            let _ = encode_rgb(&f.rgb);
            let _ = encode_depth_u16(&f.depth_raw);
            encode.push(t.elapsed().as_secs_f64());
            render.push(f.render_s);
            sub.push(f.info.subframes as f64);
        }
        let r = median(render);
        crate::outln!(
            "{:<12} render {:>7.1} ms/frame ({:>5.1} frames/s), PNG encoding {:>5.1} ms/frame, sub-frames {:.0}",
            if blur { "with blur" } else { "no blur" },
            r * 1e3,
            1.0 / r,
            median(encode) * 1e3,
            median(sub)
        )?;
    }
    Ok(())
}
