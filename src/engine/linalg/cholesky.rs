//! Sparse Cholesky `A = LLᵀ` with the symbolic analysis reused across value vectors.
//!
//! [`SymbolicCholesky::new`] runs faer's symbolic phase once per [`SparsityPattern`]: AMD
//! fill-reducing ordering, elimination tree, column counts, and the choice between a simplicial
//! and a supernodal factor. [`SymbolicCholesky::factor`] then computes the numeric factor of any
//! symmetric positive-definite matrix with exactly that pattern (for example `M - tL` for several
//! heat times `t`, or the Laplacian of a deformed mesh with the same connectivity) without
//! repeating the analysis; every [`NumericCholesky`] keeps a shared handle to the analysis it
//! came from ([`NumericCholesky::symbolic`], compare with [`SymbolicCholesky::same_analysis`]).
//!
//! Solves: [`NumericCholesky::solve`] for one right-hand side, [`NumericCholesky::solve_many`]
//! for many, in parallel over right-hand sides (each one sequential, so results do not depend on
//! the thread count), [`NumericCholesky::solve_block`] for many as one block in a single pass. The numeric factorization uses faer's rayon parallelism.
//!
//! Only the lower triangle of the matrix is read. The factorization is faer's
//! (`faer::sparse::linalg::cholesky`); this module is glue.

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{LltError, LltRegularization};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LltRef, SymbolicCholesky as FaerSymbolic, SymmetricOrdering,
};
use faer::{Conj, MatMut, Par, Side};

use super::simd_state::{clear_upper_vector_state, clear_upper_vector_state_here};
use rayon::prelude::*;

use super::sparse::{SparsityPattern, SymmetricMatrix};
use super::LinalgError;

struct Analysis {
    pattern: Arc<SparsityPattern>,
    faer: FaerSymbolic<usize>,
}

/// The symbolic analysis of one sparsity pattern; cheap to clone (shared).
#[derive(Clone)]
pub struct SymbolicCholesky {
    inner: Arc<Analysis>,
}

impl std::fmt::Debug for SymbolicCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SymbolicCholesky")
            .field("dim", &self.inner.pattern.dim())
            .field("nnz", &self.inner.pattern.nnz())
            .field("factor_len", &self.inner.faer.len_val())
            .finish()
    }
}

impl SymbolicCholesky {
    /// Analyses `pattern` (AMD ordering, elimination tree, supernodes).
    ///
    /// # Errors
    /// [`LinalgError::Factorization`] if faer cannot allocate the analysis.
    pub fn new(pattern: Arc<SparsityPattern>) -> Result<Self, LinalgError> {
        let faer = factorize_symbolic_cholesky(
            pattern.as_faer(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .map_err(|e| LinalgError::Factorization(format!("{e:?}")))?;
        Ok(Self {
            inner: Arc::new(Analysis { pattern, faer }),
        })
    }

    /// Analyses `pattern` with the given elimination order (`order[k]` is the unknown
    /// eliminated k-th, a permutation of `0..n`) instead of AMD: for callers that know a better
    /// order, such as a nested dissection of a mesh graph ([`super::dissection`]).
    ///
    /// # Errors
    /// [`LinalgError::InvalidPattern`] when `order` is not a permutation of the pattern's
    /// unknowns; [`LinalgError::Factorization`] as [`SymbolicCholesky::new`].
    pub fn with_elimination_order(
        pattern: Arc<SparsityPattern>,
        order: &[usize],
    ) -> Result<Self, LinalgError> {
        let n = pattern.dim();
        let mut inverse = vec![usize::MAX; n];
        if order.len() != n {
            return Err(LinalgError::InvalidPattern(format!(
                "elimination order has {} entries, the pattern {n} unknowns",
                order.len()
            )));
        }
        for (k, v) in order.iter().enumerate() {
            if *v >= n || inverse[*v] != usize::MAX {
                return Err(LinalgError::InvalidPattern(format!(
                    "elimination order is not a permutation (entry {k} = {v})"
                )));
            }
            inverse[*v] = k;
        }
        let perm = faer::perm::PermRef::new_checked(order, &inverse, n);
        let faer = factorize_symbolic_cholesky(
            pattern.as_faer(),
            Side::Lower,
            SymmetricOrdering::Custom(perm),
            Default::default(),
        )
        .map_err(|e| LinalgError::Factorization(format!("{e:?}")))?;
        Ok(Self {
            inner: Arc::new(Analysis { pattern, faer }),
        })
    }

    /// The analysed pattern.
    pub fn pattern(&self) -> &Arc<SparsityPattern> {
        &self.inner.pattern
    }

    /// Number of stored values of the factor `L`.
    pub fn factor_len(&self) -> usize {
        self.inner.faer.len_val()
    }

    /// Whether `self` and `other` are the very same analysis (not merely equal ones).
    pub fn same_analysis(&self, other: &SymbolicCholesky) -> bool {
        Arc::ptr_eq(&self.inner, &other.inner)
    }

    /// Numeric factorization of `matrix`, whose pattern must equal the analysed one.
    ///
    /// # Errors
    /// [`LinalgError::InvalidPattern`] for another pattern, [`LinalgError::NotPositiveDefinite`]
    /// when a pivot is not positive, [`LinalgError::Factorization`] on allocation failure.
    pub fn factor(&self, matrix: &SymmetricMatrix) -> Result<NumericCholesky, LinalgError> {
        self.factor_with(matrix, Par::rayon(0))
    }

    /// [`SymbolicCholesky::factor`] on the calling thread only: for callers that keep the
    /// other cores busy with independent work meanwhile (faer's parallel factorisation would
    /// compete with it, and gains little on systems of a few ten thousand unknowns).
    ///
    /// # Errors
    /// As [`SymbolicCholesky::factor`].
    pub fn factor_sequential(
        &self,
        matrix: &SymmetricMatrix,
    ) -> Result<NumericCholesky, LinalgError> {
        self.factor_with(matrix, Par::Seq)
    }

    fn factor_with(
        &self,
        matrix: &SymmetricMatrix,
        par: Par,
    ) -> Result<NumericCholesky, LinalgError> {
        let same = Arc::ptr_eq(matrix.pattern(), &self.inner.pattern)
            || **matrix.pattern() == *self.inner.pattern;
        if !same {
            return Err(LinalgError::InvalidPattern(
                "the matrix pattern differs from the analysed pattern".into(),
            ));
        }
        self.factor_values_with(matrix.values(), par)
    }

    /// Numeric factorization of the matrix with the analysed pattern and `values` (CSC order).
    ///
    /// # Errors
    /// As [`SymbolicCholesky::factor`], plus [`LinalgError::ValueCount`] /
    /// [`LinalgError::NonFinite`] for bad values.
    pub fn factor_values(&self, values: &[f64]) -> Result<NumericCholesky, LinalgError> {
        self.factor_values_with(values, Par::rayon(0))
    }

    fn factor_values_with(&self, values: &[f64], par: Par) -> Result<NumericCholesky, LinalgError> {
        let pattern = &self.inner.pattern;
        if values.len() != pattern.nnz() {
            return Err(LinalgError::ValueCount {
                expected: pattern.nnz(),
                got: values.len(),
            });
        }
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite { index });
        }
        let sym = &self.inner.faer;
        let mut l_values = Vec::new();
        l_values
            .try_reserve_exact(sym.len_val())
            .map_err(|e| LinalgError::Factorization(e.to_string()))?;
        l_values.resize(sym.len_val(), 0.0f64);
        let mut mem =
            MemBuffer::try_new(sym.factorize_numeric_llt_scratch::<f64>(par, Default::default()))
                .map_err(|e| LinalgError::Factorization(format!("{e:?}")))?;
        let a = faer::sparse::SparseColMatRef::new(pattern.as_faer(), values);
        let factored = sym
            .factorize_numeric_llt::<f64>(
                &mut l_values,
                a,
                Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| match e {
                LltError::NonPositivePivot { index } => {
                    LinalgError::NotPositiveDefinite { column: index }
                }
            });
        if matches!(par, Par::Seq) {
            clear_upper_vector_state_here();
        } else {
            clear_upper_vector_state();
        }
        factored?;
        Ok(NumericCholesky {
            symbolic: self.clone(),
            l_values,
        })
    }
}

/// A numeric Cholesky factor; solves `A x = b`.
#[derive(Clone)]
pub struct NumericCholesky {
    symbolic: SymbolicCholesky,
    l_values: Vec<f64>,
}

impl std::fmt::Debug for NumericCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NumericCholesky")
            .field("symbolic", &self.symbolic)
            .finish()
    }
}

impl NumericCholesky {
    /// The analysis this factor was computed from (shared, not a copy).
    pub fn symbolic(&self) -> &SymbolicCholesky {
        &self.symbolic
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.symbolic.inner.pattern.dim()
    }

    /// Solves `A x = b` in place (`x` holds `b` on entry), sequentially.
    ///
    /// # Errors
    /// [`LinalgError::RhsLength`] when `x.len() != dim`.
    pub fn solve_in_place(&self, x: &mut [f64]) -> Result<(), LinalgError> {
        self.check_len(0, x.len())?;
        self.solve_unchecked(x);
        Ok(())
    }

    /// Solves `A x = b` and returns `x`.
    ///
    /// # Errors
    /// [`LinalgError::RhsLength`] when `b.len() != dim`.
    pub fn solve(&self, b: &[f64]) -> Result<Vec<f64>, LinalgError> {
        let mut x = b.to_vec();
        self.solve_in_place(&mut x)?;
        Ok(x)
    }

    /// Solves `A xₖ = bₖ` for every right-hand side in place, in parallel over right-hand sides.
    ///
    /// # Errors
    /// [`LinalgError::RhsLength`] (with the index of the first offending vector) before any
    /// solve when a length differs from `dim`.
    pub fn solve_many(&self, rhs: &mut [Vec<f64>]) -> Result<(), LinalgError> {
        for (k, b) in rhs.iter().enumerate() {
            self.check_len(k, b.len())?;
        }
        rhs.par_iter_mut().for_each(|x| self.solve_unchecked(x));
        Ok(())
    }

    /// Solves `A xₖ = bₖ` for every right-hand side in place as one `dim × k` block: a single
    /// sequential pass over the factor serves all of them (faer's supernodal solve works on the
    /// block with dense kernels), instead of one pass each. Sequential, so results do not depend
    /// on the thread count; they may differ from [`Self::solve_many`]'s in the last bits.
    ///
    /// # Errors
    /// [`LinalgError::RhsLength`] (with the index of the first offending vector) before any
    /// solve when a length differs from `dim`.
    pub fn solve_block(&self, rhs: &mut [Vec<f64>]) -> Result<(), LinalgError> {
        for (k, b) in rhs.iter().enumerate() {
            self.check_len(k, b.len())?;
        }
        let (n, k) = (self.dim(), rhs.len());
        if k == 0 {
            return Ok(());
        }
        let mut block = Vec::with_capacity(n * k);
        for b in rhs.iter() {
            block.extend_from_slice(b);
        }
        let sym = &self.symbolic.inner.faer;
        let mut mem = MemBuffer::new(sym.solve_in_place_scratch::<f64>(k, Par::Seq));
        let llt = LltRef::<'_, usize, f64>::new(sym, &self.l_values);
        let x = MatMut::from_column_major_slice_mut(&mut block, n, k);
        llt.solve_in_place_with_conj(Conj::No, x, Par::Seq, MemStack::new(&mut mem));
        clear_upper_vector_state_here();
        for (b, col) in rhs.iter_mut().zip(block.chunks_exact(n)) {
            b.copy_from_slice(col);
        }
        Ok(())
    }

    fn check_len(&self, index: usize, got: usize) -> Result<(), LinalgError> {
        if got != self.dim() {
            return Err(LinalgError::RhsLength {
                index,
                expected: self.dim(),
                got,
            });
        }
        Ok(())
    }

    fn solve_unchecked(&self, x: &mut [f64]) {
        let sym = &self.symbolic.inner.faer;
        let n = x.len();
        let mut mem = MemBuffer::new(sym.solve_in_place_scratch::<f64>(1, Par::Seq));
        let llt = LltRef::<'_, usize, f64>::new(sym, &self.l_values);
        let rhs = MatMut::from_column_major_slice_mut(x, n, 1);
        llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(&mut mem));
        clear_upper_vector_state_here();
    }
}
