//! Feature matching (Mertens et al. 2006, §4): the target's guidance is given the source's
//! distribution by n-D histogram matching (Pitié, Kokaram, Dahyot, *N-Dimensional Probability
//! Density Function Transfer and its Application to Colour Transfer*, ICCV 2005).
//!
//! One iteration draws a random orthonormal basis of the `d`-D guidance space (Gram-Schmidt of
//! Gaussian vectors), projects both sample sets on each axis, replaces the target's projections
//! by the source's values at their own weighted ranks (an exact 1-D quantile transfer,
//! [`super::quantiles::match_to`]) and moves the target samples by the change along that axis.
//! Statistics are area-weighted (each sample by its lumped area; on the source also by its mask
//! weight), so the distribution matched is that over the surface, not over the samples.
//!
//! The axes of one rotation are orthonormal, so a move along one leaves the projections on the
//! others unchanged: their 1-D transfers are independent and run in parallel (Pitié et al.'s
//! own formulation: match every marginal of the rotated set, then rotate back).
//!
//! Convergence (Pitié et al. do not fix one): iterate until the root-mean-square move of an
//! iteration falls below `TOLERANCE` (1 %) of the source's standard deviation, at most
//! `MAX_ITERATIONS` (= 40) iterations; in 1-D one iteration is exact. The moves do not go to
//! zero (exact quantile transfers keep re-ranking samples by tiny amounts), so a smaller
//! tolerance only spends iterations.
//!
//! - `marginals` (§4.1): the values.
//! - `multiscale` (§4.2): each band of the guidance's Laplacian pyramid over the target's
//!   surface pyramid is matched to the same band of the source's (weights: the level's lumped
//!   areas, on the source times the Gaussian-smoothed mask weight), the bands are collapsed, and
//!   then the values are matched once more.

use rayon::prelude::*;
use serde::Serialize;

use super::pyramid::SurfacePyramid;
use super::quantiles::{match_to, Quantiles};
use crate::engine::control::Control;
use crate::engine::methods::MethodError;
use crate::engine::rng::SplitMix64;

/// Largest number of random rotations.
pub const MAX_ITERATIONS: usize = 40;
/// An iteration whose RMS move is below this fraction of the source's standard deviation stops.
pub const TOLERANCE: f64 = 1e-2;

/// One sample set: values (the first `dims` components used) and optional weights.
#[derive(Clone, Copy, Debug)]
pub struct Samples<'a> {
    /// Values.
    pub values: &'a [[f32; 3]],
    /// Weights (≥ 0), or `None` for equal weights.
    pub weights: Option<&'a [f32]>,
}

/// What one n-D matching did.
#[derive(Clone, Debug, Serialize)]
pub struct MatchReport {
    /// Random rotations applied.
    pub iterations: usize,
    /// Sliced Wasserstein-1 distance to the source before, relative to the source's spread.
    pub distance_before: f64,
    /// The same after.
    pub distance_after: f64,
}

/// What feature matching did: one entry per matched band (multiscale: finest band first, then
/// the coarsest Gaussian, then the values), or one for the values (marginals).
#[derive(Clone, Debug, Default, Serialize)]
pub struct FeatureMatchReport {
    /// Per matching step.
    pub steps: Vec<MatchReport>,
}

/// Matches `target` (in place) to the distribution of `source` in the first `dims` components.
///
/// # Errors
/// [`MethodError::Cancelled`].
pub fn match_nd(
    target: &mut [[f32; 3]],
    target_weights: Option<&[f32]>,
    source: Samples<'_>,
    dims: usize,
    seed: u64,
    control: &Control,
) -> Result<MatchReport, MethodError> {
    let dims = dims.clamp(1, 3);
    let spread = spread(source, dims).max(1e-12);
    let mut rng = SplitMix64::new(seed);
    let probe = random_basis(&mut SplitMix64::new(seed ^ 0xD15), dims, 8);
    let distance_before = sliced_distance(target, target_weights, source, &probe, dims) / spread;
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS {
        control.check()?;
        iterations += 1;
        let basis = random_basis(&mut rng, dims, dims);
        // The axes are orthonormal, so a move along one leaves the projections on the others
        // unchanged: the 1-D transfers of one rotation are independent and run in parallel.
        let frozen: &[[f32; 3]] = target;
        let deltas: Vec<Vec<f32>> = basis
            .par_iter()
            .map(|axis| {
                let mut proj = vec![0.0f32; frozen.len()];
                let mut src_proj = vec![0.0f32; source.values.len()];
                project(frozen, axis, &mut proj);
                project(source.values, axis, &mut src_proj);
                let q = Quantiles::new(&src_proj, source.weights);
                drop(src_proj);
                let before = proj.clone();
                match_to(&mut proj, target_weights, &q);
                proj.iter_mut().zip(&before).for_each(|(p, b)| *p -= b);
                proj
            })
            .collect();
        let mut moved = 0.0f64;
        for (axis, delta) in basis.iter().zip(&deltas) {
            for (t, d) in target.iter_mut().zip(delta) {
                moved += f64::from(*d) * f64::from(*d);
                for k in 0..dims {
                    t[k] += d * axis[k];
                }
            }
        }
        let rms = (moved / target.len().max(1) as f64).sqrt();
        if dims == 1 || rms < TOLERANCE * spread {
            break;
        }
    }
    let distance_after = sliced_distance(target, target_weights, source, &probe, dims) / spread;
    Ok(MatchReport {
        iterations,
        distance_before,
        distance_after,
    })
}

/// `marginals`: the values only. `multiscale`: the Laplacian bands over the pyramids, collapse,
/// then the values (see the module docs). `source_weight` is per source level-0 sample.
///
/// # Errors
/// [`MethodError::Cancelled`].
#[allow(clippy::too_many_arguments)]
pub fn match_guidance(
    target_guidance: &mut Vec<[f32; 3]>,
    target: &SurfacePyramid,
    source_guidance: &[[f32; 3]],
    source: &SurfacePyramid,
    source_weight: &[f32],
    dims: usize,
    multiscale: bool,
    seed: u64,
    control: &Control,
) -> Result<FeatureMatchReport, MethodError> {
    let mut report = FeatureMatchReport::default();
    let src_w0: Vec<f32> = source
        .area(0)
        .iter()
        .zip(source_weight)
        .map(|(a, w)| a * w)
        .collect();
    // Bands are matched level by level only when both pyramids have the same depth (a model
    // too small for the requested levels gets fewer, and its coarsest band, a Gaussian, would
    // face a Laplacian band of the other): otherwise only the values are matched.
    if multiscale && source.level_count() > 1 && source.level_count() == target.level_count() {
        let levels = source.level_count();
        let mut tb = target.laplacian(target_guidance);
        let sb = source.laplacian(source_guidance);
        let mask: Vec<[f32; 1]> = source_weight.iter().map(|w| [*w]).collect();
        let mask_levels = source.gaussian(&mask);
        for level in 0..levels {
            let sw: Vec<f32> = source
                .area(level)
                .iter()
                .zip(&mask_levels[level])
                .map(|(a, m)| a * m[0])
                .collect();
            let step = match_nd(
                &mut tb[level],
                Some(target.area(level)),
                Samples {
                    values: &sb[level],
                    weights: Some(&sw),
                },
                dims,
                crate::engine::rng::mix(seed, level as u64, 1),
                control,
            )?;
            report.steps.push(step);
        }
        *target_guidance = target.collapse(&tb);
    }
    let step = match_nd(
        target_guidance,
        Some(target.area(0)),
        Samples {
            values: source_guidance,
            weights: Some(&src_w0),
        },
        dims,
        crate::engine::rng::mix(seed, 99, 2),
        control,
    )?;
    report.steps.push(step);
    Ok(report)
}

fn project(values: &[[f32; 3]], axis: &[f32; 3], out: &mut [f32]) {
    for (o, v) in out.iter_mut().zip(values) {
        *o = v[0] * axis[0] + v[1] * axis[1] + v[2] * axis[2];
    }
}

fn gaussian(rng: &mut SplitMix64) -> f64 {
    let u = rng.unit_f64().max(1e-300);
    let v = rng.unit_f64();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// `count` random unit directions in the first `dims` components; the first `dims` of them
/// (and each further block of `dims`) orthonormal.
pub fn random_basis(rng: &mut SplitMix64, dims: usize, count: usize) -> Vec<[f32; 3]> {
    let mut out: Vec<[f32; 3]> = Vec::with_capacity(count);
    while out.len() < count {
        let block_start = out.len() - out.len() % dims;
        let mut v = [0.0f64; 3];
        for x in v.iter_mut().take(dims) {
            *x = gaussian(rng);
        }
        for b in &out[block_start..] {
            let d: f64 = (0..3).map(|k| v[k] * f64::from(b[k])).sum();
            for k in 0..3 {
                v[k] -= d * f64::from(b[k]);
            }
        }
        let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if n > 1e-6 {
            out.push(v.map(|x| (x / n) as f32));
        }
    }
    out
}

/// The source's weighted standard deviation, root of the summed variances of `dims` components.
fn spread(s: Samples<'_>, dims: usize) -> f64 {
    let mut sw = 0.0f64;
    let mut m = [0.0f64; 3];
    let mut m2 = [0.0f64; 3];
    for (i, v) in s.values.iter().enumerate() {
        let w = s.weights.map_or(1.0, |w| f64::from(w[i].max(0.0)));
        sw += w;
        for k in 0..dims {
            m[k] += w * f64::from(v[k]);
            m2[k] += w * f64::from(v[k]) * f64::from(v[k]);
        }
    }
    if sw <= 0.0 {
        return 0.0;
    }
    (0..dims)
        .map(|k| (m2[k] / sw - (m[k] / sw).powi(2)).max(0.0))
        .sum::<f64>()
        .sqrt()
}

/// Mean over `directions` of the 1-D Wasserstein-1 distance between the weighted projections
/// (computed on 256 quantiles).
pub fn sliced_distance(
    a: &[[f32; 3]],
    a_weights: Option<&[f32]>,
    b: Samples<'_>,
    directions: &[[f32; 3]],
    dims: usize,
) -> f64 {
    let mut pa = vec![0.0f32; a.len()];
    let mut pb = vec![0.0f32; b.values.len()];
    let mut total = 0.0;
    for d in directions {
        let mut axis = *d;
        for x in axis.iter_mut().skip(dims) {
            *x = 0.0;
        }
        project(a, &axis, &mut pa);
        project(b.values, &axis, &mut pb);
        let qa = Quantiles::new(&pa, a_weights);
        let qb = Quantiles::new(&pb, b.weights);
        let n = 256;
        total += (0..n)
            .map(|i| {
                let u = (i as f32 + 0.5) / n as f32;
                f64::from((qa.value_at(u) - qb.value_at(u)).abs())
            })
            .sum::<f64>()
            / n as f64;
    }
    total / directions.len().max(1) as f64
}
