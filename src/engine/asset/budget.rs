//! The per-job memory budget of the inputs: what a job will hold once its models are loaded,
//! computed from the image headers and the accessor counts alone (nothing decoded), so that a
//! submission that would need too much memory is refused before it is accepted, and the job
//! refuses it again before it decodes anything.
//!
//! Two quantities are budgeted over every input the method reads (source, target, source base,
//! pattern), summed:
//! - decoded image bytes (`max_decoded_image_bytes`): width × height × max(4, bytes per pixel)
//!   of each image that will be decoded, i.e. each base-colour image that a triangle primitive of
//!   an instanced mesh samples ([`sampled_images`]; an image no drawn primitive samples is never
//!   decoded), plus the pattern;
//! - instanced geometry (`max_vertices`, `max_triangles`): the vertices and triangles of every
//!   mesh instance, which is what the welded surfaces hold (a mesh instanced 1,000 times costs
//!   1,000 times its triangles).

use rayon::prelude::*;

/// Bytes a job holds per instanced triangle of its inputs: the welded surface (faces, corners,
/// origins), its BVH and the per-face data of the methods. Measured: `project` of a 2,000,000-
/// triangle grid onto itself peaks 1.49 GB above the same job on 125,000 triangles (397 bytes
/// per added triangle, its half vertex included); rounded up.
pub const TRIANGLE_BYTES: u64 = 400;
/// Bytes a job holds per instanced vertex beyond [`TRIANGLE_BYTES`] (positions, normals,
/// colours and UVs of the loaded primitives, the welded positions).
pub const VERTEX_BYTES: u64 = 64;

use super::images::{self, ImageHeader};
use super::model::Asset;
use super::{IngestError, IngestLimits};

/// One image a job will decode: its index in its input and its decoded size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageDemand {
    /// Index in the input's images (0 for the pattern).
    pub image: usize,
    /// Header width.
    pub width: u32,
    /// Header height.
    pub height: u32,
    /// [`ImageHeader::decoded_bytes`].
    pub bytes: u64,
}

/// What one input will hold once loaded.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Demand {
    /// The images that will be decoded, in index order.
    pub images: Vec<ImageDemand>,
    /// Vertices over every mesh instance.
    pub vertices: u64,
    /// Triangles over every mesh instance.
    pub triangles: u64,
}

impl Demand {
    /// The demand of a model: its sampled images (and `extra` images, e.g. a mask the method
    /// reads) and its instanced geometry.
    pub fn of_asset(asset: &Asset, extra: &[usize]) -> Self {
        let mut wanted = sampled_images(asset);
        wanted.extend(extra.iter().filter(|&&i| readable(asset, i)));
        wanted.sort_unstable();
        wanted.dedup();
        let images = wanted
            .into_iter()
            .map(|i| {
                let img = &asset.images[i];
                ImageDemand {
                    image: i,
                    width: img.width,
                    height: img.height,
                    bytes: img.decoded_bytes,
                }
            })
            .collect();
        let (vertices, triangles) = instanced_counts(asset);
        Self {
            images,
            vertices,
            triangles,
        }
    }

    /// The demand of a pattern image.
    pub fn of_image(header: &ImageHeader) -> Self {
        Self {
            images: vec![ImageDemand {
                image: 0,
                width: header.width,
                height: header.height,
                bytes: header.decoded_bytes(),
            }],
            ..Self::default()
        }
    }

    /// Bytes of all its decoded images.
    pub fn image_bytes(&self) -> u64 {
        self.images.iter().map(|i| i.bytes).sum()
    }
}

fn readable(asset: &Asset, image: usize) -> bool {
    asset.images.get(image).is_some_and(|i| i.decoded_bytes > 0)
}

/// The images that some triangle primitive of an instanced mesh samples as its base colour (the
/// material's base-colour texture has an image retex reads, and the primitive has the UV set the
/// texture names): exactly the images the methods read, in index order.
pub fn sampled_images(asset: &Asset) -> Vec<usize> {
    let mut instanced = vec![false; asset.primitives.len()];
    let mut meshes: Vec<usize> = asset.instances.iter().map(|i| i.mesh).collect();
    meshes.sort_unstable();
    meshes.dedup();
    for (p, prim) in asset.primitives.iter().enumerate() {
        instanced[p] = meshes.binary_search(&prim.mesh).is_ok();
    }
    let mut out: Vec<usize> = asset
        .primitives
        .iter()
        .zip(&instanced)
        .filter(|(_, used)| **used)
        .filter_map(|(prim, _)| {
            let material = asset.materials.get(prim.material?)?;
            let tr = material.base_color_texture?;
            let image = asset.textures.get(tr.texture)?.image?;
            prim.tex_coords.get(tr.tex_coord as usize)?;
            readable(asset, image).then_some(image)
        })
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Vertices and triangles summed over every mesh instance.
pub fn instanced_counts(asset: &Asset) -> (u64, u64) {
    let meshes = asset
        .primitives
        .iter()
        .map(|p| p.mesh + 1)
        .max()
        .unwrap_or(0);
    let mut per_mesh = vec![(0u64, 0u64); meshes];
    for p in &asset.primitives {
        per_mesh[p.mesh].0 += p.positions.len() as u64;
        per_mesh[p.mesh].1 += p.triangles.len() as u64;
    }
    asset
        .instances
        .iter()
        .filter_map(|i| per_mesh.get(i.mesh))
        .fold((0, 0), |(v, t), (pv, pt)| {
            (v.saturating_add(*pv), t.saturating_add(*pt))
        })
}

/// Checks the inputs of one job, in the order given (`source`, `target`, `source_base`,
/// `pattern`), against the budgets of `limits`. The error names the input and, for images, the
/// image that brings the total over `max_decoded_image_bytes`.
///
/// # Errors
/// The input's name and [`IngestError::ImageBudget`] or [`IngestError::GeometryBudget`].
pub fn check_job(
    inputs: &[(&'static str, &Demand)],
    limits: &IngestLimits,
) -> Result<(), (&'static str, IngestError)> {
    let mut bytes = 0u64;
    for (side, demand) in inputs {
        for img in &demand.images {
            bytes = bytes.saturating_add(img.bytes);
            if bytes > limits.max_decoded_image_bytes {
                return Err((
                    side,
                    IngestError::ImageBudget {
                        image: img.image,
                        width: img.width,
                        height: img.height,
                        bytes: img.bytes,
                        total: bytes,
                        max: limits.max_decoded_image_bytes,
                    },
                ));
            }
        }
    }
    let (mut vertices, mut triangles) = (0u64, 0u64);
    for (side, demand) in inputs {
        vertices = vertices.saturating_add(demand.vertices);
        triangles = triangles.saturating_add(demand.triangles);
        let over = if vertices > limits.max_vertices {
            Some(("vertices", vertices, limits.max_vertices))
        } else if triangles > limits.max_triangles {
            Some(("triangles", triangles, limits.max_triangles))
        } else {
            None
        };
        if let Some((what, count, max)) = over {
            return Err((side, IngestError::GeometryBudget { what, count, max }));
        }
    }
    Ok(())
}

/// Decodes the images of `demand` into `asset` (in parallel), each straight into its one
/// buffer ([`images::decode_rgba8`]).
///
/// # Errors
/// [`IngestError::ImageDecode`] for the first image (by index) that cannot be decoded.
pub fn decode_images(
    asset: &mut Asset,
    demand: &Demand,
    limits: &IngestLimits,
) -> Result<(), IngestError> {
    let decoded = demand
        .images
        .par_iter()
        .map(|d| {
            let img = &asset.images[d.image];
            let format = images::sniff(&img.bytes)
                .ok_or(IngestError::UnrecognizedImage { image: d.image })?;
            images::decode_rgba8(d.image, &img.bytes, format, limits)
        })
        .collect::<Result<Vec<_>, _>>()?;
    for (d, pixels) in demand.images.iter().zip(decoded) {
        asset.images[d.image].decoded = Some(std::sync::Arc::new(pixels));
    }
    Ok(())
}
