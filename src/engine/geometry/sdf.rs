//! Shape diameter function (Shapira, Shamir, Cohen-Or, *Consistent Mesh Partitioning and
//! Skeletonisation using the Shape Diameter Function*, The Visual Computer 2008, §3): the local
//! thickness of the object under each vertex.
//!
//! Method (the paper's): `rays` rays in a cone of full opening `cone_angle` about the inward
//! normal; each ray's length is the distance to its first hit. Rays that miss, or whose first hit
//! enters a face from its front (so the ray did not travel through the inside; the paper's "the
//! normal at the intersection points in the same direction as the point of origin"), are
//! dropped. Of the remaining lengths, those within `outlier_std` standard deviations of their
//! median are kept, and the SDF is their weighted mean with weights `1 / θ` (θ: angle between the
//! ray and the cone axis). Deviation, stated: the paper's validity test compares the hit normal
//! with the *origin's* normal, which on a sphere rejects every ray steeper than 45° of a 120°
//! cone; here the hit normal is compared with the *ray direction* (the hit must leave the solid),
//! which is the intent and keeps those rays.
//!
//! Rays: a spherical Fibonacci cap (see [`super::ray_sets`]) with `z ∈ [cos(cone_angle/2), 1)`,
//! so no ray lies exactly on the axis (θ > 0) and the rays weigh equal solid angles; they start
//! at `p - δ n` (`δ = offset × mean incident edge length`).
//!
//! Expected value on a sphere of radius ρ: a ray at angle θ from the inward normal has length
//! `2ρ cos θ`, so the SDF is `2ρ` times the filtered, weighted mean of `cos θ` over the cone: the
//! cone averaging biases it below `2ρ` (1.535ρ = 0.767 × 2ρ for the defaults; → 2ρ as the cone
//! narrows). Units: world units. Vertices with no valid ray get `NaN`.

use serde::{Deserialize, Serialize};

use super::ray_sets::{check_param, fibonacci_cap, per_vertex, vertex_frame};
use super::ray_sets::{RayContext, RayFeatureError};
use crate::engine::control::Control;
use crate::engine::mesh::surface::Surface;

/// Parameters of [`shape_diameter`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SdfParams {
    /// Full opening angle of the cone, degrees. Default: 120 (the paper's). Range: (0, 180].
    pub cone_angle: f32,
    /// Rays per vertex. Default: 30 (the paper's). Range: 1..=1024.
    pub rays: usize,
    /// Keep lengths within this many standard deviations of the median. Default: 1 (the
    /// paper's). Range: (0, 100].
    pub outlier_std: f32,
    /// Seed of the per-vertex azimuth of the ray set. Default: 0.
    pub seed: u64,
    /// Turn each vertex's ray set about its normal by a hashed azimuth. Default: true.
    pub randomize: bool,
    /// Inward start offset in multiples of the mean incident edge length. Default: 1e-3.
    /// Range: [0, 0.1].
    pub offset: f32,
}

impl Default for SdfParams {
    fn default() -> Self {
        Self {
            cone_angle: 120.0,
            rays: 30,
            outlier_std: 1.0,
            seed: 0,
            randomize: true,
            offset: 1e-3,
        }
    }
}

/// The local ray directions of [`shape_diameter`] about the `+z` axis (which the computation
/// maps to the inward normal), with their angles to the axis in radians.
pub fn sdf_cone(params: &SdfParams) -> Vec<([f32; 3], f32)> {
    let half = (params.cone_angle as f64 / 2.0).to_radians();
    fibonacci_cap(params.rays, half.cos() as f32)
        .into_iter()
        .map(|d| (d, (d[2] as f64).clamp(-1.0, 1.0).acos().max(1e-6) as f32))
        .collect()
}

/// The paper's estimator on a set of `(length, angle)` samples: drop lengths farther than
/// `outlier_std` standard deviations from the median, then average with weights `1 / angle`.
/// `NaN` for no samples. `samples` is reordered.
pub fn sdf_estimate(samples: &mut [(f32, f32)], outlier_std: f32) -> f32 {
    let n = samples.len();
    if n == 0 {
        return f32::NAN;
    }
    samples.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let median = if n % 2 == 1 {
        samples[n / 2].0 as f64
    } else {
        0.5 * (samples[n / 2 - 1].0 as f64 + samples[n / 2].0 as f64)
    };
    let mean = samples.iter().map(|s| s.0 as f64).sum::<f64>() / n as f64;
    let var = samples
        .iter()
        .map(|s| (s.0 as f64 - mean).powi(2))
        .sum::<f64>()
        / n as f64;
    let band = outlier_std as f64 * var.sqrt();
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for &(len, angle) in samples.iter() {
        if (len as f64 - median).abs() <= band {
            let w = 1.0 / angle as f64;
            num += w * len as f64;
            den += w;
        }
    }
    if den > 0.0 {
        (num / den) as f32
    } else {
        median as f32
    }
}

/// Shape diameter of every vertex of `surface` (see the module docs). `normals`: unit outward
/// vertex normals, or `None` for angle-weighted ones.
///
/// # Errors
/// [`RayFeatureError::InvalidParam`] for params out of range, [`RayFeatureError::NormalCount`],
/// [`RayFeatureError::Cancelled`].
pub fn shape_diameter(
    surface: &Surface,
    normals: Option<&[[f32; 3]]>,
    params: &SdfParams,
    control: &Control,
) -> Result<Vec<f32>, RayFeatureError> {
    validate(params)?;
    let ctx = RayContext::new(surface, normals)?;
    shape_diameter_with(&ctx, params, control)
}

fn validate(params: &SdfParams) -> Result<(), RayFeatureError> {
    check_param(
        params.cone_angle > 0.0 && params.cone_angle <= 180.0,
        "cone_angle",
        params.cone_angle as f64,
        "(0, 180]",
    )?;
    check_param(
        (1..=1024).contains(&params.rays),
        "rays",
        params.rays as f64,
        "1..=1024",
    )?;
    check_param(
        params.outlier_std > 0.0 && params.outlier_std <= 100.0,
        "outlier_std",
        params.outlier_std as f64,
        "(0, 100]",
    )?;
    check_param(
        (0.0..=0.1).contains(&params.offset),
        "offset",
        params.offset as f64,
        "[0, 0.1]",
    )
}

/// [`shape_diameter`] on a prepared [`RayContext`].
///
/// # Errors
/// As [`shape_diameter`], except the normal count (checked by the context).
pub fn shape_diameter_with(
    ctx: &RayContext<'_>,
    params: &SdfParams,
    control: &Control,
) -> Result<Vec<f32>, RayFeatureError> {
    validate(params)?;
    let cone = sdf_cone(params);
    per_vertex(
        ctx.surface.vertex_count(),
        1,
        "shape diameter",
        control,
        |v, out| {
            let n = ctx.normals[v];
            let inward = [-n[0], -n[1], -n[2]];
            let frame = vertex_frame(inward, params.seed, v, params.randomize);
            let origin = ctx.origin(v, -1.0, params.offset);
            let mut samples: Vec<(f32, f32)> = Vec::with_capacity(cone.len());
            for &(d, angle) in &cone {
                let dir = frame.to_world(d);
                if let Some(hit) = ctx.bvh.ray_cast(origin, dir, 0.0, f32::INFINITY) {
                    if ctx.is_exit(&hit, dir) {
                        samples.push((hit.t, angle));
                    }
                }
            }
            out[0] = sdf_estimate(&mut samples, params.outlier_std);
        },
    )
}
