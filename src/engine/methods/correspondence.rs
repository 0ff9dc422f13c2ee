//! Resolving the correspondences of a constraints document onto the source and target surfaces.
//!
//! Every place (a world point, a point in a triangle, or a vertex) is turned into a world-space
//! point and snapped to the nearest surface point (exact point–triangle distance through the BVH).
//! A point farther than the snap tolerance, or an index out of range, is an error naming the JSON
//! path. Triangle and vertex places use the first scene instance of their mesh.

use crate::engine::asset::constraints::{
    target_path, ConstraintsError, Correspondence, SurfaceRef,
};
use crate::engine::asset::Asset;
use crate::engine::spatial::Bvh;

/// A point on a surface.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SurfacePoint {
    /// Surface face.
    pub face: u32,
    /// Barycentric coordinates in the face.
    pub bary: [f32; 3],
    /// World-space position on the surface.
    pub position: [f32; 3],
}

/// A correspondence with both ends on the surfaces.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ResolvedCorrespondence {
    /// The source end.
    pub source: SurfacePoint,
    /// The target end(s).
    pub targets: Vec<SurfacePoint>,
}

/// One side of the resolution: an asset, the BVH of its surface, and the absolute snap tolerance.
pub struct Side<'a> {
    /// The asset whose indices the places use.
    pub asset: &'a Asset,
    /// BVH over its welded world-space surface.
    pub bvh: &'a Bvh,
    /// Largest distance from a given point to the surface, in world units.
    pub tolerance: f32,
}

/// [`resolve`] onto two welded surfaces (with their BVHs), the snap tolerance given as a fraction
/// of each surface's bounding-box diagonal.
pub fn resolve_on_surfaces(
    correspondences: &[Correspondence],
    source: (&Asset, &Bvh, &crate::engine::mesh::Surface),
    target: (&Asset, &Bvh, &crate::engine::mesh::Surface),
    snap_tolerance: f32,
) -> Result<Vec<ResolvedCorrespondence>, ConstraintsError> {
    resolve(
        correspondences,
        &Side {
            asset: source.0,
            bvh: source.1,
            tolerance: snap_tolerance * source.2.diagonal(),
        },
        &Side {
            asset: target.0,
            bvh: target.1,
            tolerance: snap_tolerance * target.2.diagonal(),
        },
    )
}

/// Resolves every correspondence onto the two sides.
pub fn resolve(
    correspondences: &[Correspondence],
    source: &Side<'_>,
    target: &Side<'_>,
) -> Result<Vec<ResolvedCorrespondence>, ConstraintsError> {
    correspondences
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let s = resolve_ref(&c.source, source, &format!("correspondences[{i}].source"))?;
            let targets = c
                .target
                .as_slice()
                .iter()
                .enumerate()
                .map(|(j, t)| resolve_ref(t, target, &target_path(i, j, c.target.is_list())))
                .collect::<Result<Vec<_>, _>>()?;
            Ok(ResolvedCorrespondence { source: s, targets })
        })
        .collect()
}

/// The world-space point a place names, before snapping.
pub fn world_point(
    r: &SurfaceRef,
    asset: &Asset,
    path: &str,
) -> Result<[f64; 3], ConstraintsError> {
    let find = |mesh: usize, primitive: usize| {
        let p = asset
            .primitives
            .iter()
            .position(|p| p.mesh == mesh && p.primitive == primitive)
            .ok_or_else(|| {
                ConstraintsError::new(
                    format!("{path}.primitive"),
                    format!("mesh {mesh} has no triangle primitive {primitive}"),
                )
            })?;
        let inst = asset
            .instances
            .iter()
            .find(|i| i.mesh == mesh)
            .ok_or_else(|| {
                ConstraintsError::new(
                    format!("{path}.mesh"),
                    format!("mesh {mesh} is not used by the scene"),
                )
            })?;
        Ok::<_, ConstraintsError>((p, inst))
    };
    match r {
        SurfaceRef::Point { point } => Ok(*point),
        SurfaceRef::Triangle {
            mesh,
            primitive,
            triangle,
            barycentric,
        } => {
            let (p, inst) = find(*mesh, *primitive)?;
            let prim = &asset.primitives[p];
            let tri = prim.triangles.get(*triangle).ok_or_else(|| {
                ConstraintsError::new(
                    format!("{path}.triangle"),
                    format!(
                        "triangle {triangle} is out of range: the primitive has {} triangles",
                        prim.triangles.len()
                    ),
                )
            })?;
            let mut out = [0.0; 3];
            for k in 0..3 {
                let w = inst.transform_point(prim.positions[tri[k] as usize]);
                for (o, c) in out.iter_mut().zip(w) {
                    *o += barycentric[k] * c;
                }
            }
            Ok(out)
        }
        SurfaceRef::Vertex { vertex } => {
            let (p, inst) = find(vertex.mesh, vertex.primitive)?;
            let prim = &asset.primitives[p];
            let pos = prim.positions.get(vertex.index).ok_or_else(|| {
                ConstraintsError::new(
                    format!("{path}.vertex.index"),
                    format!(
                        "vertex {} is out of range: the primitive has {} vertices",
                        vertex.index,
                        prim.positions.len()
                    ),
                )
            })?;
            Ok(inst.transform_point(*pos))
        }
    }
}

fn resolve_ref(
    r: &SurfaceRef,
    side: &Side<'_>,
    path: &str,
) -> Result<SurfacePoint, ConstraintsError> {
    let w = world_point(r, side.asset, path)?;
    let p = [w[0] as f32, w[1] as f32, w[2] as f32];
    let hit = side
        .bvh
        .closest_point(p, f32::INFINITY)
        .ok_or_else(|| ConstraintsError::new(path, "the mesh has no surface"))?;
    let d = hit.distance_squared.sqrt();
    if d > side.tolerance {
        let field = if matches!(r, SurfaceRef::Point { .. }) {
            format!("{path}.point")
        } else {
            path.to_string()
        };
        return Err(ConstraintsError::new(
            field,
            format!(
                "point is {d:.6} from the surface, farther than the snap tolerance of {:.6}",
                side.tolerance
            ),
        ));
    }
    Ok(SurfacePoint {
        face: hit.face,
        bary: hit.bary,
        position: hit.point,
    })
}
