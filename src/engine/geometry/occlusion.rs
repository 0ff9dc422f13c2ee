//! Directional occlusion (Mertens et al., *Texture Transfer Using Geometry Correlation*, EGSR
//! 2006, §3.2): the binary visibility function `V(ω)` of each vertex over the whole sphere of
//! directions, projected by ray casting onto the real spherical harmonics of bands 0 and 1 in
//! object space (Sloan, Kautz, Snyder 2002 convention, orthonormal over the sphere):
//!
//! `Y₀₀ = ½√(1/π)`, `Y₁₋₁ = √(3/4π) y`, `Y₁₀ = √(3/4π) z`, `Y₁₁ = √(3/4π) x`,
//! coefficient `c = ∫ V(ω) Y(ω) dω ≈ (4π / N) Σᵢ V(ωᵢ) Y(ωᵢ)`.
//!
//! Band 0 is ambient visibility (ambient occlusion up to scale); band 1 is the mean visible
//! direction, in object axes (e.g. towards gravity). Reference values: an unoccluded hemisphere
//! about the unit normal `n` (any point of a convex object) gives `c₀₀ = √π ≈ 1.7725` and
//! `(c₁₁, c₁₋₁, c₁₀) = π √(3/4π) (nₓ, n_y, n_z) ≈ 1.5350 n`; the whole sphere gives
//! `c₀₀ = 2√π` and band 1 zero. [`Occlusion::visibility`] is `c₀₀ / √π`, the visible solid
//! angle over 2π.
//!
//! Method: `rays` directions of a spherical Fibonacci set (see [`super::ray_sets`]) with the pole
//! on the vertex normal, so the two hemispheres get exactly half the rays each; each ray starts
//! at `p + δ n` (`δ = offset × mean incident edge length`) and is visible when it hits nothing
//! within `max_distance` (an any-hit query). Directions below the tangent plane are occluded by
//! the surface itself except where the polyhedral surface dips below it (edges, corners, and
//! slightly at every vertex of a curved mesh), which is the true visibility of the polyhedron.
//! Open meshes: rays leave through holes and count as visible.

use serde::{Deserialize, Serialize};

use super::ray_sets::{check_param, fibonacci_sphere, per_vertex, vertex_frame};
use super::ray_sets::{RayContext, RayFeatureError};
use crate::engine::control::Control;
use crate::engine::mesh::surface::Surface;

/// `Y₀₀`.
pub const SH_Y00: f32 = 0.282_094_8;
/// `√(3/4π)`, the factor of the band-1 functions.
pub const SH_Y1: f32 = 0.488_602_5;

/// Parameters of [`directional_occlusion`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OcclusionParams {
    /// Rays per vertex over the whole sphere (Mertens et al. do not give a count). Default: 64.
    /// Range: 2..=16384.
    pub rays: usize,
    /// Occluders farther than this fraction of the bounding-box diagonal are ignored; `None`
    /// for no limit. Default: `None`. Range: (0, 100].
    pub max_distance: Option<f32>,
    /// Seed of the per-vertex azimuth of the direction set. Default: 0.
    pub seed: u64,
    /// Turn each vertex's direction set about its normal by a hashed azimuth. Default: true.
    pub randomize: bool,
    /// Outward start offset in multiples of the mean incident edge length. Default: 1e-3.
    /// Range: [0, 0.1].
    pub offset: f32,
}

impl Default for OcclusionParams {
    fn default() -> Self {
        Self {
            rays: 64,
            max_distance: None,
            seed: 0,
            randomize: true,
            offset: 1e-3,
        }
    }
}

/// SH-projected visibility per vertex.
#[derive(Clone, Debug, PartialEq)]
pub struct Occlusion {
    /// `[c₀₀, c₁₋₁, c₁₀, c₁₁]` per vertex (the `y`, `z`, `x` order of the band-1 functions).
    pub coefficients: Vec<[f32; 4]>,
}

impl Occlusion {
    /// Visible solid angle of vertex `v` over 2π (1 for an unoccluded hemisphere).
    pub fn visibility(&self, v: usize) -> f32 {
        self.coefficients[v][0] / std::f32::consts::PI.sqrt()
    }

    /// The band-1 coefficients of vertex `v` as an object-space vector `(c₁₁, c₁₋₁, c₁₀)`
    /// (x, y, z): `√(3/4π)` times the integral of the visible directions.
    pub fn band1_vector(&self, v: usize) -> [f32; 3] {
        let c = self.coefficients[v];
        [c[3], c[1], c[2]]
    }
}

/// Directional occlusion of every vertex of `surface` (see the module docs). `normals`: unit
/// outward vertex normals, or `None` for angle-weighted ones.
///
/// # Errors
/// [`RayFeatureError::InvalidParam`] for params out of range, [`RayFeatureError::NormalCount`],
/// [`RayFeatureError::Cancelled`].
pub fn directional_occlusion(
    surface: &Surface,
    normals: Option<&[[f32; 3]]>,
    params: &OcclusionParams,
    control: &Control,
) -> Result<Occlusion, RayFeatureError> {
    validate(params)?;
    let ctx = RayContext::new(surface, normals)?;
    directional_occlusion_with(&ctx, params, control)
}

fn validate(params: &OcclusionParams) -> Result<(), RayFeatureError> {
    check_param(
        (2..=16384).contains(&params.rays),
        "rays",
        params.rays as f64,
        "2..=16384",
    )?;
    if let Some(m) = params.max_distance {
        check_param(m > 0.0 && m <= 100.0, "max_distance", m as f64, "(0, 100]")?;
    }
    check_param(
        (0.0..=0.1).contains(&params.offset),
        "offset",
        params.offset as f64,
        "[0, 0.1]",
    )
}

/// [`directional_occlusion`] on a prepared [`RayContext`].
///
/// # Errors
/// As [`directional_occlusion`], except the normal count (checked by the context).
pub fn directional_occlusion_with(
    ctx: &RayContext<'_>,
    params: &OcclusionParams,
    control: &Control,
) -> Result<Occlusion, RayFeatureError> {
    validate(params)?;
    let t_max = params
        .max_distance
        .map_or(f32::INFINITY, |m| m * ctx.diagonal);
    let local = fibonacci_sphere(params.rays);
    let weight = 4.0 * std::f64::consts::PI / params.rays as f64;
    let flat = per_vertex(
        ctx.surface.vertex_count(),
        4,
        "directional occlusion",
        control,
        |v, out| {
            let frame = vertex_frame(ctx.normals[v], params.seed, v, params.randomize);
            let origin = ctx.origin(v, 1.0, params.offset);
            let mut visible = 0u32;
            let mut sum = [0.0f64; 3];
            for d in &local {
                let dir = frame.to_world(*d);
                if !ctx.bvh.ray_hits_any(origin, dir, 0.0, t_max) {
                    visible += 1;
                    for k in 0..3 {
                        sum[k] += dir[k] as f64;
                    }
                }
            }
            let w1 = weight * SH_Y1 as f64;
            out[0] = (weight * SH_Y00 as f64 * visible as f64) as f32;
            out[1] = (w1 * sum[1]) as f32;
            out[2] = (w1 * sum[2]) as f32;
            out[3] = (w1 * sum[0]) as f32;
        },
    )?;
    let coefficients = flat.chunks(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
    Ok(Occlusion { coefficients })
}
