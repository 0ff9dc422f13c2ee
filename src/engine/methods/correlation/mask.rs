//! The training mask of the `correlation` method (issue 11, `params.mask`): source regions
//! removed from training (Mertens et al. 2006 train on the whole texture; the mask lets a
//! painted-over or damaged region of a scan be left out). A surface sample is removed (weight 0)
//! where the mask's value at its location on the input surface is above the threshold: a COLOR_0
//! channel interpolated over the triangle, or an image read through the base-colour UVs (colour
//! channels in linear space, alpha as stored), as MeshMatch's example mask reads them.

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::{Asset, Sampler};
use crate::engine::mesh::Surface;
use crate::engine::methods::meshmatch::example::Channel;
use crate::engine::multires::FacePoint;
use crate::engine::texture::sample::{sample_image, MaterialSampler};

use super::params::SourceMask;

fn channel_index(c: Channel) -> usize {
    match c {
        Channel::R => 0,
        Channel::G => 1,
        Channel::B => 2,
        Channel::A => 3,
    }
}

fn err(path: &str, message: String) -> ConstraintsError {
    ConstraintsError::new(format!("params.mask{path}"), message)
}

/// The primitive, triangle and barycentric coordinates (in the triangle's vertex order) of a
/// point of `input`'s face, or None for a surface without origins.
pub fn triangle_point(
    asset: &Asset,
    input: &Surface,
    at: FacePoint,
) -> Option<(usize, usize, [f32; 3])> {
    let f = at.face as usize;
    let o = *input.origins.get(f)?;
    let (prim, tri) = (o.primitive as usize, o.triangle as usize);
    let triangle = asset.primitives[prim].triangles[tri];
    // The face's corner order may be flipped (mirrored instances).
    let mut bary = [0.0f32; 3];
    for (k, corner) in input.corners[f].iter().enumerate() {
        if let Some(j) = triangle.iter().position(|x| *x == corner.vertex) {
            bary[j] += at.bary[k];
        }
    }
    Some((prim, tri, bary))
}

/// Per sample: 1 when it trains, 0 when the mask removes it.
///
/// # Errors
/// A [`ConstraintsError`] naming `params.mask…` for a source without COLOR_0, an image index
/// out of range or undecodable, or a mask that removes every sample.
pub fn training_weights(
    mask: &SourceMask,
    asset: &Asset,
    input: &Surface,
    at: &[FacePoint],
) -> Result<Vec<f32>, ConstraintsError> {
    let values: Vec<f32> = match mask {
        SourceMask::VertexColor { channel, .. } => {
            if !asset.primitives.iter().any(|p| p.colors.is_some()) {
                return Err(err(
                    ".vertex_color",
                    "the source has no COLOR_0 attribute".into(),
                ));
            }
            let c = channel_index(*channel);
            at.iter()
                .map(|fp| {
                    let Some((prim, tri, b)) = triangle_point(asset, input, *fp) else {
                        return 0.0;
                    };
                    let p = &asset.primitives[prim];
                    let t = p.triangles[tri];
                    match &p.colors {
                        Some(colors) => (0..3)
                            .map(|k| b[k] * colors.get(t[k] as usize).map_or(0.0, |x| x[c]))
                            .sum(),
                        None => 0.0,
                    }
                })
                .collect()
        }
        SourceMask::Image { index, channel, .. } => {
            let decoded = asset
                .decoded_image(*index)
                .map_err(|e| err(".image.index", e))?;
            let sampler = MaterialSampler::new(asset);
            let c = channel_index(*channel);
            at.iter()
                .map(|fp| {
                    let Some((prim, tri, b)) = triangle_point(asset, input, *fp) else {
                        return 0.0;
                    };
                    match sampler.texture_uv(prim, tri, b) {
                        Some(uv) => sample_image(decoded, &Sampler::default(), uv)[c],
                        None => 0.0,
                    }
                })
                .collect()
        }
    };
    let threshold = match mask {
        SourceMask::VertexColor { threshold, .. } | SourceMask::Image { threshold, .. } => {
            *threshold
        }
    };
    let weights: Vec<f32> = values
        .iter()
        .map(|v| if *v > threshold { 0.0 } else { 1.0 })
        .collect();
    if weights.iter().all(|w| *w == 0.0) {
        return Err(err(
            "",
            "the mask removes the whole source: nothing is left to train on".into(),
        ));
    }
    Ok(weights)
}
