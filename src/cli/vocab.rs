//! `stride vocab`: trains the place-recognition vocabulary on the synthetic lab (how the
//! shipped `frontend/assets/orb_vocabulary.bin` was made).

use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use stride::vocab::{train, VocabSpec};
use stride_output::fs::write_atomic;

#[derive(Debug, Args)]
pub struct VocabArgs {
    /// The vocabulary file to write (replaced atomically).
    #[arg(long)]
    out: PathBuf,
    /// Synthetic walks (terrains and paths in turn).
    #[arg(long, default_value_t = VocabSpec::default().scenes)]
    scenes: usize,
    /// Training images per walk.
    #[arg(long, default_value_t = VocabSpec::default().images_per_scene)]
    images_per_scene: usize,
    /// Children per node of the tree.
    #[arg(long, default_value_t = VocabSpec::default().branching)]
    branching: u32,
    /// Levels of the tree.
    #[arg(long, default_value_t = VocabSpec::default().depth)]
    depth: u32,
    /// Seed of the walks and the clustering.
    #[arg(long, default_value_t = VocabSpec::default().seed)]
    seed: u64,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

pub fn run(a: VocabArgs) -> Result<()> {
    let spec = VocabSpec {
        scenes: a.scenes,
        images_per_scene: a.images_per_scene,
        branching: a.branching,
        depth: a.depth,
        seed: a.seed,
        ..VocabSpec::default()
    };
    let pb = super::progress_bar(spec.scenes * spec.images_per_scene, "images", !a.quiet);
    let start = std::time::Instant::now();
    let vocabulary = train(&spec, || pb.inc(1))?;
    pb.finish_and_clear();
    let bytes = vocabulary.to_bytes();
    write_atomic(&a.out, &bytes).with_context(|| format!("writing {}", a.out.display()))?;
    tracing::info!(
        "{}: {} words ({} x {} levels), {} bytes, trained in {:.1} s",
        a.out.display(),
        vocabulary.word_count(),
        spec.branching,
        spec.depth,
        bytes.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
