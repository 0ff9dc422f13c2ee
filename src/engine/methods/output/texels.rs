//! The UV path of [`super::write_field`]: the asset's triangles grouped by material, each
//! group's UV layout rasterized and the field evaluated at every covered texel, then padding and
//! encoding into a texture edit.

use rayon::prelude::*;

use super::{
    normal_of, to_f32, FieldOutput, SurfaceField, SurfaceSample, TexelEncoding, TextureReport,
};
use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::{Edit, EncodedImage, TextureWrap};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};
use crate::engine::texture::bake::rasterize_uv_layout;
use crate::engine::texture::encode::encode_png_srgb;
use crate::engine::texture::pad::pad;

/// A triangle placed in the world, with its UVs.
#[derive(Clone)]
pub(super) struct PlacedTriangle {
    pub(super) primitive: usize,
    /// Index into the primitive's triangles.
    pub(super) triangle: usize,
    pub(super) world: [[f32; 3]; 3],
    pub(super) normal: [f32; 3],
    pub(super) uv: [[f32; 2]; 3],
}

/// Triangles grouped for output.
pub(super) struct Layout {
    /// UV path: triangles per material.
    pub(super) groups: std::collections::BTreeMap<Option<usize>, Vec<PlacedTriangle>>,
    /// Vertex path: (primitive, first instance).
    pub(super) vertex_path: Vec<(usize, usize)>,
    /// Atlas path: the replaced primitives' triangles, baked into one texture of a new
    /// material through TEXCOORD_0 ([`super::atlas`]).
    pub(super) atlas: Vec<PlacedTriangle>,
}

/// The base-color UV set of primitive `p` (0 without a texture).
pub(crate) fn uv_set_of(asset: &Asset, p: usize) -> u32 {
    asset.primitives[p]
        .material
        .and_then(|m| asset.materials.get(m))
        .and_then(|m| m.base_color_texture)
        .map_or(0, |t| t.tex_coord)
}

/// Groups triangles by material (UV path) or collects primitives for the vertex path.
pub(super) fn layout(
    asset: &Asset,
    constraints: &Constraints,
    warnings: &mut Vec<String>,
) -> Layout {
    let mut out = Layout {
        groups: Default::default(),
        vertex_path: Vec::new(),
        atlas: Vec::new(),
    };
    for (ii, inst) in asset.instances.iter().enumerate() {
        for p in asset.primitives_of_mesh(inst.mesh) {
            let prim = &asset.primitives[p];
            let set = uv_set_of(asset, p) as usize;
            if constraints.output.all_vertex_colors() || prim.tex_coords.len() <= set {
                if !out.vertex_path.iter().any(|(q, _)| *q == p) {
                    out.vertex_path.push((p, ii));
                } else {
                    warnings.push(format!(
                        "mesh {} is instanced more than once; its vertex colors follow its first instance",
                        prim.mesh
                    ));
                }
                continue;
            }
            let mirrored = inst.mirrors();
            let group = out.groups.entry(prim.material).or_default();
            for (ti, t) in prim.triangles.iter().enumerate() {
                let w = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
                let mut normal = normal_of(w[0], w[1], w[2]);
                if mirrored {
                    normal = normal.map(|x| -x);
                }
                group.push(PlacedTriangle {
                    primitive: p,
                    triangle: ti,
                    world: w,
                    normal,
                    uv: t.map(|v| prim.tex_coords[set][v as usize]),
                });
            }
        }
    }
    warnings.dedup();
    out
}

/// Texels of one group after evaluation, before padding.
pub(super) struct Baked<'a> {
    material: Option<usize>,
    /// The atlas group (new material, TEXCOORD_0).
    atlas: bool,
    tris: &'a [PlacedTriangle],
    pixels: Vec<[f32; 4]>,
    valid: Vec<bool>,
    report: TextureReport,
}

/// Rasterizes every group's UV layout and evaluates the field at its covered texels.
pub(super) fn bake_groups<'a>(
    asset: &Asset,
    layout: &'a Layout,
    size: u32,
    field: &dyn SurfaceField,
    control: &Control,
) -> Result<Vec<Baked<'a>>, Cancelled> {
    let groups: Vec<(Option<usize>, bool, &[PlacedTriangle])> = layout
        .groups
        .iter()
        .map(|(m, t)| (*m, false, t.as_slice()))
        .chain((!layout.atlas.is_empty()).then_some((None, true, layout.atlas.as_slice())))
        .collect();
    let total_texels = groups.len() as u64 * size as u64 * size as u64;
    let stage = control.stage("bake", total_texels)?;
    let mut baked = Vec::new();
    for (material, atlas, tris) in groups {
        let uvs: Vec<[[f32; 2]; 3]> = tris.iter().map(|t| t.uv).collect();
        let map = rasterize_uv_layout(&uvs, size, size);
        control.check()?;
        let mut pixels = vec![[0.0f32; 4]; (size * size) as usize];
        let mut valid = vec![false; pixels.len()];
        let row = size as usize;
        pixels
            .par_chunks_mut(row * 16)
            .zip(valid.par_chunks_mut(row * 16))
            .enumerate()
            .try_for_each(|(chunk, (px, ok))| {
                // Chunks that start after cancellation do no work.
                control.check()?;
                let base = chunk * row * 16;
                let mut hint = None;
                for i in 0..px.len() {
                    if let Some(hit) = map.hits[base + i] {
                        let t = &tris[hit.triangle as usize];
                        let b = hit.bary;
                        let mut p = [0.0f32; 3];
                        for (k, pk) in p.iter_mut().enumerate() {
                            *pk =
                                b[0] * t.world[0][k] + b[1] * t.world[1][k] + b[2] * t.world[2][k];
                        }
                        let at = SurfaceSample {
                            primitive: t.primitive,
                            triangle: t.triangle,
                            barycentric: b,
                            position: p,
                            normal: t.normal,
                        };
                        let mut value = [0.0f32; 4];
                        if let Some(h) = field.sample(&at, hint, &mut value) {
                            px[i] = value;
                            ok[i] = true;
                            hint = Some(h);
                        }
                    }
                }
                stage.tick(px.len() as u64)
            })?;
        let covered = map.covered();
        let unmatched = covered - valid.iter().filter(|v| **v).count() as u64;
        baked.push(Baked {
            material,
            atlas,
            tris,
            pixels,
            valid,
            report: TextureReport {
                material,
                size,
                tex_coord: match atlas {
                    true => 0,
                    false => tris.first().map_or(0, |t| uv_set_of(asset, t.primitive)),
                },
                triangles: tris.len(),
                covered,
                overlapped: map.overlapped,
                unmatched,
                padded: 0,
                filled: 0,
            },
        });
    }
    Ok(baked)
}

/// Encodes padded texels as `encoding` says.
fn encode(name: String, pixels: &[[f32; 4]], size: u32, encoding: TexelEncoding) -> EncodedImage {
    match encoding {
        TexelEncoding::Srgb8 => EncodedImage::srgb8_png(name, encode_png_srgb(pixels, size, size)),
        TexelEncoding::Linear8 { channels } => {
            let c = channels.clamp(1, 4) as usize;
            let flat: Vec<f32> = pixels.iter().flat_map(|p| p[..c].to_vec()).collect();
            EncodedImage::linear8(name, size, size, c as u8, &flat)
        }
        TexelEncoding::Gray16 => {
            let flat: Vec<f32> = pixels.iter().map(|p| p[0]).collect();
            EncodedImage::gray16(name, size, size, &flat)
        }
    }
}

/// Pads and encodes the baked groups (in parallel, order kept).
pub(super) fn finish_textures(
    baked: Vec<Baked<'_>>,
    size: u32,
    padding: u32,
    output: &FieldOutput,
    control: &Control,
) -> Result<Vec<(Edit, TextureReport)>, Cancelled> {
    let pad_stage = control.stage("pad", baked.len() as u64)?;
    baked
        .into_par_iter()
        .map(|mut b| {
            control.check()?;
            let pr = pad(&mut b.pixels, &b.valid, size, size, padding);
            b.report.padded = pr.padded;
            b.report.filled = pr.filled;
            let mut prims: Vec<usize> = b.tris.iter().map(|t| t.primitive).collect();
            prims.sort_unstable();
            prims.dedup();
            let name = match b.material {
                _ if b.atlas => format!("{}_atlas", output.name),
                Some(m) => format!("{}_material{m}", output.name),
                None => format!("{}_default", output.name),
            };
            let image = encode(name, &b.pixels, size, output.encoding);
            pad_stage.tick(1)?;
            Ok((
                Edit::SetTexture {
                    material: b.material,
                    slot: output.slot,
                    image,
                    tex_coord: b.report.tex_coord,
                    wrap: TextureWrap::Repeat,
                    primitives: prims,
                },
                b.report,
            ))
        })
        .collect()
}
