//! One measurement as the mappers' input stage hands it to a map: [`CellPoint`], packed into
//! 12 bytes because every frame makes about 300,000 of them.

/// A measurement assigned to a cell of a map window: the cell's storage index, where in the
/// cell it lies (or that it is a steep face's point), whether it comes from a smooth patch
/// of a depth image, the height (m, map frame) and its variance (m²). 12 bytes: the index
/// (below 2^24, the most cells a window has) shares a word with the position in the cell
/// and the smoothness flag.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CellPoint {
    /// Storage index in the low 24 bits, [`CellPoint::centrality`] times 126 in the next 7
    /// (127: [`CellPoint::face`]), [`CellPoint::smooth`] in the top bit.
    packed: u32,
    /// Height (m, map frame, up).
    pub z_m: f32,
    /// Height variance (m²).
    pub var_m2: f32,
}

impl CellPoint {
    /// A measurement of the cell with storage index `cell` (below 2^24), `centrality` in
    /// [0, 1] (stored to 1/126) or [`FACE`], from a smooth depth patch or not (`smooth`),
    /// height `z_m` (m) and variance `var_m2` (m²).
    #[inline]
    pub fn new(cell: u32, centrality: f32, smooth: bool, z_m: f32, var_m2: f32) -> Self {
        let q = if centrality < 0.0 {
            FACE_CODE
        } else {
            (centrality.min(1.0) * 126.0 + 0.5) as u32
        };
        Self {
            packed: (cell & 0x00ff_ffff) | (q << 24) | (u32::from(smooth) << 31),
            z_m,
            var_m2,
        }
    }

    /// True when the measurement comes from a pixel whose 5 x 5 neighbourhood of depths
    /// (missing returns left out) spans no jump (see `depth_pass`): it cannot be a mixed
    /// ("flying") pixel, which only occurs at a depth discontinuity. False for measurements
    /// that are not pixels, and when the mapper did not ask for the test.
    #[inline]
    pub fn smooth(&self) -> bool {
        self.packed >> 31 == 1
    }

    /// Storage index of the cell in the window.
    #[inline]
    pub fn cell(&self) -> u32 {
        self.packed & 0x00ff_ffff
    }

    /// Where in its cell the point lies: `1 - 2 (dx² + dy²)` with `dx, dy` its offsets from
    /// the cell's centre in cells, so 1 at the centre and 0 at a corner (to 1/126); 0 for a
    /// [`CellPoint::face`] point.
    #[inline]
    pub fn centrality(&self) -> f32 {
        // A table of `q / 126` (0 for the face code): the fusion reads this for every
        // point, and a division there cost more than the load.
        CENTRALITY
            .get(((self.packed >> 24) & 0x7f) as usize)
            .copied()
            .unwrap_or(0.0)
    }

    /// True for a point of a steep face moved behind it ([`crate::steep`]): a bound below
    /// the height of the cell it lands in, not a measurement of the cell's top.
    #[inline]
    pub fn face(&self) -> bool {
        (self.packed >> 24) & 0x7f == FACE_CODE
    }
}

/// The centrality given to [`CellPoint::new`] for a steep face's point ([`CellPoint::face`]).
pub const FACE: f32 = -1.0;

/// The packed code of [`FACE`].
const FACE_CODE: u32 = 127;

/// [`CellPoint::centrality`] by packed code: `q / 126`, and 0 for [`FACE_CODE`].
const CENTRALITY: [f32; 128] = {
    let mut t = [0.0; 128];
    let mut q = 0;
    while q < FACE_CODE as usize {
        t[q] = q as f32 / 126.0;
        q += 1;
    }
    t
};
