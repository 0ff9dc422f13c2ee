//! Geometric features per vertex (Berkiten et al. 2017, §3.2.2): the 60-D vector `g_i`, in this
//! order (see [`GROUPS`]):
//!
//! | cols | group | what |
//! |---|---|---|
//! | 0-4 | curvature | `k1 ≥ k2`, mean `H`, Gaussian `K`, `‖(k1, k2)‖` ([`principal_curvatures`], 1/world units) |
//! | 5 | height | the `y` coordinate (world units) |
//! | 6-8 | normal | vertex normals smoothed by a Gaussian of `σ = 4 ē` (`ē` mean edge), renormalised |
//! | 9 | sdf | shape diameter ([`shape_diameter`], 120° cone, 30 rays, world units) |
//! | 10 | seg | geodesic distance to the nearest SDF-segmentation boundary ÷ its segment's maximum |
//! | 11-16 | geo | mean, median, max, std, 10th, 90th percentile of geodesic distances ÷ √area |
//! | 17-19 | box | `(p − box centre) / box size` per axis |
//! | 20-39 | hks | HKS at 20 times (heat-trace normalised, dimensionless) |
//! | 40-59 | wks | WKS at 20 log-energies (per unit area) |
//!
//! **Smoothed normals.** The Gaussian is realised as heat diffusion on the surface for time
//! `σ²/2` (whose kernel is a Gaussian of standard deviation σ along the surface): 4 implicit
//! steps `(M − τL) N' = M N`, `τ = σ²/8`, on one Cholesky factor, from the angle-weighted normals.
//!
//! **SDF.** Vertices without a valid ray (NaN) take the median of the valid values (0 when none is
//! valid, e.g. an open plane).
//!
//! **Segmentation** (the paper cites Shapira et al. 2008, which fits a GMM to the SDF and cuts
//! with a graph cut; this is a simpler stand-in, stated): 1-D k-means (`k = 5`, SSCO08's cluster
//! count; centres started at the quantiles `(j + ½)/k`, Lloyd to convergence) on `log SDF`;
//! centres closer than `merge_log_gap = 0.15` (SDFs within ~16 % of each other: the noise of a
//! 30-ray estimate on one part, measured on spheres) are merged, so a part of constant thickness
//! is not cut by noise; labels are then smoothed by 3 rounds of one-ring majority vote (the graph
//! cut's role), and the segments are the connected components of equal label. Boundary vertices
//! are those with a neighbour in another segment; the distance to them comes from one multi-source
//! heat-method query, divided by the maximum within each segment (Chen et al. 2012). A shape
//! with a single segment gets 0.
//!
//! **Geodesic statistics.** Distances to "all others" are estimated from `geodesic_sources = 128`
//! sources picked by Euclidean farthest-point sampling (from vertex 0), each weighted by the
//! surface area it stands for (the barycentric areas of the vertices nearest to it), so the
//! statistics are those of the distance over the surface whatever the vertex density: 128
//! heat-method queries (cost in the README) instead of the n² of exact all-pairs. Weighted
//! quantiles interpolate between the samples' CDF midpoints. The error this sampling leaves is
//! measured on the sphere (see the tests and the README); the max is low by the distance from the
//! farthest point to its nearest source. Normalised by `√area` so that they are scale invariant.
//!
//! **HKS / WKS, comparable between shapes.** Each shape is scaled to unit area and its lowest
//! `spectrum_count = 100` eigenpairs computed. The times and energies are shared:
//! with `λ₁` the larger of the shapes' first non-zero eigenvalues and `λ_max` the smaller of their
//! largest computed ones (the range both spectra resolve), times are log-spaced in
//! `[4 ln 10 / λ_max, 4 ln 10 / λ₁]` (Sun et al. 2009); the 20 log-energies are evenly spaced in
//! `[log λ₁ + 2σ, log λ_max − 2σ]` with Aubry et al.'s filter width for their 100-energy layout,
//! `σ = 7δ`, `δ = (log λ_max − log λ₁)/(99 + 28)` (20 of the paper's 100 energies' span, same
//! filter). [`geometric_features_pair`] does this for a source and a target;
//! [`geometric_features`] for one shape alone.

use std::ops::Range;

use rayon::prelude::*;

use crate::engine::control::{Cancelled, Control};
use crate::engine::geometry::curvature::{principal_curvatures, CurvatureParams};
use crate::engine::geometry::expmap::mean_edge_length;
use crate::engine::geometry::heat::{HeatGeodesics, HeatParams, Source};
use crate::engine::geometry::laplacian::{cotan_laplacian, GeometryError, LaplacianParams};
use crate::engine::geometry::ray_sets::RayFeatureError;
use crate::engine::geometry::sdf::{shape_diameter, SdfParams};
use crate::engine::geometry::signatures::{
    heat_kernel_signature_at, wave_kernel_signature_at, HksNormalization,
};
use crate::engine::geometry::spectrum::{laplace_spectrum, Spectrum, SpectrumParams};
use crate::engine::linalg::{LinalgError, SymbolicCholesky};
use crate::engine::mesh::Surface;

use super::segmentation::{boundary_distance, segment_by_sdf};

/// Features per vertex.
pub const DIM: usize = 60;

/// The feature groups (name, columns), in order.
pub const GROUPS: [(&str, Range<usize>); 9] = [
    ("curvature", 0..5),
    ("height", 5..6),
    ("normal", 6..9),
    ("sdf", 9..10),
    ("seg", 10..11),
    ("geo", 11..17),
    ("box", 17..20),
    ("hks", 20..40),
    ("wks", 40..60),
];

/// Parameters (defaults and their reasons in the module doc).
#[derive(Clone, Debug)]
pub struct GeometricParams {
    /// Normal smoothing σ in mean edge lengths. Default: 4 (the paper's).
    pub normal_sigma_edges: f64,
    /// Shape diameter parameters. Default: the toolkit's (SSCO08's 120°, 30 rays).
    pub sdf: SdfParams,
    /// k-means clusters on log SDF. Default: 5. Range: 1..=32.
    pub segments: usize,
    /// Cluster centres closer than this (in log SDF) merge. Default: 0.15.
    pub merge_log_gap: f64,
    /// Geodesic sources for the distance statistics. Default: 128. Range: 1..=4096.
    pub geodesic_sources: usize,
    /// Eigenpairs per shape for HKS / WKS. Default: 100.
    pub spectrum_count: usize,
}

impl Default for GeometricParams {
    fn default() -> Self {
        Self {
            normal_sigma_edges: 4.0,
            sdf: SdfParams::default(),
            segments: 5,
            merge_log_gap: 0.15,
            geodesic_sources: 128,
            spectrum_count: 100,
        }
    }
}

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum GeometricError {
    /// Operator or solver failure.
    #[error("geometric features: {0}")]
    Geometry(#[from] GeometryError),
    /// Ray casting failure.
    #[error("geometric features: {0}")]
    Ray(#[from] RayFeatureError),
    /// Linear algebra failure.
    #[error("geometric features: {0}")]
    Linalg(#[from] LinalgError),
    /// A parameter is out of range.
    #[error("invalid geometric-feature parameter: {0}")]
    Param(String),
    /// The surface has no faces or too few vertices.
    #[error("the surface needs faces and at least 4 vertices")]
    Empty,
    /// Cancelled through the control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for GeometricError {
    fn from(_: Cancelled) -> Self {
        GeometricError::Cancelled
    }
}

/// The features of one shape.
#[derive(Clone, Debug)]
pub struct GeometricFeatures {
    /// Vertex-major `n × 60`.
    pub values: Vec<f64>,
    /// Segment id per vertex (the SDF segmentation).
    pub segments: Vec<u32>,
    /// The HKS times used (unit-area units).
    pub hks_times: Vec<f64>,
    /// The WKS log-energies used (unit-area units).
    pub wks_energies: Vec<f64>,
}

impl GeometricFeatures {
    /// The 60 features of vertex `v`.
    pub fn vertex(&self, v: usize) -> &[f64] {
        &self.values[v * DIM..(v + 1) * DIM]
    }

    /// Column `j` over all vertices.
    pub fn column(&self, j: usize) -> Vec<f64> {
        self.values.iter().skip(j).step_by(DIM).copied().collect()
    }
}

fn validate(surface: &Surface, p: &GeometricParams) -> Result<(), GeometricError> {
    if surface.faces.is_empty() || surface.vertex_count() < 4 {
        return Err(GeometricError::Empty);
    }
    let ok = p.normal_sigma_edges.is_finite()
        && p.normal_sigma_edges >= 0.0
        && (1..=32).contains(&p.segments)
        && p.merge_log_gap.is_finite()
        && p.merge_log_gap >= 0.0
        && (1..=4096).contains(&p.geodesic_sources)
        && (2..=1000).contains(&p.spectrum_count);
    if !ok {
        return Err(GeometricError::Param(format!("{p:?}")));
    }
    Ok(())
}

/// The 60 features of one shape, its HKS / WKS scales from its own unit-area spectrum.
///
/// # Errors
/// [`GeometricError`] for bad input, failed operators, or cancellation.
pub fn geometric_features(
    surface: &Surface,
    params: &GeometricParams,
    control: &Control,
) -> Result<GeometricFeatures, GeometricError> {
    validate(surface, params)?;
    let spectrum = unit_area_spectrum(surface, params, control)?;
    let scales = SpectralScales::shared(&[&spectrum])?;
    assemble(surface, &spectrum, &scales, params, control)
}

/// The 60 features of `a` and of `b` with shared HKS times and WKS energies (both spectra of the
/// shapes scaled to unit area; see the module doc), so the two are comparable.
///
/// # Errors
/// As [`geometric_features`].
pub fn geometric_features_pair(
    a: &Surface,
    b: &Surface,
    params: &GeometricParams,
    control: &Control,
) -> Result<(GeometricFeatures, GeometricFeatures), GeometricError> {
    validate(a, params)?;
    validate(b, params)?;
    let sa = unit_area_spectrum(a, params, control)?;
    let sb = unit_area_spectrum(b, params, control)?;
    let scales = SpectralScales::shared(&[&sa, &sb])?;
    Ok((
        assemble(a, &sa, &scales, params, control)?,
        assemble(b, &sb, &scales, params, control)?,
    ))
}

/// HKS times and WKS energies shared by several shapes.
struct SpectralScales {
    times: Vec<f64>,
    energies: Vec<f64>,
    sigma: f64,
}

const ZERO_THRESHOLD: f64 = 1e-8;
const SPECTRAL_SAMPLES: usize = 20;

impl SpectralScales {
    fn shared(spectra: &[&Spectrum]) -> Result<Self, GeometricError> {
        let (mut first, mut max) = (0.0f64, f64::INFINITY);
        for s in spectra {
            let top = s.values.iter().copied().fold(0.0, f64::max);
            let low = (s.values.iter().copied())
                .find(|&l| l > ZERO_THRESHOLD * top)
                .ok_or_else(|| GeometryError::Degenerate("no non-zero eigenvalue".into()))?;
            first = first.max(low);
            max = max.min(top);
        }
        if max.is_nan() || max <= first {
            return Err(GeometryError::Degenerate("spectra share no range".into()).into());
        }
        let k = SPECTRAL_SAMPLES;
        let (t0, t1) = (4.0 * 10f64.ln() / max, 4.0 * 10f64.ln() / first);
        let times = (0..k)
            .map(|j| t0 * (t1 / t0).powf(j as f64 / (k - 1) as f64))
            .collect();
        let (lo, hi) = (first.ln(), max.ln());
        let delta = (hi - lo) / (99.0 + 28.0);
        let sigma = 7.0 * delta;
        let (e0, e1) = (lo + 2.0 * sigma, hi - 2.0 * sigma);
        let energies = (0..k)
            .map(|j| e0 + (e1 - e0) * j as f64 / (k - 1) as f64)
            .collect();
        Ok(Self {
            times,
            energies,
            sigma,
        })
    }
}

/// The spectrum of `surface` scaled about the origin to unit area.
fn unit_area_spectrum(
    surface: &Surface,
    params: &GeometricParams,
    control: &Control,
) -> Result<Spectrum, GeometricError> {
    let area = surface.area();
    if !(area.is_finite() && area > 0.0) {
        return Err(GeometryError::Degenerate("zero or non-finite area".into()).into());
    }
    let s = 1.0 / area.sqrt();
    let mut unit = surface.clone();
    for p in &mut unit.positions {
        *p = p.map(|x| (x as f64 * s) as f32);
    }
    let sp = SpectrumParams {
        count: params.spectrum_count.min(surface.vertex_count() - 1),
        ..SpectrumParams::default()
    };
    Ok(laplace_spectrum(&unit, &sp, control)?)
}

/// All groups of one shape.
fn assemble(
    surface: &Surface,
    spectrum: &Spectrum,
    scales: &SpectralScales,
    params: &GeometricParams,
    control: &Control,
) -> Result<GeometricFeatures, GeometricError> {
    let nv = surface.vertex_count();
    let mut values = vec![0.0; nv * DIM];
    let mut put = |col: usize, column: &[f64]| {
        for (v, x) in column.iter().enumerate() {
            values[v * DIM + col] = *x;
        }
    };
    control.stage("geometric features: curvature, normals, box", 0)?;
    let c = principal_curvatures(surface, &CurvatureParams::default())?;
    let norm: Vec<f64> = (c.k_max.iter().zip(&c.k_min))
        .map(|(a, b)| a.hypot(*b))
        .collect();
    for (col, column) in [&c.k_max, &c.k_min, &c.mean, &c.gaussian, &norm]
        .into_iter()
        .enumerate()
    {
        put(col, column);
    }
    let height: Vec<f64> = surface.positions.iter().map(|p| p[1] as f64).collect();
    put(5, &height);
    let normals = smoothed_normals(surface, params.normal_sigma_edges)?;
    for k in 0..3 {
        put(6 + k, &normals.iter().map(|n| n[k]).collect::<Vec<_>>());
    }
    let (lo, hi) = surface.bounding_box();
    for k in 0..3 {
        let size = (hi[k] - lo[k]) as f64;
        let centre = 0.5 * (hi[k] + lo[k]) as f64;
        let column: Vec<f64> = (surface.positions.iter())
            .map(|p| {
                if size > 0.0 {
                    (p[k] as f64 - centre) / size
                } else {
                    0.0
                }
            })
            .collect();
        put(17 + k, &column);
    }
    let sdf = filled_sdf(surface, params, control)?;
    put(9, &sdf);
    let heat = HeatGeodesics::new(surface, &HeatParams::default(), control)?;
    control.stage("geometric features: segmentation", 0)?;
    let segments = segment_by_sdf(surface, &sdf, params.segments, params.merge_log_gap);
    put(10, &boundary_distance(surface, &heat, &segments)?);
    let geo = geodesic_statistics(surface, &heat, params.geodesic_sources, control)?;
    for k in 0..6 {
        put(11 + k, &geo.iter().map(|g| g[k]).collect::<Vec<_>>());
    }
    control.stage("geometric features: HKS, WKS", 0)?;
    let hks = heat_kernel_signature_at(spectrum, &scales.times, HksNormalization::AreaMean)?;
    let wks = wave_kernel_signature_at(spectrum, &scales.energies, scales.sigma, ZERO_THRESHOLD)?;
    for j in 0..SPECTRAL_SAMPLES {
        put(20 + j, &hks.column(j));
        put(40 + j, &wks.column(j));
    }
    Ok(GeometricFeatures {
        values,
        segments,
        hks_times: scales.times.clone(),
        wks_energies: scales.energies.clone(),
    })
}

/// Angle-weighted normals diffused for time `σ²/2` (4 implicit steps), renormalised.
fn smoothed_normals(surface: &Surface, sigma_edges: f64) -> Result<Vec<[f64; 3]>, GeometricError> {
    let normals = surface.vertex_normals();
    let mut cols: Vec<Vec<f64>> = (0..3)
        .map(|k| normals.iter().map(|n| n[k] as f64).collect())
        .collect();
    let sigma = sigma_edges * mean_edge_length(surface) as f64;
    if sigma > 0.0 {
        let steps = 4;
        let tau = sigma * sigma / (2.0 * steps as f64);
        let lap = cotan_laplacian(surface, &LaplacianParams::default())?;
        let mass = lap.definite_mass();
        let a = lap.stiffness.scaled_plus_diagonal(-tau, 1.0, &mass);
        let factor = SymbolicCholesky::new(lap.pattern().clone())?.factor(&a)?;
        for _ in 0..steps {
            for col in &mut cols {
                col.iter_mut().zip(&mass).for_each(|(x, m)| *x *= m);
            }
            factor.solve_many(&mut cols)?;
        }
    }
    Ok((0..surface.vertex_count())
        .map(|v| {
            let n = [cols[0][v], cols[1][v], cols[2][v]];
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if l > 0.0 {
                n.map(|x| x / l)
            } else {
                [0.0; 3]
            }
        })
        .collect())
}

/// The SDF with invalid vertices set to the median of the valid ones (0 when none).
fn filled_sdf(
    surface: &Surface,
    params: &GeometricParams,
    control: &Control,
) -> Result<Vec<f64>, GeometricError> {
    let raw = shape_diameter(surface, None, &params.sdf, control)?;
    let mut valid: Vec<f64> = (raw.iter())
        .filter(|x| x.is_finite() && **x > 0.0)
        .map(|&x| x as f64)
        .collect();
    valid.sort_by(f64::total_cmp);
    let median = valid.get(valid.len() / 2).copied().unwrap_or(0.0);
    Ok(raw
        .iter()
        .map(|&x| {
            if x.is_finite() && x > 0.0 {
                x as f64
            } else {
                median
            }
        })
        .collect())
}

/// Farthest-point sample of `count` vertices (Euclidean), from vertex 0, with the area each
/// pick stands for (the barycentric areas of the vertices nearest to it).
fn farthest_points(surface: &Surface, count: usize) -> (Vec<usize>, Vec<f64>) {
    let nv = surface.vertex_count();
    let p = |v: usize| surface.positions[v].map(|x| x as f64);
    let mut dist = vec![f64::INFINITY; nv];
    let mut owner = vec![0u32; nv];
    let mut out = Vec::with_capacity(count.min(nv));
    let mut cur = 0usize;
    while out.len() < count.min(nv) {
        let k = out.len() as u32;
        out.push(cur);
        let c = p(cur);
        (dist.par_iter_mut().zip(owner.par_iter_mut()))
            .enumerate()
            .for_each(|(v, (d, o))| {
                let q = p(v);
                let e = (q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2) + (q[2] - c[2]).powi(2);
                if e < *d {
                    *d = e;
                    *o = k;
                }
            });
        cur = (0..nv)
            .max_by(|&a, &b| dist[a].total_cmp(&dist[b]).then(b.cmp(&a)))
            .unwrap_or(0);
    }
    let mut area = vec![0.0; nv];
    for (f, corners) in surface.faces.iter().enumerate() {
        let a = surface.face_area(f) as f64 / 3.0;
        corners.iter().for_each(|&c| area[c as usize] += a);
    }
    let mut weight = vec![0.0; out.len()];
    for v in 0..nv {
        weight[owner[v] as usize] += area[v];
    }
    (out, weight)
}

/// Mean, median, max, std, 10th and 90th percentile of the geodesic distances to the sampled
/// sources, each source weighted by the area it stands for (so the statistics estimate those
/// over the whole surface, whatever the vertex density), ÷ √area.
fn geodesic_statistics(
    surface: &Surface,
    heat: &HeatGeodesics,
    sources: usize,
    control: &Control,
) -> Result<Vec<[f64; 6]>, GeometricError> {
    let (picks, weight) = farthest_points(surface, sources);
    let queries: Vec<Vec<Source>> = (picks.iter())
        .map(|&v| vec![Source::Vertex(v as u32)])
        .collect();
    let d = heat.distance_many(&queries, control)?;
    let scale = 1.0 / surface.area().sqrt();
    Ok((0..surface.vertex_count())
        .into_par_iter()
        .map(|v| {
            let mut x: Vec<(f64, f64)> = (d.iter().zip(&weight))
                .filter(|(q, w)| q[v].is_finite() && **w > 0.0)
                .map(|(q, w)| (q[v] * scale, *w))
                .collect();
            let total: f64 = x.iter().map(|a| a.1).sum();
            if x.is_empty() || total <= 0.0 {
                return [0.0; 6];
            }
            x.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mean = x.iter().map(|a| a.0 * a.1).sum::<f64>() / total;
            let var = x.iter().map(|a| (a.0 - mean).powi(2) * a.1).sum::<f64>() / total;
            // Weighted quantile: each sample at the middle of its weight's span of the CDF,
            // linear in between.
            let mids: Vec<f64> = x
                .iter()
                .scan(0.0, |acc, a| {
                    let m = (*acc + 0.5 * a.1) / total;
                    *acc += a.1;
                    Some(m)
                })
                .collect();
            let q = |p: f64| {
                let i = mids.partition_point(|&m| m < p);
                if i == 0 {
                    x[0].0
                } else if i == x.len() {
                    x[x.len() - 1].0
                } else {
                    let t = (p - mids[i - 1]) / (mids[i] - mids[i - 1]).max(1e-300);
                    x[i - 1].0 + t * (x[i].0 - x[i - 1].0)
                }
            };
            [mean, q(0.5), x[x.len() - 1].0, var.sqrt(), q(0.1), q(0.9)]
        })
        .collect())
}
