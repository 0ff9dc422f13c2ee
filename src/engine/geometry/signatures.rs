//! Spectral point signatures from the lowest Laplace–Beltrami eigenpairs ([`super::spectrum`]).
//!
//! **Heat Kernel Signature** (Sun, Ovsjanikov & Guibas 2009, "A concise and provably
//! informative multi-scale signature based on heat diffusion", eq. 3 and section 5):
//! `HKS(x, t) = Σᵢ e^{−λᵢ t} φᵢ(x)²`, the heat that stays at `x` after time `t`. Times are
//! log-spaced between `t_min = 4 ln 10 / λ_max` and `t_max = 4 ln 10 / λ₁` (`λ_max` the largest
//! computed eigenvalue, `λ₁` the first non-zero one), the paper's choice; MeshMatch (Chen et al.
//! 2012, section 4.1) uses 8 such times as its shape feature, the default here.
//!
//! **Scale-invariant normalization** ([`HksNormalization::AreaMean`], default): each time's
//! column is divided by its area-weighted mean `Σₓ HKS(x, t) M_xx / Σₓ M_xx`. Because
//! `Σₓ φᵢ(x)² M_xx = 1`, the mean is `(Σᵢ e^{−λᵢ t}) / area`, i.e. this is the paper's division by
//! the heat trace times the surface area. Scaling the surface by `s` multiplies `φ²` by `1/s²`,
//! `λ` by `1/s²` and the chosen `t` by `s²`, so the normalized values are unchanged: they are
//! dimensionless with mean 1 (and exactly 1 everywhere on a round sphere).
//!
//! **Wave Kernel Signature** (Aubry, Schlickewei & Cremers 2011, "The wave kernel signature: a
//! quantum mechanical approach to shape analysis", section 3): with log-normal energy filters
//! `f_e(λ) = exp(−(e − log λ)² / (2σ²))`, `WKS(x, e) = Σᵢ φᵢ(x)² f_e(λᵢ)² / Σᵢ f_e(λᵢ)²` for
//! `N` log-energies `e` evenly spaced (step `δ`) in `[log λ₁ + 2σ, log λ_max − 2σ]`,
//! `σ = w·δ`; paper defaults `N = 100`, `w = 7`. Zero eigenvalues are left out (their `log` is
//! undefined). The per-energy normalization makes `Σₓ WKS(x, e) M_xx = 1` (units 1 / area).
//! When the log-range is shorter than `4σ` the energies collapse to its midpoint.
//!
//! Output: vertex-major (`values[x · count + j]`), so each vertex's feature vector is contiguous.
//! Computed in parallel over vertices, deterministic.
//!
//! Written by hand: sums over the eigenpairs.

use rayon::prelude::*;

use super::laplacian::GeometryError;
use super::spectrum::Spectrum;

/// Normalization of the HKS columns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HksNormalization {
    /// Raw `Σ e^{−λt} φ²` (units 1 / world units²).
    None,
    /// Divide each time by the area-weighted mean over the surface (scale invariant).
    #[default]
    AreaMean,
}

/// Parameters of [`heat_kernel_signature`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HksParams {
    /// Number of log-spaced times. Default: 8 (MeshMatch). Range: [1, 1000].
    pub times: usize,
    /// Normalization. Default: `area_mean`.
    pub normalization: HksNormalization,
    /// Eigenvalues at most `zero_threshold · λ_max` count as 0 (constant modes; dimensionless).
    /// Default: 1e-8. Range: [0, 1e-2].
    pub zero_threshold: f64,
}

impl Default for HksParams {
    fn default() -> Self {
        Self {
            times: 8,
            normalization: HksNormalization::AreaMean,
            zero_threshold: 1e-8,
        }
    }
}

/// Parameters of [`wave_kernel_signature`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WksParams {
    /// Number of energies `N`. Default: 100 (the paper). Range: [1, 1000].
    pub energies: usize,
    /// Filter width in energy steps, `σ = variance · δ` (the paper's `w`). Default: 7.
    /// Range: (0, 100].
    pub variance: f64,
    /// As [`HksParams::zero_threshold`]. Default: 1e-8.
    pub zero_threshold: f64,
}

impl Default for WksParams {
    fn default() -> Self {
        Self {
            energies: 100,
            variance: 7.0,
            zero_threshold: 1e-8,
        }
    }
}

/// Per-vertex signature vectors.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Signature {
    /// The scale of each column: HKS times (world units²) or WKS log-energies.
    pub scales: Vec<f64>,
    /// Vertex-major values: `values[x · scales.len() + j]`.
    pub values: Vec<f64>,
}

impl Signature {
    /// Columns per vertex.
    pub fn dim(&self) -> usize {
        self.scales.len()
    }

    /// The feature vector of vertex `x`.
    pub fn vertex(&self, x: usize) -> &[f64] {
        let d = self.dim();
        &self.values[x * d..(x + 1) * d]
    }

    /// Column `j` over all vertices.
    pub fn column(&self, j: usize) -> Vec<f64> {
        self.values
            .iter()
            .skip(j)
            .step_by(self.dim())
            .copied()
            .collect()
    }
}

/// `(λ₁, λ_max)`: the first eigenvalue above the zero threshold, and the largest.
fn spectral_range(spectrum: &Spectrum, zero_threshold: f64) -> Result<(f64, f64), GeometryError> {
    if !(0.0..=1e-2).contains(&zero_threshold) {
        return Err(GeometryError::InvalidParam {
            name: "zero_threshold",
            value: zero_threshold,
            range: "[0, 1e-2]",
        });
    }
    let max = spectrum.values.iter().copied().fold(0.0, f64::max);
    let first = spectrum
        .values
        .iter()
        .copied()
        .find(|&l| l > zero_threshold * max)
        .ok_or_else(|| GeometryError::Degenerate("no non-zero eigenvalue".into()))?;
    Ok((first, max))
}

/// `out[x·d + j] = Σᵢ w[i·d + j] φᵢ(x)²`, parallel over vertices.
fn weighted_squares(spectrum: &Spectrum, weights: &[f64], d: usize) -> Vec<f64> {
    let n = spectrum.vertex_count();
    let k = spectrum.len();
    let mut out = vec![0.0; n * d];
    out.par_chunks_mut(d * 256)
        .enumerate()
        .for_each(|(chunk, block)| {
            let x0 = chunk * 256;
            for (dx, row) in block.chunks_mut(d).enumerate() {
                let x = x0 + dx;
                for i in 0..k {
                    let p = spectrum.vectors[i * n + x];
                    let p2 = p * p;
                    for (o, w) in row.iter_mut().zip(&weights[i * d..(i + 1) * d]) {
                        *o += w * p2;
                    }
                }
            }
        });
    out
}

/// The Heat Kernel Signature at `params.times` log-spaced times (see the module docs).
///
/// # Errors
/// [`GeometryError::InvalidParam`] for out-of-range parameters; [`GeometryError::Degenerate`]
/// when the spectrum has no non-zero eigenvalue or its vectors do not match its mass.
pub fn heat_kernel_signature(
    spectrum: &Spectrum,
    params: &HksParams,
) -> Result<Signature, GeometryError> {
    let d = params.times;
    if !(1..=1000).contains(&d) {
        return Err(GeometryError::InvalidParam {
            name: "times",
            value: d as f64,
            range: "[1, 1000]",
        });
    }
    check_shape(spectrum)?;
    let (first, max) = spectral_range(spectrum, params.zero_threshold)?;
    let (t_min, t_max) = (4.0 * 10f64.ln() / max, 4.0 * 10f64.ln() / first);
    let times: Vec<f64> = (0..d)
        .map(|j| {
            if d == 1 {
                (t_min * t_max).sqrt()
            } else {
                t_min * (t_max / t_min).powf(j as f64 / (d - 1) as f64)
            }
        })
        .collect();
    heat_kernel_signature_at(spectrum, &times, params.normalization)
}

/// The Heat Kernel Signature at caller-chosen `times` (world units², e.g. a fixed set for
/// surfaces normalized to unit area, so that two surfaces are evaluated at the same scales),
/// with the column normalization of the module docs. `scales` of the result are `times`.
///
/// # Errors
/// [`GeometryError::InvalidParam`] when `times` is empty, longer than 1000, or holds a value that
/// is not finite and > 0; [`GeometryError::Degenerate`] when the spectrum is empty or its vectors
/// do not match its mass.
pub fn heat_kernel_signature_at(
    spectrum: &Spectrum,
    times: &[f64],
    normalization: HksNormalization,
) -> Result<Signature, GeometryError> {
    let d = times.len();
    if !(1..=1000).contains(&d) {
        return Err(GeometryError::InvalidParam {
            name: "times (count)",
            value: d as f64,
            range: "[1, 1000]",
        });
    }
    if let Some(&t) = times.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
        return Err(GeometryError::InvalidParam {
            name: "times",
            value: t,
            range: "(0, ∞)",
        });
    }
    check_shape(spectrum)?;
    if spectrum.is_empty() || spectrum.vertex_count() == 0 {
        return Err(GeometryError::Degenerate("empty spectrum".into()));
    }
    let weights: Vec<f64> = spectrum
        .values
        .iter()
        .flat_map(|&l| times.iter().map(move |&t| (-l * t).exp()))
        .collect();
    let mut values = weighted_squares(spectrum, &weights, d);
    if normalization == HksNormalization::AreaMean {
        let area: f64 = spectrum.mass.iter().sum();
        for j in 0..d {
            let trace: f64 = (0..spectrum.len()).map(|i| weights[i * d + j]).sum();
            let scale = area / trace;
            values
                .iter_mut()
                .skip(j)
                .step_by(d)
                .for_each(|v| *v *= scale);
        }
    }
    Ok(Signature {
        scales: times.to_vec(),
        values,
    })
}

/// The Wave Kernel Signature at `params.energies` log-energies (see the module docs).
///
/// # Errors
/// As [`heat_kernel_signature`].
pub fn wave_kernel_signature(
    spectrum: &Spectrum,
    params: &WksParams,
) -> Result<Signature, GeometryError> {
    let d = params.energies;
    if !(1..=1000).contains(&d) {
        return Err(GeometryError::InvalidParam {
            name: "energies",
            value: d as f64,
            range: "[1, 1000]",
        });
    }
    if params.variance.is_nan() || params.variance <= 0.0 || params.variance > 100.0 {
        return Err(GeometryError::InvalidParam {
            name: "variance",
            value: params.variance,
            range: "(0, 100]",
        });
    }
    check_shape(spectrum)?;
    let (first, max) = spectral_range(spectrum, params.zero_threshold)?;
    let zero = params.zero_threshold * max;
    let (lo, hi) = (first.ln(), max.ln());
    // e_min = lo + 2σ, e_max = hi − 2σ, δ = (e_max − e_min)/(N − 1), σ = wδ
    // ⇒ δ = (hi − lo) / (N − 1 + 4w).
    let delta = (hi - lo) / ((d as f64 - 1.0) + 4.0 * params.variance);
    let sigma = (params.variance * delta).max(f64::MIN_POSITIVE);
    let energies: Vec<f64> = (0..d)
        .map(|j| lo + 2.0 * sigma + j as f64 * delta)
        .collect();
    Ok(wks_values(spectrum, energies, sigma, zero))
}

/// The Wave Kernel Signature at caller-chosen log-energies `energies` with filter width
/// `sigma` (e.g. one set shared by two surfaces normalized to unit area, so that both are
/// evaluated at the same scales); eigenvalues at most `zero_threshold · λ_max` are left out.
/// `scales` of the result are `energies`.
///
/// # Errors
/// [`GeometryError::InvalidParam`] for an empty or over-long `energies`, a non-finite energy, a
/// `sigma` that is not finite and > 0, or an out-of-range `zero_threshold`;
/// [`GeometryError::Degenerate`] as [`wave_kernel_signature`].
pub fn wave_kernel_signature_at(
    spectrum: &Spectrum,
    energies: &[f64],
    sigma: f64,
    zero_threshold: f64,
) -> Result<Signature, GeometryError> {
    if !(1..=1000).contains(&energies.len()) {
        return Err(GeometryError::InvalidParam {
            name: "energies (count)",
            value: energies.len() as f64,
            range: "[1, 1000]",
        });
    }
    if let Some(&e) = energies.iter().find(|e| !e.is_finite()) {
        return Err(GeometryError::InvalidParam {
            name: "energies",
            value: e,
            range: "finite",
        });
    }
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(GeometryError::InvalidParam {
            name: "sigma",
            value: sigma,
            range: "(0, ∞)",
        });
    }
    check_shape(spectrum)?;
    let (_, max) = spectral_range(spectrum, zero_threshold)?;
    Ok(wks_values(
        spectrum,
        energies.to_vec(),
        sigma,
        zero_threshold * max,
    ))
}

/// WKS values at `energies` (filter width `sigma`), eigenvalues `<= zero` left out.
fn wks_values(spectrum: &Spectrum, energies: Vec<f64>, sigma: f64, zero: f64) -> Signature {
    let d = energies.len();
    let mut weights: Vec<f64> = spectrum
        .values
        .iter()
        .flat_map(|&l| {
            energies.iter().map(move |&e| {
                if l <= zero {
                    0.0
                } else {
                    let f = (-(e - l.ln()).powi(2) / (2.0 * sigma * sigma)).exp();
                    f * f
                }
            })
        })
        .collect();
    for j in 0..d {
        let total: f64 = (0..spectrum.len()).map(|i| weights[i * d + j]).sum();
        if total > 0.0 {
            (0..spectrum.len()).for_each(|i| weights[i * d + j] /= total);
        }
    }
    Signature {
        values: weighted_squares(spectrum, &weights, d),
        scales: energies,
    }
}

fn check_shape(spectrum: &Spectrum) -> Result<(), GeometryError> {
    if spectrum.vectors.len() != spectrum.len() * spectrum.vertex_count() {
        return Err(GeometryError::Degenerate(
            "eigenvector storage does not match the vertex count".into(),
        ));
    }
    Ok(())
}
