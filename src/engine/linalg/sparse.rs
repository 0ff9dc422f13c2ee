//! Symmetric sparse matrices in compressed-column (CSC) form with both triangles stored.
//!
//! A [`SparsityPattern`] holds column pointers and ascending row indices, always including the
//! diagonal; it is shared (`Arc`) between every matrix with that pattern, so the symbolic
//! Cholesky analysis of [`super::cholesky`] can be reused for all of them (for example the cotan
//! Laplacian `L`, the heat operator `M - tL` and the Poisson operator `-L + εM` of the heat
//! method all have the pattern "vertex plus its one-ring").
//!
//! Written by hand: a few dozen lines of CSC bookkeeping; the views handed to faer are
//! [`faer::sparse::SymbolicSparseColMatRef`] and [`faer::sparse::SparseColMatRef`].

use std::sync::Arc;

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use rayon::prelude::*;

use super::LinalgError;

/// The structure of a symmetric `n × n` sparse matrix: CSC, both triangles, diagonal present,
/// row indices strictly ascending within each column.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SparsityPattern {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
}

impl SparsityPattern {
    /// Builds a pattern from per-column row lists (any order, duplicates allowed). The pattern is
    /// symmetrized (each `(i, j)` also adds `(j, i)`) and the diagonal is added.
    ///
    /// # Errors
    /// [`LinalgError::InvalidPattern`] when a row index is `>= columns.len()`.
    pub fn from_columns(columns: &[Vec<usize>]) -> Result<Self, LinalgError> {
        let n = columns.len();
        let mut cols: Vec<Vec<usize>> = columns.to_vec();
        for (j, rows) in columns.iter().enumerate() {
            for &i in rows {
                if i >= n {
                    return Err(LinalgError::InvalidPattern(format!(
                        "row {i} in column {j} is out of range for {n} columns"
                    )));
                }
                if i != j {
                    cols[i].push(j);
                }
            }
        }
        Ok(Self::from_sorted_columns(with_sorted_diagonal(cols)))
    }

    /// Builds a pattern from per-column row lists that are already symmetric (each `(i, j)` with
    /// its `(j, i)`), in any order, duplicates allowed: the diagonal is added, nothing else.
    ///
    /// # Errors
    /// [`LinalgError::InvalidPattern`] when a row index is `>= columns.len()`.
    pub(crate) fn from_symmetric_columns(columns: Vec<Vec<usize>>) -> Result<Self, LinalgError> {
        let n = columns.len();
        let cols = with_sorted_diagonal(columns);
        for (j, rows) in cols.iter().enumerate() {
            if let Some(&i) = rows.last().filter(|&&i| i >= n) {
                return Err(LinalgError::InvalidPattern(format!(
                    "row {i} in column {j} is out of range for {n} columns"
                )));
            }
        }
        Ok(Self::from_sorted_columns(cols))
    }

    /// Builds a pattern from columns that are already symmetric, sorted, deduplicated and contain
    /// their diagonal. Checked in debug builds only; callers inside this crate guarantee it.
    pub(crate) fn from_sorted_columns(cols: Vec<Vec<usize>>) -> Self {
        let n = cols.len();
        let mut col_ptr = Vec::with_capacity(n + 1);
        col_ptr.push(0);
        let mut row_idx = Vec::with_capacity(cols.iter().map(Vec::len).sum());
        for (j, rows) in cols.iter().enumerate() {
            debug_assert!(rows.windows(2).all(|w| w[0] < w[1]) && rows.binary_search(&j).is_ok());
            row_idx.extend_from_slice(rows);
            col_ptr.push(row_idx.len());
        }
        Self {
            n,
            col_ptr,
            row_idx,
        }
    }

    /// Builds a pattern from compressed columns that are already symmetric, with strictly
    /// ascending rows and the diagonal in every column (checked: O(nnz), symmetry in debug
    /// builds only).
    ///
    /// # Errors
    /// [`LinalgError::InvalidPattern`] for inconsistent arrays, unsorted or out-of-range rows,
    /// or a missing diagonal.
    pub fn from_sorted_csc(
        n: usize,
        col_ptr: Vec<usize>,
        row_idx: Vec<usize>,
    ) -> Result<Self, LinalgError> {
        let bad = |m: String| Err(LinalgError::InvalidPattern(m));
        if col_ptr.len() != n + 1 || col_ptr[0] != 0 || col_ptr[n] != row_idx.len() {
            return bad(format!("{} column pointers for {n} columns", col_ptr.len()));
        }
        for j in 0..n {
            if col_ptr[j] > col_ptr[j + 1] {
                return bad(format!("column {j} ends before it starts"));
            }
            let rows = &row_idx[col_ptr[j]..col_ptr[j + 1]];
            if !rows.windows(2).all(|w| w[0] < w[1]) || rows.last().is_some_and(|r| *r >= n) {
                return bad(format!("column {j}: rows not ascending or out of range"));
            }
            if rows.binary_search(&j).is_err() {
                return bad(format!("column {j} has no diagonal"));
            }
        }
        let pattern = Self {
            n,
            col_ptr,
            row_idx,
        };
        debug_assert!((0..n).all(|j| pattern
            .column(j)
            .iter()
            .all(|i| pattern.find(j, *i).is_some())));
        Ok(pattern)
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Stored entries (both triangles and the diagonal).
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// Column pointers (`dim + 1` entries).
    pub fn col_ptr(&self) -> &[usize] {
        &self.col_ptr
    }

    /// Row indices of column `j`, ascending.
    pub fn column(&self, j: usize) -> &[usize] {
        &self.row_idx[self.col_ptr[j]..self.col_ptr[j + 1]]
    }

    /// Position of entry `(i, j)` in the value vector, if stored.
    pub fn find(&self, i: usize, j: usize) -> Option<usize> {
        let col = self.column(j);
        col.binary_search(&i).ok().map(|k| self.col_ptr[j] + k)
    }

    /// Position of the diagonal entry of every column.
    pub fn diagonal_positions(&self) -> Vec<usize> {
        (0..self.n)
            .map(|j| self.find(j, j).expect("the diagonal is always stored"))
            .collect()
    }

    /// The faer view of this structure.
    pub fn as_faer(&self) -> SymbolicSparseColMatRef<'_, usize> {
        SymbolicSparseColMatRef::new_checked(self.n, self.n, &self.col_ptr, None, &self.row_idx)
    }
}

/// Each column with its diagonal added, sorted and deduplicated (in parallel over columns).
fn with_sorted_diagonal(cols: Vec<Vec<usize>>) -> Vec<Vec<usize>> {
    cols.into_par_iter()
        .enumerate()
        .map(|(j, mut rows)| {
            rows.push(j);
            rows.sort_unstable();
            rows.dedup();
            rows
        })
        .collect()
}

/// A symmetric sparse matrix: a shared [`SparsityPattern`] and one value per stored entry.
#[derive(Clone, Debug)]
pub struct SymmetricMatrix {
    pattern: Arc<SparsityPattern>,
    values: Vec<f64>,
}

impl SymmetricMatrix {
    /// Wraps `values` (one per stored entry of `pattern`, in CSC order).
    ///
    /// # Errors
    /// [`LinalgError::ValueCount`] on a length mismatch, [`LinalgError::NonFinite`] for NaN/inf.
    pub fn new(pattern: Arc<SparsityPattern>, values: Vec<f64>) -> Result<Self, LinalgError> {
        if values.len() != pattern.nnz() {
            return Err(LinalgError::ValueCount {
                expected: pattern.nnz(),
                got: values.len(),
            });
        }
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite { index });
        }
        Ok(Self { pattern, values })
    }

    /// The shared pattern.
    pub fn pattern(&self) -> &Arc<SparsityPattern> {
        &self.pattern
    }

    /// Values in CSC order.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.pattern.dim()
    }

    /// Entry `(i, j)`; 0 when not stored.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.pattern.find(i, j).map_or(0.0, |k| self.values[k])
    }

    /// The diagonal.
    pub fn diagonal(&self) -> Vec<f64> {
        self.pattern
            .diagonal_positions()
            .into_iter()
            .map(|k| self.values[k])
            .collect()
    }

    /// `y = A x` (parallel over columns; as A is symmetric, column j is row j).
    ///
    /// # Panics
    /// If `x.len() != dim` (a programming error).
    pub fn mul_vec(&self, x: &[f64]) -> Vec<f64> {
        assert_eq!(x.len(), self.dim(), "vector length must match the matrix");
        let p = &self.pattern;
        (0..p.dim())
            .into_par_iter()
            .with_min_len(1024)
            .map(|j| {
                let range = p.col_ptr[j]..p.col_ptr[j + 1];
                p.row_idx[range.clone()]
                    .iter()
                    .zip(&self.values[range])
                    .map(|(&i, &v)| v * x[i])
                    .sum()
            })
            .collect()
    }

    /// `xᵀ A x`.
    pub fn quadratic_form(&self, x: &[f64]) -> f64 {
        self.mul_vec(x).iter().zip(x).map(|(a, b)| a * b).sum()
    }

    /// Largest `|A_ij - A_ji|` over stored entries (0 for an exactly symmetric matrix).
    pub fn asymmetry(&self) -> f64 {
        let p = &self.pattern;
        (0..p.dim())
            .into_par_iter()
            .map(|j| {
                let mut worst = 0.0f64;
                for (k, &i) in p.column(j).iter().enumerate() {
                    let a = self.values[p.col_ptr[j] + k];
                    worst = worst.max((a - self.get(j, i)).abs());
                }
                worst
            })
            .reduce(|| 0.0, f64::max)
    }

    /// `a · self + b · diag(d)` on the same pattern (the diagonal is always stored).
    ///
    /// # Panics
    /// If `d.len() != dim` (a programming error).
    pub fn scaled_plus_diagonal(&self, a: f64, b: f64, d: &[f64]) -> SymmetricMatrix {
        assert_eq!(d.len(), self.dim(), "diagonal length must match the matrix");
        let mut values: Vec<f64> = self.values.iter().map(|v| a * v).collect();
        for (j, k) in self.pattern.diagonal_positions().into_iter().enumerate() {
            values[k] += b * d[j];
        }
        SymmetricMatrix {
            pattern: Arc::clone(&self.pattern),
            values,
        }
    }

    /// `(row, column, value)` of every stored entry, column by column.
    pub fn triplets(&self) -> Vec<(usize, usize, f64)> {
        let p = &self.pattern;
        (0..p.dim())
            .flat_map(|j| {
                p.column(j)
                    .iter()
                    .enumerate()
                    .map(move |(k, &i)| (i, j, self.values[p.col_ptr[j] + k]))
            })
            .collect()
    }

    /// The faer view of this matrix.
    pub fn as_faer(&self) -> SparseColMatRef<'_, usize, f64> {
        SparseColMatRef::new(self.pattern.as_faer(), &self.values)
    }
}
