//! The detail map of the `detail` method (Berkiten et al. 2017, §3 and Fig. 4): a scalar
//! displacement per vertex of a smooth *base* surface, the signed distance along the base normal
//! to the detailed surface.
//!
//! **Base.** The `source_base` input when given; otherwise the detailed source smoothed here (the
//! paper takes its bases as given): `steps` implicit Laplacian smoothing steps (Desbrun et al.
//! 1999) `(M − τL) x' = M x` with the cotan Laplacian `L` and mixed-Voronoi mass `M` rebuilt at
//! every step, `τ = σ²/(2·steps)`, so that the whole run is heat diffusion for time `σ²/2`: a
//! Gaussian of standard deviation `σ` along the surface, which removes detail of wavelength below
//! about `2σ` (a wavelength `λ` keeps `exp(−2π²σ²/λ²)` of its amplitude). Constants not in the
//! paper: `steps = 3`, `σ = 0.02 ×` the bounding-box diagonal. Diffusion shrinks a closed shape
//! (a sphere of radius R by `exp(−σ²/R²)`), which would show up as a constant displacement, so a
//! closed (boundary-free) result is scaled about its centroid back to the input's enclosed volume,
//! as Desbrun et al. do.
//!
//! **Displacement.** For each base vertex `p` with unit area-weighted normal `n`, the detailed
//! surface is intersected with the segment `p + t n`, `t ∈ [−d_max, d_max]` (one BVH ray cast over
//! the whole segment, every hit visited: both directions at once, and a surface through `p` itself
//! is found at `t = 0`); the hit with the smallest `|t|` gives the displacement `t`. A ray that
//! finds nothing is retried from three offsets of `1e-5 d_max` across the normal (an f32 ray
//! exactly through a shared edge or vertex can slip between the triangles). No hit within
//! `d_max` leaves the vertex at 0 and counts it as missing. `d_max` defaults to 5 % of the base's
//! bounding-box diagonal (a constant not in the paper: detail is "limited in geometric extent"
//! (§1), and a bound keeps a ray from reaching across a thin part to the other side).

use rayon::prelude::*;

use crate::engine::geometry::laplacian::{cotan_laplacian, GeometryError, LaplacianParams};
use crate::engine::linalg::{LinalgError, SymbolicCholesky};
use crate::engine::math::{add, cross, dot, scale, sub, to_f64};
use crate::engine::mesh::{topology, Surface};
use crate::engine::spatial::Bvh;

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum DisplacementError {
    /// Laplacian assembly failed (empty surface, non-finite positions).
    #[error("smoothing: {0}")]
    Geometry(#[from] GeometryError),
    /// The smoothing system could not be solved.
    #[error("smoothing: {0}")]
    Linalg(#[from] LinalgError),
    /// A parameter is out of range.
    #[error("invalid displacement parameter: {0}")]
    Param(String),
    /// A surface has no faces.
    #[error("the {0} surface has no faces")]
    Empty(&'static str),
}

/// Parameters of [`smooth_base`].
#[derive(Clone, Debug)]
pub struct BaseParams {
    /// Implicit steps.
    pub steps: usize,
    /// Gaussian width `σ` (world units); `None`: 0.02 × the bounding-box diagonal.
    pub sigma: Option<f64>,
    /// Rescale a closed result to the input's enclosed volume.
    pub preserve_volume: bool,
}

impl Default for BaseParams {
    fn default() -> Self {
        Self {
            steps: 3,
            sigma: None,
            preserve_volume: true,
        }
    }
}

/// Signed enclosed volume (divergence theorem; meaningful for closed surfaces).
fn signed_volume(s: &Surface) -> f64 {
    s.faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|v| to_f64(s.positions[v as usize]));
            dot(a, cross(b, c)) / 6.0
        })
        .sum()
}

/// The detailed surface smoothed into a base (see the module doc). Same vertices and faces.
///
/// # Errors
/// [`DisplacementError`] for an empty surface, bad parameters or a failed solve.
pub fn smooth_base(detailed: &Surface, params: &BaseParams) -> Result<Surface, DisplacementError> {
    if detailed.faces.is_empty() {
        return Err(DisplacementError::Empty("detailed"));
    }
    let sigma = params.sigma.unwrap_or(0.02 * detailed.diagonal() as f64);
    if !(sigma.is_finite() && sigma >= 0.0) || params.steps == 0 || params.steps > 100 {
        return Err(DisplacementError::Param(format!(
            "sigma {sigma} must be ≥ 0 and steps {} in 1..=100",
            params.steps
        )));
    }
    let tau = sigma * sigma / (2.0 * params.steps as f64);
    let mut out = detailed.clone();
    let lp = LaplacianParams::default();
    for _ in 0..params.steps {
        let lap = cotan_laplacian(&out, &lp)?;
        let mass = lap.definite_mass();
        let a = lap.stiffness.scaled_plus_diagonal(-tau, 1.0, &mass);
        let factor = SymbolicCholesky::new(lap.pattern().clone())?.factor(&a)?;
        let mut rhs: Vec<Vec<f64>> = (0..3)
            .map(|k| {
                out.positions
                    .iter()
                    .zip(&mass)
                    .map(|(p, m)| p[k] as f64 * m)
                    .collect()
            })
            .collect();
        factor.solve_many(&mut rhs)?;
        for (i, p) in out.positions.iter_mut().enumerate() {
            *p = [rhs[0][i] as f32, rhs[1][i] as f32, rhs[2][i] as f32];
        }
    }
    if params.preserve_volume && topology(detailed).boundary_loops.is_empty() {
        let (v0, v1) = (signed_volume(detailed), signed_volume(&out));
        if v0.abs() > 0.0 && v1.abs() > 0.0 && v0.signum() == v1.signum() {
            let s = (v0 / v1).cbrt();
            let n = out.positions.len() as f64;
            let c = out
                .positions
                .iter()
                .fold([0.0; 3], |acc, p| add(acc, to_f64(*p)));
            let c = scale(c, 1.0 / n);
            for p in &mut out.positions {
                let q = add(c, scale(sub(to_f64(*p), c), s));
                *p = q.map(|x| x as f32);
            }
        }
    }
    Ok(out)
}

/// Parameters of [`displacement`].
#[derive(Clone, Debug, Default)]
pub struct DisplacementParams {
    /// Largest `|displacement|` searched (world units); `None`: 5 % of the base's diagonal.
    pub max_distance: Option<f64>,
}

/// Displacements per base vertex.
#[derive(Clone, Debug)]
pub struct Displacement {
    /// Signed displacement along the base normal (0 where missing).
    pub values: Vec<f64>,
    /// Whether a hit was found within `max_distance`.
    pub found: Vec<bool>,
    /// Vertices without a hit.
    pub missing: usize,
    /// The search distance used.
    pub max_distance: f64,
    /// The unit base normals used.
    pub normals: Vec<[f64; 3]>,
}

/// Area-weighted unit vertex normals (zero for isolated vertices).
pub fn area_weighted_normals(s: &Surface) -> Vec<[f64; 3]> {
    let mut n = vec![[0.0; 3]; s.positions.len()];
    for f in &s.faces {
        let [a, b, c] = f.map(|v| to_f64(s.positions[v as usize]));
        let fn_ = cross(sub(b, a), sub(c, a));
        for &v in f {
            n[v as usize] = add(n[v as usize], fn_);
        }
    }
    n.into_iter().map(crate::engine::math::normalize).collect()
}

/// Two unit vectors completing the unit `n` to an orthonormal frame.
fn tangent_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a = if n[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = crate::engine::math::normalize(cross(n, a));
    (u, cross(n, u))
}

/// The displacement of `detailed` over `base` (see the module doc).
///
/// # Errors
/// [`DisplacementError::Empty`] when either surface has no faces; [`DisplacementError::Param`]
/// for a non-positive `max_distance`.
pub fn displacement(
    base: &Surface,
    detailed: &Surface,
    params: &DisplacementParams,
) -> Result<Displacement, DisplacementError> {
    if base.faces.is_empty() {
        return Err(DisplacementError::Empty("base"));
    }
    if detailed.faces.is_empty() {
        return Err(DisplacementError::Empty("detailed"));
    }
    let d_max = params.max_distance.unwrap_or(0.05 * base.diagonal() as f64);
    if !(d_max.is_finite() && d_max > 0.0) {
        return Err(DisplacementError::Param(format!(
            "max_distance {d_max} must be > 0"
        )));
    }
    let bvh = Bvh::build(&detailed.positions, &detailed.faces);
    let normals = area_weighted_normals(base);
    let hits: Vec<Option<f64>> = base
        .positions
        .par_iter()
        .zip(&normals)
        .map(|(p, n)| {
            if *n == [0.0; 3] {
                return None;
            }
            // A ray exactly through a shared edge or vertex of the detailed mesh can slip between
            // its triangles in f32: retry from tiny tangential offsets (1e-5 d_max).
            let (u, w) = tangent_basis(*n);
            let eps = 1e-5 * d_max;
            let mut best: Option<f64> = None;
            for off in [[0.0, 0.0], [1.0, 0.0], [-0.5, 0.87], [-0.5, -0.87]] {
                let shift = add(scale(u, off[0] * eps), scale(w, off[1] * eps));
                let origin = add(sub(to_f64(*p), scale(*n, d_max)), shift);
                bvh.ray_for_each_hit(
                    origin.map(|x| x as f32),
                    n.map(|x| x as f32),
                    0.0,
                    (2.0 * d_max) as f32,
                    |hit| {
                        let t = hit.t as f64 - d_max;
                        if best.is_none_or(|b| t.abs() < b.abs()) {
                            best = Some(t);
                        }
                    },
                );
                if best.is_some() {
                    break;
                }
            }
            best
        })
        .collect();
    let missing = hits.iter().filter(|h| h.is_none()).count();
    Ok(Displacement {
        values: hits.iter().map(|h| h.unwrap_or(0.0)).collect(),
        found: hits.iter().map(|h| h.is_some()).collect(),
        missing,
        max_distance: d_max,
        normals,
    })
}
