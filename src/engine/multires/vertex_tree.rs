//! The vertex tree of the hierarchy (MeshMatch, Chen et al. 2012, §4: "retaining the vertex
//! tree of parent-child relationships to allow efficient traversal between multiresolution
//! levels") and the random descendants its random search draws (§4.2, Figure 4).
//!
//! Layout: every level `l` keeps its vertices in *tree order*: the coarsest level in index order,
//! and each finer level as the concatenation, over the coarser level's tree order, of each
//! vertex's children (ascending index). Then the children of a vertex are a contiguous run of the
//! finer level's tree order, and so are its descendants any number of levels down: the
//! descendants `j` levels below a vertex are one slice, found by `j` offset lookups, and a uniform
//! draw over that slice is a uniform draw over the subtree's leaves at that level (not the biased
//! "random child at each step" walk).
//!
//! The random draws use the seeded [`SplitMix64`](crate::engine::rng::SplitMix64), so they are
//! reproducible.

use std::ops::Range;

use crate::engine::mesh::csr::group_by_key;

/// Tree order of one level.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct TreeLevel {
    /// Vertices of this level in tree order.
    pub order: Vec<u32>,
    /// Position of each vertex in `order`.
    pub rank: Vec<u32>,
    /// For levels above the finest: the children of `order[p]` are
    /// `finer.order[child_offsets[p]..child_offsets[p + 1]]`. Empty on the finest level.
    pub child_offsets: Vec<u32>,
}

/// Builds the tree order of every level from the parent arrays: `parents[l][v]` is the parent on
/// level `l + 1` of vertex `v` of level `l`; `counts[l]` is the vertex count of level `l`.
pub(crate) fn build_tree(parents: &[&[u32]], counts: &[usize]) -> Vec<TreeLevel> {
    let levels = counts.len();
    let mut out: Vec<TreeLevel> = vec![TreeLevel::default(); levels];
    let top = levels - 1;
    out[top].order = (0..counts[top] as u32).collect();
    out[top].rank = out[top].order.clone();
    for l in (0..top).rev() {
        let parent = parents[l];
        let coarse = &out[l + 1];
        // Counting sort of the fine vertices by their parent's rank (stable: ascending index).
        let by_parent = parent
            .iter()
            .enumerate()
            .map(|(v, &p)| (coarse.rank[p as usize], v as u32));
        let (offsets, order) = group_by_key(counts[l + 1], by_parent);
        let mut rank = vec![0u32; parent.len()];
        for (i, &v) in order.iter().enumerate() {
            rank[v as usize] = i as u32;
        }
        out[l + 1].child_offsets = offsets;
        out[l].order = order;
        out[l].rank = rank;
    }
    out
}

/// The range, in the tree order of level `level - j`, of the descendants of `vertex` (a vertex
/// of `level`).
pub(crate) fn descendant_range(
    tree: &[TreeLevel],
    level: usize,
    vertex: u32,
    j: usize,
) -> Range<usize> {
    let r = tree[level].rank[vertex as usize] as usize;
    let mut range = r..r + 1;
    for l in (level - j + 1..=level).rev() {
        let off = &tree[l].child_offsets;
        range = off[range.start] as usize..off[range.end] as usize;
    }
    range
}
