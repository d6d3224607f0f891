//! The project's grid format: one NumPy `.npy` file per layer (float32, row-major, NaN where
//! unknown) and a JSON header `grid.json` beside it:
//!
//! ```json
//! {"origin_x": -2.0, "origin_y": -2.0, "resolution": 0.01, "rows": 400, "cols": 400,
//!  "row_axis": "+y", "col_axis": "+x", "frame": "world", "z": "up"}
//! ```
//!
//! `origin_x`, `origin_y` are the world coordinates (m) of the *centre* of cell `[0, 0]`;
//! row `r` lies at `y = origin_y + r * resolution`, column `c` at `x = origin_x + c *
//! resolution`. Values are heights along the world's z axis (up), in metres, or whatever the
//! layer's name says (variance in m², counts). In NumPy: `np.load("elevation.npy")` with
//! `origin="lower"` in `imshow` to see +y upwards.

use crate::error::DatasetError;
use serde::{Deserialize, Serialize};
use std::path::Path;
use stride_core::grid::{Grid, GridGeometry};
use stride_output::fs::write_atomic;

/// The JSON header of a grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridHeader {
    /// World x of the centre of cell [0, 0] (m).
    pub origin_x: f64,
    /// World y of the centre of cell [0, 0] (m).
    pub origin_y: f64,
    /// Cell size (m).
    pub resolution: f64,
    /// Rows (along +y).
    pub rows: usize,
    /// Columns (along +x).
    pub cols: usize,
    /// Direction of increasing row index: always `"+y"`.
    pub row_axis: String,
    /// Direction of increasing column index: always `"+x"`.
    pub col_axis: String,
    /// The frame of x, y and the values: `"world"`.
    pub frame: String,
    /// Direction of the value axis: `"up"`.
    #[serde(default = "up")]
    pub z: String,
}

fn up() -> String {
    "up".to_owned()
}

impl GridHeader {
    /// The header of a world-frame, z-up grid with this geometry.
    pub fn world(g: &GridGeometry) -> Self {
        Self {
            origin_x: g.origin_x,
            origin_y: g.origin_y,
            resolution: g.resolution,
            rows: g.rows,
            cols: g.cols,
            row_axis: "+y".into(),
            col_axis: "+x".into(),
            frame: "world".into(),
            z: up(),
        }
    }

    /// The geometry it describes.
    pub fn geometry(&self) -> GridGeometry {
        GridGeometry {
            origin_x: self.origin_x,
            origin_y: self.origin_y,
            resolution: self.resolution,
            rows: self.rows,
            cols: self.cols,
        }
    }
}

/// Encodes a float32 array of shape `(rows, cols)` as `.npy` (version 1.0) bytes.
pub fn encode_npy_f32(rows: usize, cols: usize, data: &[f32]) -> Vec<u8> {
    let mut header =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // Magic (6) + version (2) + header length (2) + header, padded to a multiple of 64.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 4);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Decodes a 2-D `.npy` array of little-endian float32 or float64 (C order) into
/// `(rows, cols, data)`.
pub fn decode_npy_f32(bytes: &[u8], path: &Path) -> Result<(usize, usize, Vec<f32>), DatasetError> {
    let bad = |m: &str| DatasetError::invalid(path, format!("not a usable .npy array: {m}"));
    if bytes.len() < 10 || !bytes.starts_with(b"\x93NUMPY") {
        return Err(bad("missing the NumPy magic"));
    }
    let major = bytes.get(6).copied().unwrap_or(0);
    let (hlen, start) = match major {
        1 => {
            let b = bytes.get(8..10).ok_or_else(|| bad("truncated header"))?;
            (usize::from(u16::from_le_bytes([b[0], b[1]])), 10)
        }
        2 | 3 => {
            let b = bytes.get(8..12).ok_or_else(|| bad("truncated header"))?;
            (u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize, 12)
        }
        _ => return Err(bad("unknown version")),
    };
    let body_start = start + hlen; // hlen < 2^32: no overflow on 64-bit
    let header = bytes
        .get(start..body_start)
        .ok_or_else(|| bad("truncated header"))?;
    let header = std::str::from_utf8(header).map_err(|_| bad("header is not text"))?;
    let word_size = if header.contains("'<f4'") {
        4
    } else if header.contains("'<f8'") {
        8
    } else {
        return Err(bad("dtype must be little-endian float32 or float64"));
    };
    if header.contains("'fortran_order': True") {
        return Err(bad("Fortran order is not supported"));
    }
    let shape = header
        .split("'shape':")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .map(|s| s.trim().trim_start_matches('('))
        .ok_or_else(|| bad("no shape"))?;
    let dims: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().map_err(|_| bad("shape is not integers")))
        .collect::<Result<_, _>>()?;
    let [rows, cols] = dims.as_slice() else {
        return Err(bad("the array must be 2-D"));
    };
    let body = bytes.get(body_start..).unwrap_or(&[]);
    let expected = rows
        .checked_mul(*cols)
        .and_then(|n| n.checked_mul(word_size))
        .ok_or_else(|| bad(&format!("shape ({rows}, {cols}) is too large")))?;
    if body.len() != expected {
        return Err(bad(&format!(
            "expected {expected} data bytes for shape ({rows}, {cols}), found {}",
            body.len()
        )));
    }
    let data = if word_size == 4 {
        body.chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else {
        body.chunks_exact(8)
            .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]) as f32)
            .collect()
    };
    Ok((*rows, *cols, data))
}

/// Writes one layer as `.npy` (atomically).
pub fn write_layer(path: &Path, grid: &Grid<f32>) -> Result<(), DatasetError> {
    let g = grid.geometry;
    write_atomic(path, &encode_npy_f32(g.rows, g.cols, grid.as_slice()))
        .map_err(|e| DatasetError::io(path, e))
}

/// Writes the JSON header (atomically).
pub fn write_header(path: &Path, geometry: &GridGeometry) -> Result<(), DatasetError> {
    let text = serde_json::to_string_pretty(&GridHeader::world(geometry)).unwrap_or_default();
    write_atomic(path, text.as_bytes()).map_err(|e| DatasetError::io(path, e))
}

/// Parses a grid header (`grid.json`); `path` is only used in messages. Only `+y` rows and
/// `+x` columns, a positive resolution and a finite origin are accepted.
pub fn parse_grid_header(text: &str, path: &Path) -> Result<GridHeader, DatasetError> {
    let h: GridHeader = serde_json::from_str(text)
        .map_err(|e| DatasetError::parse(path, e.line(), format!("invalid grid header: {e}")))?;
    if h.row_axis != "+y" || h.col_axis != "+x" {
        return Err(DatasetError::invalid(
            path,
            "only row_axis \"+y\" and col_axis \"+x\" are supported",
        ));
    }
    if !(h.resolution.is_finite() && h.resolution > 0.0) {
        return Err(DatasetError::invalid(
            path,
            format!("resolution {} must be positive", h.resolution),
        ));
    }
    if !(h.origin_x.is_finite() && h.origin_y.is_finite()) {
        return Err(DatasetError::invalid(path, "the origin must be finite"));
    }
    Ok(h)
}

/// Reads a layer and its header: `header` defaults to the `.json` with the layer's stem
/// (`terrain.npy` -> `terrain.json`), else `grid.json` in the same folder.
pub fn read_grid(npy: &Path, header: Option<&Path>) -> Result<Grid<f32>, DatasetError> {
    // The layer first: a missing .npy is the error to report, not its missing header.
    if !npy.is_file() {
        return Err(DatasetError::io(
            npy,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    let header_path = match header {
        Some(h) => h.to_path_buf(),
        None => {
            let same_stem = npy.with_extension("json");
            if same_stem.is_file() {
                same_stem
            } else {
                npy.with_file_name("grid.json")
            }
        }
    };
    let text = crate::text::read_text(&header_path)?;
    let h = parse_grid_header(&text, &header_path)?;
    let bytes = std::fs::read(npy).map_err(|e| DatasetError::io(npy, e))?;
    let (rows, cols, data) = decode_npy_f32(&bytes, npy)?;
    if (rows, cols) != (h.rows, h.cols) {
        return Err(DatasetError::invalid(
            npy,
            format!(
                "array is {rows}x{cols} but {} says {}x{}",
                header_path.display(),
                h.rows,
                h.cols
            ),
        ));
    }
    Grid::from_vec(h.geometry(), data).ok_or_else(|| DatasetError::invalid(npy, "size mismatch"))
}

/// A colour-relief preview of an elevation grid as PNG bytes: viridis over the height range,
/// shaded by a light from the north-west, NaN cells light grey, +y up (north at the top),
/// one pixel per cell (downsampled by an integer factor to at most `max_side` pixels).
pub fn relief_png(grid: &Grid<f32>, max_side: usize) -> Result<Vec<u8>, String> {
    let g = grid.geometry;
    let (step, _) = preview_geometry(grid, max_side);
    let (h, w) = (g.rows.div_ceil(step), g.cols.div_ceil(step));
    let (lo, hi) = grid.min_max().unwrap_or((0.0, 1.0));
    let span = f64::from((hi - lo).max(1e-6));
    let res = g.resolution * step as f64;
    let at = |r: usize, c: usize| {
        grid.get(r.min(g.rows - 1), c.min(g.cols - 1))
            .map(f64::from)
    };
    let mut px = Vec::with_capacity(w * h);
    for y in 0..h {
        let r = (h - 1 - y) * step; // image top = +y edge
        for x in 0..w {
            let c = x * step;
            let v = at(r, c).unwrap_or(f64::NAN);
            if v.is_nan() {
                px.push([225u8, 225, 225]);
                continue;
            }
            let dzdx = (at(r, c + step).unwrap_or(v) - at(r, c.saturating_sub(step)).unwrap_or(v))
                / (2.0 * res);
            let dzdy = (at(r + step, c).unwrap_or(v) - at(r.saturating_sub(step), c).unwrap_or(v))
                / (2.0 * res);
            let dzdx = if dzdx.is_nan() { 0.0 } else { dzdx };
            let dzdy = if dzdy.is_nan() { 0.0 } else { dzdy };
            let n = (dzdx * dzdx + dzdy * dzdy + 1.0).sqrt();
            let shade = ((dzdx * 0.5 - dzdy * 0.5 + 0.707) / n).clamp(0.0, 1.0) * 0.6 + 0.55;
            let (cr, cg, cb) = stride_output::colormap::viridis((v - f64::from(lo)) / span);
            let f = |c: u8| (f64::from(c) * shade).round().clamp(0.0, 255.0) as u8;
            px.push([f(cr), f(cg), f(cb)]);
        }
    }
    let img =
        stride_core::image::Image::from_vec(w as u32, h as u32, px).map_err(|e| e.to_string())?;
    crate::png_io::encode_rgb(&img)
}

/// The cells per pixel of a preview of `grid` at most `max_side` pixels on a side
/// ([`relief_png`], [`heat_png`]), and the x-y extent `(x_min, x_max, y_min, y_max)` (m) its
/// pixels cover, for placing it on axes.
pub fn preview_geometry(grid: &Grid<f32>, max_side: usize) -> (usize, (f64, f64, f64, f64)) {
    let g = grid.geometry;
    let step = g.rows.max(g.cols).div_ceil(max_side.max(1)).max(1);
    let span = |n: usize| (n.div_ceil(step) * step) as f64 * g.resolution;
    let (x0, y0) = (
        g.origin_x - g.resolution / 2.0,
        g.origin_y - g.resolution / 2.0,
    );
    (step, (x0, x0 + span(g.cols), y0, y0 + span(g.rows)))
}

/// A heat map of a grid as PNG bytes: viridis from `range.0` (dark) to `range.1` (yellow),
/// values outside clamped, NaN cells light grey, +y up, one pixel per cell (downsampled by an
/// integer factor to at most `max_side` pixels, see [`preview_geometry`]).
pub fn heat_png(grid: &Grid<f32>, range: (f64, f64), max_side: usize) -> Result<Vec<u8>, String> {
    let g = grid.geometry;
    let (step, _) = preview_geometry(grid, max_side);
    let (h, w) = (g.rows.div_ceil(step), g.cols.div_ceil(step));
    let span = (range.1 - range.0).max(1e-12);
    let mut px = Vec::with_capacity(w * h);
    for y in 0..h {
        let r = (h - 1 - y) * step; // image top = +y edge
        for x in 0..w {
            let v = grid
                .get(r.min(g.rows - 1), (x * step).min(g.cols - 1))
                .map_or(f64::NAN, f64::from);
            if v.is_nan() {
                px.push([225u8, 225, 225]);
            } else {
                let (cr, cg, cb) = stride_output::colormap::viridis((v - range.0) / span);
                px.push([cr, cg, cb]);
            }
        }
    }
    let img =
        stride_core::image::Image::from_vec(w as u32, h as u32, px).map_err(|e| e.to_string())?;
    crate::png_io::encode_rgb(&img)
}

/// A binary (little-endian) PLY mesh of an elevation grid: one vertex per known cell at
/// (x, y, height) in the grid's frame, two triangles per square of four known cells.
pub fn surface_ply(grid: &Grid<f32>) -> Vec<u8> {
    let g = grid.geometry;
    let mut index = vec![u32::MAX; g.len()];
    let mut verts: Vec<[f32; 3]> = Vec::new();
    for r in 0..g.rows {
        for c in 0..g.cols {
            if let Some(h) = grid.get(r, c).filter(|v| !v.is_nan()) {
                let (x, y) = g.center(r, c);
                if let Some(slot) = index.get_mut(r * g.cols + c) {
                    *slot = verts.len() as u32;
                }
                verts.push([x as f32, y as f32, h]);
            }
        }
    }
    let at = |r: usize, c: usize| {
        index
            .get(r * g.cols + c)
            .copied()
            .filter(|&i| i != u32::MAX)
    };
    let mut faces: Vec<[u32; 3]> = Vec::new();
    for r in 0..g.rows.saturating_sub(1) {
        for c in 0..g.cols.saturating_sub(1) {
            if let (Some(a), Some(b), Some(cc), Some(d)) =
                (at(r, c), at(r, c + 1), at(r + 1, c), at(r + 1, c + 1))
            {
                faces.push([a, b, d]);
                faces.push([a, d, cc]);
            }
        }
    }
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment stride elevation surface, z up\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        verts.len(),
        faces.len()
    )
    .into_bytes();
    for v in &verts {
        for c in v {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    for f in &faces {
        out.push(3);
        for i in f {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_and_alignment() {
        let data = vec![1.0f32, f32::NAN, -2.5, 4.0, 5.0, 6.0];
        let bytes = encode_npy_f32(2, 3, &data);
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let (r, c, back) = decode_npy_f32(&bytes, Path::new("x.npy")).unwrap();
        assert_eq!((r, c), (2, 3));
        assert_eq!(back[0], 1.0);
        assert!(back[1].is_nan());
        assert!(decode_npy_f32(b"nope", Path::new("x.npy")).is_err());
        assert!(decode_npy_f32(&bytes[..bytes.len() - 2], Path::new("x.npy")).is_err());
        // A shape whose byte count overflows is an error, not a wrap-around or a panic.
        let header =
            "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296), }";
        let mut huge = b"\x93NUMPY\x01\x00".to_vec();
        huge.extend_from_slice(&(header.len() as u16).to_le_bytes());
        huge.extend_from_slice(header.as_bytes());
        let e = decode_npy_f32(&huge, Path::new("h.npy"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("too large"), "{e}");
    }

    #[test]
    fn ply_counts_vertices_and_faces() {
        let g = GridGeometry::covering(0.0, 0.0, 0.3, 0.2, 0.1);
        let mut grid = Grid::filled(g, 1.0f32);
        *grid.get_mut(0, 0).unwrap() = f32::NAN;
        let ply = surface_ply(&grid);
        let text = String::from_utf8_lossy(&ply[..200]);
        assert!(
            text.contains("element vertex 5") && text.contains("element face 2"),
            "{text}"
        );
    }

    #[test]
    fn grid_round_trip_with_header() {
        let dir = std::env::temp_dir().join(format!("stride-grid-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let g = GridGeometry::covering(-1.0, -0.5, 1.0, 0.5, 0.25);
        let mut grid = Grid::filled(g, 0.0f32);
        *grid.get_mut(1, 2).unwrap() = 0.3;
        write_layer(&dir.join("terrain.npy"), &grid).unwrap();
        write_header(&dir.join("terrain.json"), &g).unwrap();
        let back = read_grid(&dir.join("terrain.npy"), None).unwrap();
        assert_eq!(back, grid);
        let e = read_grid(&dir.join("missing.npy"), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.npy: no such file"), "{e}");
        std::fs::copy(dir.join("terrain.npy"), dir.join("lone.npy")).unwrap();
        std::fs::remove_file(dir.join("terrain.json")).unwrap();
        let e = read_grid(&dir.join("lone.npy"), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("grid.json"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
