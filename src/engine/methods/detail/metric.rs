//! Metric learning (Berkiten et al. 2017, §3.2.3, eqs. 1-2): a Mahalanobis metric `M ⪰ 0` on
//! the geometric features whose inner products imitate the detail features' inner products,
//!
//! ```text
//!   min_M  (1/n²) ‖T − GᵀMG‖²_F + λ ‖M‖₁    s.t.  M ⪰ 0,
//! ```
//!
//! with `G` the `d × n` geometric features (z-scored per feature over the shape: mean 0,
//! population standard deviation 1; a feature constant on the shape becomes 0), `T = D̄D̄ᵀ` the
//! `n × n` inner products of the mean-subtracted detail features `D̄` (`n × k`), and `‖M‖₁` the
//! entry-wise ℓ1 norm (diagonal included). `λ = 0.1` is the paper's value.
//!
//! **Scaling (not in the paper).** The paper states eq. 2 without the `1/n²`. Its data term grows
//! as `n²` while the ℓ1 term does not, so on a mesh of thousands of vertices `λ = 0.1` would be
//! a no-op; with `1/n²` both terms are per-pair averages and `λ` means the same on every mesh.
//!
//! **Never forming `T`.** With `Ĉ = GGᵀ/n` (the features' correlation matrix) and
//! `B̂ = G T Gᵀ/n² = (GD̄)(GD̄)ᵀ/n²`, and using `tr(T GᵀMG) = tr(BM)`, `‖GᵀMG‖² = tr(MCMC)`:
//!
//! ```text
//!   f(M) = (1/n²)‖T‖² − 2 tr(B̂M) + tr(MĈMĈ),     ∇f(M) = 2 (ĈMĈ − B̂),
//! ```
//!
//! and `‖T‖² = ‖D̄ᵀD̄‖²` (`k × k`). Every quantity is `d × d` or smaller: the cost of the solver
//! does not depend on `n` after one `O(n d (d + k))` pass.
//!
//! **Solver: two-block ADMM (Boyd et al. 2011, consensus form).** Soft-thresholding followed by
//! a PSD projection is *not* the proximal operator of `λ‖·‖₁ + ι_PSD` and does not reach the
//! optimum, so the two non-smooth terms go into separate copies:
//!
//! ```text
//!   min f(M) + λ‖Z₁‖₁ + ι_PSD(Z₂)   s.t.  M = Z₁,  M = Z₂.
//! ```
//!
//! The first block is `M`, the second the pair `(Z₁, Z₂)` (separable given `M`); this is the
//! standard two-block ADMM with `A = [I; I]`, `B = −I`, which converges for any `ρ > 0` because
//! every term is closed, proper and convex. Scaled duals `U₁, U₂`, `Vᵢ = Zᵢ − Uᵢ`:
//!
//! * M-step: `∇f(M) + ρ(M − V₁) + ρ(M − V₂) = 0` ⇔ `ĈMĈ + ρM = B̂ + (ρ/2)(V₁ + V₂) =: R`.
//!   In the eigenbasis `Ĉ = QΛQᵀ` (computed once), with `M̃ = QᵀMQ`, `R̃ = QᵀRQ`, this is
//!   `c_i c_j M̃_ij + ρ M̃_ij = R̃_ij`, so `M̃_ij = R̃_ij / (c_i c_j + ρ)`: exact, `O(d³)`.
//! * Z-step: `Z₁ = soft(M + U₁, λ/ρ)` (entry-wise), `Z₂ = Π_PSD(M + U₂)` (eigenvalues clipped at
//!   0): each is the exact proximal operator of its own term.
//! * Dual: `Uᵢ += M − Zᵢ`.
//!
//! **Stopping rule** (Boyd et al. §3.3.1): primal residual `r = ‖(M − Z₁, M − Z₂)‖_F`, dual
//! residual `s = ρ‖ΔZ₁ + ΔZ₂‖_F`; stop when `r ≤ √(2)·d·ε_abs + ε_rel·max(√2‖M‖, ‖(Z₁,Z₂)‖)` and
//! `s ≤ d·ε_abs + ε_rel·ρ‖U₁ + U₂‖`, or after `max_iterations` (then `converged = false`).
//! `ε_abs` is relative to the problem's scale `‖B̂‖_F / ‖Ĉ‖²_F` (the size of the unregularised
//! solution), so the rule does not depend on the units of the detail features. `ρ` starts at 1
//! (z-scored features: `tr Ĉ = d`) and is rebalanced every 10 iterations (×2 when `r > 10 s`,
//! ÷2 when `s > 10 r`, duals rescaled; Boyd §3.4.1); the rebalancing stops after 500 iterations so
//! that the fixed-`ρ` convergence guarantee applies to the tail.
//!
//! **Tolerances** (ours; the paper gives none): `ε_abs = 1e-9`, `ε_rel = 1e-6`. The tail
//! converges sublinearly (the data term is flat along `Ĉ`'s near-null directions: correlated
//! HKS / WKS columns), so each decade of `ε_rel` costs several thousand iterations on real pairs;
//! at `1e-8` the koala → cat pair ran into the 20,000-iteration cap (`converged = false`, 10 s).
//! `1e-6` gave byte-identical synthesis output to `1e-7` and `1e-8` on that pair (before the
//! residue floor below) and an objective
//! within 2e-6 relative on three real pairs (README "detail", "The metric solver's tolerance").
//! Over-relaxation (Boyd §3.4.3, α = 1.5-1.8) cut the iterations by a third on real pairs but
//! stalled on a λ = 0 test problem (not converged in 20,000 iterations), so it is not used.
//!
//! The returned metric is `Z₂` (exactly PSD); at convergence it equals `M` and `Z₁` within the
//! primal residual. [`factor`] gives `A` with `M = AᵀA` from the eigen-decomposition (`M` is
//! singular in general, so no Cholesky): rows `√μ_k q_kᵀ` for the eigenvalues `μ_k` above
//! `1e-12 · μ_max`; the pipeline uses [`factor_above`] with [`residue_floor`] (10 × the solver's
//! resolution), which leaves out the eigenvalues that are the solver's residue (they cost
//! matching time and carry no information). [`transform`] applies it to features (eqs. 3-4). [`MetricKind::Identity`] is
//! the paper's equal-weights baseline (§5, "No Metric Learning"): z-scored features, `M = I`.

use faer::Mat;
use serde::Serialize;

use crate::engine::linalg::lanczos::symmetric_eigen;

/// The paper's ℓ1 weight.
pub const DEFAULT_LAMBDA: f64 = 0.1;

/// Which metric the synthesis uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MetricKind {
    /// Learned by [`learn_metric`].
    Learned,
    /// `M = I` on the z-scored features (the paper's equal-weights baseline).
    Identity,
}

/// Solver settings of [`learn_metric`].
#[derive(Clone, Copy, Debug)]
pub struct MetricParams {
    /// ℓ1 weight `λ ≥ 0`.
    pub lambda: f64,
    /// Initial ADMM penalty `ρ > 0`.
    pub rho: f64,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Absolute tolerance (relative to the problem scale, see the module doc).
    pub eps_abs: f64,
    /// Relative tolerance.
    pub eps_rel: f64,
}

impl Default for MetricParams {
    fn default() -> Self {
        Self {
            lambda: DEFAULT_LAMBDA,
            rho: 1.0,
            max_iterations: 20_000,
            eps_abs: 1e-9,
            eps_rel: 1e-6,
        }
    }
}

/// Errors of the metric learning.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MetricError {
    /// Fewer than two samples or zero features.
    #[error("metric learning needs at least 2 samples and 1 feature (got {samples} samples, {features} features)")]
    TooSmall {
        /// Samples given.
        samples: usize,
        /// Geometric features per sample.
        features: usize,
    },
    /// An array does not have `samples × width` entries.
    #[error("{what} has {got} values, expected {expected}")]
    Shape {
        /// Which array.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// A value is NaN or infinite.
    #[error("{what} value {index} is not finite")]
    NonFinite {
        /// Which array.
        what: &'static str,
        /// Index into it.
        index: usize,
    },
    /// A parameter is out of range.
    #[error("invalid metric parameter: {0}")]
    Param(String),
    /// The dense eigen-decomposition failed.
    #[error("eigen-decomposition failed")]
    Eigen,
}

/// The problem in its `d × d` form: `Ĉ`, `B̂` and `‖T‖²/n²` (see the module doc).
#[derive(Clone, Debug)]
pub struct MetricProblem {
    /// `Ĉ = GGᵀ/n`, symmetric PSD.
    pub c: Mat<f64>,
    /// `B̂ = GTGᵀ/n²`, symmetric PSD.
    pub b: Mat<f64>,
    /// `‖T‖²_F / n²`.
    pub t_norm2: f64,
}

/// A column whose standard deviation is below this fraction of its mean's magnitude is treated
/// as constant (weight 0). Z-scoring would otherwise blow discretisation noise up to unit
/// variance: on a sphere the HKS / WKS columns are constant up to the tessellation, and the
/// learned metric then fitted that noise (measured: 99 % of the diagonal on HKS / WKS for bumps
/// that the height and normal columns explain). Not in the paper; retex's guard. The value is
/// chosen from measured noise (README "detail", "The floor measured"): on round spheres, where
/// these columns are constant in theory, std ÷ |mean| is ≤ 7e-4 on the HKS and 2e-3-7.5e-3 on
/// the WKS, while genuine columns of real shapes are ≥ 0.2 on the WKS and ≥ 1e-2 on the HKS
/// (except times where heat has spread over the whole shape); 1e-2 drops both noises (1e-3, the
/// value until 2026-12-06, kept the WKS noise) and left every learned figure of the tests and
/// of the two real scans' known answers unchanged.
pub const RELATIVE_STD_FLOOR: f64 = 1e-2;

/// Z-scoring of features: per-column mean and `1/std` (0 for a constant column, see
/// [`RELATIVE_STD_FLOOR`]).
#[derive(Clone, Debug, Serialize)]
pub struct ZScore {
    /// Per-feature mean.
    pub mean: Vec<f64>,
    /// Per-feature `1/std` (population), 0 for a constant feature.
    pub inv_std: Vec<f64>,
}

impl ZScore {
    /// Fit on `n × d` row-major features.
    pub fn fit(features: &[f64], d: usize) -> ZScore {
        let n = features.len() / d.max(1);
        let mut mean = vec![0.0; d];
        for row in features.chunks_exact(d) {
            for (m, x) in mean.iter_mut().zip(row) {
                *m += x;
            }
        }
        mean.iter_mut().for_each(|m| *m /= n.max(1) as f64);
        let mut var = vec![0.0; d];
        for row in features.chunks_exact(d) {
            for j in 0..d {
                var[j] += (row[j] - mean[j]).powi(2);
            }
        }
        let inv_std = var
            .iter()
            .zip(&mean)
            .map(|(v, m)| {
                let s = (v / n.max(1) as f64).sqrt();
                if s > 1e-12 * (1.0 + m.abs()) && s > RELATIVE_STD_FLOOR * m.abs() {
                    1.0 / s
                } else {
                    0.0
                }
            })
            .collect();
        ZScore { mean, inv_std }
    }

    /// The z-scored copy of `n × d` row-major features.
    pub fn apply(&self, features: &[f64]) -> Vec<f64> {
        let d = self.mean.len();
        let mut out = features.to_vec();
        for row in out.chunks_exact_mut(d) {
            for j in 0..d {
                row[j] = (row[j] - self.mean[j]) * self.inv_std[j];
            }
        }
        out
    }
}

fn check_finite(what: &'static str, values: &[f64]) -> Result<(), MetricError> {
    match values.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(MetricError::NonFinite { what, index }),
        None => Ok(()),
    }
}

impl MetricProblem {
    /// Builds the problem from `n × d` geometric features (z-scored here) and `n × k` detail
    /// features (mean-subtracted here), both row-major. `O(n·d·(d + k))`.
    ///
    /// # Errors
    /// [`MetricError`] on empty or mismatched shapes and non-finite values.
    pub fn from_features(
        geometric: &[f64],
        d: usize,
        detail: &[f64],
        k: usize,
    ) -> Result<MetricProblem, MetricError> {
        let n = geometric.len().checked_div(d).unwrap_or(0);
        if n < 2 || d == 0 || k == 0 {
            return Err(MetricError::TooSmall {
                samples: n,
                features: d,
            });
        }
        for (what, arr, w) in [("geometric", geometric, d), ("detail", detail, k)] {
            if arr.len() != n * w {
                return Err(MetricError::Shape {
                    what,
                    expected: n * w,
                    got: arr.len(),
                });
            }
            check_finite(what, arr)?;
        }
        let g = ZScore::fit(geometric, d).apply(geometric);
        let mut dmean = vec![0.0; k];
        for row in detail.chunks_exact(k) {
            dmean.iter_mut().zip(row).for_each(|(m, x)| *m += x);
        }
        dmean.iter_mut().for_each(|m| *m /= n as f64);
        let gm = Mat::<f64>::from_fn(d, n, |i, j| g[j * d + i]);
        let dm = Mat::<f64>::from_fn(n, k, |i, j| detail[i * k + j] - dmean[j]);
        let nf = n as f64;
        let c = (&gm * gm.transpose()) * (1.0 / nf);
        let gd = &gm * &dm; // d × k
        let b = (&gd * gd.transpose()) * (1.0 / (nf * nf));
        let dtd = dm.transpose() * &dm; // k × k
        let t_norm2 = dtd.norm_l2().powi(2) / (nf * nf);
        Ok(MetricProblem { c, b, t_norm2 })
    }

    /// The problem with `T` divided by the largest diagonal entry of `B̂` (`B̂` divided by it,
    /// `‖T‖²/n²` by its square), so that `λ` is relative to the strongest covariance between a
    /// geometric feature and the detail: `λ ≥ 2` gives `M = 0` whatever the model's units and the
    /// detail's amplitude. The minimiser scales with `T` and distances under `M` only rank
    /// candidates, so this changes what `λ` means and nothing else. Without it `λ` is in the
    /// squared units of the detail features (standard deviations of world-unit displacements),
    /// and the paper's 0.1 zeroed `M` for any detail below a few tenths of a unit (measured
    /// 2026-12-06: bumps of amplitude 0.01 gave max diag `B̂` 1.2e-6, so λ = 0.1 was 80,000 ×
    /// it and `M` solver residue of 1e-15). The paper does not state its features' scale; its
    /// λ = 0.1 "worked effectively for all of our experiments", which a relative λ makes hold
    /// for every input. A `B̂` without a positive diagonal (no detail) is returned unchanged.
    pub fn relative(mut self) -> Self {
        let d = self.b.nrows();
        let top = (0..d).map(|i| self.b[(i, i)]).fold(0.0f64, f64::max);
        if top > 0.0 && top.is_finite() {
            self.b = &self.b * (1.0 / top);
            self.t_norm2 /= top * top;
        }
        self
    }

    /// Feature count `d`.
    pub fn dim(&self) -> usize {
        self.c.nrows()
    }

    /// The smooth part `f(M)` (the scaled data term).
    pub fn data_term(&self, m: &Mat<f64>) -> f64 {
        let cm = &self.c * m;
        let quad = trace_product(&cm, &cm);
        self.t_norm2 - 2.0 * trace_product(&self.b, m) + quad
    }

    /// `f(M) + λ‖M‖₁`.
    pub fn objective(&self, m: &Mat<f64>, lambda: f64) -> f64 {
        self.data_term(m) + lambda * l1(m)
    }
}

/// `tr(A B)` for square matrices.
fn trace_product(a: &Mat<f64>, b: &Mat<f64>) -> f64 {
    let d = a.nrows();
    let mut s = 0.0;
    for i in 0..d {
        for j in 0..d {
            s += a[(i, j)] * b[(j, i)];
        }
    }
    s
}

/// Entry-wise ℓ1 norm.
pub fn l1(m: &Mat<f64>) -> f64 {
    let mut s = 0.0;
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            s += m[(i, j)].abs();
        }
    }
    s
}

/// The learned metric and the solver's record.
#[derive(Clone, Debug)]
pub struct LearnedMetric {
    /// The metric `M` (`d × d`, symmetric PSD).
    pub m: Mat<f64>,
    /// `f(M) + λ‖M‖₁` at the returned `M`.
    pub objective: f64,
    /// ADMM iterations run.
    pub iterations: usize,
    /// Final primal residual `r`.
    pub primal_residual: f64,
    /// Final dual residual `s`.
    pub dual_residual: f64,
    /// Whether the stopping rule was met (false: the iteration cap ended the run).
    pub converged: bool,
    /// Final penalty `ρ`.
    pub rho: f64,
    /// Entries of the ℓ1 copy `Z₁` that are exactly zero.
    pub zero_entries: usize,
}

/// The metric of `kind`: [`learn_metric`] or the identity.
///
/// # Errors
/// As [`learn_metric`].
pub fn metric_of_kind(
    kind: MetricKind,
    problem: &MetricProblem,
    params: &MetricParams,
) -> Result<LearnedMetric, MetricError> {
    match kind {
        MetricKind::Learned => learn_metric(problem, params),
        MetricKind::Identity => {
            let d = problem.dim();
            let m = Mat::<f64>::identity(d, d);
            Ok(LearnedMetric {
                objective: problem.objective(&m, params.lambda),
                m,
                iterations: 0,
                primal_residual: 0.0,
                dual_residual: 0.0,
                converged: true,
                rho: 0.0,
                zero_entries: d * d - d,
            })
        }
    }
}

fn symmetrised(a: &Mat<f64>) -> Mat<f64> {
    Mat::from_fn(a.nrows(), a.ncols(), |i, j| 0.5 * (a[(i, j)] + a[(j, i)]))
}

/// Projection onto the PSD cone (eigenvalues clipped at 0).
pub fn project_psd(a: &Mat<f64>) -> Result<Mat<f64>, MetricError> {
    let (vals, q) = symmetric_eigen(symmetrised(a).as_ref()).map_err(|_| MetricError::Eigen)?;
    let d = a.nrows();
    let scaled = Mat::<f64>::from_fn(d, d, |i, k| q[(i, k)] * vals[k].max(0.0));
    Ok(symmetrised(&(&scaled * q.transpose())))
}

fn soft_threshold(a: &Mat<f64>, t: f64) -> Mat<f64> {
    Mat::from_fn(a.nrows(), a.ncols(), |i, j| {
        let x = a[(i, j)];
        x.signum() * (x.abs() - t).max(0.0)
    })
}

fn check_params(problem: &MetricProblem, p: &MetricParams) -> Result<(), MetricError> {
    if !(p.lambda.is_finite() && p.lambda >= 0.0) {
        return Err(MetricError::Param(format!(
            "lambda {} must be ≥ 0",
            p.lambda
        )));
    }
    if !(p.rho.is_finite() && p.rho > 0.0) {
        return Err(MetricError::Param(format!("rho {} must be > 0", p.rho)));
    }
    if !(p.eps_abs > 0.0 && p.eps_rel >= 0.0) {
        return Err(MetricError::Param("tolerances must be positive".into()));
    }
    let d = problem.dim();
    if d == 0 || problem.c.ncols() != d || problem.b.nrows() != d || problem.b.ncols() != d {
        return Err(MetricError::Param(
            "C and B must be d × d with d ≥ 1".into(),
        ));
    }
    for j in 0..d {
        for i in 0..d {
            if !problem.c[(i, j)].is_finite() || !problem.b[(i, j)].is_finite() {
                return Err(MetricError::NonFinite {
                    what: "C or B",
                    index: j * d + i,
                });
            }
        }
    }
    Ok(())
}

/// Solves eq. 2 by the two-block ADMM of the module doc.
///
/// # Errors
/// [`MetricError::Param`] for `λ < 0`, `ρ ≤ 0`, bad tolerances or shapes;
/// [`MetricError::Eigen`] when a dense eigen-decomposition fails.
pub fn learn_metric(
    problem: &MetricProblem,
    params: &MetricParams,
) -> Result<LearnedMetric, MetricError> {
    check_params(problem, params)?;
    let d = problem.dim();
    let (cvals, q) =
        symmetric_eigen(symmetrised(&problem.c).as_ref()).map_err(|_| MetricError::Eigen)?;
    let cvals: Vec<f64> = cvals.iter().map(|c| c.max(0.0)).collect();
    let b_tilde = q.transpose() * &problem.b * &q;
    let c_norm2 = cvals.iter().map(|c| c * c).sum::<f64>().max(1e-300);
    let scale = (problem.b.norm_l2() / c_norm2).max(1e-300);
    let eps_abs = params.eps_abs * scale;
    let lambda = params.lambda;
    let df = d as f64;

    let zero = || Mat::<f64>::zeros(d, d);
    let (mut z1, mut z2, mut u1, mut u2) = (zero(), zero(), zero(), zero());
    let mut rho = params.rho;
    let (mut r, mut s) = (f64::INFINITY, f64::INFINITY);
    let mut iterations = 0;
    let mut converged = false;
    while iterations < params.max_iterations {
        iterations += 1;
        // M-step in C's eigenbasis: R̃ = B̃ + (ρ/2) Qᵀ(V₁ + V₂)Q.
        let v = Mat::<f64>::from_fn(d, d, |i, j| {
            0.5 * rho * (z1[(i, j)] - u1[(i, j)] + z2[(i, j)] - u2[(i, j)])
        });
        let v_tilde = q.transpose() * &v * &q;
        let m_tilde = Mat::<f64>::from_fn(d, d, |i, j| {
            (b_tilde[(i, j)] + v_tilde[(i, j)]) / (cvals[i] * cvals[j] + rho)
        });
        let m = symmetrised(&(&q * &m_tilde * q.transpose()));
        // Z-steps: exact proximal operators of each term.
        let z1_new = soft_threshold(&(&m + &u1), lambda / rho);
        let z2_new = project_psd(&(&m + &u2))?;
        let dz = (&z1_new - &z1) + (&z2_new - &z2);
        s = rho * dz.norm_l2();
        z1 = z1_new;
        z2 = z2_new;
        let r1 = &m - &z1;
        let r2 = &m - &z2;
        r = (r1.norm_l2().powi(2) + r2.norm_l2().powi(2)).sqrt();
        u1 += &r1;
        u2 += &r2;
        let z_norm = (z1.norm_l2().powi(2) + z2.norm_l2().powi(2)).sqrt();
        let eps_pri =
            2f64.sqrt() * df * eps_abs + params.eps_rel * (2f64.sqrt() * m.norm_l2()).max(z_norm);
        let eps_dual = df * eps_abs + params.eps_rel * rho * (&u1 + &u2).norm_l2();
        if r <= eps_pri && s <= eps_dual {
            converged = true;
            break;
        }
        if iterations % 10 == 0 && iterations <= 500 {
            let factor = if r > 10.0 * s {
                2.0
            } else if s > 10.0 * r {
                0.5
            } else {
                1.0
            };
            if factor != 1.0 {
                rho *= factor;
                u1 *= 1.0 / factor;
                u2 *= 1.0 / factor;
            }
        }
    }
    let zero_entries = (0..d)
        .flat_map(|j| (0..d).map(move |i| (i, j)))
        .filter(|&(i, j)| z1[(i, j)] == 0.0)
        .count();
    Ok(LearnedMetric {
        objective: problem.objective(&z2, lambda),
        m: z2,
        iterations,
        primal_residual: r,
        dual_residual: s,
        converged,
        rho,
        zero_entries,
    })
}

/// `A` with `M = AᵀA` (`r × d`, rows `√μ_k q_kᵀ` for the eigenvalues `μ_k > 1e-12 μ_max`, in
/// descending order). An all-zero `M` gives a `0 × d` factor.
///
/// # Errors
/// [`MetricError::Eigen`] when the eigen-decomposition fails.
pub fn factor(m: &Mat<f64>) -> Result<Mat<f64>, MetricError> {
    factor_above(m, 0.0)
}

/// The eigenvalue floor below which a learned metric's eigenvalues are the solver's residue:
/// [`RESIDUE_MARGIN`] × the larger of the final primal residual and `ε_rel‖M‖_F`. The primal
/// residual bounds how far the returned `M` is from the ADMM's other copies (Weyl: its
/// eigenvalues move by at most that much), and measured on real pairs the residue eigenvalues
/// sit at 0.5-3× it while the smallest real one is 20× or more above it (README "detail",
/// "The metric solver's tolerance").
pub fn residue_floor(learned: &LearnedMetric, params: &MetricParams) -> f64 {
    RESIDUE_MARGIN
        * learned
            .primal_residual
            .max(params.eps_rel * learned.m.norm_l2())
}

/// Margin of [`residue_floor`] over the solver's resolution.
pub const RESIDUE_MARGIN: f64 = 10.0;

/// [`factor`] keeping only the eigenvalues above `floor` (and above `1e-12 μ_max`): with
/// [`residue_floor`], the rank of the metric without the solver's residue directions.
///
/// # Errors
/// [`MetricError::Eigen`] when the eigen-decomposition fails.
pub fn factor_above(m: &Mat<f64>, floor: f64) -> Result<Mat<f64>, MetricError> {
    let d = m.nrows();
    let (vals, q) = symmetric_eigen(symmetrised(m).as_ref()).map_err(|_| MetricError::Eigen)?;
    let max = vals.iter().cloned().fold(0.0f64, f64::max);
    let keep: Vec<usize> = (0..d)
        .rev()
        .filter(|&k| max > 0.0 && vals[k] > (1e-12 * max).max(floor))
        .collect();
    Ok(Mat::from_fn(keep.len(), d, |r, i| {
        vals[keep[r]].sqrt() * q[(i, keep[r])]
    }))
}

/// The top eigenvector of `M` (unit length, largest-magnitude entry positive) and its
/// eigenvalue: the paper's per-feature significance (Fig. 14).
///
/// # Errors
/// [`MetricError::Eigen`] when the eigen-decomposition fails.
pub fn top_eigenvector(m: &Mat<f64>) -> Result<(f64, Vec<f64>), MetricError> {
    let d = m.nrows();
    let (vals, q) = symmetric_eigen(symmetrised(m).as_ref()).map_err(|_| MetricError::Eigen)?;
    let mut v: Vec<f64> = (0..d).map(|i| q[(i, d - 1)]).collect();
    let big = v
        .iter()
        .cloned()
        .fold(0.0f64, |a, x| if x.abs() > a.abs() { x } else { a });
    if big < 0.0 {
        v.iter_mut().for_each(|x| *x = -*x);
    }
    Ok((vals[d - 1], v))
}

/// Applies `A` (from [`factor`]) to `n × d` row-major features (already z-scored): `n × r`
/// row-major `A g_i` (eqs. 3-4), so Euclidean distances of the results are `M`-distances.
pub fn transform(a: &Mat<f64>, features: &[f64]) -> Vec<f64> {
    let (r, d) = (a.nrows(), a.ncols());
    let mut out = Vec::with_capacity(features.len() / d.max(1) * r);
    for row in features.chunks_exact(d.max(1)) {
        for k in 0..r {
            out.push((0..d).map(|i| a[(k, i)] * row[i]).sum());
        }
    }
    out
}
