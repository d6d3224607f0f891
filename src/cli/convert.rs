//! `stride convert` (TUM folder <-> MCAP log) and `stride info` (what a log holds).

use super::run::TopicArgs;
use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use std::time::Instant;
use stride_datasets::mcap::convert::{mcap_to_tum, tum_to_mcap, Compression, ImageFormat};
use stride_datasets::mcap::{summarize, McapSequence};
use stride_datasets::sequence::is_mcap;
use stride_datasets::tum::AssociationOptions;

#[derive(Debug, Args)]
pub struct ConvertArgs {
    /// A TUM folder (to write as MCAP) or an MCAP log (to write as a TUM folder).
    #[arg(long)]
    pub from: PathBuf,
    /// The MCAP file (ending in .mcap) or the TUM folder to write.
    #[arg(long)]
    pub to: PathBuf,
    /// Replace an existing output.
    #[arg(long)]
    pub overwrite: bool,
    /// Camera: fr1, fr2, fr3 or a camera file [default: the folder's camera.json, the
    /// folder name's TUM camera, or the log's camera info].
    #[arg(long)]
    pub camera: Option<String>,
    /// Images in a written log: `raw` (sensor_msgs/Image rgb8 and 16UC1) or `png` (the
    /// folder's files as sensor_msgs/CompressedImage).
    #[arg(long, value_enum, default_value = "raw")]
    pub images: ImagesArg,
    /// Chunk compression of a written log.
    #[arg(long, value_enum, default_value = "none")]
    pub compression: CompressionArg,
    /// Topics of an MCAP --from.
    #[command(flatten)]
    pub topics: TopicArgs,
}

/// How images are stored in a written log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ImagesArg {
    /// sensor_msgs/Image (rgb8, 16UC1).
    Raw,
    /// sensor_msgs/CompressedImage (the PNG files as they are).
    Png,
}

/// Chunk compression of a written log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CompressionArg {
    /// None.
    None,
    /// zstd.
    Zstd,
    /// lz4.
    Lz4,
}

pub fn run(a: ConvertArgs) -> Result<()> {
    let started = Instant::now();
    let counts = if a.from.is_dir() && is_mcap(&a.to) {
        if a.to.exists() && !a.overwrite {
            anyhow::bail!(
                "--to {}: the file exists; pass --overwrite to replace it",
                a.to.display()
            );
        }
        let format = match a.images {
            ImagesArg::Raw => ImageFormat::Raw,
            ImagesArg::Png => ImageFormat::Png,
        };
        let compression = match a.compression {
            CompressionArg::None => Compression::None,
            CompressionArg::Zstd => Compression::Zstd,
            CompressionArg::Lz4 => Compression::Lz4,
        };
        tum_to_mcap(&a.from, a.camera.as_deref(), &a.to, format, compression)?
    } else if is_mcap(&a.from) {
        super::check_out_dir("--to", &a.to, a.overwrite)?;
        let seq = McapSequence::open(
            &a.from,
            &a.topics.topics()?,
            a.camera.as_deref(),
            AssociationOptions::default(),
        )
        .context("opening the log")?;
        mcap_to_tum(&seq, &a.to)?
    } else {
        anyhow::bail!(
            "convert a TUM folder to a file ending in .mcap, or a .mcap file to a folder \
             (--from {}, --to {})",
            a.from.display(),
            a.to.display()
        );
    };
    crate::outln!(
        "{} colour and {} depth images, {} accelerometer and {} gyroscope samples, {} \
         ground-truth poses written to {} in {:.1} s",
        counts.rgb,
        counts.depth,
        counts.imu,
        counts.gyroscope,
        counts.groundtruth,
        a.to.display(),
        started.elapsed().as_secs_f64()
    )?;
    Ok(())
}

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// The MCAP log.
    pub file: PathBuf,
}

pub fn info(a: InfoArgs) -> Result<()> {
    let s = summarize(&a.file)?;
    crate::outln!("{}: {} messages", a.file.display(), s.messages)?;
    crate::outln!(
        "{:<36} {:<34} {:>8} {:>9} {:>9}",
        "topic",
        "schema",
        "messages",
        "span s",
        "rate Hz"
    )?;
    for t in &s.topics {
        let span = t.span_s.1 - t.span_s.0;
        let rate = if span > 0.0 {
            format!("{:.1}", (t.messages - 1) as f64 / span)
        } else {
            "-".into()
        };
        let schema = if t.encoding == "cdr" {
            t.schema.clone()
        } else {
            format!("{} ({})", t.schema, t.encoding)
        };
        crate::outln!(
            "{:<36} {:<34} {:>8} {:>9.2} {:>9}",
            t.topic,
            schema,
            t.messages,
            span,
            rate
        )?;
    }
    for (parent, child, n) in &s.transforms {
        crate::outln!("transform {parent} -> {child}: {n} (--gt-tf {parent}:{child})")?;
    }
    Ok(())
}
