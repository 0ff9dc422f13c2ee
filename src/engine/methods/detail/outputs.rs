//! The outputs of `detail` (issue 13, "Interface"; Berkiten et al. 2017 §3.3 end: the result is
//! a displacement over the target): the synthesised displacement of the finest target level
//! written into the target asset.
//!
//! - **Primitives with UVs** (the material's base-colour UV set): a 16-bit grayscale displacement
//!   texture in `materials[i].extras.retex_displacement = {index, texCoord, scale, offset}`
//!   (`d = offset + scale · value`, world units along the base normal), and a tangent-space
//!   normal map (`normalTexture`, linear 8-bit) with the TANGENT attribute it was baked in
//!   (MikkTSpace, [`crate::engine::methods::tangents`], in the same UV set) and NORMAL (kept when
//!   present, else the area-weighted vertex normals written). Each texel's target point is
//!   located on the finest level (closest point, BVH); the displacement is interpolated there.
//!   The normal map holds only the detail: the texel's own shading normal `N` tilted by the
//!   displacement's surface gradient, `n = normalize(N − ∇d)` (first order in `d`; the gradient
//!   per finest vertex is the area-weighted mean of its faces' constant gradients, interpolated),
//!   expressed in the texel's frame: with `T`, `B = w · N × T`, `N` interpolated from the
//!   vertices (world space, as a viewer builds them), the stored `c` is `[T B N]⁻¹ n`
//!   normalised, so that a viewer's `normalize(c_x T + c_y B + c_z N)` gives back `n`. Baking
//!   the displaced finest level's own normals instead (what a high-to-low baker does) was tried
//!   first: it also baked the gap between the remeshed level and the target (ears, nostrils and
//!   lips of a head showed up as detail).
//! - **Primitives without UVs** (not skinned or morphed), with `output.uv = "auto"` (the
//!   default; issue 15): one atlas is generated for all of them
//!   ([`crate::engine::methods::output::build_atlas`]), and both maps are baked through it, so
//!   they share one layout. Each primitive is replaced by its atlas copy (vertices split where
//!   charts meet, TEXCOORD_0), with NORMAL (the input's, or area-weighted, copied to the split
//!   vertices) and MikkTSpace TANGENT in the new UVs; the maps go into a new material, a copy of
//!   the primitive's own without its texture references.
//! - **Primitives without UVs** with `output.uv = "keep"`, or when no atlas could be made:
//!   replaced by their part of the displaced finest level (each finest face goes to the
//!   primitive of the input face closest to its centroid), in the primitive's local space
//!   (inverse of its first instance's transform), with vertex normals. So for such a target the
//!   output is the displaced refined mesh.
//! - Always the result file `displaced.glb`: the finest level displaced, as one mesh.
//!
//! **One bake for both maps** (issue 13, "refinement cost"). The two maps are two outputs of one
//! field (`maps::MapFields`) baked in one texel loop by the shared writer's
//! [`crate::engine::methods::output::write_fields`]: each texel is located on the finest level
//! and the texture-space refinement's residual (§3.3.2, about two source reads) is computed
//! once, then written into both images, each with its own validity, padding and encoding
//! (normal map linear 8-bit RGB, displacement 16-bit gray in the range fixed beforehand from
//! [`Refinement::sampled_range`]). Chosen over two passes, which computed the residual twice
//! per texel (7.3 s of a 14.4 s job at 2048²), and over a per-texel cache of the residual
//! between two passes (about 160 MB at 2048²): the shared loop holds nothing per texel but the
//! output images, and the outputs are byte-identical to the two passes'.
//!
//! Written by hand: the bake goes through the shared writer ([`crate::engine::methods::output`]);
//! the frame inversion and the split by primitive are a few lines each.

use rayon::prelude::*;
use serde::Serialize;

use super::displacement::area_weighted_normals;
use super::maps::{Finest, Frames, MapFields, DISPLACEMENT, NORMAL};
use super::refine::{RefineInput, RefineParams, RefineReport, Refinement};
use crate::engine::asset::constraints::{Constraints, UvMode};
use crate::engine::asset::edits::{AttributeData, Edit, PrimitiveGeometry, TextureSlot};
use crate::engine::asset::export::mesh_glb;
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};
use crate::engine::math::{add, dot, normalize, scale, to_f64, Affine};
use crate::engine::mesh::Surface;
use crate::engine::methods::output::{
    build_atlas, uv_set_of, write_fields, AtlasLayout, FieldOutput, OutputReport, TexelEncoding,
    TextureReport,
};
use crate::engine::methods::tangents::{mikktspace_tangents_in_set, mikktspace_tangents_of};
use crate::engine::methods::{MethodError, ResultFile};
use crate::engine::spatial::Bvh;

/// The material extra that carries the displacement texture.
pub const DISPLACEMENT_KEY: &str = "retex_displacement";

/// What was written.
#[derive(Clone, Debug, Default, Serialize)]
pub struct OutputSummary {
    /// `d = offset + scale · value` of the displacement textures (world units).
    pub displacement_offset: f64,
    /// See `displacement_offset`.
    pub displacement_scale: f64,
    /// Displacement textures (one per material).
    pub displacement_textures: Vec<TextureReport>,
    /// Normal maps (one per material).
    pub normal_textures: Vec<TextureReport>,
    /// Primitives that received TANGENT.
    pub tangent_primitives: usize,
    /// Primitives replaced by their part of the displaced finest level (no UVs, `output.uv`
    /// `keep`, or no atlas could be made).
    pub replaced_primitives: usize,
    /// Primitives without UVs replaced by an atlas copy (`output.uv = "auto"`) that carries
    /// the maps.
    pub atlas_primitives: usize,
    /// The generated atlas's quality figures, when one was made.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub atlas: Option<crate::engine::uv::AtlasReport>,
    /// The texture-space refinement (§3.3.2).
    pub refinement: RefineReport,
    /// Vertices and faces of `displaced.glb`.
    pub displaced_vertices: usize,
    /// See `displaced_vertices`.
    pub displaced_faces: usize,
}

/// What [`write_outputs`] produced.
#[derive(Clone, Debug)]
pub struct Written {
    /// Edits of the target.
    pub edits: Vec<Edit>,
    /// `displaced.glb`.
    pub files: Vec<ResultFile>,
    /// What was written.
    pub summary: OutputSummary,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

/// Texels of the output textures per `edge` (world units): `edge` over the mean world size of a
/// texel on the UV-mapped primitives `uv_prims` and the atlas's triangles
/// (`√(area / (uv area · size²))`); 0 without UV area.
fn texels_per_edge(
    asset: &Asset,
    surface: &Surface,
    uv_prims: &[usize],
    constraints: &Constraints,
    edge: f64,
    atlas: Option<&AtlasLayout>,
) -> f64 {
    let (mut area, mut uv_area) = atlas.map_or((0.0, 0.0), AtlasLayout::areas);
    for f in 0..surface.face_count() {
        let Some((p, t, _)) = surface.primitive_point(asset, f, [1.0 / 3.0; 3]) else {
            continue;
        };
        if !uv_prims.contains(&p) {
            continue;
        }
        let prim = &asset.primitives[p];
        let Some(uvs) = prim.tex_coords.get(uv_set_of(asset, p) as usize) else {
            continue;
        };
        let [a, b, c] = prim.triangles[t].map(|v| uvs[v as usize].map(|x| x as f64));
        uv_area += 0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])).abs();
        area += surface.face_area(f) as f64;
    }
    let size = constraints.output.texture_size as f64;
    if uv_area <= 0.0 || area <= 0.0 {
        return 0.0;
    }
    edge / (area / (uv_area * size * size)).sqrt()
}

/// Whether primitive `p` is baked into (has the UV set) rather than replaced.
fn has_uvs(asset: &Asset, constraints: &Constraints, p: usize) -> bool {
    !constraints.output.all_vertex_colors()
        && asset.primitives[p].tex_coords.len() > uv_set_of(asset, p) as usize
}

/// Area-weighted unit normals of local positions (f32); +z on vertices that only touch
/// degenerate triangles (a UV sphere's poles), where no direction is right and glTF wants a unit
/// vector.
fn local_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let s = Surface::from_triangles(positions.to_vec(), triangles.to_vec());
    area_weighted_normals(&s)
        .into_iter()
        .map(|n| match dot(n, n) > 0.5 {
            true => n.map(|x| x as f32),
            false => [0.0, 0.0, 1.0],
        })
        .collect()
}

/// The local-to-world map of the first instance of primitive `p`'s mesh (the one the shared
/// writer bakes).
fn to_world(asset: &Asset, p: usize) -> Option<Affine> {
    let mesh = asset.primitives[p].mesh;
    let inst = asset.instances.iter().find(|i| i.mesh == mesh)?;
    Some(Affine::of_column_major(&inst.world))
}

/// NORMAL (when missing) and TANGENT edits of a UV primitive, and its world-space frames.
fn frames_of(asset: &Asset, p: usize, edits: &mut Vec<Edit>) -> Option<Frames> {
    let prim = &asset.primitives[p];
    let normals = match &prim.normals {
        Some(n) => n.clone(),
        None => {
            let n = local_normals(&prim.positions, &prim.triangles);
            edits.push(Edit::SetAttribute {
                primitive: p,
                name: "NORMAL".into(),
                data: AttributeData::Vec3(n.clone()),
            });
            n
        }
    };
    let tangents = mikktspace_tangents_in_set(
        asset,
        p,
        uv_set_of(asset, p) as usize,
        &prim.positions,
        &normals,
    )?;
    edits.push(Edit::SetAttribute {
        primitive: p,
        name: "TANGENT".into(),
        data: AttributeData::Vec4(tangents.clone()),
    });
    world_frames(asset, p, &normals, &tangents, prim.triangles.clone())
}

/// NORMAL (the input's, or area-weighted when it has none, copied to every vertex split from
/// it) and MikkTSpace TANGENT in TEXCOORD_0 of the atlas copy `g` of primitive `p`, whose vertex
/// `i` was split from input vertex `origin[i]`; and its world-space frames.
fn atlas_frames(
    asset: &Asset,
    p: usize,
    g: &mut PrimitiveGeometry,
    origin: &[u32],
) -> Option<Frames> {
    let prim = &asset.primitives[p];
    let input = match &prim.normals {
        Some(n) => n.clone(),
        None => local_normals(&prim.positions, &prim.triangles),
    };
    let normals: Vec<[f32; 3]> = origin.iter().map(|&a| input[a as usize]).collect();
    let uvs = g.tex_coords.first()?;
    let tangents = mikktspace_tangents_of(&g.triangles, &g.positions, &normals, uvs);
    let frames = world_frames(asset, p, &normals, &tangents, g.triangles.clone());
    g.normals = Some(normals);
    g.tangents = Some(tangents);
    frames
}

/// Mesh-local normals and tangents of primitive `p` carried to world space (normals through
/// the inverse transpose, tangents through the matrix: glTF §3.7.2.1).
fn world_frames(
    asset: &Asset,
    p: usize,
    normals: &[[f32; 3]],
    tangents: &[[f32; 4]],
    triangles: Vec<[u32; 3]>,
) -> Option<Frames> {
    let to_world = to_world(asset, p)?;
    let to_local = to_world.inverse()?;
    Some(Frames {
        normals: normals
            .iter()
            .map(|n| normalize(to_local.transpose_linear(to_f64(*n))))
            .collect(),
        tangents: tangents
            .iter()
            .map(|t| {
                let w = normalize(to_world.linear([t[0] as f64, t[1] as f64, t[2] as f64]));
                [w[0], w[1], w[2], t[3] as f64]
            })
            .collect(),
        triangles,
    })
}

/// The displaced finest level's faces split by the input primitive nearest to each face's
/// centroid, each part in its primitive's local space.
fn replacements(
    asset: &Asset,
    input: &Surface,
    finest: &Surface,
    displaced: &[[f32; 3]],
    prims: &[usize],
) -> Vec<Edit> {
    let bvh = Bvh::build(&input.positions, &input.faces);
    let owner: Vec<Option<usize>> = finest
        .faces
        .par_iter()
        .map(|f| {
            let c = f.iter().fold([0.0f32; 3], |a, &v| {
                let q = finest.positions[v as usize];
                [a[0] + q[0] / 3.0, a[1] + q[1] / 3.0, a[2] + q[2] / 3.0]
            });
            let hit = bvh.closest_point(c, f32::INFINITY)?;
            input
                .origins
                .get(hit.face as usize)
                .map(|o| o.primitive as usize)
        })
        .collect();
    let mut edits = Vec::new();
    for &p in prims {
        let Some(to_local) = to_world(asset, p).and_then(|a| a.inverse()) else {
            continue;
        };
        let mut index = vec![u32::MAX; displaced.len()];
        let mut g = PrimitiveGeometry::default();
        for (f, face) in finest.faces.iter().enumerate() {
            if owner[f] != Some(p) {
                continue;
            }
            let tri = face.map(|v| {
                let v = v as usize;
                if index[v] == u32::MAX {
                    index[v] = g.positions.len() as u32;
                    let local = to_local.apply(to_f64(displaced[v]));
                    g.positions.push(local.map(|x| x as f32));
                }
                index[v]
            });
            g.triangles.push(tri);
        }
        if g.triangles.is_empty() {
            continue;
        }
        g.normals = Some(local_normals(&g.positions, &g.triangles));
        edits.push(Edit::ReplacePrimitive {
            primitive: p,
            geometry: g,
        });
    }
    edits
}

/// The atlas for the replaceable primitives without UVs (`prims`) when `output.uv = "auto"`:
/// `None` when not asked for, or (with a warning) when no atlas could be made.
fn atlas_for(
    target: &Asset,
    constraints: &Constraints,
    prims: &[usize],
    control: &Control,
    warnings: &mut Vec<String>,
) -> Result<Option<AtlasLayout>, MethodError> {
    let output = &constraints.output;
    if output.uv != UvMode::Auto || output.all_vertex_colors() || prims.is_empty() {
        return Ok(None);
    }
    let with_instance: Vec<(usize, usize)> = prims
        .iter()
        .filter_map(|&p| {
            let mesh = target.primitives[p].mesh;
            let inst = target.instances.iter().position(|i| i.mesh == mesh)?;
            Some((p, inst))
        })
        .collect();
    if with_instance.is_empty() {
        return Ok(None);
    }
    build_atlas(
        target,
        &with_instance,
        output.texture_size,
        output.padding,
        output.atlas_parameterization,
        control,
        warnings,
    )
    .map_err(|_: Cancelled| MethodError::Cancelled)
}

/// The refinement when it applies (enabled, enough texels and source samples per finest edge),
/// and its report (why it was skipped otherwise).
fn choose_refinement<'a>(
    refine: Option<(RefineInput<'a>, &RefineParams)>,
    texels: f64,
    edge: f64,
    control: &Control,
) -> Result<(Option<Refinement<'a>>, RefineReport), MethodError> {
    let enabled = refine.as_ref().is_some_and(|r| r.1.enabled);
    let source_ratio = refine.as_ref().map_or(0.0, |r| edge / r.0.fine.sampling());
    let min_ratio = refine.as_ref().map_or(2.0, |r| r.1.min_texels_per_edge);
    let refinement = match refine {
        Some((input, params))
            if params.enabled
                && texels >= params.min_texels_per_edge
                && source_ratio >= params.min_texels_per_edge =>
        {
            control.stage("detail: refinement", 0)?;
            Some(Refinement::new(input, edge, params))
        }
        _ => None,
    };
    let mut report = match &refinement {
        Some(r) => RefineReport {
            applied: true,
            ..r.report.clone()
        },
        None => RefineReport {
            skipped_because: Some(if !enabled {
                "params.refine is false".into()
            } else if source_ratio < min_ratio {
                format!(
                    "the source's detail is sampled {source_ratio:.2} times per finest edge: it \
                     has nothing finer than the finest level to add"
                )
            } else {
                format!(
                    "{texels:.2} texels per finest edge: the textures have no band above the \
                     finest level's sampling"
                )
            }),
            ..RefineReport::default()
        },
    };
    report.texels_per_edge = texels;
    report.source_samples_per_edge = source_ratio;
    Ok((refinement, report))
}

/// Bakes both maps (one sample per texel, [`MapFields`]) through the primitives' UVs and, when
/// there is one, the shared atlas: the normal map's and the displacement's edits and report.
fn bake(
    target: &Asset,
    constraints: &Constraints,
    fields: &MapFields<'_>,
    atlas: Option<&AtlasLayout>,
    control: &Control,
) -> Result<[(Vec<Edit>, OutputReport); 2], MethodError> {
    let output = |k| {
        let (slot, encoding, name) = match k {
            NORMAL => (
                TextureSlot::Normal { scale: 1.0 },
                TexelEncoding::Linear8 { channels: 3 },
                "detail_normal",
            ),
            _ => (
                TextureSlot::Extras(DISPLACEMENT_KEY),
                TexelEncoding::Gray16,
                "detail_displacement",
            ),
        };
        FieldOutput {
            slot,
            encoding,
            name,
            vertex_attribute: None,
            vertex_samples: 0,
        }
    };
    let outputs: [FieldOutput; 2] = std::array::from_fn(output);
    let mut written = write_fields(target, constraints, &outputs, fields, atlas, control)
        .map_err(|_: Cancelled| MethodError::Cancelled)?;
    let mut take = |k: usize| written.get_mut(k).map(std::mem::take);
    match (take(NORMAL), take(DISPLACEMENT)) {
        (Some(normal), Some(displacement)) => Ok([normal, displacement]),
        _ => Err(MethodError::Internal(
            "the shared writer returned fewer outputs than asked".into(),
        )),
    }
}

/// Writes the outputs (see the module doc): edits of the target, `displaced.glb`, the summary
/// and warnings.
///
/// # Errors
/// [`MethodError::Cancelled`]; [`MethodError::Internal`] if `displaced.glb` cannot be written.
pub fn write_outputs(
    target: &Asset,
    input: &Surface,
    finest: &Surface,
    displacement: &[f64],
    refine: Option<(RefineInput<'_>, &RefineParams)>,
    constraints: &Constraints,
    control: &Control,
) -> Result<Written, MethodError> {
    let normals = area_weighted_normals(finest);
    let displaced: Vec<[f32; 3]> = (finest.positions.iter().zip(&normals))
        .zip(displacement)
        .map(|((p, n), d)| add(to_f64(*p), scale(*n, *d)).map(|x| x as f32))
        .collect();
    let glb = mesh_glb(&displaced, &finest.faces)
        .map_err(|e| MethodError::Internal(format!("displaced.glb: {e}")))?;
    let located = Finest::new(finest, displacement);
    let (lo, hi) = displacement
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &d| {
            (a.min(d), b.max(d))
        });
    let (mut offset, mut range) = if lo < hi {
        (lo, hi - lo)
    } else {
        (lo.min(0.0), 1.0)
    };
    let mut summary = OutputSummary {
        displacement_offset: offset,
        displacement_scale: range,
        displaced_vertices: displaced.len(),
        displaced_faces: finest.faces.len(),
        ..OutputSummary::default()
    };
    let n = target.primitives.len();
    let (uv_prims, bare): (Vec<usize>, Vec<usize>) =
        (0..n).partition(|&p| has_uvs(target, constraints, p));
    let mut warnings = Vec::new();
    let replaceable: Vec<usize> = bare
        .iter()
        .copied()
        .filter(|&p| crate::engine::methods::output::atlas_replaceable(target, p))
        .collect();
    if replaceable.len() < bare.len() {
        warnings.push(format!(
            "{} skinned or morphed primitive(s) without uvs kept their geometry: detail could not \
             be written into them",
            bare.len() - replaceable.len()
        ));
    }
    let mut atlas = atlas_for(target, constraints, &replaceable, control, &mut warnings)?;
    let atlased = atlas.as_ref().map_or(Vec::new(), AtlasLayout::primitives);
    let rest: Vec<usize> = (replaceable.iter().copied())
        .filter(|p| !atlased.contains(p))
        .collect();
    let mut edits = replacements(target, input, finest, &displaced, &rest);
    summary.replaced_primitives = edits.len();
    if uv_prims.is_empty() && atlas.is_none() {
        return Ok(Written {
            edits,
            files: vec![result_file(glb)],
            summary,
            warnings,
        });
    }
    let mut frames: Vec<Option<Frames>> = (0..n).map(|_| None).collect();
    for &p in &uv_prims {
        control
            .check()
            .map_err(|_: Cancelled| MethodError::Cancelled)?;
        frames[p] = frames_of(target, p, &mut edits);
    }
    if let Some(a) = &mut atlas {
        // The replaced primitives go first: the texture edits assign their new material.
        let mut replaced = Vec::new();
        for (e, origin) in a.edits.iter_mut().zip(&a.origins) {
            if let Edit::ReplacePrimitive {
                primitive,
                geometry,
            } = e
            {
                frames[*primitive] = atlas_frames(target, *primitive, geometry, origin);
            }
            replaced.push(e.clone());
        }
        replaced.append(&mut edits);
        edits = replaced;
        summary.atlas_primitives = atlased.len();
        summary.atlas = Some(a.report.clone());
    }
    summary.tangent_primitives = frames.iter().filter(|f| f.is_some()).count();
    let edge = crate::engine::geometry::expmap::mean_edge_length(finest) as f64;
    let texels = texels_per_edge(target, input, &uv_prims, constraints, edge, atlas.as_ref());
    let (refinement, refine_report) = choose_refinement(refine, texels, edge, control)?;
    summary.refinement = refine_report;
    if let Some(r) = &refinement {
        let [a, b] = r.sampled_range();
        if a.is_finite() && b.is_finite() && b > a {
            (offset, range) = (a.min(offset), (b.max(offset + range)) - a.min(offset));
            summary.displacement_offset = offset;
            summary.displacement_scale = range;
        }
    }
    let fields = MapFields {
        finest: &located,
        refinement: refinement.as_ref(),
        frames,
        offset,
        scale: range,
    };
    let [(normal_edits, normal_report), (disp_edits, disp_report)] =
        bake(target, constraints, &fields, atlas.as_ref(), control)?;
    // Each normal-map edit without a material creates one at the end of the material list, in
    // order; the displacement of the same primitives (same groups, same order) goes into it.
    let mut created = target.json["materials"].as_array().map_or(0, |m| m.len());
    edits.extend(normal_edits);
    let extra = serde_json::json!({ "scale": range, "offset": offset });
    for mut e in disp_edits {
        if let Edit::SetTexture { material, .. } = &mut e {
            let m = match *material {
                Some(m) => m,
                None => {
                    created += 1;
                    created - 1
                }
            };
            *material = Some(m);
            edits.push(Edit::SetMaterialExtra {
                material: m,
                key: DISPLACEMENT_KEY.into(),
                value: extra.clone(),
            });
        }
        edits.push(e);
    }
    warnings.extend(
        (normal_report
            .warnings
            .into_iter()
            .chain(disp_report.warnings))
        .filter(|w| !w.contains("have no UVs")),
    );
    warnings.dedup();
    if let Some(r) = &refinement {
        [summary.refinement.points, summary.refinement.reads] = r.counts();
    }
    summary.normal_textures = normal_report.textures;
    summary.displacement_textures = disp_report.textures;
    Ok(Written {
        edits,
        files: vec![result_file(glb)],
        summary,
        warnings,
    })
}

fn result_file(bytes: Vec<u8>) -> ResultFile {
    ResultFile {
        name: "displaced.glb".into(),
        media_type: "model/gltf-binary".into(),
        bytes,
    }
}
