//! The atlas path of [`super::write_field`] (`output.uv = "auto"`, issue 15): primitives without
//! the base-colour UV set get a generated atlas ([`crate::engine::uv`]) instead of COLOR_0 on a
//! refined copy. Each such primitive is replaced by a copy whose vertices are split only where
//! charts meet (one output vertex per (input vertex, chart)), with TEXCOORD_0 per corner; its
//! triangles, in the same order and corner order, are baked like any UV layout into one texture
//! for all of them, in a new material (`<name>_atlas`).
//!
//! The primitives' first instances are welded on exact world positions (so vertices duplicated
//! along normal seams share a chart vertex); triangles that are degenerate there (zero area or a
//! repeated vertex) take the UVs their vertices got in another triangle (a fallback, they cover
//! no texel). Normals are kept; tangents and other UV sets are dropped (they would not match the
//! new layout). Skinned or morphed primitives are left to the vertex path (replacing them would
//! drop their joints and targets). When the atlas fails (e.g. too many charts for the texture),
//! the primitives fall back to the vertex path with a warning.

use std::collections::HashMap;

use super::texels::PlacedTriangle;
use super::{normal_of, to_f32};
use crate::engine::asset::edits::{Edit, PrimitiveGeometry};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::Surface;
use crate::engine::uv::{generate, AtlasError, AtlasParams, AtlasReport};

/// Gutter between charts: the padding, at least 2 texels (no two charts share a texel under
/// bilinear filtering) and at most 8 (beyond that the packing loses more than the padding
/// gains; dilation still fills the rest of the empty texture).
fn gutter(padding: u32) -> u32 {
    padding.clamp(2, 8)
}

/// The atlas output of some primitives.
pub(crate) struct AtlasLayout {
    /// ReplacePrimitive per primitive.
    pub(crate) edits: Vec<Edit>,
    /// Per edit: the input vertex each new vertex was split from.
    pub(crate) origins: Vec<Vec<u32>>,
    /// The new triangles, placed, for the bake.
    pub(super) tris: Vec<PlacedTriangle>,
    /// Quality figures.
    pub(crate) report: AtlasReport,
}

impl AtlasLayout {
    /// The replaced primitives, in edit order.
    pub(crate) fn primitives(&self) -> Vec<usize> {
        self.edits
            .iter()
            .filter_map(|e| match e {
                Edit::ReplacePrimitive { primitive, .. } => Some(*primitive),
                _ => None,
            })
            .collect()
    }

    /// World area and texel area (in texture widths², i.e. UV area) of the atlas's triangles.
    pub(crate) fn areas(&self) -> (f64, f64) {
        self.tris.iter().fold((0.0, 0.0), |(a, u), t| {
            let w = t.world.map(|p| p.map(f64::from));
            let n = crate::engine::math::cross(
                crate::engine::math::sub(w[1], w[0]),
                crate::engine::math::sub(w[2], w[0]),
            );
            let q = t.uv.map(|c| c.map(f64::from));
            let uv = 0.5
                * ((q[1][0] - q[0][0]) * (q[2][1] - q[0][1])
                    - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]))
                    .abs();
            (a + 0.5 * crate::engine::math::dot(n, n).sqrt(), u + uv)
        })
    }
}

/// Whether primitive `p` may be replaced (no skin, no morph targets).
pub(crate) fn replaceable(asset: &Asset, p: usize) -> bool {
    let prim = &asset.primitives[p];
    let j = &asset.json["meshes"][prim.mesh]["primitives"][prim.primitive];
    j.get("targets").is_none() && j["attributes"].get("JOINTS_0").is_none()
}

/// Welds the first instances of `prims` ((primitive, instance) pairs) on exact world positions.
/// Returns the surface and, per surface face, (primitive, triangle).
fn weld(asset: &Asset, prims: &[(usize, usize)]) -> (Surface, Vec<(usize, usize)>) {
    let mut index: HashMap<[u32; 3], u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    let mut origin = Vec::new();
    for &(p, ii) in prims {
        let prim = &asset.primitives[p];
        let inst = &asset.instances[ii];
        let ids: Vec<u32> = prim
            .positions
            .iter()
            .map(|x| {
                let w = to_f32(inst.transform_point(*x));
                let key = w.map(|c| if c == 0.0 { 0 } else { c.to_bits() });
                *index.entry(key).or_insert_with(|| {
                    positions.push(w);
                    (positions.len() - 1) as u32
                })
            })
            .collect();
        for (ti, t) in prim.triangles.iter().enumerate() {
            let mut f = t.map(|v| ids[v as usize]);
            if inst.mirrors() {
                f.swap(1, 2);
            }
            if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
                continue;
            }
            let w = f.map(|v| positions[v as usize]);
            let n = normal_of(w[0], w[1], w[2]);
            if !n.iter().all(|c| c.is_finite()) || n == [0.0; 3] {
                continue;
            }
            faces.push(f);
            origin.push((p, ti));
        }
    }
    let mut s = Surface::from_triangles(positions, faces);
    // Zero-area faces that normal_of accepted are dropped by the atlas check; filter them here.
    let keep: Vec<bool> = (0..s.faces.len())
        .map(|f| f64::from(s.face_area(f)) > 0.0)
        .collect();
    let mut k = keep.iter();
    s.faces.retain(|_| *k.next().unwrap_or(&false));
    let mut k = keep.iter();
    origin.retain(|_| *k.next().unwrap_or(&false));
    (s, origin)
}

/// Builds the atlas output for `prims` ((primitive, first instance) pairs), or `None` with a
/// warning when no atlas could be made.
pub(crate) fn build(
    asset: &Asset,
    prims: &[(usize, usize)],
    texture_size: u32,
    padding: u32,
    parameterization: crate::engine::asset::constraints::AtlasParameterization,
    control: &Control,
    warnings: &mut Vec<String>,
) -> Result<Option<AtlasLayout>, Cancelled> {
    let _weld_stage = control.stage("atlas_weld", 1)?;
    let (surface, origin) = weld(asset, prims);
    let params = AtlasParams {
        texture_size,
        gutter: gutter(padding),
        parameterization: parameterization.into(),
        ..AtlasParams::default()
    };
    let atlas = match generate(&surface, &params, control) {
        Ok(a) => a,
        Err(AtlasError::Cancelled) => return Err(Cancelled),
        Err(e) => {
            warnings.push(format!(
                "no uv atlas could be made ({e}); the primitives without uvs got COLOR_0 instead"
            ));
            return Ok(None);
        }
    };
    // (primitive, triangle) -> surface face (u32::MAX: dropped by the weld).
    let mut face_of: HashMap<usize, Vec<u32>> = prims
        .iter()
        .map(|&(p, _)| (p, vec![u32::MAX; asset.primitives[p].triangles.len()]))
        .collect();
    for (f, (p, t)) in origin.iter().enumerate() {
        if let Some(list) = face_of.get_mut(p) {
            list[*t] = f as u32;
        }
    }
    let mut edits = Vec::new();
    let mut origins = Vec::new();
    let mut tris = Vec::new();
    for &(p, ii) in prims {
        control.check()?;
        let prim = &asset.primitives[p];
        let inst = &asset.instances[ii];
        // Corner UV and chart of (triangle, corner k).
        let faces = &face_of[&p];
        let corner = |ti: usize, k: usize| -> Option<(u32, [f32; 2])> {
            let f = faces[ti];
            if f == u32::MAX {
                return None;
            }
            // Corner k of the primitive triangle sits at the same slot of the surface face,
            // after the swap of corners 1 and 2 for mirroring instances.
            let slot = if inst.mirrors() { [0, 2, 1][k] } else { k };
            let uv = atlas.face_uv(&surface, f as usize)[slot];
            Some((atlas.face_chart[f as usize], uv))
        };
        let mut fallback: Vec<Option<[f32; 2]>> = vec![None; prim.positions.len()];
        for (ti, t) in prim.triangles.iter().enumerate() {
            for (k, a) in t.iter().enumerate() {
                if fallback[*a as usize].is_none() {
                    fallback[*a as usize] = corner(ti, k).map(|c| c.1);
                }
            }
        }
        let mut g = PrimitiveGeometry::default();
        let mut uv = Vec::new();
        let mut origin = Vec::new();
        // (original vertex, chart) -> new vertex: the first chart of each vertex in `first`,
        // the others (seam vertices) in `index`.
        let mut first: Vec<Option<(u32, u32)>> = vec![None; prim.positions.len()];
        let mut index: HashMap<(u32, u32), u32> = HashMap::new();
        for (ti, t) in prim.triangles.iter().enumerate() {
            let mut tri = [0u32; 3];
            for (k, a) in t.iter().enumerate() {
                let (chart, coord) = corner(ti, k)
                    .unwrap_or((u32::MAX, fallback[*a as usize].unwrap_or([0.0, 0.0])));
                let mut add = || {
                    g.positions.push(prim.positions[*a as usize]);
                    origin.push(*a);
                    uv.push(coord);
                    (g.positions.len() - 1) as u32
                };
                tri[k] = match first[*a as usize] {
                    Some((c, id)) if c == chart => id,
                    Some(_) => *index.entry((*a, chart)).or_insert_with(add),
                    None => {
                        let id = add();
                        first[*a as usize] = Some((chart, id));
                        id
                    }
                };
            }
            g.triangles.push(tri);
            let world = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
            let mut normal = normal_of(world[0], world[1], world[2]);
            if inst.mirrors() {
                normal = normal.map(|x| -x);
            }
            tris.push(PlacedTriangle {
                primitive: p,
                triangle: ti,
                world,
                normal,
                uv: tri.map(|v| uv[v as usize]),
            });
        }
        for (a, f) in first.iter().enumerate() {
            if let Some((c, id)) = f {
                index.insert((a as u32, *c), *id);
            }
        }
        g.normals = split_normals(prim.normals.as_deref(), &index, g.positions.len());
        g.tex_coords.push(uv);
        edits.push(Edit::ReplacePrimitive {
            primitive: p,
            geometry: g,
        });
        origins.push(origin);
    }
    Ok(Some(AtlasLayout {
        edits,
        origins,
        tris,
        report: atlas.report,
    }))
}

/// The normals of a primitive whose vertices were split per chart: `index` maps (original
/// vertex, chart) → new vertex; each new vertex takes its original's normal. `None` when the
/// primitive had none.
pub(crate) fn split_normals(
    normals: Option<&[[f32; 3]]>,
    index: &HashMap<(u32, u32), u32>,
    count: usize,
) -> Option<Vec<[f32; 3]>> {
    let n = normals?;
    let mut out = vec![[0.0; 3]; count];
    for ((a, _), id) in index {
        out[*id as usize] = n[*a as usize];
    }
    Some(out)
}
