//! Shift-invert block Lanczos for the lowest eigenpairs of a symmetric-definite pencil
//! `K φ = λ M φ` (`K` symmetric positive semi-definite, `M` diagonal positive), with thick
//! (Krylov–Schur) restarts.
//!
//! The caller factors `K − σM = LLᵀ` for a shift `σ` below the wanted eigenvalues (for the
//! Laplacian, slightly below 0). The operator `Op = (K − σM)⁻¹ M` is self-adjoint in the
//! `M`-inner product `⟨x, y⟩_M = xᵀ M y`; its eigenvalues `θ = 1 / (λ − σ)` are largest for
//! the `λ` nearest `σ`, so the lowest `λ` converge first and fast (Ericsson & Ruhe 1980,
//! "The spectral transformation Lanczos method"; Grimes, Lewis & Simon 1994, "A shifted block
//! Lanczos algorithm"). Restarts follow Stewart 2001, "A Krylov–Schur algorithm for large
//! eigenproblems": after a Rayleigh–Ritz step the best `p` Ritz vectors and the newest block are
//! kept, and the projected matrix becomes "diagonal plus one coupling block".
//!
//! Every new block is orthogonalized against the whole basis twice (block classical
//! Gram–Schmidt, "CGS2"), then within itself by modified Gram–Schmidt, all in the `M`-inner
//! product ("full reorthogonalization"). A column that vanishes (an invariant subspace was found)
//! is replaced by a fresh pseudo-random vector.
//!
//! **Convergence.** A Ritz pair `(θ, y = Q s)` has the residual `Op y − θ y = Q₊ R s₊` (`Q₊`
//! the newest block, `R` its coupling coefficients, `s₊` the last block of `s`), so
//! `‖Op y − θ y‖_M = ‖R s₊‖` costs nothing. A pair counts as converged when this is at most
//! `tolerance · θ`.
//!
//! **Determinism.** Start vectors come from a seeded SplitMix64 generator; products over the
//! long dimension are summed over a fixed row partition in a fixed order; the solves of a block
//! run in parallel but each is sequential; the small dense eigendecompositions are sequential.
//! Results are therefore identical for any rayon thread count.
//!
//! Written by hand (the iteration); faer does the dense products and small eigendecompositions,
//! [`super::cholesky`] the solves.

use faer::diag::Diag;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{self_adjoint_evd, self_adjoint_evd_scratch, ComputeEigenvectors};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::simd_state::clear_upper_vector_state_here;
use rayon::prelude::*;

use super::{LinalgError, NumericCholesky};
use crate::engine::control::Cancelled;
use crate::engine::rng::SplitMix64;

/// Rows per task in products over the long dimension (fixed, so sums do not depend on threads).
const ROW_CHUNK: usize = 4096;

/// Parameters of [`shift_invert_lanczos`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LanczosParams {
    /// Vectors per block (solved in parallel). Must be at least the largest eigenvalue
    /// multiplicity to resolve exactly repeated eigenvalues reliably. Default: 8. Range: [1, 64].
    pub block_size: usize,
    /// Largest basis size (columns). 0 = automatic: `max(2k, k + 4·block_size)`, rounded up to a
    /// multiple of the block size. Otherwise at least `k + 2·block_size`.
    pub basis_size: usize,
    /// Convergence: `‖Op y − θ y‖_M ≤ tolerance · θ` (dimensionless). Default: 1e-10.
    /// Range: [1e-15, 1e-2].
    pub tolerance: f64,
    /// Thick restarts before giving up (the result then reports `converged < k`). Default: 100.
    pub max_restarts: usize,
    /// Seed of the pseudo-random start block. Default: 0x5EED.
    pub seed: u64,
}

impl Default for LanczosParams {
    fn default() -> Self {
        Self {
            block_size: 8,
            basis_size: 0,
            tolerance: 1e-10,
            max_restarts: 100,
            seed: 0x5EED,
        }
    }
}

/// Errors of [`shift_invert_lanczos`].
#[derive(Debug, thiserror::Error)]
pub enum LanczosError {
    /// A parameter is out of range.
    #[error("invalid Lanczos parameter: {0}")]
    InvalidParam(String),
    /// A solve failed.
    #[error(transparent)]
    Linalg(#[from] LinalgError),
    /// A dense eigendecomposition did not converge.
    #[error("dense eigendecomposition did not converge")]
    DenseEigen,
    /// Cancelled by the progress callback.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

/// Result of [`shift_invert_lanczos`]: the `k` largest eigenvalues `θ` of `Op`, descending.
#[derive(Clone, Debug)]
pub struct ShiftInvertEigen {
    /// Ritz values `θ = 1 / (λ − σ)`, descending.
    pub theta: Vec<f64>,
    /// Ritz vectors, `n × k`, `M`-orthonormal.
    pub vectors: Mat<f64>,
    /// `‖Op y − θ y‖_M / θ` per pair (the convergence measure).
    pub residual_estimates: Vec<f64>,
    /// How many of the leading pairs met the tolerance (`k` on success).
    pub converged: usize,
    /// Thick restarts performed.
    pub restarts: usize,
    /// Applications of `Op` (one solve each).
    pub operator_applications: usize,
}

/// Eigendecomposition of a small symmetric matrix (lower triangle read), ascending, computed
/// sequentially (deterministic).
///
/// # Errors
/// [`LanczosError::DenseEigen`] when faer's QR iteration does not converge.
pub fn symmetric_eigen(a: MatRef<'_, f64>) -> Result<(Vec<f64>, Mat<f64>), LanczosError> {
    let n = a.nrows();
    let mut s = Diag::<f64>::zeros(n);
    let mut u = Mat::<f64>::zeros(n, n);
    let scratch =
        self_adjoint_evd_scratch::<f64>(n, ComputeEigenvectors::Yes, Par::Seq, Default::default());
    let mut mem = MemBuffer::new(scratch);
    let result = self_adjoint_evd(
        a,
        s.as_mut(),
        Some(u.as_mut()),
        Par::Seq,
        MemStack::new(&mut mem),
        Default::default(),
    );
    clear_upper_vector_state_here();
    result.map_err(|_| LanczosError::DenseEigen)?;
    Ok(((0..n).map(|i| s[i]).collect(), u))
}

/// `Aᵀ B`, summed over a fixed row partition in a fixed order.
fn gram(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> Mat<f64> {
    let partials: Vec<Mat<f64>> = a
        .par_row_chunks(ROW_CHUNK)
        .zip(b.par_row_chunks(ROW_CHUNK))
        .map(|(ac, bc)| {
            let mut p = Mat::<f64>::zeros(a.ncols(), b.ncols());
            matmul(
                p.as_mut(),
                Accum::Replace,
                ac.transpose(),
                bc,
                1.0,
                Par::Seq,
            );
            clear_upper_vector_state_here();
            p
        })
        .collect();
    let mut out = Mat::<f64>::zeros(a.ncols(), b.ncols());
    for p in &partials {
        for j in 0..out.ncols() {
            for i in 0..out.nrows() {
                out[(i, j)] += p[(i, j)];
            }
        }
    }
    out
}

/// `dst = beta·dst + alpha · A B` with rows in parallel (each row block sequential).
fn product_into(
    dst: MatMut<'_, f64>,
    accum: Accum,
    a: MatRef<'_, f64>,
    b: MatRef<'_, f64>,
    alpha: f64,
) {
    dst.par_row_chunks_mut(ROW_CHUNK)
        .zip(a.par_row_chunks(ROW_CHUNK))
        .for_each(|(dc, ac)| {
            matmul(dc, accum, ac, b, alpha, Par::Seq);
            clear_upper_vector_state_here();
        });
}

/// `diag(mass) · X`.
fn mass_times(x: MatRef<'_, f64>, mass: &[f64]) -> Mat<f64> {
    Mat::from_fn(x.nrows(), x.ncols(), |i, j| mass[i] * x[(i, j)])
}

fn m_dot(x: MatRef<'_, f64>, i: usize, y: MatRef<'_, f64>, j: usize, mass: &[f64]) -> f64 {
    let (xc, yc) = (x.col(i), y.col(j));
    (0..mass.len()).map(|r| mass[r] * xc[r] * yc[r]).sum()
}

/// `M`-orthonormalizes the columns of `w` against `q` (twice) and among themselves. Returns the
/// coefficients `h = Qᵀ M W₀` and the upper-triangular `R` with `W₀ = Q h + W R`.
fn orthonormalize(
    w: &mut Mat<f64>,
    q: MatRef<'_, f64>,
    mass: &[f64],
    rng: &mut SplitMix64,
) -> (Mat<f64>, Mat<f64>) {
    let b = w.ncols();
    let mut h = Mat::<f64>::zeros(q.ncols(), b);
    let original: Vec<f64> = (0..b)
        .map(|c| m_dot(w.as_ref(), c, w.as_ref(), c, mass).sqrt())
        .collect();
    if q.ncols() > 0 {
        for _ in 0..2 {
            let pass = gram(q, mass_times(w.as_ref(), mass).as_ref());
            product_into(w.as_mut(), Accum::Add, q, pass.as_ref(), -1.0);
            h += &pass;
        }
    }
    let mut r = Mat::<f64>::zeros(b, b);
    for c in 0..b {
        for _ in 0..2 {
            for d in 0..c {
                let coef = m_dot(w.as_ref(), d, w.as_ref(), c, mass);
                r[(d, c)] += coef;
                for i in 0..mass.len() {
                    let x = w[(i, d)];
                    w[(i, c)] -= coef * x;
                }
            }
        }
        let norm = m_dot(w.as_ref(), c, w.as_ref(), c, mass).sqrt();
        if norm > 1e-10 * original[c] && norm > 0.0 {
            r[(c, c)] = norm;
            w.col_mut(c).iter_mut().for_each(|x| *x /= norm);
        } else {
            // Breakdown: an invariant subspace; continue with a fresh direction (R[c, c] = 0).
            let mut fresh = Mat::<f64>::from_fn(mass.len(), 1, |_, _| rng.signed_unit_f64());
            for _ in 0..2 {
                if q.ncols() > 0 {
                    let p = gram(q, mass_times(fresh.as_ref(), mass).as_ref());
                    product_into(fresh.as_mut(), Accum::Add, q, p.as_ref(), -1.0);
                }
                for d in 0..c {
                    let coef = m_dot(w.as_ref(), d, fresh.as_ref(), 0, mass);
                    for i in 0..mass.len() {
                        fresh[(i, 0)] -= coef * w[(i, d)];
                    }
                }
            }
            let fnorm = m_dot(fresh.as_ref(), 0, fresh.as_ref(), 0, mass).sqrt();
            for i in 0..mass.len() {
                w[(i, c)] = fresh[(i, 0)] / fnorm;
            }
        }
    }
    (h, r)
}

/// Ritz values (descending), Ritz vectors in basis coordinates, residual estimates.
type RitzPairs = (Vec<f64>, Mat<f64>, Vec<f64>);

/// One Rayleigh–Ritz step on the leading `dim × dim` block of `h`: Ritz values (descending),
/// vectors, and residual estimates `‖R s₊‖ / θ` using the coupling block `h[dim.., dim-b..dim]`.
fn rayleigh_ritz(h: &Mat<f64>, dim: usize, b: usize) -> Result<RitzPairs, LanczosError> {
    let sym = Mat::<f64>::from_fn(dim, dim, |i, j| 0.5 * (h[(i, j)] + h[(j, i)]));
    let (vals, vecs) = symmetric_eigen(sym.as_ref())?;
    // Descending order.
    let theta: Vec<f64> = vals.iter().rev().copied().collect();
    let s = Mat::<f64>::from_fn(dim, dim, |i, j| vecs[(i, dim - 1 - j)]);
    let est = (0..dim)
        .map(|j| {
            let mut sq = 0.0;
            for a in 0..b {
                let mut acc = 0.0;
                for c in 0..b {
                    acc += h[(dim + a, dim - b + c)] * s[(dim - b + c, j)];
                }
                sq += acc * acc;
            }
            sq.sqrt() / theta[j].abs().max(f64::MIN_POSITIVE)
        })
        .collect();
    Ok((theta, s, est))
}

/// The `k` largest eigenvalues `θ` of `Op = (K − σM)⁻¹ M` and their `M`-orthonormal vectors,
/// given `factor` = Cholesky of `K − σM` and the diagonal `mass` of `M` (all positive). Solves
/// run through [`NumericCholesky::solve_many`]. `progress(converged)` is called after every
/// block (return `Err` to cancel).
///
/// # Errors
/// As [`shift_invert_lanczos_with`].
pub fn shift_invert_lanczos(
    factor: &NumericCholesky,
    mass: &[f64],
    k: usize,
    params: &LanczosParams,
    progress: &mut dyn FnMut(usize) -> Result<(), Cancelled>,
) -> Result<ShiftInvertEigen, LanczosError> {
    let n = factor.dim();
    let mut solve = |mut block: MatMut<'_, f64>| -> Result<(), LinalgError> {
        let mut rhs: Vec<Vec<f64>> = (0..block.ncols())
            .map(|c| (0..n).map(|i| block[(i, c)]).collect())
            .collect();
        factor.solve_many(&mut rhs)?;
        for (c, x) in rhs.iter().enumerate() {
            for i in 0..n {
                block[(i, c)] = x[i];
            }
        }
        Ok(())
    };
    shift_invert_lanczos_with(n, &mut solve, mass, k, params, progress)
}

/// As [`shift_invert_lanczos`] with any solver of `(K − σM) X = B`: `solve(block)` replaces
/// the `n × b` block `B` by `X`. It must be deterministic for determinism of the result.
///
/// # Errors
/// [`LanczosError::InvalidParam`] for bad parameters or `k` (`1 ≤ k`,
/// `k + 2·block_size ≤ basis ≤ n − block_size`), [`LanczosError::Linalg`] for a failed solve,
/// [`LanczosError::DenseEigen`], [`LanczosError::Cancelled`].
pub fn shift_invert_lanczos_with(
    n: usize,
    solve: &mut dyn FnMut(MatMut<'_, f64>) -> Result<(), LinalgError>,
    mass: &[f64],
    k: usize,
    params: &LanczosParams,
    progress: &mut dyn FnMut(usize) -> Result<(), Cancelled>,
) -> Result<ShiftInvertEigen, LanczosError> {
    let b = params.block_size;
    if !(1..=64).contains(&b) {
        return Err(LanczosError::InvalidParam(format!(
            "block_size = {b}, range [1, 64]"
        )));
    }
    let tol = params.tolerance;
    if !(1e-15..=1e-2).contains(&tol) {
        return Err(LanczosError::InvalidParam(format!(
            "tolerance = {tol}, range [1e-15, 1e-2]"
        )));
    }
    if mass.len() != n || mass.iter().any(|&m| m.is_nan() || m <= 0.0) {
        return Err(LanczosError::InvalidParam(
            "mass must have n positive entries".into(),
        ));
    }
    let cap = if params.basis_size == 0 {
        (2 * k).max(k + 4 * b).div_ceil(b) * b
    } else {
        params.basis_size
    };
    if k == 0 || cap < k + 2 * b || cap + b > n {
        return Err(LanczosError::InvalidParam(format!(
            "need 1 <= k, k + 2·block_size <= basis size <= n - block_size \
             (k = {k}, basis = {cap}, block = {b}, n = {n})"
        )));
    }
    // Ritz vectors kept at a restart (then at least one block fits before the next one).
    let keep = k + (cap - b - k) / 2;
    let mut rng = SplitMix64::new(params.seed);
    // Basis: up to `cap` expanded columns plus the newest block.
    let mut q = Mat::<f64>::zeros(n, cap + b);
    let mut h = Mat::<f64>::zeros(cap + b, cap);
    let mut start = Mat::<f64>::from_fn(n, b, |_, _| rng.signed_unit_f64());
    orthonormalize(&mut start, q.as_ref().subcols(0, 0), mass, &mut rng);
    q.as_mut().subcols_mut(0, b).copy_from(&start);
    drop(start);
    let mut used = b;
    let (mut restarts, mut applications) = (0usize, 0usize);
    loop {
        // Expand: W = Op Q[:, active..active + b], with active = used - b.
        let active = used - b;
        let mut w = mass_times(q.as_ref().subcols(active, b), mass);
        solve(w.as_mut())?;
        applications += b;
        let (coef, r) = orthonormalize(&mut w, q.as_ref().subcols(0, used), mass, &mut rng);
        h.as_mut()
            .submatrix_mut(0, active, used, b)
            .copy_from(&coef);
        h.as_mut().submatrix_mut(used, active, b, b).copy_from(&r);
        q.as_mut().subcols_mut(used, b).copy_from(&w);
        drop(w);
        let dim = used;
        used += b;
        let must_restart = dim + b > cap;
        if dim < k + b && !must_restart {
            progress(0)?;
            continue;
        }
        let (theta, s, est) = rayleigh_ritz(&h, dim, b)?;
        let converged = est.iter().take(k).take_while(|&&e| e <= tol).count();
        progress(converged)?;
        let give_up = must_restart && restarts >= params.max_restarts;
        if converged >= k || give_up {
            let mut vectors = Mat::<f64>::zeros(n, k);
            product_into(
                vectors.as_mut(),
                Accum::Replace,
                q.as_ref().subcols(0, dim),
                s.as_ref().subcols(0, k),
                1.0,
            );
            return Ok(ShiftInvertEigen {
                theta: theta[..k].to_vec(),
                vectors,
                residual_estimates: est[..k].to_vec(),
                converged,
                restarts,
                operator_applications: applications,
            });
        }
        if must_restart {
            // Krylov–Schur: keep the best `keep` Ritz vectors and the newest block.
            let mut kept = Mat::<f64>::zeros(n, keep);
            product_into(
                kept.as_mut(),
                Accum::Replace,
                q.as_ref().subcols(0, dim),
                s.as_ref().subcols(0, keep),
                1.0,
            );
            let newest = q.as_ref().subcols(dim, b).to_owned();
            q.as_mut().subcols_mut(0, keep).copy_from(&kept);
            q.as_mut().subcols_mut(keep, b).copy_from(&newest);
            let mut coupling = Mat::<f64>::zeros(b, keep);
            matmul(
                coupling.as_mut(),
                Accum::Replace,
                h.as_ref().submatrix(dim, dim - b, b, b),
                s.as_ref().submatrix(dim - b, 0, b, keep),
                1.0,
                Par::Seq,
            );
            h.fill(0.0);
            for i in 0..keep {
                h[(i, i)] = theta[i];
            }
            h.as_mut()
                .submatrix_mut(keep, 0, b, keep)
                .copy_from(&coupling);
            used = keep + b;
            restarts += 1;
        }
    }
}
