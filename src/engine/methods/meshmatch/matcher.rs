//! The E-step of MeshMatch (Chen et al. 2012, §4.2): the nearest-neighbour field (NNF) from
//! target vertices to source vertices with a relative rotation, improved by propagation and
//! random search under the patch dissimilarity of §4.1 (eq. 2).
//!
//! **Dissimilarity.** `D(t, s) = Σ_shape (f_T(t) − f_S(s))² + min_k Σ_fan (F_T(t)_j − F_S(s)_{j+k})²`:
//! the shape vectors at the fan centres plus the geodesic-fan colours at the best of the `A`
//! rotations (spoke `j` of the target against spoke `j + k` of the source). The caller scales
//! both blocks so their weights are equal after normalizing for dimension and variance (paper §5.2).
//! Rotations are searched exhaustively (the paper) or, with `randomized_rotations`, only around
//! the rotation carried from where the candidate came from plus one random rotation (Barnes et
//! al. 2010, the speed-up the paper suggests in §5.5). Sums are abandoned ring by ring once they
//! pass the best distance so far.
//!
//! **Area weights.** With `fan_area_weights` (default) ring `i` of the fan sum is weighted by
//! `2(i + 1)/(R + 1)`, the share of the fan's disc its samples stand for, so the comparison is
//! area-uniform like the paper's surface sampling (README: measured on real and synthetic pairs).
//!
//! **Pruning.** Before any rotation is compared, a candidate is refused when the rotation-free
//! lower bound of its fan distance ([`FanShape::rotation_free_bound`]: per-ring means and
//! residual norms) already reaches the best distance so far. The bound is exact algebra, so the
//! field is the one the full search finds (test `fan_pruning`).
//!
//! **Propagation.** Target vertices are visited in breadth-first order from a start per connected
//! component (random at first, then the last vertex of the previous sequence, the paper's
//! alternating passes). Candidates are the current match and every source vertex adjacent to (or
//! equal to) the match of a target neighbour. For determinism with any thread count the order is
//! cut into fixed blocks of [`BLOCK`] vertices processed in parallel: inside a block updates are
//! seen at once (Gauss–Seidel, as in PatchMatch), across blocks the field from the start of the
//! pass is read.
//!
//! **Random search.** For the current match `s` and `j = 1, 2, …` up to the coarsest source level,
//! a uniformly random descendant of `s`'s ancestor `j` levels up (Figure 4): samples at distances
//! growing like `√2^j`. On the coarsest level synthesised (`EStep::whole_source_draws`; not
//! necessarily the source hierarchy's top), uniform samples over the whole source level. Each
//! target vertex has its own seeded generator, so the result does not depend on threads.

use rayon::prelude::*;

use crate::engine::geometry::fans::FanShape;
use crate::engine::multires::Hierarchy;
use crate::engine::rng::{mix, SplitMix64};

/// Target vertices per propagation block (fixed: the result must not depend on threads).
pub const BLOCK: usize = 2048;

/// The nearest-neighbour field of one level.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Nnf {
    /// Matched source vertex per target vertex.
    pub source: Vec<u32>,
    /// Rotation in spokes: target spoke `j` matches source spoke `j + rotation`.
    pub rotation: Vec<u16>,
    /// Dissimilarity of the match.
    pub distance: Vec<f32>,
}

impl Nnf {
    /// Mean dissimilarity (the EM energy per vertex), over finite entries.
    pub fn energy(&self) -> f64 {
        let (sum, n) = self
            .distance
            .iter()
            .filter(|d| d.is_finite())
            .fold((0.0f64, 0usize), |(s, n), &d| (s + d as f64, n + 1));
        if n == 0 {
            0.0
        } else {
            sum / n as f64
        }
    }
}

/// Floats of a doubled source fan kept on the stack in [`PatchSpace::evaluate`].
const DOUBLED_ON_STACK: usize = 512;

/// A candidate is pruned when its rotation-free lower bound times this is not below the best
/// distance so far (the bound's rounding error is far below 1e-3).
const BOUND_MARGIN: f32 = 0.999;

/// Features of both meshes on one level.
#[derive(Clone, Copy)]
pub struct PatchSpace<'a> {
    /// Fan layout (rings, spokes, channels).
    pub fan: FanShape,
    /// Target fans, `fan.len()` floats per vertex (already weighted).
    pub target_fans: &'a [f32],
    /// Source fans.
    pub source_fans: &'a [f32],
    /// Target shape vectors, `shape_dim` per vertex (already weighted).
    pub target_shape: &'a [f32],
    /// Source shape vectors.
    pub source_shape: &'a [f32],
    /// Floats per shape vector (0 without shape features).
    pub shape_dim: usize,
    /// Source vertices that may be matched (by-example mode); `None`: all.
    pub source_allowed: Option<&'a [bool]>,
    /// Candidates closer than a radius to the target vertex are refused (self-matching a mesh).
    pub exclude: Option<Exclusion<'a>>,
    /// [`FanShape::ring_stats`] of the target fans, for pruning candidates by
    /// [`FanShape::rotation_free_bound`] before any rotation is tried; empty: no pruning.
    pub target_ring_stats: &'a [f32],
    /// [`FanShape::ring_stats`] of the source fans (empty with the target's).
    pub source_ring_stats: &'a [f32],
    /// One factor per fan ring in the patch distance ([`FanShape::area_ring_weights`]);
    /// empty: every ring 1.
    pub ring_weights: &'a [f32],
    /// Completeness: a cost added to every match of source vertex `s` (its over-use by the
    /// current field, see [`usage_penalty`]); empty: none.
    pub source_penalty: &'a [f32],
}

/// Refuses matches between nearby points (the self-match of a source against itself).
#[derive(Clone, Copy)]
pub struct Exclusion<'a> {
    /// Target vertex positions.
    pub target: &'a [[f32; 3]],
    /// Source vertex positions.
    pub source: &'a [[f32; 3]],
    /// Squared radius.
    pub radius2: f32,
}

/// Which rotations to try for a candidate.
#[derive(Clone, Copy, Debug)]
pub enum Rotations {
    /// All `A` rotations (the paper).
    All,
    /// `prior − 1, prior, prior + 1` and `extra`.
    Around { prior: u16, extra: u16 },
}

impl PatchSpace<'_> {
    /// Whether source vertex `s` may be matched.
    #[inline]
    pub fn allowed(&self, s: usize) -> bool {
        self.source_allowed.is_none_or(|a| a[s])
    }

    fn shape_distance(&self, t: usize, s: usize) -> f32 {
        let d = self.shape_dim;
        let a = &self.target_shape[t * d..(t + 1) * d];
        let b = &self.source_shape[s * d..(s + 1) * d];
        a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
    }

    /// The best rotation and dissimilarity of target `t` against source `s`, or `None` when it is
    /// not below `bound`.
    pub fn evaluate(
        &self,
        t: usize,
        s: usize,
        rotations: Rotations,
        bound: f32,
    ) -> Option<(u16, f32)> {
        if let Some(x) = &self.exclude {
            let (a, b) = (x.target[t], x.source[s]);
            let d2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
            if d2 < x.radius2 {
                return None;
            }
        }
        let penalty = self.source_penalty.get(s).copied().unwrap_or(0.0);
        let shape = self.shape_distance(t, s) + penalty;
        if shape >= bound {
            return None;
        }
        if !self.target_ring_stats.is_empty() {
            let m = self.fan.stats_len();
            let lower = self.fan.rotation_free_bound(
                &self.target_ring_stats[t * m..(t + 1) * m],
                &self.source_ring_stats[s * m..(s + 1) * m],
                self.ring_weights,
            );
            // The bound is exact algebra; the margin covers f32 rounding of both sides.
            if lower * BOUND_MARGIN >= bound - shape {
                return None;
            }
        }
        let n = self.fan.len();
        let a = &self.target_fans[t * n..(t + 1) * n];
        let b = &self.source_fans[s * n..(s + 1) * n];
        let spokes = self.fan.spokes as u16;
        let mut best: Option<(u16, f32)> = None;
        let mut limit = bound - shape;
        // The source fan with its rings doubled, so every rotation of a ring is one contiguous
        // comparison (on the stack for fans up to DOUBLED_ON_STACK floats, the default's 324;
        // on the heap for larger fans).
        let (mut on_stack, mut on_heap) = ([0.0f32; DOUBLED_ON_STACK], Vec::new());
        let b2: &mut [f32] = if self.fan.doubled_len() <= DOUBLED_ON_STACK {
            &mut on_stack[..self.fan.doubled_len()]
        } else {
            on_heap.resize(self.fan.doubled_len(), 0.0);
            &mut on_heap
        };
        self.fan.double_rings(b, b2);
        let b2 = &*b2;
        let mut try_k = |k: u16| {
            let d = self
                .fan
                .distance_below_doubled(a, b2, k as usize, limit, self.ring_weights);
            if d < limit {
                limit = d;
                best = Some((k, d + shape));
            }
        };
        match rotations {
            Rotations::All => (0..spokes).for_each(&mut try_k),
            Rotations::Around { prior, extra } => {
                let p = prior % spokes;
                try_k(p);
                try_k((p + 1) % spokes);
                try_k((p + spokes - 1) % spokes);
                try_k(extra % spokes);
            }
        }
        best
    }
}

/// The completeness cost of every source vertex (see the `em` module docs): `weight × scale ×
/// uses(s) / expected`, where `uses(s)` counts the free target vertices matched to `s` in `nnf`,
/// `expected` is their number over the usable source vertices' (the use of each under a field
/// that covers the source evenly) and `scale` the cost unit (the fan's dimension: a patch in
/// colour units of the source's standard deviation). Empty when `weight` is 0.
pub fn usage_penalty(
    nnf: &Nnf,
    source_count: usize,
    allowed: Option<&[bool]>,
    fixed: Option<&[bool]>,
    weight: f32,
    scale: f32,
) -> Vec<f32> {
    if weight <= 0.0 || source_count == 0 {
        return Vec::new();
    }
    let mut uses = vec![0u32; source_count];
    let mut free = 0usize;
    for (t, &s) in nnf.source.iter().enumerate() {
        if fixed.is_some_and(|f| f[t]) {
            continue;
        }
        free += 1;
        if let Some(u) = uses.get_mut(s as usize) {
            *u += 1;
        }
    }
    let usable = allowed.map_or(source_count, |a| a.iter().filter(|&&x| x).count());
    let expected = free as f32 / usable.max(1) as f32;
    if expected <= 0.0 {
        return Vec::new();
    }
    let unit = weight * scale / expected;
    uses.iter().map(|&u| unit * u as f32).collect()
}

/// Everything an E-step needs besides the field.
pub struct EStep<'a> {
    /// Features.
    pub space: PatchSpace<'a>,
    /// Target 1-rings (CSR offsets, neighbours).
    pub target_adjacency: (&'a [u32], &'a [u32]),
    /// Source 1-rings.
    pub source_adjacency: (&'a [u32], &'a [u32]),
    /// The source hierarchy and the level being matched.
    pub source_hierarchy: &'a Hierarchy,
    /// Level index.
    pub level: usize,
    /// Whether random search also draws uniformly over the whole source level: on the coarsest
    /// level synthesised, which is not the source hierarchy's top when the source has more
    /// levels than the target.
    pub whole_source_draws: bool,
    /// Randomized rotation search instead of exhaustive.
    pub randomized_rotations: bool,
    /// Target vertices whose match never changes (by-example mode); `None`: none.
    pub fixed: Option<&'a [bool]>,
    /// Seed of this level and iteration.
    pub seed: u64,
}

pub(super) fn ring<'a>(adj: (&'a [u32], &'a [u32]), v: usize) -> &'a [u32] {
    &adj.1[adj.0[v] as usize..adj.0[v + 1] as usize]
}

impl EStep<'_> {
    fn rotations(&self, prior: u16, rng: &mut SplitMix64) -> Rotations {
        if self.randomized_rotations {
            Rotations::Around {
                prior,
                extra: rng.below(self.space.fan.spokes as u64) as u16,
            }
        } else {
            Rotations::All
        }
    }

    fn is_fixed(&self, t: usize) -> bool {
        self.fixed.is_some_and(|f| f[t])
    }

    /// Re-evaluates every current match (the target fans changed with the last vote).
    pub fn refresh(&self, nnf: &mut Nnf) {
        nnf.source
            .par_iter()
            .zip(nnf.rotation.par_iter_mut())
            .zip(nnf.distance.par_iter_mut())
            .enumerate()
            .for_each(|(t, ((s, k), d))| {
                let mut rng = SplitMix64::new(mix(self.seed, 1, t as u64));
                let r = self.rotations(*k, &mut rng);
                match self.space.evaluate(t, *s as usize, r, f32::INFINITY) {
                    Some((nk, nd)) => {
                        *k = nk;
                        *d = nd;
                    }
                    None => *d = f32::INFINITY,
                }
            });
    }

    /// One propagation pass in `order` (a permutation of the target vertices). Returns how many
    /// matches changed.
    pub fn propagate(&self, nnf: &mut Nnf, order: &[u32]) -> usize {
        let n = order.len();
        let mut pos = vec![0u32; n];
        for (i, &v) in order.iter().enumerate() {
            pos[v as usize] = i as u32;
        }
        let snapshot = &*nnf;
        let mut perm: Vec<(u32, u16, f32)> = order
            .iter()
            .map(|&v| {
                let v = v as usize;
                (
                    snapshot.source[v],
                    snapshot.rotation[v],
                    snapshot.distance[v],
                )
            })
            .collect();
        let changed: usize = perm
            .par_chunks_mut(BLOCK)
            .enumerate()
            .map(|(b, block)| {
                let base = b * BLOCK;
                let mut seen: Vec<u32> = Vec::with_capacity(64);
                let mut changed = 0usize;
                for i in 0..block.len() {
                    let t = order[base + i] as usize;
                    if self.is_fixed(t) {
                        continue;
                    }
                    let mut rng = SplitMix64::new(mix(self.seed, 2, t as u64));
                    let (mut best_s, mut best_k, mut best_d) = block[i];
                    seen.clear();
                    seen.push(best_s);
                    for &nb in ring(self.target_adjacency, t) {
                        let p = pos[nb as usize] as usize;
                        let (sn, kn) = if p >= base && p < base + block.len() {
                            (block[p - base].0, block[p - base].1)
                        } else {
                            (snapshot.source[nb as usize], snapshot.rotation[nb as usize])
                        };
                        let around = std::iter::once(sn)
                            .chain(ring(self.source_adjacency, sn as usize).iter().copied());
                        for c in around {
                            if seen.contains(&c) || !self.space.allowed(c as usize) {
                                continue;
                            }
                            seen.push(c);
                            let r = self.rotations(kn, &mut rng);
                            if let Some((k, d)) = self.space.evaluate(t, c as usize, r, best_d) {
                                (best_s, best_k, best_d) = (c, k, d);
                            }
                        }
                    }
                    if best_s != block[i].0 {
                        changed += 1;
                    }
                    block[i] = (best_s, best_k, best_d);
                }
                changed
            })
            .sum();
        for (i, &v) in order.iter().enumerate() {
            let (s, k, d) = perm[i];
            nnf.source[v as usize] = s;
            nnf.rotation[v as usize] = k;
            nnf.distance[v as usize] = d;
        }
        changed
    }

    /// One random-search pass (parallel, per-vertex generators). Returns how many matches
    /// changed.
    pub fn random_search(&self, nnf: &mut Nnf) -> usize {
        let h = self.source_hierarchy;
        let top = h.level_count() - 1;
        let source_count = h.level(self.level).surface.vertex_count() as u64;
        let draws_at_top = (64 - source_count.leading_zeros()).max(1) as usize;
        nnf.source
            .par_iter_mut()
            .zip(nnf.rotation.par_iter_mut())
            .zip(nnf.distance.par_iter_mut())
            .enumerate()
            .map(|(t, ((s, k), d))| {
                if self.is_fixed(t) {
                    return 0usize;
                }
                let mut rng = SplitMix64::new(mix(self.seed, 3, t as u64));
                let start = *s;
                let consider =
                    |c: u32, rng: &mut SplitMix64, s: &mut u32, k: &mut u16, d: &mut f32| {
                        if c == *s || !self.space.allowed(c as usize) {
                            return;
                        }
                        let r = self.rotations(*k, rng);
                        if let Some((nk, nd)) = self.space.evaluate(t, c as usize, r, *d) {
                            (*s, *k, *d) = (c, nk, nd);
                        }
                    };
                for j in 1..=(top - self.level) {
                    let ancestor = h.ancestor(self.level, *s, j);
                    let c = h.random_descendant(self.level + j, ancestor, j, &mut rng);
                    consider(c, &mut rng, s, k, d);
                }
                if self.whole_source_draws {
                    for _ in 0..draws_at_top {
                        let c = rng.below(source_count) as u32;
                        consider(c, &mut rng, s, k, d);
                    }
                }
                usize::from(*s != start)
            })
            .sum()
    }
}

/// Breadth-first visiting order of all target vertices, one sweep per connected component from
/// `starts[c]` (updated to the last vertex reached, the start of the next pass).
pub fn bfs_order(adjacency: (&[u32], &[u32]), component: &[u32], starts: &mut [u32]) -> Vec<u32> {
    let n = component.len();
    let mut visited = vec![false; n];
    let mut order = Vec::with_capacity(n);
    for start in starts.iter_mut() {
        let first = order.len();
        let s = *start as usize;
        visited[s] = true;
        order.push(*start);
        let mut head = first;
        while head < order.len() {
            let v = order[head] as usize;
            head += 1;
            for &nb in ring(adjacency, v) {
                if !visited[nb as usize] {
                    visited[nb as usize] = true;
                    order.push(nb);
                }
            }
        }
        *start = *order.last().unwrap_or(start);
    }
    // Vertices of no listed component (isolated): appended in index order.
    for v in 0..n {
        if !visited[v] {
            order.push(v as u32);
        }
    }
    order
}

/// Connected components of a vertex graph: a label per vertex (numbered by lowest vertex) and the
/// lowest vertex of each component.
pub fn components(adjacency: (&[u32], &[u32]), n: usize) -> (Vec<u32>, Vec<u32>) {
    components_where(adjacency, n, |_, _| true)
}

/// Connected components of the vertex graph restricted to the edges `(a, b)` for which
/// `keep_edge(a, b)` holds: a label per vertex (numbered by lowest vertex) and the lowest vertex
/// of each component.
pub fn components_where(
    adjacency: (&[u32], &[u32]),
    n: usize,
    keep_edge: impl Fn(usize, usize) -> bool,
) -> (Vec<u32>, Vec<u32>) {
    let mut label = vec![u32::MAX; n];
    let mut firsts = Vec::new();
    let mut stack = Vec::new();
    for v in 0..n {
        if label[v] != u32::MAX {
            continue;
        }
        let c = firsts.len() as u32;
        firsts.push(v as u32);
        label[v] = c;
        stack.push(v);
        while let Some(x) = stack.pop() {
            for &nb in ring(adjacency, x) {
                let nb = nb as usize;
                if label[nb] == u32::MAX && keep_edge(x, nb) {
                    label[nb] = c;
                    stack.push(nb);
                }
            }
        }
    }
    (label, firsts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::control::Control;
    use crate::engine::mesh::primitives::icosphere;
    use crate::engine::multires::{build_hierarchy, HierarchyParams};

    fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
        (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f32>().sqrt()
    }

    /// A source hierarchy deeper than the synthesis: on the coarsest level synthesised (1), the
    /// random search must still draw over the whole source. Shape-only patches: the dissimilarity
    /// of a source vertex is its distance to a pole, and every match starts at the far pole, so
    /// hierarchical draws (descendants of the far pole's ancestors) cannot get near the pole.
    #[test]
    fn random_search_draws_over_the_whole_source_on_the_coarsest_synthesised_level() {
        let sphere = icosphere(1.0, 16);
        let params = HierarchyParams {
            min_vertices: 32,
            ..Default::default()
        };
        let h = build_hierarchy(&sphere, &params, &Control::new()).unwrap();
        assert!(h.level_count() >= 4, "{} levels", h.level_count());
        let level = 1;
        let positions = &h.level(level).surface.positions;
        let pole = [0.0, 0.0, 1.0];
        let source_shape: Vec<f32> = positions.iter().map(|&p| distance(p, pole)).collect();
        let far = (0..positions.len())
            .max_by(|&a, &b| source_shape[a].total_cmp(&source_shape[b]))
            .unwrap() as u32;
        let targets = 64;
        let target_shape = vec![0.0f32; targets];
        // One-float fans, equal everywhere: only the shape distance differs.
        let (target_fans, source_fans) = (vec![0.0f32; targets], vec![0.0f32; positions.len()]);
        let rings = (vec![0u32; targets + 1], Vec::new());
        let source_rings = (vec![0u32; positions.len() + 1], Vec::new());
        let mean_after = |whole_source_draws: bool| {
            let step = EStep {
                space: PatchSpace {
                    fan: FanShape {
                        rings: 1,
                        spokes: 1,
                        dim: 1,
                    },
                    target_fans: &target_fans,
                    source_fans: &source_fans,
                    target_shape: &target_shape,
                    source_shape: &source_shape,
                    shape_dim: 1,
                    source_allowed: None,
                    exclude: None,
                    source_penalty: &[],
                    ring_weights: &[],
                    target_ring_stats: &[],
                    source_ring_stats: &[],
                },
                target_adjacency: (&rings.0, &rings.1),
                source_adjacency: (&source_rings.0, &source_rings.1),
                source_hierarchy: &h,
                level,
                whole_source_draws,
                randomized_rotations: false,
                fixed: None,
                seed: 7,
            };
            let mut nnf = Nnf {
                source: vec![far; targets],
                rotation: vec![0; targets],
                distance: vec![source_shape[far as usize].powi(2); targets],
            };
            step.random_search(&mut nnf);
            nnf.source
                .iter()
                .map(|&s| source_shape[s as usize])
                .sum::<f32>()
                / targets as f32
        };
        let hierarchical = mean_after(false);
        let whole = mean_after(true);
        // Hierarchical draws stay in the far pole's top-level cluster; uniform draws (about
        // log₂ n of them) land on average within about a radian of the pole.
        assert!(
            hierarchical > 1.5,
            "hierarchical draws reached {hierarchical}"
        );
        assert!(whole < 1.0, "whole-source draws reached only {whole}");
    }
}
