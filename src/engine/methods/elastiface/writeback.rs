//! The output: the fitted shape written into the source asset (issue 10, "Interface").
//!
//! Every source primitive keeps its vertex count, order, indices and UVs. A vertex's new world
//! position is that of its welded surface vertex (so split UV-seam vertices move together),
//! brought into the primitive's mesh-local frame through the inverse of its node's world
//! transform. NORMAL (where present) is recomputed from the fitted welded surface (area-weighted
//! face normals) and carried to local space with the transpose of the node's linear part; a
//! TANGENT is recomputed with MikkTSpace on the written positions and normals ([`crate::engine::methods::tangents`]),
//! or removed if the primitive lacks the UV set it follows. A vertex that lies on no
//! surviving (non-degenerate) face (e.g. the corner of a triangle dropped as degenerate) has no
//! welded vertex: it moves with the closest point of the source surface (same face and
//! barycentric coordinates on the fitted surface).
//!
//! With `output = "morph_target"` POSITION is kept and one morph target `elastiface` (default
//! weight 0, or `params.blend.weight` when given, so without a blend the rig's neutral shape is unchanged) holds the mesh-local displacement in the
//! source's own frame: the inverse of the initial similarity is applied first, so the blend shape
//! does not move or scale the head. Existing morph targets are kept (export extends `weights`).
//!
//! A mesh instanced by two nodes cannot hold two fitted shapes: it is refused.

use std::collections::HashMap;

use crate::engine::asset::edits::{AttributeData, Edit, MorphDeltas};
use crate::engine::asset::{Asset, Primitive};
use crate::engine::math::{cross, normalize, sub, Affine};
use crate::engine::mesh::Surface;

use super::MethodError;
use crate::engine::methods::tangents::mikktspace_tangents;

/// Per primitive, per vertex: the welded vertex of the (first) instance, or `u32::MAX`.
pub fn welded_map(asset: &Asset, surface: &Surface) -> Vec<Vec<u32>> {
    let mut map: Vec<Vec<u32>> = asset
        .primitives
        .iter()
        .map(|p| vec![u32::MAX; p.positions.len()])
        .collect();
    for (face, corners) in surface.faces.iter().zip(&surface.corners) {
        for k in 0..3 {
            let c = corners[k];
            if let Some(slot) = map[c.primitive as usize].get_mut(c.vertex as usize) {
                *slot = face[k];
            }
        }
    }
    map
}

/// Refuses a source whose mesh is instanced by more than one node.
///
/// # Errors
/// [`MethodError::UnusableInput`] naming the mesh and the nodes.
pub fn check_single_instances(asset: &Asset) -> Result<(), MethodError> {
    let mut seen: HashMap<usize, usize> = HashMap::new();
    for inst in &asset.instances {
        if let Some(first) = seen.insert(inst.mesh, inst.node) {
            return Err(MethodError::UnusableInput {
                field: Some("source".into()),
                kind: "instanced-mesh",
                message: format!(
                    "source mesh {} is instanced by nodes {first} and {}: elastiface writes one \
                     fitted shape per mesh and cannot fit two placements of it",
                    inst.mesh, inst.node
                ),
            });
        }
    }
    Ok(())
}

/// Area-weighted vertex normals of positions with faces.
fn vertex_normals(x: &[[f64; 3]], faces: &[[u32; 3]]) -> Vec<[f64; 3]> {
    let mut n = vec![[0.0; 3]; x.len()];
    for f in faces {
        let p = f.map(|v| x[v as usize]);
        let c = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        for &v in f {
            for d in 0..3 {
                n[v as usize][d] += c[d];
            }
        }
    }
    n
}

/// What to write: fitted world positions, or the morph form.
pub struct Placement<'a> {
    /// Fitted welded positions, world frame of the target.
    pub fitted: &'a [[f64; 3]],
    /// Welded faces.
    pub faces: &'a [[u32; 3]],
    /// Per primitive, per vertex: welded vertex.
    pub welded: &'a [Vec<u32>],
    /// Target world frame → source world frame (the inverse of the initial similarity).
    pub to_source_frame: &'a dyn Fn([f64; 3]) -> [f64; 3],
    /// A source world point → its fitted position (through the closest source surface point),
    /// for vertices on no face.
    pub follow_surface: &'a dyn Fn([f64; 3]) -> [f64; 3],
    /// Write a morph target instead of POSITION.
    pub morph: bool,
    /// The morph target's default weight (0, or the blend weight of §5).
    pub morph_weight: f32,
}

/// The geometry edits (POSITION, NORMAL, TANGENT, or the morph target).
///
/// # Errors
/// [`MethodError::UnusableInput`] for a node transform that cannot be inverted.
pub fn geometry_edits(source: &Asset, place: &Placement<'_>) -> Result<Vec<Edit>, MethodError> {
    let normals = vertex_normals(place.fitted, place.faces);
    let mut edits = Vec::new();
    let mut morphs: Vec<(usize, Vec<MorphDeltas>)> = Vec::new();
    for inst in &source.instances {
        let to_world = Affine::of_column_major(&inst.world);
        let to_local = to_world
            .inverse()
            .ok_or_else(|| MethodError::UnusableInput {
                field: Some("source".into()),
                kind: "unusable-mesh",
                message: format!("node {} has a singular transform", inst.node),
            })?;
        let mut deltas = Vec::new();
        for p in source.primitives_of_mesh(inst.mesh) {
            let prim = &source.primitives[p];
            let map = &place.welded[p];
            let world_fitted = |v: usize| -> [f64; 3] {
                match map[v] {
                    u32::MAX => (place.follow_surface)(inst.transform_point(prim.positions[v])),
                    w => place.fitted[w as usize],
                }
            };
            if place.morph {
                let d = (0..prim.positions.len())
                    .map(|v| {
                        let local = to_local.apply((place.to_source_frame)(world_fitted(v)));
                        std::array::from_fn(|k| (local[k] - prim.positions[v][k] as f64) as f32)
                    })
                    .collect();
                deltas.push(MorphDeltas {
                    primitive: p,
                    positions: d,
                    normals: None,
                });
                continue;
            }
            let pos: Vec<[f32; 3]> = (0..prim.positions.len())
                .map(|v| to_local.apply(world_fitted(v)).map(|c| c as f32))
                .collect();
            edits.push(Edit::SetAttribute {
                primitive: p,
                name: "POSITION".into(),
                data: AttributeData::Vec3(pos.clone()),
            });
            let n = local_normals(prim, map, &normals, &to_world);
            if prim.normals.is_some() {
                edits.push(Edit::SetAttribute {
                    primitive: p,
                    name: "NORMAL".into(),
                    data: AttributeData::Vec3(n.clone()),
                });
            }
            if has_tangents(source, p) {
                edits.push(match mikktspace_tangents(source, p, &pos, &n) {
                    Some(t) => Edit::SetAttribute {
                        primitive: p,
                        name: "TANGENT".into(),
                        data: AttributeData::Vec4(t),
                    },
                    None => Edit::RemoveAttribute {
                        primitive: p,
                        name: "TANGENT".into(),
                    },
                });
            }
        }
        if place.morph {
            morphs.push((inst.mesh, deltas));
        }
    }
    for (mesh, deltas) in morphs {
        edits.push(Edit::AddMorphTarget {
            mesh,
            name: "elastiface".into(),
            weight: place.morph_weight,
            deltas,
        });
    }
    Ok(edits)
}

/// Unit mesh-local normals of a primitive's vertices from the fitted welded normals (the old
/// normal, or +z without one, where the vertex has no welded vertex or a degenerate normal).
fn local_normals(
    prim: &Primitive,
    map: &[u32],
    normals: &[[f64; 3]],
    to_world: &Affine,
) -> Vec<[f32; 3]> {
    (0..prim.positions.len())
        .map(|v| {
            let old = prim.normals.as_ref().map_or([0.0, 0.0, 1.0], |o| o[v]);
            match map[v] {
                u32::MAX => old,
                w => {
                    let n = normalize(to_world.transpose_linear(normals[w as usize]));
                    if n.iter().all(|c| c.is_finite()) && n != [0.0; 3] {
                        n.map(|c| c as f32)
                    } else {
                        old
                    }
                }
            }
        })
        .collect()
}

fn has_tangents(asset: &Asset, p: usize) -> bool {
    let prim = &asset.primitives[p];
    asset.json["meshes"][prim.mesh]["primitives"][prim.primitive]["attributes"]
        .get("TANGENT")
        .is_some()
}
