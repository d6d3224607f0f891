//! `stride bench mcap`: how fast frames come out of an MCAP log, against the TUM folder it
//! was converted from, in the same run.

use super::median;
use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stride_datasets::mcap::convert::{tum_to_mcap, Compression, ImageFormat};
use stride_datasets::mcap::McapTopics;
use stride_datasets::sequence::Sequence;
use stride_datasets::tum::AssociationOptions;

#[derive(Debug, Args)]
pub struct McapBenchArgs {
    /// A TUM folder; it is converted to logs in a temporary folder (raw images without
    /// compression, raw with zstd, and its own PNG files) and each is read back.
    #[arg(long)]
    pub dataset: PathBuf,
    /// Reads of each source (medians are reported).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
}

/// Frames per second of one pass over `seq` (every frame decoded to images).
fn read_rate(seq: &Sequence) -> Result<f64> {
    let start = Instant::now();
    let mut n = 0usize;
    for item in seq.stream(None, 4) {
        let d = item.map_err(|e| anyhow::anyhow!("{e}"))?;
        std::hint::black_box(&d.frame);
        n += 1;
    }
    Ok(n as f64 / start.elapsed().as_secs_f64())
}

fn open(path: &Path) -> Result<Sequence> {
    Sequence::open(
        path,
        None,
        AssociationOptions::default(),
        &McapTopics::default(),
    )
    .with_context(|| format!("opening {}", path.display()))
}

pub fn bench_mcap(a: McapBenchArgs) -> Result<()> {
    let tmp = tempfile::tempdir().context("a temporary folder for the logs")?;
    let mut sources = vec![("TUM folder (PNG files)".to_owned(), a.dataset.clone(), 0u64)];
    for (name, format, compression) in [
        ("raw.mcap", ImageFormat::Raw, Compression::None),
        ("raw-zstd.mcap", ImageFormat::Raw, Compression::Zstd),
        ("png.mcap", ImageFormat::Png, Compression::None),
    ] {
        let path = tmp.path().join(name);
        tum_to_mcap(&a.dataset, None, &path, format, compression)?;
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        sources.push((format!("MCAP {name}"), path, bytes));
    }
    let seqs: Vec<Sequence> = sources.iter().map(|s| open(&s.1)).collect::<Result<_>>()?;
    let frames = seqs.first().map_or(0, Sequence::len);
    let (w, h) = seqs.first().map_or((0, 0), |s| {
        (s.camera().camera.width(), s.camera().camera.height())
    });
    // Runs interleave the sources so that a change of the machine's speed hits all alike.
    let mut rates = vec![Vec::new(); seqs.len()];
    for _ in 0..a.runs.max(1) {
        for (r, seq) in rates.iter_mut().zip(&seqs) {
            r.push(read_rate(seq)?);
        }
    }
    let base = median(rates[0].clone());
    crate::outln!(
        "{frames} frames of {}x{h} RGB-D from {}, {} runs each, decoded on one background thread",
        w,
        a.dataset.display(),
        a.runs.max(1)
    )?;
    crate::outln!(
        "{:<34} {:>10} {:>14} {:>12}",
        "source",
        "MB",
        "frames/s",
        "/ TUM"
    )?;
    for ((name, _, bytes), r) in sources.iter().zip(&rates) {
        let m = median(r.clone());
        let lo = r.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = r.iter().copied().fold(0.0, f64::max);
        crate::outln!(
            "{:<34} {:>10} {:>14} {:>12.2}",
            name,
            if *bytes > 0 {
                format!("{:.0}", *bytes as f64 / 1e6)
            } else {
                "-".into()
            },
            format!("{m:.0} [{lo:.0}-{hi:.0}]"),
            m / base
        )?;
    }
    Ok(())
}
