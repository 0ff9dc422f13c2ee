//! Linear algebra: sparse assembly and a reusable sparse Cholesky factorization (thin wrappers
//! over faer), and small eigen-solvers.
