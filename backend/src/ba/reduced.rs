//! The reduced camera system of bundle adjustment (the Schur complement of the points) as a
//! block-sparse symmetric matrix of 6x6 blocks, factorised by faer's sparse Cholesky.
//!
//! The block pattern is fixed for one optimization: the sparse matrix's structure and its
//! symbolic factorisation are built once and reused by every iteration; only the values
//! change. Factorisation and solve run on the calling thread (`Par::Seq`): the systems of a
//! local window are small, and the back end's own parallelism is over points.

use crate::error::BackendError;
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, SymbolicCholesky};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, Mat, Par, Side};
use nalgebra::{Matrix6, Vector6};

/// Which 6x6 blocks of the lower triangle are present: for every block column `b` (a free
/// camera), the sorted block rows `a >= b` coupled with it (always `b` itself first).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BlockPattern {
    rows_of_col: Vec<Vec<u32>>,
    offsets: Vec<usize>,
    /// `slot + 1` of block `(a, b)` at `a * n + b` (0: absent), for up to
    /// [`DENSE_SLOTS_MAX`] cameras; empty above, where [`Self::slot`] searches the column.
    dense: Vec<u32>,
}

/// Most cameras for which [`BlockPattern`] keeps a dense table of slots (4 MB at most): the
/// Schur complement looks a slot up for every pair of observations of every point.
const DENSE_SLOTS_MAX: usize = 1024;

impl BlockPattern {
    /// The pattern of `n` cameras with the given coupled pairs (in either order; duplicates
    /// and self-pairs are ignored).
    pub fn new(n: usize, pairs: impl IntoIterator<Item = (usize, usize)>) -> Self {
        let mut rows_of_col: Vec<Vec<u32>> = (0..n).map(|b| vec![b as u32]).collect();
        for (a, b) in pairs {
            let (hi, lo) = if a >= b { (a, b) } else { (b, a) };
            if hi != lo && hi < n {
                if let Some(col) = rows_of_col.get_mut(lo) {
                    col.push(hi as u32);
                }
            }
        }
        for col in &mut rows_of_col {
            col.sort_unstable();
            col.dedup();
        }
        let mut offsets = Vec::with_capacity(n + 1);
        let mut acc = 0;
        for col in &rows_of_col {
            offsets.push(acc);
            acc += col.len();
        }
        offsets.push(acc);
        let mut dense = Vec::new();
        if n <= DENSE_SLOTS_MAX {
            dense = vec![0u32; n * n];
            for (b, col) in rows_of_col.iter().enumerate() {
                for (i, &a) in col.iter().enumerate() {
                    let slot = offsets.get(b).map_or(0, |o| o + i);
                    if let Some(d) = dense.get_mut(a as usize * n + b) {
                        *d = slot as u32 + 1;
                    }
                }
            }
        }
        Self {
            rows_of_col,
            offsets,
            dense,
        }
    }

    /// Number of cameras (block rows and columns).
    pub fn cameras(&self) -> usize {
        self.rows_of_col.len()
    }

    /// Number of stored blocks.
    pub fn blocks(&self) -> usize {
        self.offsets.last().copied().unwrap_or(0)
    }

    /// The storage slot of block `(a, b)`, `a >= b`, if present.
    pub fn slot(&self, a: usize, b: usize) -> Option<usize> {
        let n = self.rows_of_col.len();
        if !self.dense.is_empty() {
            if a >= n || b >= n {
                return None;
            }
            let d = *self.dense.get(a * n + b)?;
            return (d > 0).then(|| d as usize - 1);
        }
        let col = self.rows_of_col.get(b)?;
        let pos = col.binary_search(&(a as u32)).ok()?;
        Some(self.offsets.get(b)? + pos)
    }

    /// The block rows of column `b` and the slot of the first one.
    pub fn column(&self, b: usize) -> (&[u32], usize) {
        match (self.rows_of_col.get(b), self.offsets.get(b)) {
            (Some(c), Some(&o)) => (c, o),
            _ => (&[], 0),
        }
    }
}

/// The reduced system `S x = r` with `S` given by its lower 6x6 blocks, and its reusable
/// factorisation.
pub struct ReducedSystem {
    pattern: BlockPattern,
    csc: SymbolicSparseColMat<usize>,
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    l_values: Vec<f64>,
    buffer: MemBuffer,
}

impl ReducedSystem {
    /// Builds the sparse structure of `pattern` and its symbolic factorisation.
    pub fn new(pattern: BlockPattern) -> Result<Self, BackendError> {
        let n = pattern.cameras() * 6;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0usize);
        for b in 0..pattern.cameras() {
            let (rows, _) = pattern.column(b);
            for c in 0..6 {
                for &a in rows {
                    let a = a as usize;
                    let first = if a == b { c } else { 0 };
                    row_idx.extend((first..6).map(|r| 6 * a + r));
                }
                col_ptr.push(row_idx.len());
            }
        }
        let csc = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let symbolic = factorize_symbolic_cholesky(
            csc.as_ref(),
            Side::Lower,
            Default::default(),
            Default::default(),
        )
        .map_err(|e| BackendError::Solver(format!("symbolic factorisation: {e:?}")))?;
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ]);
        let buffer = MemBuffer::try_new(req)
            .map_err(|_| BackendError::Solver("out of memory for the factorisation".into()))?;
        Ok(Self {
            values: vec![0.0; csc.row_idx().len()],
            l_values: vec![0.0; symbolic.len_val()],
            pattern,
            csc,
            symbolic,
            buffer,
        })
    }

    /// The block pattern.
    pub fn pattern(&self) -> &BlockPattern {
        &self.pattern
    }

    /// Solves `S x = rhs` for `S` given by `blocks` (one per slot of the pattern, block
    /// `(a, b)` with `a >= b` holding rows of `a` and columns of `b`). `None` when `S` is not
    /// numerically positive definite.
    pub fn solve(
        &mut self,
        blocks: &[Matrix6<f64>],
        rhs: &[Vector6<f64>],
    ) -> Option<Vec<Vector6<f64>>> {
        let nc = self.pattern.cameras();
        if blocks.len() != self.pattern.blocks() || rhs.len() != nc {
            return None;
        }
        if nc == 0 {
            return Some(Vec::new());
        }
        let mut k = 0;
        for b in 0..nc {
            let (rows, first_slot) = self.pattern.column(b);
            for c in 0..6 {
                for (i, &a) in rows.iter().enumerate() {
                    let block = blocks.get(first_slot + i)?;
                    let first = if a as usize == b { c } else { 0 };
                    for r in first..6 {
                        *self.values.get_mut(k)? = block[(r, c)];
                        k += 1;
                    }
                }
            }
        }
        let a = SparseColMatRef::new(self.csc.as_ref(), &self.values);
        let stack = MemStack::new(&mut self.buffer);
        let llt = self
            .symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.l_values,
                a,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                stack,
                Default::default(),
            )
            .ok()?;
        let mut x = Mat::<f64>::from_fn(6 * nc, 1, |i, _| rhs.get(i / 6).map_or(0.0, |v| v[i % 6]));
        llt.solve_in_place_with_conj(
            Conj::No,
            x.as_mut(),
            Par::Seq,
            MemStack::new(&mut self.buffer),
        );
        let out: Vec<Vector6<f64>> = (0..nc)
            .map(|b| Vector6::from_fn(|r, _| x[(6 * b + r, 0)]))
            .collect();
        out.iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
            .then_some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_block_tridiagonal_system_like_a_dense_solver() {
        let n = 4;
        let pattern = BlockPattern::new(n, [(0, 1), (1, 2), (3, 2), (2, 1)]);
        assert_eq!(pattern.blocks(), 4 + 3);
        let mut sys = ReducedSystem::new(pattern).unwrap();
        let mut dense = nalgebra::DMatrix::<f64>::zeros(6 * n, 6 * n);
        let mut blocks = vec![Matrix6::zeros(); sys.pattern().blocks()];
        for b in 0..n {
            let (rows, first) = sys.pattern().column(b);
            let rows: Vec<u32> = rows.to_vec();
            for (i, a) in rows.into_iter().enumerate() {
                let a = a as usize;
                let blk = if a == b {
                    Matrix6::from_fn(|r, c| {
                        if r == c {
                            10.0 + r as f64
                        } else {
                            0.3 / (1.0 + (r + c) as f64)
                        }
                    })
                } else {
                    Matrix6::from_fn(|r, c| 0.1 * ((r * 7 + c * 3 + a + b) % 5) as f64 - 0.2)
                };
                blocks[first + i] = blk;
                for r in 0..6 {
                    for c in 0..6 {
                        dense[(6 * a + r, 6 * b + c)] = blk[(r, c)];
                        dense[(6 * b + c, 6 * a + r)] = blk[(r, c)];
                    }
                }
            }
        }
        let rhs: Vec<Vector6<f64>> = (0..n)
            .map(|b| Vector6::from_fn(|r, _| (b * 6 + r) as f64 - 7.0))
            .collect();
        let x = sys.solve(&blocks, &rhs).unwrap();
        let rhs_d = nalgebra::DVector::from_fn(6 * n, |i, _| rhs[i / 6][i % 6]);
        let expect = dense.cholesky().unwrap().solve(&rhs_d);
        for i in 0..6 * n {
            assert!((x[i / 6][i % 6] - expect[i]).abs() < 1e-10);
        }
        // A second solve with the same structure reuses the symbolic factorisation.
        let x2 = sys.solve(&blocks, &rhs).unwrap();
        assert_eq!(x, x2);
    }

    #[test]
    fn slots_agree_with_the_columns_with_and_without_the_dense_table() {
        for n in [7, DENSE_SLOTS_MAX + 3] {
            let p = BlockPattern::new(n, (0..n).map(|i| (i, (i * 7 + 3) % n)));
            let mut found = 0;
            for b in 0..n {
                let (rows, first) = p.column(b);
                for a in b..n {
                    let expect = rows
                        .iter()
                        .position(|&r| r as usize == a)
                        .map(|i| first + i);
                    assert_eq!(p.slot(a, b), expect, "n {n}, block ({a}, {b})");
                    found += usize::from(expect.is_some());
                }
            }
            assert_eq!(found, p.blocks());
            assert_eq!(p.slot(n, 0), None);
        }
    }

    #[test]
    fn reports_an_indefinite_matrix() {
        let mut sys = ReducedSystem::new(BlockPattern::new(1, [])).unwrap();
        let blocks = vec![-Matrix6::identity()];
        assert!(sys.solve(&blocks, &[Vector6::zeros()]).is_none());
    }
}
