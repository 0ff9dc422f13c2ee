//! The low end of the Laplace–Beltrami spectrum of a surface: the `k` smallest eigenpairs of the
//! generalized problem
//!
//! ```text
//!     −L φ = λ M φ,    λ ≥ 0,    φᵢᵀ M φⱼ = δᵢⱼ
//! ```
//!
//! with `L` the cotan Laplacian (negative semi-definite, see [`super::laplacian`]) and `M` the
//! lumped mass matrix. **Sign convention:** eigenvalues are non-negative and ascending
//! (`λ₀ = 0` with a constant `φ₀` on a connected surface); units 1 / world units², so scaling
//! the surface by `s` divides every `λ` by `s²` and every `φ` by `s`. On the unit sphere the
//! continuous spectrum is `l(l + 1)` with multiplicity `2l + 1`. Rounding-level negative
//! Rayleigh quotients (of a constant mode) are reported as 0.
//!
//! Solvers ([`SpectrumSolver`]):
//! - **Iterative** (default above [`SpectrumParams::dense_max_vertices`]): shift-invert block
//!   Lanczos with thick restarts ([`crate::engine::linalg::lanczos`]) on the Cholesky factor of
//!   `−L − σM`, `σ = −shift · trace(−L) / trace(M)` (slightly below 0, so the matrix is
//!   positive definite). The final eigenvalues are the Rayleigh quotients `φᵀ(−L)φ` of the
//!   `M`-normalized Ritz vectors.
//! - **Dense** (small meshes): faer's symmetric eigendecomposition of
//!   `M^{-1/2} (−L) M^{-1/2}`, then `φ = M^{-1/2} u`. O(n³) time, O(n²) memory.
//!
//! Every result carries its residuals `‖−Lφᵢ − λᵢ M φᵢ‖_{M⁻¹}` divided by the largest computed
//! eigenvalue (a backward error relative to the computed part of the spectrum), and whether the
//! iteration converged. Each eigenvector's sign is fixed so that its largest-magnitude entry
//! (first on ties) is positive; inside a repeated eigenvalue the basis is arbitrary but
//! deterministic (seeded start block, thread-count independent sums).
//!
//! Vertices whose mass is 0 (used only by zero-area faces) get the tiny mass
//! `1e-12 · area / n`, as in [`super::heat`].
//!
//! Written by hand: operator assembly and post-processing around faer and
//! [`crate::engine::linalg`].

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LltRef, SymbolicCholesky as FaerSymbolic, SymmetricOrdering,
};
use faer::{Conj, Mat, MatMut, Par, Side};

use crate::engine::linalg::simd_state::{clear_upper_vector_state, clear_upper_vector_state_here};
use rayon::prelude::*;

use super::laplacian::{cotan_laplacian, GeometryError, Laplacian, LaplacianParams};
use crate::engine::control::Control;
use crate::engine::linalg::lanczos::{
    shift_invert_lanczos_with, symmetric_eigen, LanczosError, LanczosParams,
};
use crate::engine::linalg::{LinalgError, SymmetricMatrix};
use crate::engine::mesh::Surface;

/// Which eigensolver [`laplace_spectrum`] uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SpectrumSolver {
    /// Dense up to [`SpectrumParams::dense_max_vertices`] vertices, iterative above.
    #[default]
    Auto,
    /// Always dense (refused above 8000 vertices).
    Dense,
    /// Always shift-invert Lanczos.
    Iterative,
}

/// Parameters of [`laplace_spectrum`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SpectrumParams {
    /// Number `k` of eigenpairs (the lowest). Default: 100. Range: [1, n − 1] (iterative:
    /// `k + 3·block_size ≤ n`).
    pub count: usize,
    /// Laplacian and mass matrix. Default: mixed Voronoi mass, cotangent clamp 1e5.
    pub laplacian: LaplacianParams,
    /// Solver choice. Default: `auto`.
    pub solver: SpectrumSolver,
    /// `auto` uses the dense solver up to this many vertices. Default: 2000. Range: [0, 8000].
    pub dense_max_vertices: usize,
    /// Relative shift: `σ = −shift · trace(−L) / trace(M)` (dimensionless). Default: 1e-8.
    /// Range: (0, 1e-2].
    pub shift: f64,
    /// Iteration parameters (block size, basis size, tolerance, restarts, seed).
    pub lanczos: LanczosParams,
}

impl Default for SpectrumParams {
    fn default() -> Self {
        Self {
            count: 100,
            laplacian: LaplacianParams::default(),
            solver: SpectrumSolver::Auto,
            dense_max_vertices: 2000,
            shift: 1e-8,
            lanczos: LanczosParams::default(),
        }
    }
}

/// The lowest eigenpairs of `−L φ = λ M φ`.
#[derive(Clone, Debug)]
pub struct Spectrum {
    /// Eigenvalues, ascending, 1 / world units².
    pub values: Vec<f64>,
    /// Eigenvectors, column-major `n × k` (vector `i` is `vectors[i·n..(i+1)·n]`),
    /// `M`-orthonormal.
    pub vectors: Vec<f64>,
    /// Diagonal of `M` used (world units²).
    pub mass: Vec<f64>,
    /// `‖−Lφᵢ − λᵢ M φᵢ‖_{M⁻¹} / λ_{k−1}` per pair (dimensionless).
    pub residuals: Vec<f64>,
    /// Whether every pair met the tolerance (always true for the dense solver).
    pub converged: bool,
    /// The solver that ran (`dense` or `iterative`).
    pub solver: SpectrumSolver,
    /// Solves with the shifted factor (0 for dense).
    pub operator_applications: usize,
    /// Thick restarts of the Lanczos iteration (0 for dense).
    pub restarts: usize,
}

impl Spectrum {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.mass.len()
    }

    /// Number of eigenpairs.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether there are no eigenpairs.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Eigenvector `i`.
    pub fn vector(&self, i: usize) -> &[f64] {
        let n = self.vertex_count();
        &self.vectors[i * n..(i + 1) * n]
    }
}

fn invalid(name: &'static str, value: f64, range: &'static str) -> GeometryError {
    GeometryError::InvalidParam { name, value, range }
}

fn from_lanczos(e: LanczosError) -> GeometryError {
    match e {
        LanczosError::Linalg(e) => GeometryError::Linalg(e),
        LanczosError::Cancelled(c) => GeometryError::Cancelled(c),
        other => GeometryError::Degenerate(other.to_string()),
    }
}

/// Builds `L` and `M` of `surface` and computes the lowest `params.count` eigenpairs.
///
/// # Errors
/// As [`cotan_laplacian`]; [`GeometryError::InvalidParam`] for out-of-range parameters;
/// [`GeometryError::Degenerate`] for zero total area or a failed dense eigendecomposition;
/// [`GeometryError::Linalg`] when the shifted matrix cannot be factored; cancellation.
pub fn laplace_spectrum(
    surface: &Surface,
    params: &SpectrumParams,
    control: &Control,
) -> Result<Spectrum, GeometryError> {
    control.stage("spectrum: operators", 0)?;
    let lap = cotan_laplacian(surface, &params.laplacian)?;
    pencil_spectrum(&lap, params, control)
}

/// As [`laplace_spectrum`] for an already built Laplacian (`params.laplacian` is ignored).
///
/// # Errors
/// As [`laplace_spectrum`].
pub fn pencil_spectrum(
    lap: &Laplacian,
    params: &SpectrumParams,
    control: &Control,
) -> Result<Spectrum, GeometryError> {
    let n = lap.mass.len();
    let k = params.count;
    if k == 0 || k >= n {
        return Err(invalid("count", k as f64, "[1, n - 1]"));
    }
    if params.dense_max_vertices > 8000 {
        return Err(invalid(
            "dense_max_vertices",
            params.dense_max_vertices as f64,
            "[0, 8000]",
        ));
    }
    if params.shift.is_nan() || params.shift <= 0.0 || params.shift > 1e-2 {
        return Err(invalid("shift", params.shift, "(0, 1e-2]"));
    }
    let area: f64 = lap.mass.iter().sum();
    if area.is_nan() || area <= 0.0 {
        return Err(GeometryError::Degenerate("zero total area".into()));
    }
    let mass = lap.definite_mass();
    let solver = match params.solver {
        SpectrumSolver::Auto if n <= params.dense_max_vertices => SpectrumSolver::Dense,
        SpectrumSolver::Auto => SpectrumSolver::Iterative,
        s => s,
    };
    let (vectors, applications, restarts, converged) = if solver == SpectrumSolver::Dense {
        if n > 8000 {
            return Err(invalid("solver (dense, vertices)", n as f64, "[1, 8000]"));
        }
        control.stage("spectrum: dense eigendecomposition", 0)?;
        (dense_vectors(lap, &mass, k)?, 0, 0, true)
    } else {
        let trace_k: f64 = -lap.stiffness.diagonal().iter().sum::<f64>();
        let sigma = -params.shift * trace_k / area;
        control.stage("spectrum: factorization", 0)?;
        let shifted = lap.stiffness.scaled_plus_diagonal(-1.0, -sigma, &mass);
        let factor = BlockFactor::new(&shifted)?;
        let stage = control.stage("spectrum: lanczos", k as u64)?;
        let mut reported = 0usize;
        let mut progress = |converged: usize| {
            let delta = converged.saturating_sub(reported);
            reported = reported.max(converged);
            stage.tick(delta as u64)
        };
        let mut solve = |block: MatMut<'_, f64>| {
            factor.solve_block(block);
            Ok(())
        };
        let eig =
            shift_invert_lanczos_with(n, &mut solve, &mass, k, &params.lanczos, &mut progress)
                .map_err(from_lanczos)?;
        let vecs: Vec<Vec<f64>> = (0..k)
            .map(|j| eig.vectors.col(j).iter().copied().collect())
            .collect();
        (
            vecs,
            eig.operator_applications,
            eig.restarts,
            eig.converged >= k,
        )
    };
    control.stage("spectrum: residuals", 0)?;
    finish(
        lap,
        mass,
        vectors,
        (solver, applications, restarts, converged),
    )
}

/// Right-hand sides solved together per task (fixed, so results do not depend on threads).
const SOLVE_GROUP: usize = 4;

/// The sparse Cholesky factor of `−L − σM` with block solves: faer's supernodal solve reads the
/// factor once per group of [`SOLVE_GROUP`] right-hand sides, where
/// [`crate::engine::linalg::NumericCholesky::solve_many`] reads it once per right-hand side
/// (the solves are memory bound, so this is about 3× faster per vector).
struct BlockFactor {
    symbolic: FaerSymbolic<usize>,
    l_values: Vec<f64>,
}

impl BlockFactor {
    fn new(matrix: &SymmetricMatrix) -> Result<Self, GeometryError> {
        let fail = |e: String| GeometryError::Linalg(LinalgError::Factorization(e));
        let pattern = matrix.pattern();
        let symbolic = factorize_symbolic_cholesky(
            pattern.as_faer(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .map_err(|e| fail(format!("{e:?}")))?;
        let par = Par::rayon(0);
        let mut l_values = vec![0.0; symbolic.len_val()];
        let scratch = symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default());
        let mut mem = MemBuffer::try_new(scratch).map_err(|e| fail(format!("{e:?}")))?;
        let factored = symbolic
            .factorize_numeric_llt::<f64>(
                &mut l_values,
                matrix.as_faer(),
                Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|_| GeometryError::Linalg(LinalgError::NotPositiveDefinite { column: 0 }));
        clear_upper_vector_state();
        factored?;
        Ok(Self { symbolic, l_values })
    }

    /// Replaces `block` by `(−L − σM)⁻¹ block`, groups of columns in parallel.
    fn solve_block(&self, block: MatMut<'_, f64>) {
        block.par_col_chunks_mut(SOLVE_GROUP).for_each(|mut cols| {
            let scratch = self
                .symbolic
                .solve_in_place_scratch::<f64>(cols.ncols(), Par::Seq);
            let mut mem = MemBuffer::new(scratch);
            let llt = LltRef::<'_, usize, f64>::new(&self.symbolic, &self.l_values);
            llt.solve_in_place_with_conj(
                Conj::No,
                cols.as_mut(),
                Par::Seq,
                MemStack::new(&mut mem),
            );
            clear_upper_vector_state_here();
        });
    }
}

/// Dense solve: eigenvectors of `M^{-1/2}(−L)M^{-1/2}`, mapped back by `M^{-1/2}`.
fn dense_vectors(lap: &Laplacian, mass: &[f64], k: usize) -> Result<Vec<Vec<f64>>, GeometryError> {
    let n = mass.len();
    let inv_sqrt: Vec<f64> = mass.iter().map(|m| 1.0 / m.sqrt()).collect();
    let mut a = Mat::<f64>::zeros(n, n);
    for (i, j, v) in lap.stiffness.triplets() {
        a[(i, j)] = -v * inv_sqrt[i] * inv_sqrt[j];
    }
    let (_, u) = symmetric_eigen(a.as_ref()).map_err(from_lanczos)?;
    Ok((0..k)
        .map(|j| (0..n).map(|i| u[(i, j)] * inv_sqrt[i]).collect())
        .collect())
}

type SolveInfo = (SpectrumSolver, usize, usize, bool);

/// Normalizes, fixes signs, computes Rayleigh quotients and residuals, sorts ascending.
fn finish(
    lap: &Laplacian,
    mass: Vec<f64>,
    vectors: Vec<Vec<f64>>,
    (solver, operator_applications, restarts, converged): SolveInfo,
) -> Result<Spectrum, GeometryError> {
    let n = mass.len();
    let mut pairs: Vec<(f64, Vec<f64>, Vec<f64>)> = vectors
        .into_par_iter()
        .map(|mut v| {
            let norm = v
                .iter()
                .zip(&mass)
                .map(|(x, m)| x * x * m)
                .sum::<f64>()
                .sqrt();
            let mut big = 0usize;
            for i in 0..n {
                if v[i].abs() > v[big].abs() {
                    big = i;
                }
            }
            let s = if v[big] < 0.0 { -1.0 } else { 1.0 } / norm;
            v.iter_mut().for_each(|x| *x *= s);
            // K φ = −L φ.
            let kv: Vec<f64> = lap.stiffness.mul_vec(&v).iter().map(|x| -x).collect();
            let lambda: f64 = kv.iter().zip(&v).map(|(a, b)| a * b).sum();
            (lambda.max(0.0), v, kv)
        })
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let top = pairs.last().map_or(1.0, |p| p.0);
    let top = if top > 0.0 { top } else { 1.0 };
    let residuals = pairs
        .par_iter()
        .map(|(lambda, v, kv)| {
            let r2: f64 = (0..n)
                .map(|i| {
                    let r = kv[i] - lambda * mass[i] * v[i];
                    r * r / mass[i]
                })
                .sum();
            r2.sqrt() / top
        })
        .collect();
    let mut values = Vec::with_capacity(pairs.len());
    let mut flat = Vec::with_capacity(pairs.len() * n);
    for (lambda, v, _) in pairs {
        values.push(lambda);
        flat.extend(v);
    }
    Ok(Spectrum {
        values,
        vectors: flat,
        mass,
        residuals,
        converged,
        solver,
        operator_applications,
        restarts,
    })
}
