//! [`StackConfig`], the parameters of [`super::StackMapper`], and their checks.

use crate::denoise::DepthSmoothing;
use crate::error::{self, MappingError};
use crate::input::{EdgeFilter, PrimeSenseHeight};
use crate::post::MedianFilter;
/// Parameters of [`super::StackMapper`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StackConfig {
    /// Cell size (m).
    pub resolution_m: f64,
    /// Side of the moving window (m).
    pub size_m: f64,
    /// Height of a voxel of the stack (m).
    pub voxel_height_m: f64,
    /// Vitality increase for an updated column (`V_i`).
    pub vitality_increase: u8,
    /// Vitality decrease for a column not updated (`V_d`).
    pub vitality_decrease: u8,
    /// Vitality threshold above which a column is established (`V_t`).
    pub vitality_threshold: u8,
    /// Establish a column at once, without the vitality counter's repeated sightings, when
    /// the voxel a frame feeds to its cell filter holds a measurement from a smooth depth
    /// patch: a pixel whose 5 x 5 neighbourhood (missing returns left out) spans no more
    /// depth than a surface seen at about 21 deg or steeper, plus the edge filter's noise
    /// allowance (an extension of paper 000). A flying (mixed) pixel only occurs at a depth
    /// discontinuity, so it is never smooth and still waits for the counter; a column seen
    /// once or twice on open ground, which the counter would drop, is kept. Needs the edge
    /// filter (its bound is the jump).
    pub establish_smooth: bool,
    /// Step edges: the cell filter takes the highest voxel measured in a frame among those
    /// holding at least this fraction of the column's measurements weighted by where they
    /// land in the cell (1 at the centre, 0 at a corner), or else the best supported one,
    /// so that a cell straddling a step follows the surface under its centre instead of
    /// always the top. 0 is paper 000's rule (the highest voxel); 0.5 (the default) takes
    /// the voxel with most of the support. In [0, 1].
    pub step_support_fraction: f32,
    /// Faces steeper than 45 degrees (walls, box faces, risers) are solid behind
    /// themselves: each of their pixels is moved this many depth standard deviations
    /// `sigma_d` farther along its ray before binning ([`crate::steep`]), so that depth
    /// noise does not throw a face's points into the floor's cells before it. 0 turns it
    /// off (an extension of paper 000). Finite, 0 or more.
    pub steep_push_sigmas: f32,
    /// Run the visibility check.
    pub visibility_check: bool,
    /// Also run the see-through check on depth images (an extension of paper 000): a
    /// mapped column whose top the sensor now sees through (every pixel of the 3 x 3
    /// neighbourhood of its projection measures a surface beyond it by more than
    /// `3 sigma_d + resolution`) loses its top voxel. It removes the flying-pixel phantoms
    /// that hang in an obstacle's shadow, which the line-of-sight check cannot see.
    pub see_through_check: bool,
    /// Lateral tolerance of the visibility check (m): the lines of sight are grouped by
    /// azimuth in bins this wide at the sensor's far range (`sensor.max_depth_m`).
    pub visibility_bin_m: f64,
    /// The window is centred this far ahead of the sensor along its horizontal viewing
    /// direction (m).
    pub lookahead_m: f64,
    /// The window moves when its desired centre is farther than this from its centre (m).
    pub recenter_threshold_m: f64,
    /// Most columns kept in the archive of columns the window left behind (16 bytes each);
    /// beyond it the tiles farthest from the window are dropped (counted by
    /// [`super::StackMapper::archive_cells`]). At least 1.
    pub archive_max_cells: usize,
    /// The sensor model.
    pub sensor: PrimeSenseHeight,
    /// Edge-preserving smoothing of depth images before everything else
    /// ([`crate::denoise`]): each pixel's depth becomes the mean over the neighbours on
    /// its own surface, so that a surface's points land in its own cells, not several
    /// cells before it (depth noise moves a point along its ray, which is nearly
    /// horizontal at range). An extension of paper 000; `None` maps the depths as
    /// measured.
    #[serde(with = "stride_core::serde_opt")]
    pub depth_smoothing: Option<DepthSmoothing>,
    /// Depth-edge (flying pixel) filter on depth images, the sensor front end that paper
    /// 000 assumes before the map ([`crate::input::EdgeFilter`]); `None` turns it off.
    #[serde(with = "stride_core::serde_opt")]
    pub edge_filter: Option<EdgeFilter>,
    /// Paper 000's median filter applied by [`crate::ElevationMapper::finished`] (hole filling,
    /// isolated-cell removal); `None` leaves the map as the filters left it.
    #[serde(with = "stride_core::serde_opt")]
    pub median_filter: Option<MedianFilter>,
}

impl Default for StackConfig {
    /// Paper 000's values: `V_i = 3`, `V_d = 2`, `V_t = 7`; 1 cm cells in a 4 x 4 m window;
    /// 2 cm voxels.
    fn default() -> Self {
        Self {
            resolution_m: 0.01,
            size_m: 4.0,
            voxel_height_m: 0.02,
            vitality_increase: 3,
            vitality_decrease: 2,
            vitality_threshold: 7,
            establish_smooth: true,
            step_support_fraction: 0.5,
            steep_push_sigmas: 2.0,
            visibility_check: true,
            visibility_bin_m: 0.01,
            see_through_check: true,
            lookahead_m: 1.2,
            recenter_threshold_m: 0.3,
            archive_max_cells: 8_000_000,
            sensor: PrimeSenseHeight::default(),
            depth_smoothing: Some(DepthSmoothing::default()),
            edge_filter: Some(EdgeFilter::default()),
            median_filter: Some(MedianFilter::default()),
        }
    }
}

impl StackConfig {
    /// Checks every parameter ([`super::StackMapper::new`] does): a window of 8 to
    /// [`crate::error::MAX_CELLS_PER_SIDE`] cells per side, positive voxel height and
    /// visibility bin, a depth range with `min < max`, an edge filter's angle within
    /// (0, 90) degrees, a depth smoothing's radius within 1 to 4 pixels and positive
    /// `sigmas`, a finite, non-negative steep push. Returns the window's cells per side.
    pub fn validate(&self) -> Result<usize, MappingError> {
        let cells = error::window_cells(
            self.resolution_m,
            self.size_m,
            self.lookahead_m,
            self.recenter_threshold_m,
        )?;
        error::positive("voxel_height_m", self.voxel_height_m)?;
        if !(0.0..=1.0).contains(&self.step_support_fraction) {
            return Err(MappingError::Parameter {
                name: "step_support_fraction",
                value: f64::from(self.step_support_fraction),
                reason: "must lie within [0, 1]",
            });
        }
        if !(self.steep_push_sigmas >= 0.0 && self.steep_push_sigmas.is_finite()) {
            return Err(MappingError::Parameter {
                name: "steep_push_sigmas",
                value: f64::from(self.steep_push_sigmas),
                reason: "must be finite and 0 or more",
            });
        }
        error::positive("visibility_bin_m", self.visibility_bin_m)?;
        if self.archive_max_cells == 0 {
            return Err(MappingError::Parameter {
                name: "archive_max_cells",
                value: 0.0,
                reason: "must be at least 1",
            });
        }
        error::depth_range(self.sensor.min_depth_m, self.sensor.max_depth_m)?;
        if let Some(e) = &self.edge_filter {
            e.validate()?;
        }
        if let Some(d) = &self.depth_smoothing {
            d.validate()?;
        }
        Ok(cells)
    }
}
