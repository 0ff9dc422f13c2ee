//! The 12-D geometric features of Mertens et al. 2006, §3.2, computed per vertex of the welded
//! input surface and interpolated to the surface samples (§3.1) through their (face, barycentric)
//! location:
//!
//! | index | feature |
//! |---|---|
//! | 0 | height along the `up` axis, normalised to [0, 1] over the bounding box |
//! | 1-3 | unit vertex normal (object space) |
//! | 4-7 | solid-angle curvature at the four `curvature_radii` (fractions of the diagonal) |
//! | 8-11 | directional occlusion projected on SH bands 0 and 1 (`c₀₀, c₁₋₁, c₁₀, c₁₁`) |
//!
//! Constants the paper does not publish: the radii (default `[0.0125, 0.025, 0.05, 0.1]` of
//! the bounding-box diagonal, doubling from creases to limbs) and the ray counts (default 128
//! per vertex for the curvature and 128 for the occlusion: the Fibonacci sets are stratified, so
//! the error of a fraction is about 1/128, well below the features' spread across a model).
//!
//! Deviation: the paper computes the solid angle analytically from the sphere-surface
//! intersection; [`crate::engine::geometry::solid_angle`] estimates the same sphere-surface
//! fraction with rays (its doc states the error bound). The occlusion is the ray-cast binary
//! visibility of [`crate::engine::geometry::occlusion`] over the whole sphere, as in the paper.
//! Interpolated normals are re-normalised.

use rayon::prelude::*;

use crate::engine::control::Control;
use crate::engine::geometry::occlusion::{directional_occlusion_with, OcclusionParams};
use crate::engine::geometry::ray_sets::{RayContext, RayFeatureError};
use crate::engine::geometry::solid_angle::{solid_angle_curvature_with, SolidAngleParams};
use crate::engine::mesh::Surface;
use crate::engine::methods::MethodError;
use crate::engine::multires::FacePoint;

/// Feature dimensions.
pub const DIMS: usize = 12;

/// A 12-D feature vector.
pub type Feature = [f32; DIMS];

/// Names of the features, in order (for the report's CCA weights, the paper's Fig. 4).
pub const NAMES: [&str; DIMS] = [
    "height",
    "normal_x",
    "normal_y",
    "normal_z",
    "curvature_0",
    "curvature_1",
    "curvature_2",
    "curvature_3",
    "occlusion_y00",
    "occlusion_y1m1",
    "occlusion_y10",
    "occlusion_y11",
];

/// How the features are computed.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureParams {
    /// Unit up axis.
    pub up: [f32; 3],
    /// Curvature radii as fractions of the bounding-box diagonal.
    pub radii: [f32; 4],
    /// Rays per vertex, for the curvature and the occlusion each.
    pub rays: usize,
    /// Seed of the ray sets' azimuths.
    pub seed: u64,
}

fn ray_error(e: RayFeatureError) -> MethodError {
    match e {
        RayFeatureError::Cancelled => MethodError::Cancelled,
        other => MethodError::Internal(format!("features: {other}")),
    }
}

/// The 12-D features of every vertex of `surface`. Control stages `curvature`, `occlusion`
/// (the ray casting's own progress).
///
/// # Errors
/// [`MethodError::UnusableInput`] for a surface without faces or a flat bounding box,
/// [`MethodError::Cancelled`].
pub fn vertex_features(
    surface: &Surface,
    params: &FeatureParams,
    control: &Control,
) -> Result<Vec<Feature>, MethodError> {
    let diagonal = surface.diagonal();
    if surface.face_count() == 0 || !(diagonal > 0.0 && diagonal.is_finite()) {
        return Err(MethodError::UnusableInput {
            field: None,
            kind: "unusable-mesh",
            message: "a surface without area has no geometric features".into(),
        });
    }
    let normals = surface.vertex_normals();
    let ctx = RayContext::new(surface, Some(&normals)).map_err(ray_error)?;
    control.stage("curvature", 0)?;
    let curvature = solid_angle_curvature_with(
        &ctx,
        &SolidAngleParams {
            radii: params.radii.to_vec(),
            rays: params.rays,
            seed: params.seed,
            ..Default::default()
        },
        control,
    )
    .map_err(ray_error)?;
    control.stage("occlusion", 0)?;
    let occlusion = directional_occlusion_with(
        &ctx,
        &OcclusionParams {
            rays: params.rays,
            seed: params.seed ^ 0x5eed,
            ..Default::default()
        },
        control,
    )
    .map_err(ray_error)?;
    let heights: Vec<f32> = surface
        .positions
        .iter()
        .map(|p| dot(*p, params.up))
        .collect();
    let lo = heights.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = heights.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let span = if hi > lo { hi - lo } else { 1.0 };
    Ok((0..surface.vertex_count())
        .map(|v| {
            let mut f = [0.0f32; DIMS];
            f[0] = (heights[v] - lo) / span;
            f[1..4].copy_from_slice(&normals[v]);
            f[4..8].copy_from_slice(curvature.vertex(v));
            f[8..12].copy_from_slice(&occlusion.coefficients[v]);
            f
        })
        .collect())
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Interpolates per-vertex values of `surface` to points on its faces (barycentric); a point on
/// no face ([`FacePoint::NONE`]) gets zeros.
pub fn interpolate<const D: usize>(
    surface: &Surface,
    values: &[[f32; D]],
    at: &[FacePoint],
) -> Vec<[f32; D]> {
    at.par_iter()
        .map(|fp| {
            let Some(face) = surface.faces.get(fp.face as usize) else {
                return [0.0; D];
            };
            let mut out = [0.0f32; D];
            for (k, &v) in face.iter().enumerate() {
                let w = fp.bary[k];
                for (o, x) in out.iter_mut().zip(&values[v as usize]) {
                    *o += w * x;
                }
            }
            out
        })
        .collect()
}

/// The features at the samples `at` (see [`interpolate`]), normals re-normalised.
pub fn sample_features(surface: &Surface, vertex: &[Feature], at: &[FacePoint]) -> Vec<Feature> {
    let mut out = interpolate(surface, vertex, at);
    for f in &mut out {
        let n = (f[1] * f[1] + f[2] * f[2] + f[3] * f[3]).sqrt();
        if n > 1e-12 {
            for x in &mut f[1..4] {
                *x /= n;
            }
        }
    }
    out
}
