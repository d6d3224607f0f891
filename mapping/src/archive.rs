//! The columns a moving window left behind: compact tiles of cells in world cell
//! coordinates, with a cap on how many cells they hold.
//!
//! A walking robot's map window (4 x 4 m) moves with it; the columns it leaves are archived
//! here so that the exported map keeps them and the window can resume them when the robot
//! comes back ([`crate::stack::StackMapper`]). Cells are stored in square tiles of
//! [`TILE`] x [`TILE`] cells, 16 bytes per cell (a hash map of single cells took about 40),
//! and only tiles that hold a cell exist. When the archive holds more than its cap, the tiles
//! farthest from the robot are dropped whole (counted), so memory stays bounded however
//! long the walk: at the default cap of 8 million cells (800 m² at 1 cm), 128 MB when the
//! tiles are full (tiles at the edge of a walk's swath are partly empty).

use std::collections::HashMap;

/// Cells per side of a tile.
pub const TILE: i64 = 64;

/// An archived column: what the map exports for it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Archived {
    /// Height (m); NaN marks an empty slot of a tile.
    pub(crate) h: f32,
    /// Height variance (m²).
    pub(crate) var: f32,
    /// Frames that updated the column.
    pub(crate) updates: u32,
    /// Vitality counter.
    pub(crate) vitality: u8,
    /// The estimate rests on steep faces' points alone (`Cell::bound_only`).
    pub(crate) bound_only: bool,
}

// Still 16 bytes a cell (the flag sits in the vitality's padding).
const _: () = assert!(std::mem::size_of::<Archived>() == 16);

impl Archived {
    const EMPTY: Self = Self {
        h: f32::NAN,
        var: f32::NAN,
        updates: 0,
        vitality: 0,
        bound_only: false,
    };
}

/// One tile: `TILE * TILE` cells, row-major, and how many of them are filled.
#[derive(Debug, Clone)]
struct Tile {
    cells: Vec<Archived>,
    filled: usize,
}

/// The archive: tiles by tile coordinates (`cell.div_euclid(TILE)`).
#[derive(Debug, Clone, Default)]
pub(crate) struct Archive {
    tiles: HashMap<(i64, i64), Tile>,
    cells: usize,
    /// Cells dropped with their tiles to keep the cap.
    dropped: usize,
    /// Cells taken back out (the window came back over them).
    taken: usize,
}

/// The tile of a cell `(row, col)` and the cell's slot in it.
fn locate(cell: (i64, i64)) -> ((i64, i64), usize) {
    let key = (cell.0.div_euclid(TILE), cell.1.div_euclid(TILE));
    let slot = cell.0.rem_euclid(TILE) * TILE + cell.1.rem_euclid(TILE);
    (key, slot as usize)
}

impl Archive {
    /// Archives a column (replacing what was there).
    pub(crate) fn insert(&mut self, cell: (i64, i64), a: Archived) {
        let (key, slot) = locate(cell);
        let tile = self.tiles.entry(key).or_insert_with(|| Tile {
            cells: vec![Archived::EMPTY; (TILE * TILE) as usize],
            filled: 0,
        });
        if let Some(c) = tile.cells.get_mut(slot) {
            if c.h.is_nan() {
                tile.filled += 1;
                self.cells += 1;
            }
            *c = a;
        }
    }

    /// Takes a column out of the archive.
    pub(crate) fn remove(&mut self, cell: (i64, i64)) -> Option<Archived> {
        let (key, slot) = locate(cell);
        let tile = self.tiles.get_mut(&key)?;
        let c = tile.cells.get_mut(slot)?;
        if c.h.is_nan() {
            return None;
        }
        let out = std::mem::replace(c, Archived::EMPTY);
        tile.filled -= 1;
        self.cells -= 1;
        self.taken += 1;
        if tile.filled == 0 {
            self.tiles.remove(&key);
        }
        Some(out)
    }

    /// True when no column is archived.
    pub(crate) fn is_empty(&self) -> bool {
        self.cells == 0
    }

    /// Archived columns.
    pub(crate) fn len(&self) -> usize {
        self.cells
    }

    /// Columns dropped so far to keep the cap.
    pub(crate) fn dropped(&self) -> usize {
        self.dropped
    }

    /// Columns taken back out so far ([`Archive::remove`]).
    pub(crate) fn taken(&self) -> usize {
        self.taken
    }

    /// Every archived column with its world cell `(row, col)`.
    pub(crate) fn iter(&self) -> impl Iterator<Item = ((i64, i64), &Archived)> + Clone + '_ {
        self.tiles.iter().flat_map(|(&(tr, tc), tile)| {
            tile.cells
                .iter()
                .enumerate()
                .filter(|(_, a)| !a.h.is_nan())
                .map(move |(i, a)| {
                    let i = i as i64;
                    ((tr * TILE + i / TILE, tc * TILE + i % TILE), a)
                })
        })
    }

    /// Heap bytes held.
    pub(crate) fn memory_bytes(&self) -> usize {
        let per_tile = (TILE * TILE) as usize * std::mem::size_of::<Archived>()
            + std::mem::size_of::<((i64, i64), Tile)>();
        self.tiles.capacity() * std::mem::size_of::<((i64, i64), Tile)>()
            + self.tiles.len() * per_tile
    }

    /// Drops the tiles farthest from world cell `near` until at most `max_cells` columns
    /// remain; returns the columns dropped now.
    pub(crate) fn cap(&mut self, max_cells: usize, near: (i64, i64)) -> usize {
        if self.cells <= max_cells {
            return 0;
        }
        let centre = (near.0 as f64 / TILE as f64, near.1 as f64 / TILE as f64);
        let mut by_distance: Vec<((i64, i64), f64)> = self
            .tiles
            .keys()
            .map(|&(r, c)| {
                let (dr, dc) = (r as f64 + 0.5 - centre.0, c as f64 + 0.5 - centre.1);
                ((r, c), dr.hypot(dc))
            })
            .collect();
        // Farthest first; ties by tile coordinates, so the result is repeatable.
        by_distance.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        let mut dropped = 0;
        for (key, _) in by_distance {
            if self.cells <= max_cells {
                break;
            }
            if let Some(t) = self.tiles.remove(&key) {
                self.cells -= t.filled;
                dropped += t.filled;
            }
        }
        self.dropped += dropped;
        dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(h: f32) -> Archived {
        Archived {
            h,
            var: 1e-4,
            updates: 3,
            vitality: 9,
            bound_only: false,
        }
    }

    #[test]
    fn cells_go_in_and_out_across_tile_borders_and_negative_coordinates() {
        let mut a = Archive::default();
        let cells = [(0, 0), (-1, -1), (63, 64), (-65, 130), (1000, -1000)];
        for (i, &c) in cells.iter().enumerate() {
            a.insert(c, cell(i as f32));
        }
        a.insert((0, 0), cell(7.0));
        assert_eq!(a.len(), cells.len());
        let mut seen: Vec<((i64, i64), f32)> = a.iter().map(|(c, x)| (c, x.h)).collect();
        seen.sort_by_key(|x| x.0);
        let mut want: Vec<((i64, i64), f32)> = cells
            .iter()
            .enumerate()
            .map(|(i, &c)| (c, if i == 0 { 7.0 } else { i as f32 }))
            .collect();
        want.sort_by_key(|x| x.0);
        assert_eq!(seen, want);
        assert_eq!(a.remove((63, 64)).map(|x| x.h), Some(2.0));
        assert_eq!(a.remove((63, 64)), None);
        assert_eq!(a.len(), cells.len() - 1);
        for &c in &cells {
            a.remove(c);
        }
        assert!(a.is_empty() && a.tiles.is_empty());
    }

    #[test]
    fn the_cap_drops_the_farthest_tiles_first() {
        let mut a = Archive::default();
        // A 10-tile strip of full tiles along the columns.
        for c in 0..10 * TILE {
            for r in 0..TILE {
                a.insert((r, c), cell(0.0));
            }
        }
        let per_tile = (TILE * TILE) as usize;
        assert_eq!(a.cap(10 * per_tile, (0, 0)), 0);
        // Near the strip's start: the 6 far tiles go.
        assert_eq!(a.cap(4 * per_tile, (0, 0)), 6 * per_tile);
        assert_eq!((a.len(), a.dropped()), (4 * per_tile, 6 * per_tile));
        assert!(a.iter().all(|((_, c), _)| c < 4 * TILE));
    }
}
