//! Canonical correlation analysis between the 12-D features and the source colour (Mertens et
//! al. 2006, §3.3), and the PCA baseline of the paper's Fig. 5/6.
//!
//! Statistics are weighted (each sample by its lumped area times its mask weight). The features
//! are standardised first (centred on the source's weighted mean, divided by the source's
//! standard deviation; a feature constant on the source gets weight zero) so that one ridge
//! constant means the same for every feature and the reported weights per feature (the paper's
//! Fig. 4) are comparable.
//!
//! CCA: the colour is reduced to its principal subspace of rank `d = min(3, rank)` (eigenvalues
//! of the colour covariance above `RANK_TOLERANCE` × the largest; a grey source has `d = 1`, a
//! constant one too, with correlation 0) and whitened there; with `Kx = (Cxx + λI)^{-1/2}` and
//! `M = Kx Cxy Ey` the canonical directions are the top `d` left singular vectors `U` of `M`
//! (eigenvectors of `MMᵀ`, so they stay orthonormal when a singular value is zero), the canonical
//! correlations its singular values, and `W_x = Kx U`. The guidance is `x* = W_xᵀ(x − mean)` on
//! source and target with the source's mean, scale and `W_x`, each component scaled to unit
//! variance on the source. The sign of each component is fixed so that it correlates positively
//! with the source's luminance (or, when it does not correlate with it, so that its largest
//! feature weight is positive).
//!
//! Ridge (not published in the paper, which notes the collinearity of normals and height):
//! `λ = 1e-3` on the standardised features' correlation matrix: collinear features (height and
//! `normal_y` on a sphere) stay solvable, and a correlation near 1 is lowered by about 0.1 %.
//!
//! PCA (`reduction = "pca"`): the top three principal components of the standardised features
//! (correlation-matrix PCA; on raw features the occlusion's units would decide), each scaled to
//! unit variance on the source.
//!
//! The eigen-decompositions are faer's.

use faer::{Mat, Side};
use rayon::prelude::*;
use serde::Serialize;

use super::features::{Feature, DIMS, NAMES};
use crate::engine::methods::MethodError;

/// Relative eigenvalue below which a colour direction does not count towards the rank.
pub const RANK_TOLERANCE: f64 = 1e-4;
/// Ridge added to the standardised features' correlation matrix.
pub const RIDGE: f64 = 1e-3;

/// Which reduction a [`GuidanceModel`] is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// Canonical correlation analysis.
    Cca,
    /// Principal components.
    Pca,
}

/// The linear map from features to guidance, fitted on the source.
#[derive(Clone, Debug, Serialize)]
pub struct GuidanceModel {
    /// CCA or PCA.
    pub kind: Kind,
    /// Guidance dimensions `d` (1..=3).
    pub dims: usize,
    /// Per guidance component: its correlation with the colour (CCA: the canonical
    /// correlation; PCA: the multiple correlation of the colour's best linear fit from it,
    /// measured on the source).
    pub correlations: Vec<f64>,
    /// PCA: the share of the standardised features' variance per component; CCA: empty.
    pub explained_variance: Vec<f64>,
    /// Per guidance component: the weight of each standardised feature (`NAMES` order), before
    /// the unit-variance scaling (the paper's Fig. 4).
    pub feature_weights: Vec<Vec<f64>>,
    /// The feature names, in the order of the weights.
    pub feature_names: Vec<&'static str>,
    /// Source feature mean.
    #[serde(skip)]
    mean: [f64; DIMS],
    /// 1 / source feature standard deviation (0 for a constant feature).
    #[serde(skip)]
    inv_std: [f64; DIMS],
    /// Per component, the weights applied to the standardised features (unit variance folded).
    #[serde(skip)]
    applied: Vec<[f64; DIMS]>,
}

impl GuidanceModel {
    /// The guidance of `features` (unused components are 0).
    pub fn apply(&self, features: &[Feature]) -> Vec<[f32; 3]> {
        features
            .par_iter()
            .map(|f| {
                let z: [f64; DIMS] =
                    std::array::from_fn(|j| (f64::from(f[j]) - self.mean[j]) * self.inv_std[j]);
                let mut g = [0.0f32; 3];
                for (k, w) in self.applied.iter().enumerate() {
                    g[k] = w.iter().zip(&z).map(|(a, b)| a * b).sum::<f64>() as f32;
                }
                g
            })
            .collect()
    }
}

/// Weighted first and second moments of features and colour.
struct Moments {
    mean_x: [f64; DIMS],
    /// Covariance of `[x, y]` (15 × 15), row-major.
    cov: Vec<f64>,
}

const J: usize = DIMS + 3;

fn moments(x: &[Feature], y: &[[f32; 3]], w: &[f32]) -> Result<Moments, MethodError> {
    let n = x.len();
    if y.len() != n || w.len() != n {
        return Err(MethodError::Internal(format!(
            "cca: {n} features, {} colours, {} weights",
            y.len(),
            w.len()
        )));
    }
    let joint = |i: usize| -> [f64; J] {
        std::array::from_fn(|j| {
            if j < DIMS {
                f64::from(x[i][j])
            } else {
                f64::from(y[i][j - DIMS])
            }
        })
    };
    // Fixed chunks summed in order: the result does not depend on the thread count.
    let chunks: Vec<(f64, [f64; J])> = (0..n)
        .into_par_iter()
        .chunks(8192)
        .map(|idx| {
            let mut s = [0.0; J];
            let mut sw = 0.0;
            for i in idx {
                let wi = f64::from(w[i].max(0.0));
                let z = joint(i);
                sw += wi;
                for j in 0..J {
                    s[j] += wi * z[j];
                }
            }
            (sw, s)
        })
        .collect();
    let total: f64 = chunks.iter().map(|c| c.0).sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(MethodError::UnusableInput {
            field: Some("source".into()),
            kind: "empty-training-set",
            message: "no source sample has a positive weight (the mask removes everything)".into(),
        });
    }
    let mut mean = [0.0; J];
    for c in &chunks {
        for j in 0..J {
            mean[j] += c.1[j] / total;
        }
    }
    let parts: Vec<Vec<f64>> = (0..n)
        .into_par_iter()
        .chunks(8192)
        .map(|idx| {
            let mut c = vec![0.0; J * J];
            for i in idx {
                let wi = f64::from(w[i].max(0.0));
                if wi == 0.0 {
                    continue;
                }
                let z = joint(i);
                let d: [f64; J] = std::array::from_fn(|j| z[j] - mean[j]);
                for a in 0..J {
                    for b in a..J {
                        c[a * J + b] += wi * d[a] * d[b];
                    }
                }
            }
            c
        })
        .collect();
    let mut cov = vec![0.0; J * J];
    for p in &parts {
        for (c, v) in cov.iter_mut().zip(p) {
            *c += v / total;
        }
    }
    for a in 0..J {
        for b in 0..a {
            cov[a * J + b] = cov[b * J + a];
        }
    }
    if cov.iter().any(|v| !v.is_finite()) {
        return Err(MethodError::UnusableInput {
            field: Some("source".into()),
            kind: "unusable-mesh",
            message: "the source's features or colours are not finite".into(),
        });
    }
    Ok(Moments {
        mean_x: std::array::from_fn(|j| mean[j]),
        cov,
    })
}

/// Eigen-decomposition of a symmetric `n × n` matrix: eigenvalues descending, eigenvectors as
/// columns `vectors[k]`.
fn sym_eigen(
    n: usize,
    a: impl Fn(usize, usize) -> f64,
) -> Result<(Vec<f64>, Vec<Vec<f64>>), MethodError> {
    let m = Mat::<f64>::from_fn(n, n, |i, j| 0.5 * (a(i, j) + a(j, i)));
    let e = m.self_adjoint_eigen(Side::Lower);
    crate::engine::linalg::simd_state::clear_upper_vector_state_here();
    let e = e.map_err(|e| MethodError::Internal(format!("eigen-decomposition failed: {e:?}")))?;
    let s = e.S().column_vector();
    let u = e.U();
    let mut values = Vec::with_capacity(n);
    let mut vectors = Vec::with_capacity(n);
    for k in (0..n).rev() {
        values.push(s[k]);
        vectors.push((0..n).map(|i| u[(i, k)]).collect());
    }
    Ok((values, vectors))
}

/// Standardisation of the features: (mean, 1/std with 0 for constant ones), and the
/// standardised feature covariance (correlation matrix) plus the standardised cross-covariance
/// with colour (12 × 3).
struct Standard {
    inv_std: [f64; DIMS],
    cxx: Vec<f64>,
    cxy: Vec<[f64; 3]>,
    cyy: [[f64; 3]; 3],
}

fn standardise(m: &Moments) -> Standard {
    let inv_std: [f64; DIMS] = std::array::from_fn(|j| {
        let v = m.cov[j * J + j];
        if v > 1e-12 {
            1.0 / v.sqrt()
        } else {
            0.0
        }
    });
    let cxx = (0..DIMS * DIMS)
        .map(|k| {
            let (a, b) = (k / DIMS, k % DIMS);
            m.cov[a * J + b] * inv_std[a] * inv_std[b]
        })
        .collect();
    let cxy = (0..DIMS)
        .map(|a| std::array::from_fn(|c| m.cov[a * J + DIMS + c] * inv_std[a]))
        .collect();
    let cyy = std::array::from_fn(|a| std::array::from_fn(|b| m.cov[(DIMS + a) * J + DIMS + b]));
    Standard {
        inv_std,
        cxx,
        cxy,
        cyy,
    }
}

/// Fits the CCA guidance on the source: `features`, linear RGB `colors` and sample `weights`.
///
/// # Errors
/// [`MethodError::UnusableInput`] when no sample has a positive weight or values are not finite.
pub fn fit_cca(
    features: &[Feature],
    colors: &[[f32; 3]],
    weights: &[f32],
) -> Result<GuidanceModel, MethodError> {
    let m = moments(features, colors, weights)?;
    let st = standardise(&m);
    // Colour principal subspace, whitened.
    let (cv, cvec) = sym_eigen(3, |a, b| st.cyy[a][b])?;
    let top = cv[0].max(0.0);
    let rank = if top > 1e-12 {
        cv.iter().filter(|v| **v > RANK_TOLERANCE * top).count()
    } else {
        0
    };
    let d = rank.clamp(1, 3);
    // Ey: 3 × d, whitening the kept colour directions (a zero-variance colour keeps a unit map).
    let ey: Vec<[f64; 3]> = (0..d)
        .map(|k| {
            let s = if cv[k] > 1e-12 {
                1.0 / cv[k].sqrt()
            } else {
                0.0
            };
            std::array::from_fn(|c| cvec[k][c] * s)
        })
        .collect();
    // Kx = (Cxx + λI)^{-1/2}.
    let (xv, xvec) = sym_eigen(DIMS, |a, b| {
        st.cxx[a * DIMS + b] + if a == b { RIDGE } else { 0.0 }
    })?;
    let kx = |a: usize, b: usize| -> f64 {
        (0..DIMS)
            .map(|k| xvec[k][a] * xvec[k][b] / xv[k].max(RIDGE).sqrt())
            .sum()
    };
    let kxm: Vec<f64> = (0..DIMS * DIMS).map(|i| kx(i / DIMS, i % DIMS)).collect();
    // M = Kx Cxy Ey (12 × d).
    let cxy_e: Vec<Vec<f64>> = (0..DIMS)
        .map(|a| {
            (0..d)
                .map(|k| (0..3).map(|c| st.cxy[a][c] * ey[k][c]).sum())
                .collect()
        })
        .collect();
    let mm: Vec<Vec<f64>> = (0..DIMS)
        .map(|a| {
            (0..d)
                .map(|k| (0..DIMS).map(|b| kxm[a * DIMS + b] * cxy_e[b][k]).sum())
                .collect()
        })
        .collect();
    let (sv, svec) = sym_eigen(DIMS, |a, b| (0..d).map(|k| mm[a][k] * mm[b][k]).sum())?;
    let lum = [0.2126, 0.7152, 0.0722];
    let mut applied = Vec::with_capacity(d);
    let mut raw = Vec::with_capacity(d);
    let mut correlations = Vec::with_capacity(d);
    for k in 0..d {
        let u = &svec[k];
        let mut wx: [f64; DIMS] =
            std::array::from_fn(|a| (0..DIMS).map(|b| kxm[a * DIMS + b] * u[b]).sum());
        let var = quad(&st.cxx, &wx);
        let lum_cov: f64 = (0..DIMS)
            .map(|a| wx[a] * (0..3).map(|c| st.cxy[a][c] * lum[c]).sum::<f64>())
            .sum();
        let sign = orientation(lum_cov, var, &wx);
        wx = wx.map(|v| v * sign);
        raw.push(wx.to_vec());
        let scale = if var > 1e-18 { 1.0 / var.sqrt() } else { 0.0 };
        applied.push(wx.map(|v| v * scale));
        correlations.push(if rank == 0 {
            0.0
        } else {
            sv[k].max(0.0).sqrt().min(1.0)
        });
    }
    Ok(GuidanceModel {
        kind: Kind::Cca,
        dims: d,
        correlations,
        explained_variance: Vec::new(),
        feature_weights: raw,
        feature_names: NAMES.to_vec(),
        mean: m.mean_x,
        inv_std: st.inv_std,
        applied,
    })
}

/// +1 or −1: positive correlation with luminance, or else a positive largest weight.
fn orientation(lum_cov: f64, var: f64, w: &[f64; DIMS]) -> f64 {
    if var > 0.0 && lum_cov.abs() > 1e-6 * var.sqrt() {
        return lum_cov.signum();
    }
    let big = w
        .iter()
        .copied()
        .fold(0.0f64, |m, v| if v.abs() > m.abs() { v } else { m });
    if big < 0.0 {
        -1.0
    } else {
        1.0
    }
}

fn quad(c: &[f64], w: &[f64; DIMS]) -> f64 {
    (0..DIMS)
        .map(|a| {
            (0..DIMS)
                .map(|b| w[a] * c[a * DIMS + b] * w[b])
                .sum::<f64>()
        })
        .sum()
}

/// Fits the PCA guidance on the source (top three principal components of the standardised
/// features). `colors` only serve the reported correlations.
///
/// # Errors
/// As [`fit_cca`].
pub fn fit_pca(
    features: &[Feature],
    colors: &[[f32; 3]],
    weights: &[f32],
) -> Result<GuidanceModel, MethodError> {
    let m = moments(features, colors, weights)?;
    let st = standardise(&m);
    let (xv, xvec) = sym_eigen(DIMS, |a, b| st.cxx[a * DIMS + b])?;
    let total: f64 = xv.iter().map(|v| v.max(0.0)).sum::<f64>().max(1e-300);
    let d = xv.iter().take(3).filter(|v| **v > 1e-9).count().max(1);
    let mut applied = Vec::new();
    let mut raw = Vec::new();
    let mut correlations = Vec::new();
    let mut explained = Vec::new();
    for k in 0..d {
        let mut w: [f64; DIMS] = std::array::from_fn(|a| xvec[k][a]);
        let sign = orientation(0.0, 1.0, &w);
        w = w.map(|v| v * sign);
        raw.push(w.to_vec());
        let scale = if xv[k] > 1e-18 {
            1.0 / xv[k].sqrt()
        } else {
            0.0
        };
        applied.push(w.map(|v| v * scale));
        explained.push(xv[k].max(0.0) / total);
        // Multiple correlation of the colour with this component: the colour variance its
        // linear fit explains over the colour variance.
        let cy: [f64; 3] = std::array::from_fn(|c| (0..DIMS).map(|a| w[a] * st.cxy[a][c]).sum());
        let ty = st.cyy[0][0] + st.cyy[1][1] + st.cyy[2][2];
        let fit = if xv[k] > 1e-18 {
            cy.iter().map(|v| v * v).sum::<f64>() / xv[k]
        } else {
            0.0
        };
        correlations.push(if ty > 1e-18 {
            (fit / ty).clamp(0.0, 1.0).sqrt()
        } else {
            0.0
        });
    }
    Ok(GuidanceModel {
        kind: Kind::Pca,
        dims: d,
        correlations,
        explained_variance: explained,
        feature_weights: raw,
        feature_names: NAMES.to_vec(),
        mean: m.mean_x,
        inv_std: st.inv_std,
        applied,
    })
}
