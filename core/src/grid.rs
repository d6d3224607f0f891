//! Regular 2-D grids over the world's x-y plane (z up): elevation maps, variance maps,
//! ground-truth terrain.
//!
//! Geometry is explicit: cell `[row, col]` has its centre at
//! `(x, y) = (origin_x + col * resolution, origin_y + row * resolution)` in the grid's frame
//! (stated by whoever owns the grid, usually the world frame, z up). Rows run along +y,
//! columns along +x. Storage is row-major.

/// Where a grid lies in its frame and how fine it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    /// x of the centre of cell `[0, 0]` (m).
    pub origin_x: f64,
    /// y of the centre of cell `[0, 0]` (m).
    pub origin_y: f64,
    /// Cell size (m).
    pub resolution: f64,
    /// Number of rows (along +y).
    pub rows: usize,
    /// Number of columns (along +x).
    pub cols: usize,
}

impl GridGeometry {
    /// A grid covering the rectangle `[x0, x1] x [y0, y1]` (m) with square cells of
    /// `resolution` (m); at least one cell per axis.
    pub fn covering(x0: f64, y0: f64, x1: f64, y1: f64, resolution: f64) -> Self {
        let cols = (((x1 - x0) / resolution).ceil() as usize).max(1);
        let rows = (((y1 - y0) / resolution).ceil() as usize).max(1);
        Self {
            origin_x: x0 + resolution / 2.0,
            origin_y: y0 + resolution / 2.0,
            resolution,
            rows,
            cols,
        }
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.rows * self.cols
    }

    /// True when the grid has no cell.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Centre `(x, y)` of cell `[row, col]` (m).
    pub fn center(&self, row: usize, col: usize) -> (f64, f64) {
        (
            self.origin_x + col as f64 * self.resolution,
            self.origin_y + row as f64 * self.resolution,
        )
    }

    /// Continuous cell coordinates `(row, col)` of a point: integers at cell centres.
    pub fn continuous(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (y - self.origin_y) / self.resolution,
            (x - self.origin_x) / self.resolution,
        )
    }

    /// The cell `[row, col]` containing `(x, y)`, or `None` outside the grid.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let (r, c) = self.continuous(x, y);
        let (r, c) = (r.round(), c.round());
        if r >= 0.0 && c >= 0.0 && (r as usize) < self.rows && (c as usize) < self.cols {
            Some((r as usize, c as usize))
        } else {
            None
        }
    }

    /// Row-major index of `[row, col]`, or `None` outside the grid.
    pub fn index(&self, row: usize, col: usize) -> Option<usize> {
        (row < self.rows && col < self.cols).then_some(row * self.cols + col)
    }

    /// x-y extent `(x_min, y_min, x_max, y_max)` of the cells' outer edges (m).
    pub fn extent(&self) -> (f64, f64, f64, f64) {
        let h = self.resolution / 2.0;
        (
            self.origin_x - h,
            self.origin_y - h,
            self.origin_x + (self.cols as f64 - 0.5) * self.resolution,
            self.origin_y + (self.rows as f64 - 0.5) * self.resolution,
        )
    }
}

/// A grid of values with its geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid<T> {
    /// Placement and size.
    pub geometry: GridGeometry,
    data: Vec<T>,
}

impl<T: Copy> Grid<T> {
    /// A grid with every cell set to `value`.
    pub fn filled(geometry: GridGeometry, value: T) -> Self {
        Self {
            geometry,
            data: vec![value; geometry.len()],
        }
    }

    /// Wraps row-major data; `None` if its length does not match the geometry.
    pub fn from_vec(geometry: GridGeometry, data: Vec<T>) -> Option<Self> {
        (data.len() == geometry.len()).then_some(Self { geometry, data })
    }

    /// The value of cell `[row, col]`, or `None` outside.
    pub fn get(&self, row: usize, col: usize) -> Option<T> {
        self.data.get(self.geometry.index(row, col)?).copied()
    }

    /// Mutable access to cell `[row, col]`, or `None` outside.
    pub fn get_mut(&mut self, row: usize, col: usize) -> Option<&mut T> {
        let i = self.geometry.index(row, col)?;
        self.data.get_mut(i)
    }

    /// The value of the cell containing `(x, y)`, or `None` outside.
    pub fn at(&self, x: f64, y: f64) -> Option<T> {
        let (r, c) = self.geometry.cell_of(x, y)?;
        self.get(r, c)
    }

    /// All values, row-major.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    /// All values, row-major, mutable.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }
}

impl Grid<f32> {
    /// Bilinear interpolation between the four cell centres around `(x, y)`; points between
    /// the outermost centres and the grid's edge take the nearest edge value. `None` outside
    /// the grid or when a needed cell is NaN.
    pub fn sample_bilinear(&self, x: f64, y: f64) -> Option<f32> {
        let g = &self.geometry;
        let (r, c) = g.continuous(x, y);
        if r < -0.5 || c < -0.5 || r > g.rows as f64 - 0.5 || c > g.cols as f64 - 0.5 {
            return None;
        }
        let r = r.clamp(0.0, (g.rows - 1) as f64);
        let c = c.clamp(0.0, (g.cols - 1) as f64);
        let (r0, c0) = (r.floor() as usize, c.floor() as usize);
        let (r1, c1) = ((r0 + 1).min(g.rows - 1), (c0 + 1).min(g.cols - 1));
        let (fr, fc) = ((r - r0 as f64) as f32, (c - c0 as f64) as f32);
        let v00 = self.get(r0, c0)?;
        let v01 = self.get(r0, c1)?;
        let v10 = self.get(r1, c0)?;
        let v11 = self.get(r1, c1)?;
        let v = (v00 * (1.0 - fc) + v01 * fc) * (1.0 - fr) + (v10 * (1.0 - fc) + v11 * fc) * fr;
        (!v.is_nan()).then_some(v)
    }

    /// Smallest and largest non-NaN values, or `None` if every cell is NaN.
    pub fn min_max(&self) -> Option<(f32, f32)> {
        self.data
            .iter()
            .filter(|v| !v.is_nan())
            .fold(None, |acc, &v| match acc {
                None => Some((v, v)),
                Some((a, b)) => Some((a.min(v), b.max(v))),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geometry_maps_points_to_cells_and_back() {
        let g = GridGeometry::covering(-1.0, -2.0, 1.0, 2.0, 0.5);
        assert_eq!((g.rows, g.cols), (8, 4));
        assert_eq!(g.center(0, 0), (-0.75, -1.75));
        assert_eq!(g.cell_of(-0.99, -1.99), Some((0, 0)));
        assert_eq!(g.cell_of(0.99, 1.99), Some((7, 3)));
        assert_eq!(g.cell_of(1.01, 0.0), None);
        assert_eq!(g.extent(), (-1.0, -2.0, 1.0, 2.0));
    }

    #[test]
    fn bilinear_sampling() {
        let g = GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 1.0,
            rows: 2,
            cols: 2,
        };
        let grid = Grid::from_vec(g, vec![0.0f32, 1.0, 2.0, 3.0]).unwrap();
        assert_eq!(grid.sample_bilinear(0.5, 0.5), Some(1.5));
        assert_eq!(grid.sample_bilinear(1.4, 0.0), Some(1.0));
        assert_eq!(grid.sample_bilinear(2.0, 0.0), None);
        let mut holes = grid.clone();
        *holes.get_mut(0, 1).unwrap() = f32::NAN;
        assert_eq!(holes.sample_bilinear(0.5, 0.5), None);
        assert_eq!(holes.min_max(), Some((0.0, 3.0)));
    }
}
