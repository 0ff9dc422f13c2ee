//! The [`Surface`]: every triangle of an [`Asset`] in world space, welded into one indexed mesh.
//!
//! [`build_surface`] walks `asset.instances × asset.primitives_of_mesh(instance.mesh)`, transforms
//! each referenced vertex with [`MeshInstance::transform_point`](crate::engine::asset::MeshInstance)
//! (f64 products, stored as f32), merges vertices whose positions lie within the weld tolerance of
//! each other (position only, so vertices duplicated along UV and normal seams merge), and drops
//! triangles that became degenerate. Every face keeps a link back to the triangle it came from
//! ([`FaceOrigin`]) and every face corner to the original vertex ([`Corner`]), so results can be
//! written back into the asset.
//!
//! Conventions:
//! - Units: world units of the asset (glTF: metres); the weld tolerance is absolute world units.
//! - Winding: faces are counter-clockwise seen from the side their normal points to
//!   (`n = (b - a) × (c - a)`, right-handed). Triangles of mirroring instances (negative
//!   determinant, [`MeshInstance::mirrors`](crate::engine::asset::MeshInstance::mirrors)) have
//!   their winding flipped (corners 1 and 2 swapped) so normals keep pointing outward.
//! - Order: faces are ordered by (instance, primitive, triangle); welded vertices by the first
//!   corner that refers to them in that order.
//! - Welding is greedy and sequential over the corners in that order: a vertex joins the nearest
//!   already-created welded vertex within the tolerance (grid hashing with cells of four times the
//!   tolerance), else it starts a new one at its own position. The result is therefore independent of the
//!   thread count. With tolerance 0 only bit-identical positions merge (`-0.0 == 0.0`).
//! - A triangle is degenerate when two of its corners weld to the same vertex, or when its area is
//!   zero: `|(b - a) × (c - a)|` (in f64) at most `f32::EPSILON² · (longest edge)²`.
//!
//! Written by hand: welding with back-links to glTF corners is specific to this crate.

use std::collections::HashMap;

use rayon::prelude::*;

use crate::engine::asset::Asset;
use crate::engine::math::{cross, dot, normalize, sub, to_f32};

/// Where one corner of a surface face came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Corner {
    /// Index into [`Asset::instances`].
    pub instance: u32,
    /// Index into [`Asset::primitives`].
    pub primitive: u32,
    /// Vertex index within that primitive.
    pub vertex: u32,
}

/// Which triangle of which primitive instance a surface face came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FaceOrigin {
    /// Index into [`Asset::instances`].
    pub instance: u32,
    /// Index into [`Asset::primitives`].
    pub primitive: u32,
    /// Index into that primitive's `triangles`.
    pub triangle: u32,
}

/// All triangles of an asset in world space, welded. See the module docs for conventions.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    /// Welded vertex positions, world space. Every vertex is used by at least one face (for
    /// surfaces from [`build_surface`]).
    pub positions: Vec<[f32; 3]>,
    /// Vertex indices per face, counter-clockwise (winding flipped for mirroring instances).
    pub faces: Vec<[u32; 3]>,
    /// Per face, per corner: the original vertex it came from. Empty for
    /// [`Surface::from_triangles`].
    pub corners: Vec<[Corner; 3]>,
    /// Per face: the original triangle. Empty for [`Surface::from_triangles`].
    pub origins: Vec<FaceOrigin>,
    /// Triangles dropped because a vertex repeated after welding or the area was zero.
    pub degenerate_removed: usize,
    /// The absolute weld tolerance used, world units.
    pub weld_tolerance: f32,
}

/// Parameters of [`build_surface`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WeldParams {
    /// Weld distance as a fraction of the bounding-box diagonal of the instanced triangles.
    /// Default: 1e-6. Range: [0, 1e-2]; 0 merges only identical positions.
    pub relative_tolerance: f32,
}

impl Default for WeldParams {
    fn default() -> Self {
        Self {
            relative_tolerance: 1e-6,
        }
    }
}

/// Errors of the mesh module.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The scene instantiates no triangles at all.
    #[error("the scene has no triangles")]
    EmptySurface,
    /// Every triangle was degenerate.
    #[error("all {removed} triangles are degenerate (repeated vertex or zero area)")]
    AllDegenerate {
        /// How many triangles were dropped.
        removed: usize,
    },
    /// A parameter is outside its documented range.
    #[error("parameter {name} = {value} is out of range {range}")]
    InvalidParam {
        /// Parameter name.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// The valid range, as text.
        range: &'static str,
    },
    /// A triangle refers to a vertex its primitive does not have.
    #[error(
        "primitive {primitive} triangle {triangle}: vertex index {index} >= vertex count {count}"
    )]
    VertexIndexOutOfRange {
        /// Index into the asset's primitives.
        primitive: usize,
        /// Triangle index in that primitive.
        triangle: usize,
        /// The offending vertex index.
        index: u32,
        /// The primitive's vertex count.
        count: usize,
    },
    /// A vertex is not finite after the instance transform.
    #[error(
        "instance {instance} primitive {primitive} vertex {vertex}: world position is not finite"
    )]
    NonFinitePosition {
        /// Index into the asset's instances.
        instance: usize,
        /// Index into the asset's primitives.
        primitive: usize,
        /// Vertex index in that primitive.
        vertex: u32,
    },
    /// The surface has more vertices or faces than 32-bit indices can address.
    #[error("the scene has {count} {what}, more than 32-bit indices can address")]
    TooLarge {
        /// `"vertices"` or `"triangles"`.
        what: &'static str,
        /// The count.
        count: usize,
    },
}

/// One (instance, primitive) pair with its world-space vertices and raw triangles.
struct Piece {
    instance: u32,
    primitive: u32,
    /// Primitive vertex index of each used vertex, in first-use order.
    vertices: Vec<u32>,
    /// World position of each used vertex.
    world: Vec<[f32; 3]>,
    /// Triangles as indices into `vertices`, winding already flipped for mirroring instances.
    triangles: Vec<[u32; 3]>,
}

/// Builds the welded world-space [`Surface`] of every mesh instance of `asset`.
///
/// # Errors
/// [`MeshError::InvalidParam`] for a tolerance outside [0, 1e-2]; [`MeshError::EmptySurface`] when
/// the scene has no triangles; [`MeshError::AllDegenerate`] when none survive;
/// [`MeshError::VertexIndexOutOfRange`] / [`MeshError::NonFinitePosition`] for broken input;
/// [`MeshError::TooLarge`] beyond `u32` indices.
pub fn build_surface(asset: &Asset, params: &WeldParams) -> Result<Surface, MeshError> {
    let rel = params.relative_tolerance;
    if !(rel.is_finite() && (0.0..=1e-2).contains(&rel)) {
        return Err(MeshError::InvalidParam {
            name: "relative_tolerance",
            value: rel as f64,
            range: "[0, 1e-2]",
        });
    }
    let pairs: Vec<(usize, usize)> = asset
        .instances
        .iter()
        .enumerate()
        .flat_map(|(i, inst)| asset.primitives_of_mesh(inst.mesh).map(move |p| (i, p)))
        .collect();
    let total_triangles: usize = pairs
        .iter()
        .map(|&(_, p)| asset.primitives[p].triangles.len())
        .sum();
    if total_triangles == 0 {
        return Err(MeshError::EmptySurface);
    }
    if total_triangles > u32::MAX as usize {
        return Err(MeshError::TooLarge {
            what: "triangles",
            count: total_triangles,
        });
    }
    let pieces: Vec<Piece> = pairs
        .par_iter()
        .map(|&(i, p)| make_piece(asset, i, p))
        .collect::<Result<_, _>>()?;
    let raw_vertices: usize = pieces.iter().map(|pc| pc.world.len()).sum();
    if raw_vertices > u32::MAX as usize {
        return Err(MeshError::TooLarge {
            what: "vertices",
            count: raw_vertices,
        });
    }

    // Bounding box of all used vertices (exact min/max, order independent).
    let (lo, hi) = pieces.iter().flat_map(|pc| pc.world.iter()).fold(
        ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
            )
        },
    );
    let diag = (0..3)
        .map(|k| ((hi[k] - lo[k]) as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let tolerance = (rel as f64 * diag) as f32;

    // Weld: every used vertex of every piece gets a welded index.
    let mut welder = Welder::new(tolerance);
    let piece_maps: Vec<Vec<u32>> = pieces
        .iter()
        .map(|pc| pc.world.iter().map(|p| welder.insert(*p)).collect())
        .collect();
    let welded_positions = welder.positions;

    // Faces, with degenerate ones dropped. Per piece in parallel, concatenated in order.
    type PieceFaces = (Vec<[u32; 3]>, Vec<[Corner; 3]>, Vec<FaceOrigin>);
    let per_piece: Vec<PieceFaces> = pieces
        .par_iter()
        .zip(piece_maps.par_iter())
        .map(|(pc, map)| {
            let mut faces = Vec::with_capacity(pc.triangles.len());
            let mut corners = Vec::with_capacity(pc.triangles.len());
            let mut origins = Vec::with_capacity(pc.triangles.len());
            for (t, tri) in pc.triangles.iter().enumerate() {
                let f = [
                    map[tri[0] as usize],
                    map[tri[1] as usize],
                    map[tri[2] as usize],
                ];
                if is_degenerate(&welded_positions, f) {
                    continue;
                }
                faces.push(f);
                corners.push(tri.map(|k| Corner {
                    instance: pc.instance,
                    primitive: pc.primitive,
                    vertex: pc.vertices[k as usize],
                }));
                origins.push(FaceOrigin {
                    instance: pc.instance,
                    primitive: pc.primitive,
                    triangle: t as u32,
                });
            }
            (faces, corners, origins)
        })
        .collect();
    let mut faces = Vec::with_capacity(total_triangles);
    let mut corners = Vec::with_capacity(total_triangles);
    let mut origins = Vec::with_capacity(total_triangles);
    for (f, c, o) in per_piece {
        faces.extend(f);
        corners.extend(c);
        origins.extend(o);
    }
    let degenerate_removed = total_triangles - faces.len();
    if faces.is_empty() {
        return Err(MeshError::AllDegenerate {
            removed: degenerate_removed,
        });
    }

    // Drop welded vertices that only degenerate faces used; keep first-use order.
    let mut remap = vec![u32::MAX; welded_positions.len()];
    let mut positions = Vec::with_capacity(welded_positions.len());
    for f in &mut faces {
        for v in f.iter_mut() {
            let r = &mut remap[*v as usize];
            if *r == u32::MAX {
                *r = positions.len() as u32;
                positions.push(welded_positions[*v as usize]);
            }
            *v = *r;
        }
    }
    Ok(Surface {
        positions,
        faces,
        corners,
        origins,
        degenerate_removed,
        weld_tolerance: tolerance,
    })
}

/// Transforms the used vertices of one primitive instance and re-indexes its triangles.
fn make_piece(asset: &Asset, instance: usize, primitive: usize) -> Result<Piece, MeshError> {
    let inst = &asset.instances[instance];
    let prim = &asset.primitives[primitive];
    let mirror = inst.mirrors();
    let mut local = vec![u32::MAX; prim.positions.len()];
    let mut vertices = Vec::new();
    let mut world = Vec::new();
    let mut triangles = Vec::with_capacity(prim.triangles.len());
    for (t, tri) in prim.triangles.iter().enumerate() {
        let mut out = [0u32; 3];
        for (k, &v) in tri.iter().enumerate() {
            let slot = local
                .get_mut(v as usize)
                .ok_or(MeshError::VertexIndexOutOfRange {
                    primitive,
                    triangle: t,
                    index: v,
                    count: prim.positions.len(),
                })?;
            if *slot == u32::MAX {
                let w = inst.transform_point(prim.positions[v as usize]);
                let w = [w[0] as f32, w[1] as f32, w[2] as f32];
                if !w.iter().all(|c| c.is_finite()) {
                    return Err(MeshError::NonFinitePosition {
                        instance,
                        primitive,
                        vertex: v,
                    });
                }
                *slot = vertices.len() as u32;
                vertices.push(v);
                world.push(w);
            }
            out[k] = *slot;
        }
        if mirror {
            out.swap(1, 2);
        }
        triangles.push(out);
    }
    Ok(Piece {
        instance: instance as u32,
        primitive: primitive as u32,
        vertices,
        world,
        triangles,
    })
}

/// Whether a welded face repeats a vertex or has zero area (see the module docs).
fn is_degenerate(positions: &[[f32; 3]], f: [u32; 3]) -> bool {
    if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
        return true;
    }
    let p = f.map(|v| positions[v as usize].map(|c| c as f64));
    let e1 = sub(p[1], p[0]);
    let e2 = sub(p[2], p[0]);
    let e3 = sub(p[2], p[1]);
    let n = cross(e1, e2);
    let n2 = dot(n, n);
    let longest2 = dot(e1, e1).max(dot(e2, e2)).max(dot(e3, e3));
    let eps = (f32::EPSILON as f64).powi(2);
    // |n| <= eps * longest², compared squared.
    n2 <= eps * eps * longest2 * longest2
}

/// A fast, deterministic hasher for small integer keys (multiply-rotate, as in rustc's FxHash).
#[derive(Default, Clone, Copy)]
struct KeyHasher(u64);

impl std::hash::Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, x: i64) {
        self.write_u64(x as u64);
    }
    fn write_u32(&mut self, x: u32) {
        self.write_u64(x as u64);
    }
    fn write_usize(&mut self, x: usize) {
        self.write_u64(x as u64);
    }
}

type KeyMap<K, V> = HashMap<K, V, std::hash::BuildHasherDefault<KeyHasher>>;

/// Cell edge length of the weld grid, in multiples of the tolerance. Welded vertices are at least
/// one tolerance apart, so a cell holds a bounded number of them; a query point looks at its own
/// cell plus, per axis, the neighbour it is within one tolerance of (on average 1.5³ cells).
const CELL_OVER_TOLERANCE: f64 = 4.0;

/// Greedy grid-hash welder (see the module docs).
struct Welder {
    tolerance: f32,
    inv_cell: f64,
    positions: Vec<[f32; 3]>,
    /// tolerance > 0: cell → welded vertices whose position lies in it.
    cells: KeyMap<[i64; 3], Vec<u32>>,
    /// tolerance == 0: exact bit pattern → welded vertex.
    exact: KeyMap<[u32; 3], u32>,
}

impl Welder {
    fn new(tolerance: f32) -> Self {
        let inv_cell = if tolerance > 0.0 {
            1.0 / (CELL_OVER_TOLERANCE * tolerance as f64)
        } else {
            0.0
        };
        Self {
            tolerance,
            inv_cell,
            positions: Vec::new(),
            cells: KeyMap::default(),
            exact: KeyMap::default(),
        }
    }

    /// Returns the welded index for `p`, creating a new welded vertex if none is within tolerance.
    fn insert(&mut self, p: [f32; 3]) -> u32 {
        if self.tolerance <= 0.0 {
            // Normalize -0.0 to 0.0 so they merge.
            let key = p.map(|c| (c + 0.0).to_bits());
            let next = self.positions.len() as u32;
            let id = *self.exact.entry(key).or_insert(next);
            if id == next {
                self.positions.push(p);
            }
            return id;
        }
        let scaled = p.map(|c| c as f64 * self.inv_cell);
        let cell = scaled.map(|x| x.floor() as i64);
        // Per axis: which neighbouring cells can hold a point within tolerance.
        let reach = 1.0 / CELL_OVER_TOLERANCE + 1e-9;
        let span = |k: usize| {
            let frac = scaled[k] - scaled[k].floor();
            let lo = if frac < reach { -1 } else { 0 };
            let hi = if frac > 1.0 - reach { 1 } else { 0 };
            lo..=hi
        };
        let tol2 = self.tolerance as f64 * self.tolerance as f64;
        let mut best: Option<(f64, u32)> = None;
        for dx in span(0) {
            for dy in span(1) {
                for dz in span(2) {
                    let Some(list) = self.cells.get(&[cell[0] + dx, cell[1] + dy, cell[2] + dz])
                    else {
                        continue;
                    };
                    for &id in list {
                        let q = self.positions[id as usize];
                        let d2 = (0..3)
                            .map(|k| (p[k] as f64 - q[k] as f64).powi(2))
                            .sum::<f64>();
                        if d2 <= tol2
                            && best.is_none_or(|(bd, bid)| d2 < bd || (d2 == bd && id < bid))
                        {
                            best = Some((d2, id));
                        }
                    }
                }
            }
        }
        if let Some((_, id)) = best {
            return id;
        }
        let id = self.positions.len() as u32;
        self.positions.push(p);
        self.cells.entry(cell).or_default().push(id);
        id
    }
}

impl Surface {
    /// A surface straight from positions and faces: no welding, no degenerate removal, no
    /// back-links (`corners` and `origins` empty). For analytic shapes and tests.
    ///
    /// # Panics
    /// If a face refers to a vertex index `>= positions.len()` (a programming error).
    pub fn from_triangles(positions: Vec<[f32; 3]>, faces: Vec<[u32; 3]>) -> Surface {
        let n = positions.len();
        for (i, f) in faces.iter().enumerate() {
            assert!(
                f.iter().all(|&v| (v as usize) < n),
                "face {i} {f:?} refers past {n} vertices"
            );
        }
        Surface {
            positions,
            faces,
            corners: Vec::new(),
            origins: Vec::new(),
            degenerate_removed: 0,
            weld_tolerance: 0.0,
        }
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of faces.
    pub fn face_count(&self) -> usize {
        self.faces.len()
    }

    /// The three corner positions of `face`.
    pub fn face_positions(&self, face: usize) -> [[f32; 3]; 3] {
        self.faces[face].map(|v| self.positions[v as usize])
    }

    /// The distance from `p` to `face`, widened by a relative 1e-4 (and 1e-12) so that a
    /// closest-point search bounded by it still finds that face and any tie: the warm-start
    /// bound of texel-by-texel closest-point queries, where `face` was the previous texel's hit.
    pub fn hint_bound(&self, face: usize, p: [f32; 3]) -> f32 {
        let [a, b, c] = self.face_positions(face);
        let (d2, _, _) = crate::engine::spatial::point_triangle_distance_squared(p, a, b, c);
        d2.sqrt() * (1.0 + 1e-4) + 1e-12
    }

    /// The point with barycentric coordinates `bary` (weights of corners 0, 1, 2) on `face`.
    pub fn face_point(&self, face: usize, bary: [f32; 3]) -> [f32; 3] {
        let [a, b, c] = self.face_positions(face);
        std::array::from_fn(|k| bary[0] * a[k] + bary[1] * b[k] + bary[2] * c[k])
    }

    /// Where the point `bary` of `face` lies on the asset's own triangle: `(primitive, triangle,
    /// barycentrics in that triangle's vertex order)`. The face's corner order may differ from
    /// the triangle's (winding flipped for mirroring instances), so the weights are permuted by
    /// matching each corner's original vertex. None for a surface without origins
    /// ([`Surface::from_triangles`]) or a face out of range.
    pub fn primitive_point(
        &self,
        asset: &Asset,
        face: usize,
        bary: [f32; 3],
    ) -> Option<(usize, usize, [f32; 3])> {
        let o = *self.origins.get(face)?;
        let corners = self.corners.get(face)?;
        let (primitive, triangle) = (o.primitive as usize, o.triangle as usize);
        let tri = *asset.primitives.get(primitive)?.triangles.get(triangle)?;
        let mut b = [0.0f32; 3];
        for k in 0..3 {
            if let Some(j) = tri.iter().position(|v| *v == corners[k].vertex) {
                b[j] += bary[k];
            }
        }
        Some((primitive, triangle, b))
    }

    /// Unit normal of `face` from its winding (`(b - a) × (c - a)`, normalized); `[0, 0, 0]` for a
    /// face of zero area.
    pub fn face_normal(&self, face: usize) -> [f32; 3] {
        to_f32(normalize(self.face_cross(face)))
    }

    /// Area of `face`, world units squared.
    pub fn face_area(&self, face: usize) -> f32 {
        let n = self.face_cross(face);
        (0.5 * dot(n, n).sqrt()) as f32
    }

    fn face_cross(&self, face: usize) -> [f64; 3] {
        let p = self.face_positions(face).map(|v| v.map(|c| c as f64));
        cross(sub(p[1], p[0]), sub(p[2], p[0]))
    }

    /// Angle-weighted vertex normals (Thürmer & Wüthrich 1998): the sum over incident faces of
    /// the face normal times the corner angle, normalized. `[0, 0, 0]` for vertices without a
    /// non-degenerate face.
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        let mut acc = vec![[0.0f64; 3]; self.positions.len()];
        for f in &self.faces {
            let p = f.map(|v| self.positions[v as usize].map(|c| c as f64));
            let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
            let len = dot(n, n).sqrt();
            if len <= 0.0 || !len.is_finite() {
                continue;
            }
            let n = n.map(|c| c / len);
            for k in 0..3 {
                let e1 = sub(p[(k + 1) % 3], p[k]);
                let e2 = sub(p[(k + 2) % 3], p[k]);
                let angle = dot(cross(e1, e2), n).atan2(dot(e1, e2));
                let a = &mut acc[f[k] as usize];
                for j in 0..3 {
                    a[j] += angle * n[j];
                }
            }
        }
        acc.into_iter()
            .map(|n| {
                let len = dot(n, n).sqrt();
                if len > 0.0 {
                    n.map(|c| (c / len) as f32)
                } else {
                    [0.0; 3]
                }
            })
            .collect()
    }

    /// Axis-aligned bounding box (min, max) of all vertices; `([0; 3], [0; 3])` when empty.
    pub fn bounding_box(&self) -> ([f32; 3], [f32; 3]) {
        if self.positions.is_empty() {
            return ([0.0; 3], [0.0; 3]);
        }
        self.positions.iter().fold(
            ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
            |(lo, hi), p| {
                (
                    std::array::from_fn(|k| lo[k].min(p[k])),
                    std::array::from_fn(|k| hi[k].max(p[k])),
                )
            },
        )
    }

    /// Length of the bounding-box diagonal, world units.
    pub fn diagonal(&self) -> f32 {
        let (lo, hi) = self.bounding_box();
        (0..3)
            .map(|k| ((hi[k] - lo[k]) as f64).powi(2))
            .sum::<f64>()
            .sqrt() as f32
    }

    /// Total area, world units squared (summed in f64).
    pub fn area(&self) -> f64 {
        (0..self.faces.len())
            .map(|f| {
                let n = self.face_cross(f);
                0.5 * dot(n, n).sqrt()
            })
            .sum()
    }

    /// Map from original triangle to surface face. Triangles removed as degenerate are absent.
    /// Empty for surfaces from [`Surface::from_triangles`].
    pub fn face_lookup(&self) -> HashMap<FaceOrigin, u32> {
        self.origins
            .iter()
            .enumerate()
            .map(|(i, o)| (*o, i as u32))
            .collect()
    }
}
