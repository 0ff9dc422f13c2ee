//! The output (Soler et al. 2002, §4.3, and the output contract): TEXCOORD_0 per corner
//! into the unmodified pattern image.
//!
//! Every primitive instanced in the scene is replaced by a copy whose vertices are split only
//! where patches meet: one output vertex per (input vertex, patch). A corner's UV is its
//! patch's pattern-pixel position divided by the image size, so UVs are continuous inside each
//! triangle and never wrapped per vertex (REPEAT tiles them when the pattern is toroidal; a
//! non-toroidal pattern gets CLAMP_TO_EDGE and UVs clamped into [0, 1], counted in a warning).
//! Degenerate triangles (dropped from the surface) take the UVs their vertices got elsewhere.
//! No COLOR_0 is written; the base-colour texture is the uploaded image, byte for byte, in a new
//! material assigned to the replaced primitives.
//!
//! §4.3's averaging of per-vertex coordinates over the recursion is not needed here: a patch's
//! coordinates come from one flattening of the whole cluster (see [`super::flatten`]), so there
//! are no cracks inside a patch to close.

use std::collections::HashMap;

use super::bands::Patch;
use super::hierarchy::NONE;
use super::texture::PatternTexture;
use crate::engine::asset::edits::{
    Edit, EncodedImage, PrimitiveGeometry, TextureSlot, TextureWrap,
};
use crate::engine::asset::Asset;
use crate::engine::mesh::Surface;
use crate::engine::methods::output::atlas::split_normals;
use crate::engine::methods::PatternImage;

/// The edits and what they hold.
pub struct UvOutput {
    /// ReplacePrimitive per instanced primitive, then the SetTexture.
    pub edits: Vec<Edit>,
    /// Output vertices in all.
    pub vertices: usize,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

/// Builds the output edits (see the module doc).
pub fn write_uvs(
    asset: &Asset,
    surface: &Surface,
    face_patch: &[u32],
    patches: &[Patch],
    pattern: &PatternImage,
    toroidal: bool,
) -> UvOutput {
    let size = [pattern.image.width as f32, pattern.image.height as f32];
    let np = asset.primitives.len();
    let mut first_instance = vec![u32::MAX; np];
    let mut instanced_twice = vec![false; np];
    for o in &surface.origins {
        let p = o.primitive as usize;
        if first_instance[p] != u32::MAX && first_instance[p] != o.instance {
            instanced_twice[p] = true;
        }
        first_instance[p] = first_instance[p].min(o.instance);
    }
    let mut face_of: Vec<HashMap<u32, u32>> = vec![HashMap::new(); np];
    for (f, o) in surface.origins.iter().enumerate() {
        if o.instance == first_instance[o.primitive as usize] {
            face_of[o.primitive as usize].insert(o.triangle, f as u32);
        }
    }
    let mut edits = Vec::new();
    let mut used = Vec::new();
    let mut vertices = 0;
    let mut clamped = 0usize;
    for (p, prim) in asset.primitives.iter().enumerate() {
        if first_instance[p] == u32::MAX {
            continue;
        }
        // The UV of each (primitive vertex, patch) corner.
        let corner_uv = |ti: usize, a: u32| -> Option<(u32, [f32; 2])> {
            let f = *face_of[p].get(&(ti as u32))?;
            let patch = face_patch[f as usize];
            if patch == NONE {
                return None;
            }
            let k = surface.corners[f as usize]
                .iter()
                .position(|c| c.vertex == a)?;
            let w = surface.faces[f as usize][k];
            let px = patches[patch as usize].px_of(w)?;
            Some((patch, [px[0] / size[0], px[1] / size[1]]))
        };
        let mut fallback: Vec<Option<[f32; 2]>> = vec![None; prim.positions.len()];
        for (ti, t) in prim.triangles.iter().enumerate() {
            for a in t {
                if fallback[*a as usize].is_none() {
                    fallback[*a as usize] = corner_uv(ti, *a).map(|c| c.1);
                }
            }
        }
        let mut g = PrimitiveGeometry::default();
        let mut uv = Vec::new();
        let mut index: HashMap<(u32, u32), u32> = HashMap::new();
        for (ti, t) in prim.triangles.iter().enumerate() {
            let mut tri = [0u32; 3];
            for (k, a) in t.iter().enumerate() {
                let (patch, mut coord) = corner_uv(ti, *a)
                    .unwrap_or((NONE, fallback[*a as usize].unwrap_or([0.0, 0.0])));
                if !toroidal && coord.iter().any(|c| !(0.0..=1.0).contains(c)) {
                    clamped += 1;
                    coord = coord.map(|c| c.clamp(0.0, 1.0));
                }
                let key = (*a, patch);
                let id = *index.entry(key).or_insert_with(|| {
                    g.positions.push(prim.positions[*a as usize]);
                    uv.push(coord);
                    (g.positions.len() - 1) as u32
                });
                tri[k] = id;
            }
            g.triangles.push(tri);
        }
        g.normals = split_normals(prim.normals.as_deref(), &index, g.positions.len());
        g.tex_coords.push(uv);
        vertices += g.positions.len();
        used.push(p);
        edits.push(Edit::ReplacePrimitive {
            primitive: p,
            geometry: g,
        });
    }
    let mut warnings = Vec::new();
    if instanced_twice.iter().any(|x| *x) {
        warnings.push(format!(
            "{} primitive(s) are instanced more than once: all instances share the texture coordinates of the first",
            instanced_twice.iter().filter(|x| **x).count()
        ));
    }
    if clamped > 0 {
        warnings.push(format!(
            "{clamped} corner(s) fell outside the non-toroidal pattern and were clamped to its edge"
        ));
    }
    let stem = std::path::Path::new(&pattern.name)
        .file_stem()
        .and_then(|s| s.to_str())
        .filter(|s| !s.is_empty())
        .unwrap_or("pattern")
        .to_string();
    edits.push(Edit::SetTexture {
        material: None,
        slot: TextureSlot::BaseColor,
        image: EncodedImage::passthrough(stem, pattern.bytes.clone(), pattern.mime_type),
        tex_coord: 0,
        wrap: if toroidal {
            TextureWrap::Repeat
        } else {
            TextureWrap::ClampToEdge
        },
        primitives: used,
    });
    UvOutput {
        edits,
        vertices,
        warnings,
    }
}

/// Mean colour difference across the patch borders (see
/// [`super::report::PatternReport::mean_seam_error`]), unnormalised.
pub fn seam_error(
    surface: &Surface,
    topo: &crate::engine::mesh::Topology,
    face_patch: &[u32],
    patches: &[Patch],
    texture: &PatternTexture,
) -> Option<f32> {
    let mut sum = 0.0f64;
    let mut weight = 0.0f64;
    for (f, fv) in surface.faces.iter().enumerate() {
        let pa = face_patch[f];
        for e in 0..3 {
            let Some(o) = topo.face_neighbors[f][e] else {
                continue;
            };
            let pb = face_patch[o as usize];
            if (o as usize) < f || pa == pb || pa == NONE || pb == NONE {
                continue;
            }
            let (a, b) = (fv[e], fv[(e + 1) % 3]);
            let (qa, qb) = (&patches[pa as usize], &patches[pb as usize]);
            let (Some(a0), Some(a1), Some(b0), Some(b1)) =
                (qa.px_of(a), qa.px_of(b), qb.px_of(a), qb.px_of(b))
            else {
                continue;
            };
            let pa3 = surface.positions[a as usize];
            let pb3 = surface.positions[b as usize];
            let len = (0..3)
                .map(|k| (pa3[k] - pb3[k]).powi(2))
                .sum::<f32>()
                .sqrt();
            for t in [0.25f32, 0.5, 0.75] {
                let lerp =
                    |p: [f32; 2], q: [f32; 2]| [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])];
                let ca = texture.sample(lerp(a0, a1));
                let cb = texture.sample(lerp(b0, b1));
                let d: f32 = (0..3).map(|k| (ca[k] - cb[k]).powi(2)).sum();
                sum += f64::from(d * len);
                weight += f64::from(len);
            }
        }
    }
    (weight > 0.0).then(|| (sum / weight) as f32)
}
