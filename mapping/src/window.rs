//! A robot-centred window of map cells that moves without copying.
//!
//! Cells have world-fixed integer coordinates `(row, col)`: cell `(r, c)` covers
//! `x in [(c - 0.5) res, (c + 0.5) res)`, `y in [(r - 0.5) res, (r + 0.5) res)` in the map
//! frame (z up). The window holds `size x size` of them around a centre; storage is a
//! circular buffer indexed by `(r mod size, c mod size)`, as grid_map does, so moving the
//! window only resets the cells that leave it (after handing them to the caller).

/// The integer cell coordinate of `v` (m) for cells of `1 / inv` metres centred on
/// multiples of the cell size: `floor(v inv + 0.5)`, so cell `k` covers `[k - 0.5, k + 0.5)`.
#[inline]
pub(crate) fn cell_coord(v: f64, inv: f64) -> i64 {
    (v * inv + 0.5).floor() as i64
}

/// Where map-frame points fall in a [`Window`]'s storage: the cell's storage index and its
/// band (storage rows split into bands of equal height), without a division per point.
/// A snapshot of the window's placement: valid until the window moves.
#[derive(Debug, Clone, Copy)]
pub struct CellBinner {
    /// Cells per metre.
    inv: f64,
    /// World cell row and column of the window's lowest corner cell.
    or: i64,
    oc: i64,
    /// Side in cells.
    n: i64,
    /// Storage row and column of the lowest corner cell.
    mr: i64,
    mc: i64,
    /// `floor(r / rows_per_band)` is `(r * magic) >> 32` (exact for `r < 2^32 / rows_per_band`).
    magic: u64,
    /// `1 / rows_per_band`.
    inv_rows: f32,
}

impl CellBinner {
    /// Storage index and band of the cell containing map-frame `(x, y)` (m), or `None`
    /// outside the window. Cell `k` covers `[k - 0.5, k + 0.5)` cells, as [`Window::world_cell`].
    #[inline]
    pub fn locate(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let r = cell_coord(y, self.inv) - self.or;
        let c = cell_coord(x, self.inv) - self.oc;
        if r < 0 || c < 0 || r >= self.n || c >= self.n {
            return None;
        }
        Some(self.storage(r, c))
    }

    /// Map-frame `(x, y)` (m) of the window's lowest corner (the lower edges of its lowest
    /// row and column): a point's window-relative cell column is `floor((x - x0) / res)`.
    pub fn corner_m(&self) -> (f64, f64) {
        (
            (self.oc as f64 - 0.5) / self.inv,
            (self.or as f64 - 0.5) / self.inv,
        )
    }

    /// Cells per metre.
    pub fn cells_per_m(&self) -> f64 {
        self.inv
    }

    /// Side of the window in cells.
    pub fn side(&self) -> usize {
        self.n as usize
    }

    /// [`CellBinner::locate`]'s storage index and band in f32 arithmetic, for loops the
    /// compiler vectorises: for window-relative fractional cell coordinates
    /// `0 <= row, col < side`, the storage index and the band as floats that hold exact
    /// integers (a window has at most 4096 x 4096 = 2^24 cells; the band is
    /// `floor((r + 0.5) / rows_per_band)`, half a row away from any rounding). Other inputs
    /// give meaningless numbers.
    #[inline(always)]
    pub fn storage_f32(&self, row: f32, col: f32) -> (f32, f32) {
        let n = self.n as f32;
        let wrap = |x: f32| if x >= n { x - n } else { x };
        let sr = wrap(row.floor() + self.mr as f32);
        let sc = wrap(col.floor() + self.mc as f32);
        (sr * n + sc, ((sr + 0.5) * self.inv_rows).floor())
    }

    /// Where map-frame `(x, y)` (m) lies in its cell: [`crate::input::CellPoint::centrality`].
    pub fn centrality(&self, x: f64, y: f64) -> f32 {
        // The fraction in f64 (world coordinates can be large), the formula in f32.
        let frac = |v: f64| {
            let c = v * self.inv + 0.5;
            (c - c.floor()) as f32
        };
        centrality(frac(x), frac(y))
    }

    /// Storage index and band of window-relative row `r` and column `c` (both in `0..n`).
    #[inline(always)]
    fn storage(&self, r: i64, c: i64) -> (usize, usize) {
        let (mut sr, mut sc) = (self.mr + r, self.mc + c);
        if sr >= self.n {
            sr -= self.n;
        }
        if sc >= self.n {
            sc -= self.n;
        }
        (
            (sr * self.n + sc) as usize,
            ((sr as u64).wrapping_mul(self.magic) >> 32) as usize,
        )
    }
}

/// [`crate::input::CellPoint::centrality`] of a point at fractional cell coordinates
/// `(col, row)`, where cell `k` spans `[k, k + 1)`: `1 - 2 (dx² + dy²)` with `dx, dy` the
/// offsets from the cell's centre.
#[inline(always)]
pub(crate) fn centrality(col: f32, row: f32) -> f32 {
    let (dx, dy) = (col - col.floor() - 0.5, row - row.floor() - 0.5);
    1.0 - 2.0 * (dx * dx + dy * dy)
}

/// Circular-buffer storage of a square window of cells.
#[derive(Debug, Clone)]
pub struct Window<T> {
    size: usize,
    resolution: f64,
    /// World cell coordinates of the window's lowest row and column.
    origin: (i64, i64),
    cells: Vec<T>,
    /// Whether [`Window::follow`] has placed the window yet.
    placed: bool,
    /// Storage indices of the cells that entered the window in the last move.
    entered: Vec<usize>,
}

impl<T: Clone + Default> Window<T> {
    /// A window of `size x size` cells of `resolution` metres, its lowest corner cell at
    /// world cell `origin` (row, col).
    pub fn new(size: usize, resolution: f64, origin: (i64, i64)) -> Self {
        Self {
            size: size.max(1),
            resolution,
            origin,
            cells: vec![T::default(); size.max(1) * size.max(1)],
            placed: false,
            entered: Vec::new(),
        }
    }

    /// Side in cells.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Cell size (m).
    pub fn resolution(&self) -> f64 {
        self.resolution
    }

    /// World cell coordinates (row, col) of the lowest corner cell.
    pub fn origin(&self) -> (i64, i64) {
        self.origin
    }

    /// The world cell (row, col) containing map-frame `(x, y)`.
    pub fn world_cell(&self, x: f64, y: f64) -> (i64, i64) {
        let inv = 1.0 / self.resolution;
        (cell_coord(y, inv), cell_coord(x, inv))
    }

    /// Centre (x, y) of a world cell (m).
    pub fn cell_center(&self, cell: (i64, i64)) -> (f64, f64) {
        (
            cell.1 as f64 * self.resolution,
            cell.0 as f64 * self.resolution,
        )
    }

    /// True when the world cell lies inside the window.
    pub fn contains(&self, cell: (i64, i64)) -> bool {
        let (r, c) = (cell.0 - self.origin.0, cell.1 - self.origin.1);
        r >= 0 && c >= 0 && (r as usize) < self.size && (c as usize) < self.size
    }

    /// Storage index of a world cell inside the window.
    pub fn index(&self, cell: (i64, i64)) -> Option<usize> {
        self.contains(cell).then(|| {
            let n = self.size as i64;
            (cell.0.rem_euclid(n) * n + cell.1.rem_euclid(n)) as usize
        })
    }

    /// The world cell stored at a storage index.
    pub fn cell_of_index(&self, index: usize) -> (i64, i64) {
        let n = self.size as i64;
        let (sr, sc) = ((index / self.size) as i64, (index % self.size) as i64);
        // The unique world row r with r mod n = sr inside [origin, origin + n).
        let r = self.origin.0 + (sr - self.origin.0).rem_euclid(n);
        let c = self.origin.1 + (sc - self.origin.1).rem_euclid(n);
        (r, c)
    }

    /// A fast indexer for many points: storage index of the cell containing map-frame
    /// `(x, y)` (m), or `None` outside the window (no integer division per point).
    pub fn indexer(&self) -> impl Fn(f64, f64) -> Option<usize> + Sync + Send + Copy + 'static {
        let ix = self.band_indexer(1);
        move |x, y| ix(x, y).map(|(i, _)| i)
    }

    /// Like [`Window::indexer`], also giving the band of the index when the storage rows
    /// are split into bands of `rows_per_band` rows: `(index, index / size / rows_per_band)`.
    pub fn band_indexer(
        &self,
        rows_per_band: usize,
    ) -> impl Fn(f64, f64) -> Option<(usize, usize)> + Sync + Send + Copy + 'static {
        let b = self.binner(rows_per_band);
        move |x: f64, y: f64| b.locate(x, y)
    }

    /// The window's current storage layout as plain numbers, for binning many points into
    /// storage cells and bands of `rows_per_band` storage rows (see [`CellBinner`]).
    pub fn binner(&self, rows_per_band: usize) -> CellBinner {
        let n = self.size as i64;
        let (or, oc) = self.origin;
        let d = rows_per_band.max(1) as u64;
        CellBinner {
            inv: 1.0 / self.resolution,
            or,
            oc,
            n,
            mr: or.rem_euclid(n),
            mc: oc.rem_euclid(n),
            magic: (1u64 << 32).div_ceil(d),
            inv_rows: 1.0 / d as f32,
        }
    }

    /// A fast inverse of storage indices: the map-frame centre `(x, y)` (m) of the cell
    /// stored at an index (no integer division by a variable per call beyond one).
    pub fn locator(&self) -> impl Fn(usize) -> (f64, f64) + Sync + Send + Copy + 'static {
        let n = self.size as i64;
        let (or, oc) = self.origin;
        let (mr, mc) = (or.rem_euclid(n), oc.rem_euclid(n));
        let res = self.resolution;
        let size = self.size;
        move |index: usize| {
            let (sr, sc) = ((index / size) as i64, (index % size) as i64);
            let (mut r, mut c) = (sr - mr, sc - mc);
            if r < 0 {
                r += n;
            }
            if c < 0 {
                c += n;
            }
            ((oc + c) as f64 * res, (or + r) as f64 * res)
        }
    }

    /// The cell at a world cell, if inside.
    pub fn get(&self, cell: (i64, i64)) -> Option<&T> {
        self.cells.get(self.index(cell)?)
    }

    /// Mutable cell at a world cell, if inside.
    pub fn get_mut(&mut self, cell: (i64, i64)) -> Option<&mut T> {
        let i = self.index(cell)?;
        self.cells.get_mut(i)
    }

    /// Bytes held by the cells.
    pub fn memory_bytes(&self) -> usize {
        self.cells.capacity() * std::mem::size_of::<T>()
    }

    /// All cells in storage order.
    pub fn cells(&self) -> &[T] {
        &self.cells
    }

    /// All cells in storage order, mutable.
    pub fn cells_mut(&mut self) -> &mut [T] {
        &mut self.cells
    }

    /// Moves the window so that its lowest corner cell is `origin`. Every cell that leaves
    /// the window is passed to `evict` with its world coordinates and then reset.
    pub fn move_to(&mut self, origin: (i64, i64), mut evict: impl FnMut((i64, i64), &T)) {
        if origin == self.origin {
            return;
        }
        let n = self.size as i64;
        self.entered.clear();
        for i in 0..self.cells.len() {
            let cell = self.cell_of_index(i);
            let (r, c) = (cell.0 - origin.0, cell.1 - origin.1);
            let stays = r >= 0 && c >= 0 && r < n && c < n;
            if !stays {
                if let Some(v) = self.cells.get_mut(i) {
                    evict(cell, v);
                    *v = T::default();
                }
                self.entered.push(i);
            }
        }
        self.origin = origin;
    }

    /// Storage indices of the cells that entered the window in the last move (their
    /// storage was reset; [`Window::cell_of_index`] gives their world cells).
    pub fn entered(&self) -> &[usize] {
        &self.entered
    }

    /// Keeps the window ahead of a sensor: its centre belongs `lookahead_m` (m) ahead of
    /// `map_from_sensor` along the sensor's horizontal viewing direction (its z axis
    /// projected on the map's x-y plane). The window moves there on the first call and
    /// whenever that point is more than `threshold_m` (m) from its centre; the cells that
    /// leave go to `evict` ([`Window::move_to`]). Returns whether it moved.
    pub fn follow(
        &mut self,
        map_from_sensor: &nalgebra::Isometry3<f64>,
        lookahead_m: f64,
        threshold_m: f64,
        evict: impl FnMut((i64, i64), &T),
    ) -> bool {
        let fwd = map_from_sensor.rotation * nalgebra::Vector3::z();
        let horiz = nalgebra::Vector2::new(fwd.x, fwd.y);
        let dir = if horiz.norm() > 1e-6 {
            horiz.normalize()
        } else {
            nalgebra::Vector2::zeros()
        };
        let t = map_from_sensor.translation.vector;
        let want = nalgebra::Vector2::new(t.x, t.y) + dir * lookahead_m;
        let n = self.size as i64;
        let (r0, c0) = self.origin;
        let (cx, cy) = self.cell_center((r0 + n / 2, c0 + n / 2));
        if self.placed && (nalgebra::Vector2::new(cx, cy) - want).norm() <= threshold_m {
            return false;
        }
        let (wr, wc) = self.world_cell(want.x, want.y);
        self.move_to((wr - n / 2, wc - n / 2), evict);
        self.placed = true;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexes_wrap_and_moving_keeps_overlapping_cells() {
        let mut w: Window<i32> = Window::new(4, 0.5, (0, 0));
        for r in 0..4 {
            for c in 0..4 {
                *w.get_mut((r, c)).unwrap() = (r * 10 + c) as i32;
            }
        }
        assert_eq!(w.world_cell(1.24, 0.76), (2, 2));
        assert_eq!(w.cell_center((2, 3)), (1.5, 1.0));
        assert!(w.get((4, 0)).is_none());
        for i in 0..16 {
            assert_eq!(w.index(w.cell_of_index(i)), Some(i));
        }
        {
            let ix = w.indexer();
            assert_eq!(ix(1.24, 0.76), w.index((2, 2)));
            assert_eq!(ix(5.0, 0.0), None);
            let bix = w.band_indexer(3);
            for r in 0..4 {
                for c in 0..4 {
                    let (x, y) = w.cell_center((r, c));
                    let (i, b) = bix(x, y).unwrap();
                    assert_eq!((Some(i), b), (w.index((r, c)), i / 4 / 3));
                }
            }
        }
        let mut evicted = Vec::new();
        w.move_to((1, 2), |cell, v| evicted.push((cell, *v)));
        // Rows 0 and columns 0-1 left the window: 4 + 2 * 3 = 10 cells.
        assert_eq!(evicted.len(), 10);
        assert!(evicted.contains(&((0, 3), 3)));
        assert_eq!(
            w.get((3, 3)),
            Some(&33),
            "overlapping cells keep their values"
        );
        assert_eq!(w.get((4, 5)), Some(&0), "new cells start empty");
        assert_eq!(w.get((1, 1)), None);
        for i in 0..16 {
            assert_eq!(w.index(w.cell_of_index(i)), Some(i));
        }
        let ix = w.indexer();
        let loc = w.locator();
        for r in 1..5 {
            for c in 2..6 {
                let (x, y) = w.cell_center((r, c));
                assert_eq!(ix(x, y), w.index((r, c)));
                assert_eq!(loc(w.index((r, c)).unwrap()), (x, y));
            }
        }
    }
}
