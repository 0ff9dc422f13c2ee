//! Writing a color field into the target: the output half shared by every method that produces
//! a color per target surface point.
//!
//! A method supplies a [`ColorField`] (linear RGBA at a world-space point of the target) and
//! [`write_color_field`] does the rest:
//!
//! * target primitives whose material's base-color UV set exists are grouped by material; each
//!   group's UV layout is rasterized ([`rasterize_uv_layout`]), the field is evaluated at every
//!   covered texel (parallel over chunks of 16 texel rows, each chunk carrying the field's hint
//!   from texel to texel), uncovered and unmatched texels are filled ([`pad`]) and the texture is
//!   encoded as an sRGB PNG ([`encode_png_srgb`]);
//! * primitives without such UVs (or all of them, when `output.vertex_colors` is set) receive
//!   COLOR_0: on a refined copy with about `vertex_color_samples` vertices in all (on their own
//!   vertices when vertex colors were requested or the primitive is skinned or morphed); vertices
//!   where the field has no value take their neighbours' mean ([`fill_from_neighbours`]).
//!
//! The output depends only on the field's values, never on the thread count: texels and
//! vertices are independent and results are collected in order.

use rayon::prelude::*;
use serde::Serialize;

use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::{
    AttributeData, Edit, EncodedImage, PrimitiveGeometry, TextureSlot, TextureWrap,
};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};
use crate::engine::multires::{edge_length_for_vertex_count, refine, RefineParams};
use crate::engine::texture::bake::rasterize_uv_layout;
use crate::engine::texture::encode::encode_png_srgb;
use crate::engine::texture::pad::pad;

/// A color field over the target's world-space surface.
pub trait ColorField: Sync {
    /// Linear RGBA at world point `p` of the target, whose (unit) face normal is `normal`;
    /// `hint` is the value returned by the previous call for a nearby point (same texel row), or None.
    /// Returns the color and a new hint, or None where the field has no value (counted unmatched, filled by padding).
    fn color_at(&self, p: [f32; 3], normal: [f32; 3], hint: Option<u32>)
        -> Option<([f32; 4], u32)>;
}

/// Figures of one baked texture.
#[derive(Clone, Debug, Serialize)]
pub struct TextureReport {
    /// Target material (`None`: a new material for primitives without one).
    pub material: Option<usize>,
    /// Texture width = height.
    pub size: u32,
    /// UV set baked into.
    pub tex_coord: u32,
    /// Triangles rasterized.
    pub triangles: usize,
    /// Texels inside some triangle.
    pub covered: u64,
    /// Covered texels claimed by more than one triangle (resolved to the lowest index).
    pub overlapped: u64,
    /// Covered texels with no valid source point (distance or normal gating); padded instead.
    pub unmatched: u64,
    /// Texels filled by dilation padding.
    pub padded: u64,
    /// Remaining texels filled by pull-push.
    pub filled: u64,
}

/// Figures of one primitive that received COLOR_0.
#[derive(Clone, Debug, Serialize)]
pub struct VertexColorReport {
    /// glTF mesh index.
    pub mesh: usize,
    /// Primitive index within the mesh.
    pub primitive: usize,
    /// Whether a refined copy replaced the primitive.
    pub refined: bool,
    /// Vertices written.
    pub vertices: usize,
    /// Vertices with no valid source point (filled from neighbours).
    pub unmatched: usize,
}

/// What was written.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ColorOutputReport {
    /// One entry per baked texture.
    pub textures: Vec<TextureReport>,
    /// One entry per primitive that received COLOR_0.
    pub vertex_colors: Vec<VertexColorReport>,
    /// Things the user should know (lowercase sentences).
    pub warnings: Vec<String>,
}

pub(super) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(u: [f32; 3], v: [f32; 3]) -> [f32; 3] {
    [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ]
}

fn normal_of(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> [f32; 3] {
    let n = cross(sub(b, a), sub(c, a));
    let l = dot(n, n).sqrt();
    if l > 0.0 {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    }
}

pub(super) fn to_f32(p: [f64; 3]) -> [f32; 3] {
    [p[0] as f32, p[1] as f32, p[2] as f32]
}

/// A target triangle placed in the world, with its UVs.
struct PlacedTriangle {
    primitive: usize,
    world: [[f32; 3]; 3],
    normal: [f32; 3],
    uv: [[f32; 2]; 3],
}

/// Target triangles grouped for output.
struct Layout {
    /// UV path: triangles per target material.
    groups: std::collections::BTreeMap<Option<usize>, Vec<PlacedTriangle>>,
    /// COLOR_0 path: (primitive, first instance).
    vertex_path: Vec<(usize, usize)>,
}

/// The base-color UV set of target primitive `p` (0 without a texture).
fn uv_set_of(target: &Asset, p: usize) -> u32 {
    target.primitives[p]
        .material
        .and_then(|m| target.materials.get(m))
        .and_then(|m| m.base_color_texture)
        .map_or(0, |t| t.tex_coord)
}

/// Groups target triangles by material (UV path) or collects primitives for COLOR_0.
fn layout(target: &Asset, constraints: &Constraints, warnings: &mut Vec<String>) -> Layout {
    let mut out = Layout {
        groups: Default::default(),
        vertex_path: Vec::new(),
    };
    for (ii, inst) in target.instances.iter().enumerate() {
        for p in target.primitives_of_mesh(inst.mesh) {
            let prim = &target.primitives[p];
            let set = uv_set_of(target, p) as usize;
            if constraints.output.vertex_colors || prim.tex_coords.len() <= set {
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
            for t in &prim.triangles {
                let w = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
                let mut normal = normal_of(w[0], w[1], w[2]);
                if mirrored {
                    normal = normal.map(|x| -x);
                }
                group.push(PlacedTriangle {
                    primitive: p,
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
struct Baked<'a> {
    material: Option<usize>,
    tris: &'a [PlacedTriangle],
    pixels: Vec<[f32; 4]>,
    valid: Vec<bool>,
    report: TextureReport,
}

/// Rasterizes every group's UV layout and evaluates the field at its covered texels.
fn bake_groups<'a>(
    target: &Asset,
    layout: &'a Layout,
    size: u32,
    field: &dyn ColorField,
    control: &Control,
) -> Result<Vec<Baked<'a>>, Cancelled> {
    let total_texels = layout.groups.len() as u64 * size as u64 * size as u64;
    let stage = control.stage("bake", total_texels)?;
    let mut baked = Vec::new();
    for (material, tris) in &layout.groups {
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
                        if let Some((c, face)) = field.color_at(p, t.normal, hint) {
                            px[i] = c;
                            ok[i] = true;
                            hint = Some(face);
                        }
                    }
                }
                stage.tick(px.len() as u64)
            })?;
        let covered = map.covered();
        let unmatched = covered - valid.iter().filter(|v| **v).count() as u64;
        baked.push(Baked {
            material: *material,
            tris,
            pixels,
            valid,
            report: TextureReport {
                material: *material,
                size,
                tex_coord: tris.first().map_or(0, |t| uv_set_of(target, t.primitive)),
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

/// Pads and encodes the baked groups (in parallel, order kept).
fn finish_textures(
    baked: Vec<Baked<'_>>,
    size: u32,
    padding: u32,
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
                Some(m) => format!("retex_basecolor_material{m}"),
                None => "retex_basecolor_default".to_string(),
            };
            let png = encode_png_srgb(&b.pixels, size, size);
            pad_stage.tick(1)?;
            Ok((
                Edit::SetTexture {
                    material: b.material,
                    slot: TextureSlot::BaseColor,
                    image: EncodedImage::srgb8_png(name, png),
                    tex_coord: b.report.tex_coord,
                    wrap: TextureWrap::Repeat,
                    primitives: prims,
                },
                b.report,
            ))
        })
        .collect()
}

/// Writes `field` into `target`: baked base-color textures for primitives with UVs, COLOR_0 (on a refined copy, `vertex_color_samples` vertices in all) for those without. Control stages "bake" and "pad" as today.
pub fn write_color_field(
    target: &Asset,
    constraints: &Constraints,
    vertex_color_samples: usize,
    field: &dyn ColorField,
    control: &Control,
) -> Result<(Vec<Edit>, ColorOutputReport), Cancelled> {
    let mut report = ColorOutputReport::default();
    let layout = layout(target, constraints, &mut report.warnings);
    let size = constraints.output.texture_size;
    let span = control.span(0.0, 0.75);
    let baked = bake_groups(target, &layout, size, field, control)?;
    drop(span);

    let span = control.span(0.75, 0.9);
    let finished = finish_textures(baked, size, constraints.output.padding, control)?;
    let mut edits = Vec::new();
    for (texture, tr) in finished {
        edits.push(texture);
        report.textures.push(tr);
    }
    drop(span);

    let _span = control.span(0.9, 1.0);
    let vertex_edits = write_vertex_colors(
        target,
        constraints,
        &layout,
        vertex_color_samples,
        field,
        control,
        &mut report,
    )?;
    edits.extend(vertex_edits.into_edits());
    Ok((edits, report))
}

/// The COLOR_0 path: evaluates the field at the (refined) vertices of every collected primitive.
#[allow(clippy::too_many_arguments)]
fn write_vertex_colors(
    target: &Asset,
    constraints: &Constraints,
    layout: &Layout,
    vertex_color_samples: usize,
    field: &dyn ColorField,
    control: &Control,
    report: &mut ColorOutputReport,
) -> Result<VertexEdits, Cancelled> {
    let mut edits = VertexEdits::default();
    let vertex_path = &layout.vertex_path;
    if vertex_path.is_empty() {
        return Ok(edits);
    }
    let stage = control.stage("vertex_colors", vertex_path.len() as u64)?;
    let area: f64 = vertex_path
        .iter()
        .map(|&(p, ii)| primitive_world_area(target, p, ii))
        .sum();
    let max_edge = edge_length_for_vertex_count(area, vertex_color_samples);
    for &(p, ii) in vertex_path {
        let prim = &target.primitives[p];
        let inst = &target.instances[ii];
        let prim_json = &target.json["meshes"][prim.mesh]["primitives"][prim.primitive];
        let skinned_or_morphed =
            prim_json.get("targets").is_some() || prim_json["attributes"].get("JOINTS_0").is_some();
        let refine_it = !constraints.output.vertex_colors && !skinned_or_morphed;
        if !constraints.output.vertex_colors && skinned_or_morphed {
            report.warnings.push(format!(
                "mesh {} primitive {} has skin or morph data; COLOR_0 was written on its own vertices instead of a refined copy",
                prim.mesh, prim.primitive
            ));
        }
        let (positions, triangles, normals) = if refine_it {
            let scale = instance_scale(&inst.world);
            let r = refine(
                &prim.positions,
                &prim.triangles,
                &RefineParams {
                    max_edge_length: max_edge / scale,
                    ..Default::default()
                },
            );
            let normals = prim.normals.as_ref().map(|n| {
                r.interpolate(n)
                    .into_iter()
                    .map(|v| {
                        let l = dot(v, v).sqrt();
                        if l > 0.0 {
                            [v[0] / l, v[1] / l, v[2] / l]
                        } else {
                            [0.0, 0.0, 1.0]
                        }
                    })
                    .collect()
            });
            (r.positions, r.triangles, normals)
        } else {
            (prim.positions.clone(), prim.triangles.clone(), None)
        };
        control.check()?;
        let world: Vec<[f32; 3]> = positions
            .iter()
            .map(|q| to_f32(inst.transform_point(*q)))
            .collect();
        let mut vnormals = vec![[0.0f32; 3]; world.len()];
        for t in &triangles {
            let n = normal_of(
                world[t[0] as usize],
                world[t[1] as usize],
                world[t[2] as usize],
            );
            let n = if inst.mirrors() { n.map(|x| -x) } else { n };
            for &v in t {
                for k in 0..3 {
                    vnormals[v as usize][k] += n[k];
                }
            }
        }
        // Chunks of vertices, each checking for cancellation before its work.
        let found: Vec<Vec<Option<[f32; 4]>>> = world
            .par_chunks(4096)
            .zip(vnormals.par_chunks(4096))
            .map(|(qs, ns)| {
                control.check()?;
                Ok(qs
                    .iter()
                    .zip(ns)
                    .map(|(q, n)| {
                        let l = dot(*n, *n).sqrt().max(1e-20);
                        field.color_at(*q, n.map(|x| x / l), None).map(|(c, _)| c)
                    })
                    .collect())
            })
            .collect::<Result<_, Cancelled>>()?;
        let found: Vec<Option<[f32; 4]>> = found.into_iter().flatten().collect();
        let unmatched = found.iter().filter(|c| c.is_none()).count();
        let colors = fill_from_neighbours(found, &triangles);
        report.vertex_colors.push(VertexColorReport {
            mesh: prim.mesh,
            primitive: prim.primitive,
            refined: refine_it,
            vertices: positions.len(),
            unmatched,
        });
        if refine_it {
            edits.refined.push(Edit::ReplacePrimitive {
                primitive: p,
                geometry: PrimitiveGeometry {
                    positions,
                    normals,
                    colors: Some(colors),
                    triangles,
                    ..Default::default()
                },
            });
        } else {
            edits.vertex_colors.push(Edit::SetAttribute {
                primitive: p,
                name: "COLOR_0".into(),
                data: AttributeData::Vec4(colors),
            });
        }
        if let Some(m) = prim.material {
            if !layout.groups.contains_key(&Some(m)) && !edits.untextured_materials.contains(&m) {
                edits.untextured_materials.push(m);
            }
        }
        stage.tick(1)?;
    }
    edits.untextured_materials.sort_unstable();
    if !vertex_path.is_empty() && !constraints.output.vertex_colors {
        report.warnings.push(format!(
            "{} primitive(s) have no UVs for a base color texture: the color was written as COLOR_0 on a refined copy",
            vertex_path.len()
        ));
    }
    Ok(edits)
}

/// The COLOR_0 path's edits, kept by kind so they are exported in a fixed order: materials
/// that lose their base-colour texture, COLOR_0 on original vertices, refined copies.
#[derive(Default)]
struct VertexEdits {
    untextured_materials: Vec<usize>,
    vertex_colors: Vec<Edit>,
    refined: Vec<Edit>,
}

impl VertexEdits {
    fn into_edits(self) -> impl Iterator<Item = Edit> {
        self.untextured_materials
            .into_iter()
            .map(|material| Edit::ClearTexture {
                material,
                slot: TextureSlot::BaseColor,
            })
            .chain(self.vertex_colors)
            .chain(self.refined)
    }
}

/// Cube root of |det| of the upper 3x3: the mean linear scale of an instance transform.
fn instance_scale(m: &[[f64; 4]; 4]) -> f32 {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[2][1] * m[1][2])
        - m[1][0] * (m[0][1] * m[2][2] - m[2][1] * m[0][2])
        + m[2][0] * (m[0][1] * m[1][2] - m[1][1] * m[0][2]);
    let s = det.abs().cbrt() as f32;
    if s > 0.0 && s.is_finite() {
        s
    } else {
        1.0
    }
}

/// Surface area of primitive `p` placed by instance `instance`, world units.
fn primitive_world_area(asset: &Asset, p: usize, instance: usize) -> f64 {
    let prim = &asset.primitives[p];
    let inst = &asset.instances[instance];
    prim.triangles
        .iter()
        .map(|t| {
            let w = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
            let n = cross(sub(w[1], w[0]), sub(w[2], w[0]));
            0.5 * (dot(n, n) as f64).sqrt()
        })
        .sum()
}

/// Vertices without a color take the mean of their colored neighbours, repeatedly; any left
/// (an island with no valid source point at all) take the mean of all colored vertices, or grey.
fn fill_from_neighbours(
    mut colors: Vec<Option<[f32; 4]>>,
    triangles: &[[u32; 3]],
) -> Vec<[f32; 4]> {
    for _ in 0..64 {
        if colors.iter().all(Option::is_some) {
            break;
        }
        let mut sum = vec![([0.0f32; 4], 0u32); colors.len()];
        for t in triangles {
            for a in 0..3 {
                for b in 0..3 {
                    let (va, vb) = (t[a] as usize, t[b] as usize);
                    if a != b && colors[va].is_none() {
                        if let Some(c) = colors[vb] {
                            for k in 0..4 {
                                sum[va].0[k] += c[k];
                            }
                            sum[va].1 += 1;
                        }
                    }
                }
            }
        }
        let mut changed = false;
        for (c, (s, n)) in colors.iter_mut().zip(sum) {
            if c.is_none() && n > 0 {
                *c = Some(s.map(|x| x / n as f32));
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let known: Vec<[f32; 4]> = colors.iter().flatten().copied().collect();
    let mean = if known.is_empty() {
        [0.5, 0.5, 0.5, 1.0]
    } else {
        let mut m = [0.0f32; 4];
        for c in &known {
            for k in 0..4 {
                m[k] += c[k] / known.len() as f32;
            }
        }
        m
    };
    colors.into_iter().map(|c| c.unwrap_or(mean)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unmatched_vertices_take_their_neighbours_mean() {
        let tris = [[0, 1, 2], [1, 2, 3]];
        let red = [1.0, 0.0, 0.0, 1.0];
        let blue = [0.0, 0.0, 1.0, 1.0];
        let out = fill_from_neighbours(vec![Some(red), Some(blue), None, None], &tris);
        // Vertex 2 sees red once and blue twice (edge 1-2 is in both triangles).
        let want = [1.0 / 3.0, 0.0, 2.0 / 3.0, 1.0];
        assert!(
            (0..4).all(|k| (out[2][k] - want[k]).abs() < 1e-6),
            "{:?}",
            out[2]
        );
        // Vertex 3 sees only blue: vertex 2 was still unknown in that pass.
        assert_eq!(out[3], blue);
        let grey = fill_from_neighbours(vec![None, None, None], &[[0, 1, 2]]);
        assert!(grey.iter().all(|c| *c == [0.5, 0.5, 0.5, 1.0]));
    }

    #[test]
    fn instance_scale_is_the_cube_root_of_the_determinant() {
        let mut m = [[0.0f64; 4]; 4];
        m[0][0] = 2.0;
        m[1][1] = -2.0;
        m[2][2] = 2.0;
        m[3][3] = 1.0;
        assert!((instance_scale(&m) - 2.0).abs() < 1e-6);
        assert_eq!(instance_scale(&[[0.0; 4]; 4]), 1.0);
    }
}
