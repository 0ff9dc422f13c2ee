//! The per-level structures MeshMatch works on (Chen et al. 2012, §4): the multiresolution
//! hierarchy of a synthesis mesh (levels of about half the vertices down to about 128, with the
//! vertex tree), and on every level the tangent frames of the fans, the 1-rings for propagation
//! and a BVH for upsampling. Per-vertex fields move between levels by barycentric prolongation
//! (coarse → fine) and by averaging the children (fine → coarse).

use rayon::prelude::*;

use crate::engine::control::Control;
use crate::engine::geometry::expmap::{local_frames, mean_edge_length, FrameParams, LocalFrames};
use crate::engine::mesh::csr::vertex_neighbours;
use crate::engine::mesh::Surface;
use crate::engine::multires::{build_hierarchy, Hierarchy, HierarchyError, HierarchyParams};
use crate::engine::spatial::Bvh;

/// One synthesis mesh with its hierarchy and per-level data.
pub struct MeshLevels {
    /// Levels 0 (the synthesis mesh) to coarsest.
    pub hierarchy: Hierarchy,
    /// Tangent frames per level (tangent from the `up` direction where defined).
    pub frames: Vec<LocalFrames>,
    /// 1-rings per level, CSR.
    pub adjacency: Vec<(Vec<u32>, Vec<u32>)>,
    /// BVH per level.
    pub bvh: Vec<Bvh>,
    /// Mean edge length per level, world units.
    pub mean_edge: Vec<f32>,
}

impl MeshLevels {
    /// Builds the hierarchy and the per-level data.
    ///
    /// # Errors
    /// [`HierarchyError`] for a bad surface or cancellation.
    pub fn build(
        surface: &Surface,
        min_vertices: usize,
        up: Option<[f32; 3]>,
        control: &Control,
    ) -> Result<Self, HierarchyError> {
        let hierarchy = build_hierarchy(
            surface,
            &HierarchyParams {
                min_vertices,
                ..Default::default()
            },
            control,
        )?;
        control.check()?;
        let per_level: Vec<_> = hierarchy
            .levels()
            .par_iter()
            .map(|l| {
                let s = &l.surface;
                (
                    local_frames(
                        s,
                        &FrameParams {
                            up,
                            ..Default::default()
                        },
                    ),
                    vertex_neighbours(s),
                    Bvh::build(&s.positions, &s.faces),
                    mean_edge_length(s),
                )
            })
            .collect();
        let mut out = MeshLevels {
            hierarchy,
            frames: Vec::new(),
            adjacency: Vec::new(),
            bvh: Vec::new(),
            mean_edge: Vec::new(),
        };
        for (f, a, b, e) in per_level {
            out.frames.push(f);
            out.adjacency.push(a);
            out.bvh.push(b);
            out.mean_edge.push(e);
        }
        Ok(out)
    }

    /// Number of levels.
    pub fn len(&self) -> usize {
        self.hierarchy.level_count()
    }

    /// Whether there are no levels (never: a hierarchy has at least one).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The surface of `level`.
    pub fn surface(&self, level: usize) -> &Surface {
        &self.hierarchy.level(level).surface
    }

    /// 1-ring of `level` as borrowed CSR.
    pub fn rings(&self, level: usize) -> (&[u32], &[u32]) {
        let (o, n) = &self.adjacency[level];
        (o, n)
    }

    /// The finest level with at most `vertices` vertices (the coarsest if none).
    pub fn level_with_at_most(&self, vertices: usize) -> usize {
        (0..self.len())
            .find(|&l| self.surface(l).vertex_count() <= vertices)
            .unwrap_or(self.len() - 1)
    }

    /// A field given on level `at` (`dim` floats per vertex), carried to every level: prolongated
    /// to the finer ones, averaged over children for the coarser ones.
    pub fn spread(&self, at: usize, dim: usize, values: Vec<f32>) -> Vec<Vec<f32>> {
        let n = self.len();
        let mut out: Vec<Vec<f32>> = vec![Vec::new(); n];
        out[at] = values;
        for l in (0..at).rev() {
            out[l] = self.hierarchy.prolongate_flat(l + 1, dim, &out[l + 1]);
        }
        for l in at + 1..n {
            out[l] = self.restrict(l, dim, &out[l - 1]);
        }
        out
    }

    /// Averages a field of level `coarse − 1` over the children of each vertex of `coarse`.
    pub fn restrict(&self, coarse: usize, dim: usize, fine: &[f32]) -> Vec<f32> {
        let nc = self.surface(coarse).vertex_count();
        let mut out = vec![0.0f32; nc * dim];
        out.par_chunks_mut(dim.max(1))
            .enumerate()
            .for_each(|(u, o)| {
                let children = self.hierarchy.children(coarse, u as u32);
                if children.is_empty() {
                    return;
                }
                for &c in children {
                    for (x, y) in o
                        .iter_mut()
                        .zip(&fine[c as usize * dim..(c as usize + 1) * dim])
                    {
                        *x += y;
                    }
                }
                let inv = 1.0 / children.len() as f32;
                o.iter_mut().for_each(|x| *x *= inv);
            });
        out
    }

    /// A boolean mask of level 0 carried up: a coarse vertex is set when all its children are.
    pub fn restrict_mask_all(&self, mask: &[bool]) -> Vec<Vec<bool>> {
        let mut out = vec![mask.to_vec()];
        for l in 1..self.len() {
            let nc = self.surface(l).vertex_count();
            let prev = &out[l - 1];
            let m: Vec<bool> = (0..nc)
                .map(|u| {
                    let ch = self.hierarchy.children(l, u as u32);
                    !ch.is_empty() && ch.iter().all(|&c| prev[c as usize])
                })
                .collect();
            out.push(m);
        }
        out
    }
}
