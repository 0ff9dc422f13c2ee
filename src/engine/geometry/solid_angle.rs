//! Multi-scale solid-angle curvature (Connolly, *Measurement of protein surface shape by solid
//! angles*, 1986), as used by Mertens et al., *Texture Transfer Using Geometry Correlation*
//! (EGSR 2006), §3.2: for a vertex `p` and a radius `r`, the fraction of the sphere `S(p, r)`
//! that lies inside the object, at several radii scaled by the bounding-box diagonal.
//!
//! Definition. This is the *sphere-surface* fraction (the solid angle of the part of `S(p, r)`
//! inside the solid, over 4π), which is what Connolly and Mertens measure ("the solid angle
//! subtended by the intersection of the surface with this sphere"). It is 1/2 on a plane. On a
//! ball of radius ρ with `p` on its boundary, a point `p + r ω` is inside when
//! `|p + r ω - c|² ≤ ρ²`, i.e. `cos θ ≥ r / (2ρ)` with θ the angle between ω and the inward
//! normal: a cap of area fraction `(1 - r/(2ρ)) / 2 = 1/2 - r/(4ρ)` (for `r ≤ 2ρ`). The volume
//! version (the fraction of the *ball* `B(p, r)` inside) would give `1/2 - 3r/(16ρ)` instead.
//! Values below 1/2 mean convex at that scale, above 1/2 concave.
//!
//! Method. Mertens et al. intersect the sphere with the surface analytically (spherical excess);
//! here the fraction is estimated with `rays` directions ω of a spherical Fibonacci set whose
//! pole is on the vertex normal (see [`super::ray_sets`]): for each ω one ray from
//! `p' = p - δ n` (just inside, `δ = offset × mean incident edge length`) collects every surface
//! crossing up to the largest radius; the point `p' + r ω` is inside when the signed crossing
//! count (`+1` entering through a face's front, `-1` leaving) plus the start value 1 is
//! positive. One traversal serves all radii. Because the Fibonacci set is exactly stratified in
//! the height along the normal, a plane gives exactly 1/2 and a sphere's cap is counted to within
//! one ray (error ≤ 1/`rays`); coincident crossings of the same sign (a ray through a shared
//! edge) count once.
//!
//! Meshes: meant for closed, consistently outward-oriented meshes; overlapping closed parts
//! count as their union (winding number > 0). On open meshes the side behind a sheet (against
//! its normal) counts as inside until a ray crosses another sheet, so a large open plane gives
//! 1/2 and rays leaving through a hole keep their state. Inward-oriented meshes give `1 - f`.

use serde::{Deserialize, Serialize};

use super::ray_sets::{check_param, fibonacci_sphere, per_vertex, vertex_frame};
use super::ray_sets::{RayContext, RayFeatureError};
use crate::engine::control::Control;
use crate::engine::mesh::surface::Surface;

/// Parameters of [`solid_angle_curvature`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolidAngleParams {
    /// Sphere radii as fractions of the bounding-box diagonal. Mertens et al. use four radii
    /// "scaled relatively to the diagonal" without giving values; default
    /// `[0.0125, 0.025, 0.05, 0.1]` (doubling from fine detail to global exposure). Range: each
    /// in (0, 2], 1 to 16 radii.
    pub radii: Vec<f32>,
    /// Directions per vertex (one ray each, shared by all radii). Default: 64. Range: 2..=4096.
    /// The per-vertex quadrature error on smooth surfaces is about 1/`rays`.
    pub rays: usize,
    /// Seed of the per-vertex azimuth of the direction set. Default: 0.
    pub seed: u64,
    /// Turn each vertex's direction set about its normal by a hashed azimuth. Default: true.
    pub randomize: bool,
    /// Inward start offset in multiples of the mean incident edge length. Default: 1e-3.
    /// Range: [0, 0.1].
    pub offset: f32,
}

impl Default for SolidAngleParams {
    fn default() -> Self {
        Self {
            radii: vec![0.0125, 0.025, 0.05, 0.1],
            rays: 64,
            seed: 0,
            randomize: true,
            offset: 1e-3,
        }
    }
}

/// Solid-angle curvature per vertex and radius.
#[derive(Clone, Debug, PartialEq)]
pub struct SolidAngleCurvature {
    /// The radii used, world units (params' fractions times the diagonal).
    pub radii: Vec<f32>,
    /// `values[v * radii.len() + i]`: fraction in [0, 1] of the sphere of radius `radii[i]`
    /// around vertex `v` inside the object.
    pub values: Vec<f32>,
}

impl SolidAngleCurvature {
    /// The values of vertex `v`, one per radius.
    pub fn vertex(&self, v: usize) -> &[f32] {
        let k = self.radii.len();
        &self.values[v * k..(v + 1) * k]
    }

    /// The values at radius index `i` for every vertex.
    pub fn at_radius(&self, i: usize) -> Vec<f32> {
        self.values
            .chunks(self.radii.len())
            .map(|row| row[i])
            .collect()
    }
}

/// Solid-angle curvature of every vertex of `surface` at every radius (see the module docs).
/// `normals`: unit outward vertex normals, or `None` for angle-weighted ones.
///
/// # Errors
/// [`RayFeatureError::InvalidParam`] for params out of range, [`RayFeatureError::NormalCount`],
/// [`RayFeatureError::Cancelled`].
pub fn solid_angle_curvature(
    surface: &Surface,
    normals: Option<&[[f32; 3]]>,
    params: &SolidAngleParams,
    control: &Control,
) -> Result<SolidAngleCurvature, RayFeatureError> {
    validate(params)?;
    let ctx = RayContext::new(surface, normals)?;
    solid_angle_curvature_with(&ctx, params, control)
}

fn validate(params: &SolidAngleParams) -> Result<(), RayFeatureError> {
    let k = params.radii.len();
    check_param((1..=16).contains(&k), "radii.len", k as f64, "1..=16")?;
    for &r in &params.radii {
        check_param(r > 0.0 && r <= 2.0, "radii", r as f64, "(0, 2]")?;
    }
    check_param(
        (2..=4096).contains(&params.rays),
        "rays",
        params.rays as f64,
        "2..=4096",
    )?;
    check_param(
        (0.0..=0.1).contains(&params.offset),
        "offset",
        params.offset as f64,
        "[0, 0.1]",
    )
}

/// [`solid_angle_curvature`] on a prepared [`RayContext`].
///
/// # Errors
/// As [`solid_angle_curvature`], except the normal count (checked by the context).
pub fn solid_angle_curvature_with(
    ctx: &RayContext<'_>,
    params: &SolidAngleParams,
    control: &Control,
) -> Result<SolidAngleCurvature, RayFeatureError> {
    validate(params)?;
    let radii: Vec<f32> = params.radii.iter().map(|r| r * ctx.diagonal).collect();
    let r_max = radii.iter().copied().fold(0.0f32, f32::max);
    let local = fibonacci_sphere(params.rays);
    let k = radii.len();
    let inv_n = 1.0 / params.rays as f32;
    let values = per_vertex(
        ctx.surface.vertex_count(),
        k,
        "solid angle curvature",
        control,
        |v, out| {
            let frame = vertex_frame(ctx.normals[v], params.seed, v, params.randomize);
            let origin = ctx.origin(v, -1.0, params.offset);
            let mut inside = [0u32; 16];
            let mut hits: Vec<(f32, i32)> = Vec::with_capacity(16);
            for d in &local {
                let dir = frame.to_world(*d);
                hits.clear();
                ctx.bvh.ray_for_each_hit(origin, dir, 0.0, r_max, |h| {
                    hits.push((h.t, if ctx.is_exit(&h, dir) { -1 } else { 1 }));
                });
                hits.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                // Same-sign crossings at (nearly) the same t are one crossing through an edge.
                let tol = 1e-6 * r_max;
                let mut last: Option<(f32, i32)> = None;
                hits.retain(|&(t, s)| {
                    let dup = last.is_some_and(|(lt, ls)| ls == s && t - lt <= tol);
                    last = Some((t, s));
                    !dup
                });
                for (i, &r) in radii.iter().enumerate() {
                    let winding: i32 = 1 + hits
                        .iter()
                        .take_while(|h| h.0 <= r)
                        .map(|h| h.1)
                        .sum::<i32>();
                    if winding > 0 {
                        inside[i] += 1;
                    }
                }
            }
            for i in 0..k {
                out[i] = inside[i] as f32 * inv_n;
            }
        },
    )?;
    Ok(SolidAngleCurvature { radii, values })
}
