//! Training the place-recognition vocabulary ([`stride_frontend::place::Vocabulary`]) on
//! the synthetic lab, so that the shipped vocabulary can be remade by anyone, bit for bit,
//! from the project alone (no image fetched from elsewhere).
//!
//! The lab renders walks over each procedural terrain (mixed, steps, ramps, boxes, rubble,
//! slopes) with objects, motion blur and the three path shapes in turn; every
//! [`VocabSpec::frame_step`]-th frame gives the descriptors the map's keyframes carry: the
//! tracking's FAST corners (default odometry settings) with ORB descriptors.

use stride_datasets::synth::motion::PathKind;
use stride_datasets::synth::terrain::PROCEDURAL_NAMES;
use stride_datasets::synth::{Synth, SynthConfig, SynthError, TerrainSource};
use stride_frontend::features::{gray_mat, Detector, OrbDescriptor};
use stride_frontend::place::{PlaceError, Vocabulary};
use stride_frontend::{FrontendError, VoConfig};

/// How the vocabulary is trained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VocabSpec {
    /// Synthetic walks (terrains and paths taken in turn, seeds `seed + i`).
    pub scenes: usize,
    /// Training images per walk.
    pub images_per_scene: usize,
    /// Frames between two training images (at 30 Hz), so that images are distinct views.
    pub frame_step: usize,
    /// Children per node of the tree.
    pub branching: u32,
    /// Levels of the tree: `branching^depth` words at most.
    pub depth: u32,
    /// Seed of the walks and of the clustering.
    pub seed: u64,
}

impl Default for VocabSpec {
    /// The shipped vocabulary's settings: 12 walks of 40 images (480 images, about 0.4
    /// million descriptors), 6 children over 5 levels (at most 7,776 words). Chosen by
    /// `stride bench place` on teddy_200 among 10x3, 32x2, 8x4, 16x3, 6x5 and 10x5 trees:
    /// 6x5 found a verifiable place (at least 15 matches, at least 1 s away) among its
    /// top 5 candidates most often (0.45 against 0.35-0.44, chance 0.23).
    fn default() -> Self {
        Self {
            scenes: 12,
            images_per_scene: 40,
            frame_step: 8,
            branching: 6,
            depth: 5,
            seed: 1,
        }
    }
}

/// Why training failed.
#[derive(Debug, thiserror::Error)]
pub enum VocabError {
    /// A synthetic walk could not be built.
    #[error("synthetic walk {scene}: {source}")]
    Synth {
        /// Walk number.
        scene: usize,
        /// The error.
        source: SynthError,
    },
    /// Feature detection failed.
    #[error(transparent)]
    Frontend(#[from] FrontendError),
    /// Clustering failed.
    #[error(transparent)]
    Place(#[from] PlaceError),
}

/// The lab's walk number `scene` of `spec`.
pub fn scene_config(spec: &VocabSpec, scene: usize) -> SynthConfig {
    let mut c = SynthConfig::default();
    let names = PROCEDURAL_NAMES;
    c.terrain = TerrainSource::Procedural {
        name: names
            .get(scene % names.len())
            .unwrap_or(&"mixed")
            .to_string(),
        resolution_m: 0.01,
    };
    c.motion.path = [PathKind::Straight, PathKind::Square, PathKind::Turn]
        .get(scene % 3)
        .copied()
        .unwrap_or(PathKind::Straight);
    c.motion.speed_m_s = 0.15;
    c.frames = spec.images_per_scene * spec.frame_step;
    c.seed = spec.seed + scene as u64;
    c
}

/// The training images' descriptors, one `Vec` per image; `on_image` is called after each.
pub fn lab_descriptors(
    spec: &VocabSpec,
    mut on_image: impl FnMut(),
) -> Result<Vec<Vec<OrbDescriptor>>, VocabError> {
    let vo = VoConfig::default();
    let mut detector = Detector::new(&vo)?;
    let mut images = Vec::with_capacity(spec.scenes * spec.images_per_scene);
    for scene in 0..spec.scenes {
        let synth = Synth::new(scene_config(spec, scene))
            .map_err(|source| VocabError::Synth { scene, source })?;
        let renderer = synth.renderer();
        for i in 0..spec.images_per_scene {
            let frame = synth.render_frame(&renderer, i * spec.frame_step);
            let gray_img = frame.rgb.to_gray();
            let gray = gray_mat(&gray_img)?;
            let corners = detector.detect(&gray, &[], &vo)?;
            let points: Vec<_> = corners.iter().map(|c| c.px).collect();
            let descriptors = detector.describe(&gray, &gray_img, &points)?;
            images.push(descriptors.into_iter().flatten().collect());
            on_image();
        }
    }
    Ok(images)
}

/// Trains the vocabulary of `spec` on the lab's images.
pub fn train(spec: &VocabSpec, on_image: impl FnMut()) -> Result<Vocabulary, VocabError> {
    let images = lab_descriptors(spec, on_image)?;
    Ok(Vocabulary::train(
        &images,
        spec.branching,
        spec.depth,
        spec.seed,
    )?)
}
