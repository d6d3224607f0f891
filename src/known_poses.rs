//! Elevation mapping of a recorded sequence with known poses (ground truth, or a
//! trajectory file): every depth frame at its pose interpolated at the depth image's time,
//! into one or more mappers side by side, scored against the true terrain when there is
//! one.

use crate::PipelineError;
use stride_core::grid::Grid;
use stride_core::trajectory::Trajectory;
use stride_datasets::sequence::Sequence;
use stride_datasets::stream::StreamError;
use stride_mapping::input::{Rejections, SensorFrame};
use stride_mapping::metrics::{
    compare, compare_over_seen, floor_fit, phantoms, FloorFit, MapScore, PhantomScore, SeenScore,
};
use stride_mapping::post::MedianStats;
use stride_mapping::{ElevationMapper, MapLayers, UpdateStats};

/// A mapper's results over the sequence.
pub struct MapperRun {
    /// Its name.
    pub name: &'static str,
    /// Its layers (stack: after the median fill).
    pub layers: MapLayers,
    /// Update time per frame (s).
    pub update_s: Vec<f64>,
    /// Points used.
    pub points_used: usize,
    /// Points dropped because their column had too many distinct voxels in one frame
    /// ([`stride_mapping::UpdateStats::points_overflow`]).
    pub points_overflow: usize,
    /// Dropped measurements.
    pub rejected: Rejections,
    /// Columns cleared by the visibility check.
    pub cells_cleared: usize,
    /// Depth pixels of steep faces moved behind them
    /// ([`stride_mapping::UpdateStats::steep_pushed`]).
    pub steep_pushed: usize,
    /// What the median filter changed (stack mapper only).
    pub median: MedianStats,
    /// Comparison with ground truth.
    pub score: Option<MapScore>,
    /// Phantom obstacles over flat ground truth.
    pub phantoms: Option<PhantomScore>,
    /// Scored over the cells seen (when the cells seen, `NaiveMedian::seen`, were mapped
    /// beside it).
    pub seen: Option<SeenScore>,
    /// The floor's plane fit.
    pub floor: Option<FloorFit>,
    /// Bytes the mapper held at the end ([`ElevationMapper::memory_bytes`]).
    pub memory_bytes: usize,
    /// Mapped columns dropped at the archive's cap
    /// ([`ElevationMapper::archive_dropped_cells`]).
    pub archive_dropped_cells: usize,
}

/// Ground truth spanning more than this height (m) within [`STEP_RADIUS_M`] of a cell puts
/// the cell near a step.
pub const STEP_M: f64 = 0.02;

/// See [`STEP_M`] (m).
pub const STEP_RADIUS_M: f64 = 0.02;

/// Scores `map` against the true terrain `gt` (same world frame, z up) over the cells the
/// map knows, split at [`STEP_M`] / [`STEP_RADIUS_M`]: near a step or an obstacle's foot
/// (truth spanning more than 2 cm within 2 cm, or no truth there: a wall's or an object's
/// footprint) and away from them. Near a wall's face the sensor's depth noise throws the
/// face's points into the floor's cells in front of it, so a few such cells can hold most of
/// a map's squared error; away from them the error is the terrain's.
pub fn score_near_and_away_from_steps(map: &Grid<f32>, gt: &Grid<f32>) -> Option<SeenScore> {
    compare_over_seen(map, map, gt, STEP_M, STEP_RADIUS_M)
}

/// Cells within this height of the floor plane (m) count as floor in the flatness fit.
pub const FLOOR_BAND_M: f64 = 0.10;

/// Phantom obstacles: cells more than 2 cm above ground truth that is flat (within 1 cm)
/// over 5 cm around.
pub fn phantom_score(map: &Grid<f32>, gt: &Grid<f32>) -> PhantomScore {
    phantoms(map, gt, 0.05, 0.01, 0.02)
}

/// Frames mapped and skipped.
#[derive(Debug, Default, Clone, Copy)]
pub struct FrameCounts {
    /// Frames in the sequence (up to --max-frames).
    pub frames: usize,
    /// Frames integrated.
    pub mapped: usize,
    /// Frames outside the poses' time span.
    pub no_pose: usize,
    /// Frames that could not be loaded.
    pub unreadable: usize,
}

/// One mapper's updates over a sequence, summed ([`UpdateStats`] per frame).
#[derive(Default)]
struct Tally {
    update_s: Vec<f64>,
    points_used: usize,
    points_overflow: usize,
    rejected: Rejections,
    cells_cleared: usize,
    steep_pushed: usize,
}

impl Tally {
    fn add(&mut self, u: &UpdateStats) {
        self.update_s.push(u.update_s);
        self.points_used += u.points_used;
        self.points_overflow += u.points_overflow;
        self.rejected.add(&u.rejected);
        self.cells_cleared += u.cells_cleared;
        self.steep_pushed += u.steep_pushed;
    }
}

/// Maps a sequence with the given poses into each mapper; returns per-mapper runs, each
/// map as its mapper finishes it (the stack map's median fill per its configuration).
pub fn map_sequence(
    seq: &Sequence,
    poses: &Trajectory,
    mut mappers: Vec<Box<dyn ElevationMapper>>,
    max_frames: Option<usize>,
    gt: Option<&Grid<f32>>,
    mut on_frame: impl FnMut(),
) -> Result<(Vec<MapperRun>, FrameCounts), PipelineError> {
    let stream = seq.stream(max_frames, 4);
    let mut counts = FrameCounts::default();
    let mut stats: Vec<Tally> = mappers.iter().map(|_| Tally::default()).collect();
    for item in stream {
        counts.frames += 1;
        on_frame();
        let decoded = match item {
            Ok(d) => d,
            Err(StreamError::Frame(f)) => {
                crate::pipeline::warn_skipped(counts.unreadable, f.index, &f.error);
                counts.unreadable += 1;
                continue;
            }
            Err(StreamError::Stopped(e)) => return Err(e.into()),
        };
        let frame = &decoded.frame;
        let Some(pose) = poses.interpolate(frame.t_depth_s) else {
            counts.no_pose += 1;
            continue;
        };
        counts.mapped += 1;
        let sf = SensorFrame::depth(&frame.depth_m, &seq.camera().camera, pose, frame.t_depth_s)?;
        for (m, s) in mappers.iter_mut().zip(stats.iter_mut()) {
            s.add(&m.integrate(&sf));
        }
    }
    let mut runs = Vec::new();
    for (m, t) in mappers.iter().zip(stats) {
        // The mapper's own post-processing (the stack map's median fill; none for the
        // baseline).
        let (layers, median) = m.finished();
        let score = gt.and_then(|g| compare(&layers.elevation, g));
        let phantoms = gt.map(|g| phantom_score(&layers.elevation, g));
        let floor = floor_fit(&layers.elevation, FLOOR_BAND_M);
        runs.push(MapperRun {
            name: m.name(),
            layers,
            update_s: t.update_s,
            points_used: t.points_used,
            points_overflow: t.points_overflow,
            rejected: t.rejected,
            cells_cleared: t.cells_cleared,
            steep_pushed: t.steep_pushed,
            median,
            score,
            phantoms,
            seen: None,
            floor,
            memory_bytes: m.memory_bytes(),
            archive_dropped_cells: m.archive_dropped_cells(),
        });
    }
    // With the cells seen among the maps, every map is also scored over them.
    if let (Some(g), Some(seen)) = (gt, runs.iter().find(|r| r.name == "seen")) {
        let scores: Vec<Option<SeenScore>> = runs
            .iter()
            .map(|r| {
                let s = &seen.layers.elevation;
                compare_over_seen(&r.layers.elevation, s, g, STEP_M, STEP_RADIUS_M)
            })
            .collect();
        for (r, score) in runs.iter_mut().zip(scores) {
            r.seen = score;
        }
    }
    Ok((runs, counts))
}

/// The pipeline's elevation map made from the same views with other poses (ground truth,
/// to separate the SLAM's part of a map's error from the mapper's): each frame of `frames`
/// (indices in `seq`) loaded and mapped at `poses` (world frame, z up) interpolated at its
/// depth image's time, as [`crate::Pipeline`] maps its views. Returns the map and the
/// number of frames outside the poses' time span (left out).
pub fn views_map(
    seq: &Sequence,
    frames: &[usize],
    poses: &Trajectory,
    config: crate::pipeline::terrain::TerrainConfig,
) -> Result<(MapLayers, usize), PipelineError> {
    let mut terrain = crate::pipeline::terrain::Terrain::new(&seq.camera().camera, config)?;
    terrain.set_world(nalgebra::Isometry3::identity());
    let mut outside = 0;
    let wanted: std::collections::BTreeMap<usize, usize> = frames
        .iter()
        .enumerate()
        .map(|(position, &index)| (index, position))
        .collect();
    // Only the views' frames are decoded, in one pass (an MCAP log is read in order).
    for item in seq.stream_frames(wanted.keys().copied().collect(), 4) {
        let frame = match item {
            Ok(d) => d.frame,
            Err(StreamError::Frame(f)) => return Err(f.error.into()),
            Err(StreamError::Stopped(e)) => return Err(e.into()),
        };
        let Some(&position) = wanted.get(&frame.index) else {
            continue;
        };
        let Some(pose) = poses.interpolate(frame.t_depth_s) else {
            outside += 1;
            continue;
        };
        // Each view is its own keyframe, placed at once.
        let id = position as u64;
        terrain.add_view(
            position,
            frame.t_s,
            &frame.depth_m,
            id,
            nalgebra::Isometry3::identity(),
        );
        terrain.set_poses(&[(id, pose)]);
        terrain.update()?;
    }
    let (layers, _) = terrain.finish(|_| None, |_| false)?;
    Ok((layers, outside))
}
