//! The multiresolution mesh hierarchy of MeshMatch (Chen, Funkhouser, Goldman, Shechtman 2012,
//! §4): levels built by iterative shortest-edge-first collapse to the midpoint, each with about
//! half the vertices of the previous, down to about 128 vertices, and the vertex tree linking
//! them. It serves the three traversals of §4.2: projecting a fine vertex onto the coarser level
//! (upsampling, Figure 6), drawing a uniformly random descendant `j` levels down (random search,
//! Figure 4), and prolongating per-vertex fields from coarse to fine.
//!
//! Conventions:
//! - Level 0 is the input surface (same vertex and face numbering); level `l + 1` is coarser than
//!   level `l`. "Parent" points one level coarser, "children" one level finer.
//! - Every vertex of level `l` has exactly one parent on level `l + 1`: the vertex its collapse
//!   group merged into. Every coarse vertex has at least one child.
//! - Projections are the closest point ([`Bvh::closest_point`]) of the fine vertex's position on
//!   the coarser level's triangles, as (face of the coarser level, barycentric weights of its
//!   corners). Prolongation interpolates barycentrically at that point.
//! - Positions are in the input's units; the collapse rules are in [`super::collapse`].
//! - Deterministic: the collapses are sequential in a total order; the projections are
//!   independent per vertex. The result is identical for any thread count.

use rayon::prelude::*;

use super::collapse::{decimate, CollapseRules};
use super::vertex_tree::{build_tree, descendant_range, TreeLevel};
use super::FacePoint;
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::csr::vertex_faces;
use crate::engine::mesh::Surface;
use crate::engine::rng::SplitMix64;
use crate::engine::spatial::{closest_point_on_triangle, Bvh};

/// Parameters of [`build_hierarchy`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HierarchyParams {
    /// Vertex count of each level as a fraction of the previous level's. Default: 0.5 (the
    /// paper's "approximately half"). Range: [0.2, 0.8].
    pub target_ratio: f32,
    /// Size of the coarsest level: a further level is built only while its target
    /// (`round(n · target_ratio)`) is at least `0.75 · min_vertices`, so with the default ratio
    /// the coarsest level has about 0.75 to 1.5 times this many vertices. Default: 128 (the
    /// paper's "approximately 128"). Range: 4..=1,000,000.
    pub min_vertices: usize,
    /// Smallest allowed triangle quality `4√3·area / Σ edge²` (1 = equilateral) of the worst face
    /// a collapse leaves around its edge, unless the worst face there was already worse. Default:
    /// 0.2. Range: [0, 0.9].
    pub min_triangle_quality: f32,
    /// Largest allowed rotation of a face normal by one collapse, degrees (anything above 90
    /// still forbids flips). Default: 60. Range: (0, 150].
    pub max_normal_change_degrees: f32,
    /// A boundary edge collapses (to its midpoint) only where the boundary turns by at most this
    /// many degrees at both of its ends, so boundary corners stay put and the boundary does not
    /// shrink. Default: 20. Range: [0, 90].
    pub max_boundary_turn_degrees: f32,
}

impl Default for HierarchyParams {
    fn default() -> Self {
        Self {
            target_ratio: 0.5,
            min_vertices: 128,
            min_triangle_quality: 0.2,
            max_normal_change_degrees: 60.0,
            max_boundary_turn_degrees: 20.0,
        }
    }
}

/// Errors of [`build_hierarchy`].
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum HierarchyError {
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
    /// A vertex is used by no face (it would have no place in the vertex tree).
    #[error("vertex {vertex} is used by no face")]
    UnreferencedVertex {
        /// The vertex index.
        vertex: usize,
    },
    /// A vertex position is not finite.
    #[error("vertex {vertex} has a non-finite position")]
    NonFinitePosition {
        /// The vertex index.
        vertex: usize,
    },
    /// The surface has no faces.
    #[error("the surface has no faces")]
    Empty,
    /// Cancelled through the [`Control`].
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for HierarchyError {
    fn from(_: Cancelled) -> Self {
        HierarchyError::Cancelled
    }
}

/// One level of the hierarchy.
#[derive(Clone, Debug)]
pub struct Level {
    /// The level's mesh (level 0: a copy of the input's positions and faces).
    pub surface: Surface,
    /// Parent on the next coarser level of every vertex; empty on the coarsest level.
    pub parent: Vec<u32>,
    /// Closest point on the next coarser level of every vertex; empty on the coarsest level.
    pub projection: Vec<FacePoint>,
}

/// The hierarchy: levels from fine (0) to coarse, and the vertex tree. See the module docs.
#[derive(Clone, Debug)]
pub struct Hierarchy {
    levels: Vec<Level>,
    tree: Vec<TreeLevel>,
}

/// Builds the hierarchy of `surface` (MeshMatch §4). Every vertex must be used by a face. A
/// surface with too few vertices gives a single level. A level may stop short of its target
/// when no admissible collapse is left (locked or tightly constrained regions); building stops
/// after a level that removed less than a quarter of its vertices.
///
/// # Errors
/// [`HierarchyError::InvalidParam`], [`HierarchyError::Empty`],
/// [`HierarchyError::UnreferencedVertex`], [`HierarchyError::NonFinitePosition`] for bad input;
/// [`HierarchyError::Cancelled`] when `control` is cancelled.
pub fn build_hierarchy(
    surface: &Surface,
    params: &HierarchyParams,
    control: &Control,
) -> Result<Hierarchy, HierarchyError> {
    check_params(params)?;
    if surface.faces.is_empty() {
        return Err(HierarchyError::Empty);
    }
    let mut used = vec![false; surface.positions.len()];
    for f in &surface.faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    if let Some(v) = used.iter().position(|u| !u) {
        return Err(HierarchyError::UnreferencedVertex { vertex: v });
    }
    if let Some(v) = surface
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(HierarchyError::NonFinitePosition { vertex: v });
    }
    let rules = CollapseRules {
        cos_max_normal_change: (params.max_normal_change_degrees as f64).to_radians().cos(),
        min_quality: params.min_triangle_quality as f64,
        cos_max_boundary_turn: (params.max_boundary_turn_degrees as f64).to_radians().cos(),
    };
    let ratio = params.target_ratio as f64;
    let floor = 0.75 * params.min_vertices as f64;
    // Work units: collapses; the levels remove n0·(1 - r)·(1 + r + r² + …) ≈ n0 vertices.
    let stage = control.stage("hierarchy", surface.positions.len().max(1) as u64)?;

    let mut levels = vec![Level {
        surface: Surface::from_triangles(surface.positions.clone(), surface.faces.clone()),
        parent: Vec::new(),
        projection: Vec::new(),
    }];
    loop {
        let fine = &levels.last().expect("one level").surface;
        let n = fine.positions.len();
        let target = (n as f64 * ratio).round();
        if target < floor {
            break;
        }
        let d = decimate(
            &fine.positions,
            &fine.faces,
            target as usize,
            &rules,
            &stage,
        )?;
        let coarse = Surface::from_triangles(d.positions, d.faces);
        let projection = project(fine, &coarse, &d.parent, control)?;
        let reduced = coarse.positions.len() as f64 / n as f64;
        let last = levels.last_mut().expect("one level");
        last.parent = d.parent;
        last.projection = projection;
        levels.push(Level {
            surface: coarse,
            parent: Vec::new(),
            projection: Vec::new(),
        });
        if reduced > 0.75 {
            break;
        }
    }
    control.check()?;
    let parents: Vec<&[u32]> = levels.iter().map(|l| l.parent.as_slice()).collect();
    let counts: Vec<usize> = levels.iter().map(|l| l.surface.positions.len()).collect();
    let tree = build_tree(&parents[..parents.len() - 1], &counts);
    Ok(Hierarchy { levels, tree })
}

fn check_params(p: &HierarchyParams) -> Result<(), HierarchyError> {
    let bad = |name, value: f64, range| Err(HierarchyError::InvalidParam { name, value, range });
    if !(0.2..=0.8).contains(&p.target_ratio) {
        return bad("target_ratio", p.target_ratio as f64, "[0.2, 0.8]");
    }
    if !(4..=1_000_000).contains(&p.min_vertices) {
        return bad("min_vertices", p.min_vertices as f64, "4..=1000000");
    }
    if !(0.0..=0.9).contains(&p.min_triangle_quality) {
        return bad(
            "min_triangle_quality",
            p.min_triangle_quality as f64,
            "[0, 0.9]",
        );
    }
    let t = p.max_boundary_turn_degrees;
    if !(0.0..=90.0).contains(&t) {
        return bad("max_boundary_turn_degrees", t as f64, "[0, 90]");
    }
    let a = p.max_normal_change_degrees;
    if !(a > 0.0 && a <= 150.0) {
        return bad("max_normal_change_degrees", a as f64, "(0, 150]");
    }
    Ok(())
}

/// Closest point on `coarse` of every vertex of `fine`, in parallel blocks (each block checks
/// for cancellation). The distance to the faces around the vertex's parent bounds the BVH search
/// (the result is the exact closest point all the same; ties go to the lowest face index).
fn project(
    fine: &Surface,
    coarse: &Surface,
    parent: &[u32],
    control: &Control,
) -> Result<Vec<FacePoint>, Cancelled> {
    let bvh = Bvh::build(&coarse.positions, &coarse.faces);
    // Coarse vertex → faces (CSR).
    let (offsets, vfaces) = vertex_faces(coarse);
    let query = |v: usize, p: [f32; 3]| -> FacePoint {
        let u = parent[v] as usize;
        let mut bound = f32::INFINITY;
        for &f in &vfaces[offsets[u] as usize..offsets[u + 1] as usize] {
            let [a, b, c] = coarse.face_positions(f as usize);
            let (q, _) = closest_point_on_triangle(p, a, b, c);
            let d2 = (0..3).map(|k| (p[k] - q[k]) * (p[k] - q[k])).sum::<f32>();
            bound = bound.min(d2);
        }
        let limit = bound.sqrt() * (1.0 + 1e-5) + f32::MIN_POSITIVE;
        let hit = bvh
            .closest_point(p, limit)
            .or_else(|| bvh.closest_point(p, f32::INFINITY))
            .expect("the coarse level has faces");
        FacePoint {
            face: hit.face,
            bary: hit.bary,
        }
    };
    const BLOCK: usize = 4096;
    let blocks: Vec<Result<Vec<FacePoint>, Cancelled>> = fine
        .positions
        .par_chunks(BLOCK)
        .enumerate()
        .map(|(b, chunk)| {
            control.check()?;
            Ok(chunk
                .iter()
                .enumerate()
                .map(|(i, &p)| query(b * BLOCK + i, p))
                .collect())
        })
        .collect();
    let mut out = Vec::with_capacity(fine.positions.len());
    for b in blocks {
        out.extend(b?);
    }
    Ok(out)
}

impl Hierarchy {
    /// Number of levels (at least 1).
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// All levels, finest first.
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// Level `level` (0 = the input).
    pub fn level(&self, level: usize) -> &Level {
        &self.levels[level]
    }

    /// Parent of `vertex` of `level` on level `level + 1`; `None` on the coarsest level.
    pub fn parent(&self, level: usize, vertex: u32) -> Option<u32> {
        self.levels[level].parent.get(vertex as usize).copied()
    }

    /// Ancestor of `vertex` of `level`, `j` levels up.
    ///
    /// # Panics
    /// If `level + j` is past the coarsest level or `vertex` is out of range.
    pub fn ancestor(&self, level: usize, vertex: u32, j: usize) -> u32 {
        assert!(level + j < self.levels.len(), "no level {}", level + j);
        let mut v = vertex;
        for l in level..level + j {
            v = self.levels[l].parent[v as usize];
        }
        v
    }

    /// Children of `vertex` of `level` on level `level - 1` (ascending); empty on level 0.
    pub fn children(&self, level: usize, vertex: u32) -> &[u32] {
        if level == 0 {
            return &[];
        }
        self.descendants(level, vertex, 1)
    }

    /// All descendants of `vertex` of `level` on level `level - j` (`j = 0`: the vertex itself),
    /// in tree order.
    ///
    /// # Panics
    /// If `j > level` or `vertex` is out of range.
    pub fn descendants(&self, level: usize, vertex: u32, j: usize) -> &[u32] {
        assert!(j <= level, "cannot descend {j} levels from level {level}");
        let range = descendant_range(&self.tree, level, vertex, j);
        &self.tree[level - j].order[range]
    }

    /// A uniformly random descendant of `vertex` of `level`, `j` levels down (on level
    /// `level - j`): uniform over all of the subtree's vertices on that level (MeshMatch §4.2
    /// random search). Uses one draw of `rng`.
    ///
    /// # Panics
    /// If `j > level` or `vertex` is out of range.
    pub fn random_descendant(
        &self,
        level: usize,
        vertex: u32,
        j: usize,
        rng: &mut SplitMix64,
    ) -> u32 {
        let d = self.descendants(level, vertex, j);
        d[rng.below(d.len() as u64) as usize]
    }

    /// The closest point of `vertex` of `level` on level `level + 1`: face of level `level + 1`
    /// and barycentric weights.
    ///
    /// # Panics
    /// On the coarsest level or for a vertex out of range.
    pub fn project_to_coarser(&self, level: usize, vertex: u32) -> FacePoint {
        self.levels[level].projection[vertex as usize]
    }

    /// Interpolates a per-vertex field of level `coarse_level` onto level `coarse_level - 1`
    /// (barycentric at each fine vertex's projection).
    ///
    /// # Panics
    /// If `coarse_level` is 0 or past the coarsest level, or `field` does not have one value per
    /// vertex of `coarse_level`.
    pub fn prolongate<const N: usize>(
        &self,
        coarse_level: usize,
        field: &[[f32; N]],
    ) -> Vec<[f32; N]> {
        assert!(coarse_level >= 1, "level 0 has no finer level");
        let coarse = &self.levels[coarse_level].surface;
        assert_eq!(
            field.len(),
            coarse.positions.len(),
            "one value per coarse vertex"
        );
        self.levels[coarse_level - 1]
            .projection
            .par_iter()
            .map(|fp| {
                let face = coarse.faces[fp.face as usize];
                std::array::from_fn(|k| {
                    fp.bary[0] * field[face[0] as usize][k]
                        + fp.bary[1] * field[face[1] as usize][k]
                        + fp.bary[2] * field[face[2] as usize][k]
                })
            })
            .collect()
    }

    /// [`Hierarchy::prolongate`] for a flat field of `dim` floats per vertex.
    ///
    /// # Panics
    /// As [`Hierarchy::prolongate`], or if `field.len()` is not `dim` times the vertex count.
    pub fn prolongate_flat(&self, coarse_level: usize, dim: usize, field: &[f32]) -> Vec<f32> {
        assert!(coarse_level >= 1, "level 0 has no finer level");
        let coarse = &self.levels[coarse_level].surface;
        assert_eq!(
            field.len(),
            dim * coarse.positions.len(),
            "dim values per coarse vertex"
        );
        let proj = &self.levels[coarse_level - 1].projection;
        let mut out = vec![0.0f32; proj.len() * dim];
        if dim == 0 {
            return out;
        }
        out.par_chunks_mut(dim)
            .zip(proj.par_iter())
            .for_each(|(o, fp)| {
                let face = coarse.faces[fp.face as usize];
                for (c, &w) in face.iter().zip(&fp.bary) {
                    let src = &field[*c as usize * dim..(*c as usize + 1) * dim];
                    for (x, s) in o.iter_mut().zip(src) {
                        *x += w * s;
                    }
                }
            });
        out
    }
}
