//! The UV path of [`super::write_field`] and [`super::write_fields`]: the asset's triangles
//! grouped by material, each group's UV layout rasterized once and the fields evaluated once at
//! every covered texel into one image per output, then each image padded and encoded into a
//! texture edit.

use rayon::prelude::*;

use super::{
    normal_of, to_f32, FieldOutput, SurfaceFields, SurfaceSample, TexelEncoding, TextureReport,
};
use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::{Edit, EncodedImage, TextureWrap};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control, StageProgress};
use crate::engine::texture::bake::{rasterize_uv_layout, TexelMap};
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

/// One output's texels of one group after evaluation, before padding.
struct Image {
    pixels: Vec<[f32; 4]>,
    /// Texels the output has a value at.
    valid: Vec<bool>,
    report: TextureReport,
}

/// Texels of one group after evaluation, before padding: one image per output.
pub(super) struct Baked<'a> {
    material: Option<usize>,
    /// The atlas group (new material, TEXCOORD_0).
    atlas: bool,
    tris: &'a [PlacedTriangle],
    images: Vec<Image>,
}

/// Rasterizes every group's UV layout once and evaluates `fields` at its covered texels, into
/// `outputs` images per group.
pub(super) fn bake_groups<'a>(
    asset: &Asset,
    layout: &'a Layout,
    size: u32,
    fields: &dyn SurfaceFields,
    outputs: usize,
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
        let texels = bake_texels(&map, tris, size, fields, outputs, &stage, control)?;
        let covered = map.covered();
        let tex_coord = match atlas {
            true => 0,
            false => tris.first().map_or(0, |t| uv_set_of(asset, t.primitive)),
        };
        let images = texels
            .into_iter()
            .map(|(pixels, valid)| Image {
                report: TextureReport {
                    material,
                    size,
                    tex_coord,
                    triangles: tris.len(),
                    covered,
                    overlapped: map.overlapped,
                    unmatched: covered - valid.iter().filter(|v| **v).count() as u64,
                    padded: 0,
                    filled: 0,
                },
                pixels,
                valid,
            })
            .collect();
        baked.push(Baked {
            material,
            atlas,
            tris,
            images,
        });
    }
    Ok(baked)
}

/// One output's texels of one group and which of them have a value.
type Texels = (Vec<[f32; 4]>, Vec<bool>);

/// The texel loop of one group: every covered texel sampled once, its values written into
/// each output's texels (parallel over chunks of 16 rows, each chunk carrying the hint from
/// texel to texel). Per output: texels and which have a value.
fn bake_texels(
    map: &TexelMap,
    tris: &[PlacedTriangle],
    size: u32,
    fields: &dyn SurfaceFields,
    outputs: usize,
    stage: &StageProgress<'_>,
    control: &Control,
) -> Result<Vec<Texels>, Cancelled> {
    let len = (size * size) as usize;
    let rows16 = size as usize * 16;
    let mut images: Vec<Texels> = (0..outputs)
        .map(|_| (vec![[0.0f32; 4]; len], vec![false; len]))
        .collect();
    // Per chunk of 16 rows, every output's part of it.
    type Part<'p> = (&'p mut [[f32; 4]], &'p mut [bool]);
    let mut chunks: Vec<Vec<Part<'_>>> = (0..len.div_ceil(rows16.max(1)))
        .map(|_| Vec::with_capacity(outputs))
        .collect();
    for (pixels, valid) in &mut images {
        let parts = pixels.chunks_mut(rows16).zip(valid.chunks_mut(rows16));
        for (chunk, part) in chunks.iter_mut().zip(parts) {
            chunk.push(part);
        }
    }
    chunks
        .into_par_iter()
        .enumerate()
        .try_for_each(|(chunk, mut parts)| {
            // Chunks that start after cancellation do no work.
            control.check()?;
            let base = chunk * rows16;
            let count = rows16.min(len - base);
            let mut hint = None;
            let mut values = vec![None; outputs];
            for i in 0..count {
                let Some(hit) = map.hits[base + i] else {
                    continue;
                };
                let t = &tris[hit.triangle as usize];
                let b = hit.bary;
                let mut p = [0.0f32; 3];
                for (k, pk) in p.iter_mut().enumerate() {
                    *pk = b[0] * t.world[0][k] + b[1] * t.world[1][k] + b[2] * t.world[2][k];
                }
                let at = SurfaceSample {
                    primitive: t.primitive,
                    triangle: t.triangle,
                    barycentric: b,
                    position: p,
                    normal: t.normal,
                };
                values.fill(None);
                if let Some(h) = fields.sample(&at, hint, &mut values) {
                    hint = Some(h);
                }
                for ((px, ok), value) in parts.iter_mut().zip(&values) {
                    if let Some(v) = value {
                        px[i] = *v;
                        ok[i] = true;
                    }
                }
            }
            stage.tick(count as u64)
        })?;
    Ok(images)
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

/// Pads and encodes the baked groups' images (in parallel, order kept): per output, its
/// texture edits and reports in group order.
pub(super) fn finish_textures(
    baked: Vec<Baked<'_>>,
    size: u32,
    padding: u32,
    outputs: &[FieldOutput],
    control: &Control,
) -> Result<Vec<Vec<(Edit, TextureReport)>>, Cancelled> {
    let pad_stage = control.stage("pad", (baked.len() * outputs.len()) as u64)?;
    let mut work = Vec::new();
    for b in baked {
        let mut prims: Vec<usize> = b.tris.iter().map(|t| t.primitive).collect();
        prims.sort_unstable();
        prims.dedup();
        for (k, image) in b.images.into_iter().enumerate() {
            work.push((k, b.material, b.atlas, prims.clone(), image));
        }
    }
    let done: Vec<(usize, Edit, TextureReport)> = work
        .into_par_iter()
        .map(|(k, material, atlas, prims, mut image)| {
            control.check()?;
            let output = &outputs[k];
            let pr = pad(&mut image.pixels, &image.valid, size, size, padding);
            image.report.padded = pr.padded;
            image.report.filled = pr.filled;
            let name = match material {
                _ if atlas => format!("{}_atlas", output.name),
                Some(m) => format!("{}_material{m}", output.name),
                None => format!("{}_default", output.name),
            };
            let encoded = encode(name, &image.pixels, size, output.encoding);
            pad_stage.tick(1)?;
            let edit = Edit::SetTexture {
                material,
                slot: output.slot,
                image: encoded,
                tex_coord: image.report.tex_coord,
                wrap: TextureWrap::Repeat,
                primitives: prims,
            };
            Ok((k, edit, image.report))
        })
        .collect::<Result<_, Cancelled>>()?;
    let mut per_output: Vec<Vec<(Edit, TextureReport)>> =
        outputs.iter().map(|_| Vec::new()).collect();
    for (k, edit, report) in done {
        per_output[k].push((edit, report));
    }
    Ok(per_output)
}
