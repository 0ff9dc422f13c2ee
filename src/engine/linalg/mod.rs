//! Linear algebra: sparse assembly and a reusable sparse Cholesky factorization (thin wrappers
//! over faer), and small eigen-solvers.
//!
//! - [`sparse`]: a symmetric sparsity pattern in compressed-column form (both triangles stored,
//!   diagonal always present) and a symmetric matrix of values on such a pattern, with parallel
//!   products. Geometry operators (cotan Laplacian, `M - tL`, `-L + εM`) share one pattern, so a
//!   shifted operator is just another value vector.
//! - [`cholesky`]: the sparse `LLᵀ` factorization of faer (supernodal or simplicial, AMD
//!   ordering) split into a [`cholesky::SymbolicCholesky`] computed once per pattern and
//!   [`cholesky::NumericCholesky`] factors computed from it for any value vector, with solves for
//!   one or many right-hand sides.
//! - [`dissection`]: a nested-dissection elimination order from breadth-first level
//!   structures, for the large planar-like systems where AMD leaves too much fill.
//! - [`lanczos`]: shift-invert block Lanczos (Krylov–Schur restarts) for the lowest eigenpairs
//!   of `K φ = λ M φ` with `M` diagonal, on a Cholesky factor of `K − σM`.
//!
//! Written by hand: only the glue (pattern bookkeeping, value reuse, parallel multi-RHS solves);
//! the factorization itself is faer's.

pub mod cholesky;
pub mod dissection;
pub mod lanczos;
pub mod simd_state;
pub mod sparse;

pub use cholesky::{NumericCholesky, SymbolicCholesky};
pub use sparse::{SparsityPattern, SymmetricMatrix};

/// Errors of the linear-algebra module.
#[derive(Debug, thiserror::Error)]
pub enum LinalgError {
    /// A pattern's arrays are inconsistent.
    #[error("invalid sparsity pattern: {0}")]
    InvalidPattern(String),
    /// A value vector does not match its pattern.
    #[error("value vector has {got} entries, the pattern has {expected}")]
    ValueCount {
        /// Entries in the pattern.
        expected: usize,
        /// Entries given.
        got: usize,
    },
    /// A right-hand side has the wrong length.
    #[error("right-hand side {index} has {got} rows, the matrix has {expected}")]
    RhsLength {
        /// Which right-hand side.
        index: usize,
        /// Rows of the matrix.
        expected: usize,
        /// Rows given.
        got: usize,
    },
    /// A value is NaN or infinite.
    #[error("value {index} is not finite")]
    NonFinite {
        /// Index into the value vector.
        index: usize,
    },
    /// The numeric factorization met a non-positive pivot.
    #[error("matrix is not positive definite (non-positive pivot in column {column})")]
    NotPositiveDefinite {
        /// Column of the permuted matrix where the pivot failed (as reported by faer).
        column: usize,
    },
    /// faer could not allocate or analyse the matrix.
    #[error("factorization failed: {0}")]
    Factorization(String),
}
