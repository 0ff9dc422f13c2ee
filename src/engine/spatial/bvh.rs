//! A bounding volume hierarchy over triangles with exact closest-point and ray-cast queries.
//!
//! Build: binned surface-area heuristic (Wald, *On fast Construction of SAH-based Bounding Volume
//! Hierarchies*, 2007): 16 bins per axis (4 to 16 for nodes under 32 triangles) over the
//! triangle-box centroids, the split of least `area(left)·n_left + area(right)·n_right`, leaves of
//! at most [`MAX_LEAF`] triangles. Nodes at depth 48 or more split at the object median instead, which bounds the depth (< 80) and so the fixed
//! traversal stack. Large nodes bin in parallel and subtrees build in parallel (rayon); every
//! reduction is an exact min/max or integer sum and every sort key is a total order, so the tree
//! is identical for any thread count.
//!
//! Layout: nodes in depth-first order (left child right after its parent); the triangle corners
//! are copied into leaf order so a leaf's triangles are contiguous in memory.
//!
//! Queries: a stack-based traversal visiting the nearer child first and pruning by the squared
//! point–box distance (closest point) or by the slab entry distance (rays); no allocation per
//! query. Distances are in the units of the positions given to [`Bvh::build`]; barycentric
//! coordinates refer to the face's corners in the order of the `faces` array. Ties (equal
//! distance or equal `t`) go to the lowest face index.
//!
//! Written by hand: the crates that exist either lack exact point–triangle queries with filters
//! or allocate per query.

use glam::Vec3A;
use rayon::prelude::*;

use super::triangle::{closest_point_on_triangle, ray_triangle};
use crate::engine::math::{dot, sub};

/// Most triangles in a leaf.
pub const MAX_LEAF: usize = 4;
const BINS: usize = 16;
/// Below this depth, splits fall back to the object median.
const MEDIAN_DEPTH: u32 = 48;
const STACK: usize = 96;
/// Subtrees with at least this many triangles are built in parallel.
const PAR_SUBTREE: usize = 4096;
/// Nodes with at least this many triangles are binned in parallel chunks.
const PAR_BIN: usize = 65536;

/// Result of a closest-point query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClosestHit {
    /// Index of the face in the `faces` array given to [`Bvh::build`].
    pub face: u32,
    /// Barycentric coordinates of `point` on the face (weights of its corners 0, 1, 2).
    pub bary: [f32; 3],
    /// The closest point.
    pub point: [f32; 3],
    /// Squared distance from the query point to `point`.
    pub distance_squared: f32,
}

/// Result of a ray cast.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit {
    /// Index of the face hit.
    pub face: u32,
    /// Ray parameter of the hit: `origin + t * dir`.
    pub t: f32,
    /// Barycentric coordinates of the hit on the face.
    pub bary: [f32; 3],
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Node {
    pub(super) lo: [f32; 3],
    pub(super) hi: [f32; 3],
    /// Leaf: first triangle (leaf order). Interior: index of the right child.
    pub(super) index: u32,
    /// Leaf: triangle count (> 0). Interior: 0.
    pub(super) count: u32,
}

/// Per-triangle build record: bounds and the face index.
#[derive(Clone, Copy, Debug)]
struct Prim {
    lo: Vec3A,
    hi: Vec3A,
    face: u32,
}

impl Prim {
    /// Twice the box centroid along `axis` (the factor 2 cancels out of every use).
    #[inline(always)]
    fn centroid2(&self, axis: usize) -> f32 {
        self.lo[axis] + self.hi[axis]
    }

    /// Twice the box centroid.
    #[inline(always)]
    fn centroid2v(&self) -> Vec3A {
        self.lo + self.hi
    }
}

/// A bounding volume hierarchy over a triangle set. See the module docs.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    pub(super) nodes: Vec<Node>,
    /// Triangle corners in leaf order.
    pub(super) tris: Vec<[[f32; 3]; 3]>,
    /// Face index of each triangle in leaf order.
    pub(super) faces: Vec<u32>,
}

#[derive(Clone, Copy)]
struct Aabb {
    lo: Vec3A,
    hi: Vec3A,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: Vec3A::INFINITY,
        hi: Vec3A::NEG_INFINITY,
    };

    #[inline(always)]
    fn grow(&mut self, lo: Vec3A, hi: Vec3A) {
        self.lo = self.lo.min(lo);
        self.hi = self.hi.max(hi);
    }

    fn union(mut self, o: Aabb) -> Aabb {
        self.grow(o.lo, o.hi);
        self
    }

    /// Half the surface area (0 for an empty box).
    fn half_area(&self) -> f32 {
        let d = self.hi - self.lo;
        if d.x < 0.0 {
            return 0.0;
        }
        d.x * d.y + d.y * d.z + d.z * d.x
    }
}

/// `min` without NaN handling (maps to a single instruction).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `max` without NaN handling (maps to a single instruction).
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Bounds of the triangle boxes and of their (doubled) centroids.
fn bounds(prims: &[Prim]) -> (Aabb, Aabb) {
    let fold = |(mut b, mut c): (Aabb, Aabb), p: &Prim| {
        b.grow(p.lo, p.hi);
        let m = p.centroid2v();
        c.grow(m, m);
        (b, c)
    };
    if prims.len() >= PAR_BIN {
        prims
            .par_chunks(8192)
            .map(|ch| ch.iter().fold((Aabb::EMPTY, Aabb::EMPTY), fold))
            .reduce(
                || (Aabb::EMPTY, Aabb::EMPTY),
                |a, b| (a.0.union(b.0), a.1.union(b.1)),
            )
    } else {
        prims.iter().fold((Aabb::EMPTY, Aabb::EMPTY), fold)
    }
}

#[derive(Clone, Copy)]
struct Bins {
    count: [[u32; BINS]; 3],
    bounds: [[Aabb; BINS]; 3],
}

impl Bins {
    fn empty() -> Self {
        Bins {
            count: [[0; BINS]; 3],
            bounds: [[Aabb::EMPTY; BINS]; 3],
        }
    }

    fn merge(mut self, o: &Bins) -> Self {
        for k in 0..3 {
            for b in 0..BINS {
                self.count[k][b] += o.count[k][b];
                self.bounds[k][b] = self.bounds[k][b].union(o.bounds[k][b]);
            }
        }
        self
    }
}

/// Maps doubled centroids to bins along each axis.
#[derive(Clone, Copy)]
struct Binner {
    origin: Vec3A,
    scale: Vec3A,
    /// Bins in use: fewer for small nodes, where the sweep would dominate.
    bins: usize,
}

impl Binner {
    fn new(c: &Aabb, count: usize) -> Self {
        let bins = (count / 2).clamp(4, BINS);
        let mut scale = Vec3A::ZERO;
        for k in 0..3 {
            let ext = c.hi[k] - c.lo[k];
            if ext > 0.0 {
                scale[k] = bins as f32 * (1.0 - 1e-5) / ext;
            }
        }
        Binner {
            origin: c.lo,
            scale,
            bins,
        }
    }

    #[inline(always)]
    fn bin(&self, p: &Prim, axis: usize) -> usize {
        let x = (p.centroid2(axis) - self.origin[axis]) * self.scale[axis];
        (fmax(x, 0.0) as usize).min(self.bins - 1)
    }

    fn fill(&self, prims: &[Prim]) -> Bins {
        let mut bins = Bins::empty();
        let top = (self.bins - 1) as f32;
        for p in prims {
            // Same arithmetic as `bin`, for the three axes at once.
            let x = ((p.centroid2v() - self.origin) * self.scale)
                .max(Vec3A::ZERO)
                .min(Vec3A::splat(top));
            let b = [x.x as usize, x.y as usize, x.z as usize];
            for (k, &bk) in b.iter().enumerate() {
                bins.count[k][bk] += 1;
                bins.bounds[k][bk].grow(p.lo, p.hi);
            }
        }
        bins
    }
}

/// Chooses (axis, last bin of the left side) of least SAH cost, if any axis has extent.
fn best_split(binner: &Binner, bins: &Bins) -> Option<(usize, usize)> {
    let nb = binner.bins;
    let mut best: Option<(f32, usize, usize)> = None;
    for k in 0..3 {
        if binner.scale[k] <= 0.0 {
            continue;
        }
        let mut right_cost = [0.0f32; BINS];
        let mut acc = Aabb::EMPTY;
        let mut n = 0u32;
        for b in (1..nb).rev() {
            acc = acc.union(bins.bounds[k][b]);
            n += bins.count[k][b];
            right_cost[b] = acc.half_area() * n as f32;
        }
        let mut acc = Aabb::EMPTY;
        let mut n = 0u32;
        let total: u32 = bins.count[k][..nb].iter().sum();
        for b in 0..nb - 1 {
            acc = acc.union(bins.bounds[k][b]);
            n += bins.count[k][b];
            if n == 0 || n == total {
                continue;
            }
            let cost = acc.half_area() * n as f32 + right_cost[b + 1];
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, k, b));
            }
        }
    }
    best.map(|(_, k, b)| (k, b))
}

/// Bounds of a range of prims: their boxes and their (doubled) centroids.
#[derive(Clone, Copy)]
struct Extent {
    bx: Aabb,
    cb: Aabb,
}

impl Extent {
    const EMPTY: Extent = Extent {
        bx: Aabb::EMPTY,
        cb: Aabb::EMPTY,
    };

    #[inline(always)]
    fn grow(&mut self, p: &Prim) {
        self.bx.grow(p.lo, p.hi);
        let m = p.centroid2v();
        self.cb.grow(m, m);
    }

    fn of(prims: &[Prim]) -> Extent {
        let (bx, cb) = bounds(prims);
        Extent { bx, cb }
    }
}

/// In-place partition; returns the size of the `pred == true` prefix and the extents of both
/// sides (each element is classified exactly once).
fn partition(prims: &mut [Prim], pred: impl Fn(&Prim) -> bool) -> (usize, Extent, Extent) {
    let mut left = Extent::EMPTY;
    let mut right = Extent::EMPTY;
    let mut i = 0;
    let mut j = prims.len();
    while i < j {
        if pred(&prims[i]) {
            left.grow(&prims[i]);
            i += 1;
        } else {
            j -= 1;
            prims.swap(i, j);
            right.grow(&prims[j]);
        }
    }
    (i, left, right)
}

/// Builds the subtree over `prims` (which start at leaf-order offset `base`, with extent `ext`)
/// into a node list whose indices are relative to its own root at 0.
fn build_subtree(prims: &mut [Prim], ext: Extent, base: u32, depth: u32) -> Vec<Node> {
    if prims.len() < PAR_SUBTREE {
        let mut nodes = Vec::with_capacity(prims.len() / 2 + 1);
        build_into(prims, ext, base, depth, &mut nodes);
        return nodes;
    }
    let (mid, le, re) = split(prims, &ext, depth);
    let (left, right) = prims.split_at_mut(mid);
    let (ln, rn) = rayon::join(
        || build_subtree(left, le, base, depth + 1),
        || build_subtree(right, re, base + mid as u32, depth + 1),
    );
    let mut nodes = Vec::with_capacity(1 + ln.len() + rn.len());
    nodes.push(Node {
        lo: ext.bx.lo.to_array(),
        hi: ext.bx.hi.to_array(),
        index: 1 + ln.len() as u32,
        count: 0,
    });
    for part in [ln, rn] {
        let shift = nodes.len() as u32;
        nodes.extend(part.into_iter().map(|mut n| {
            if n.count == 0 {
                n.index += shift;
            }
            n
        }));
    }
    nodes
}

/// Sequential recursive build appending to `nodes` (indices relative to `nodes`).
fn build_into(prims: &mut [Prim], ext: Extent, base: u32, depth: u32, nodes: &mut Vec<Node>) {
    if prims.len() <= MAX_LEAF {
        nodes.push(Node {
            lo: ext.bx.lo.to_array(),
            hi: ext.bx.hi.to_array(),
            index: base,
            count: prims.len() as u32,
        });
        return;
    }
    let (mid, le, re) = split(prims, &ext, depth);
    let me = nodes.len();
    nodes.push(Node {
        lo: ext.bx.lo.to_array(),
        hi: ext.bx.hi.to_array(),
        index: 0,
        count: 0,
    });
    let (left, right) = prims.split_at_mut(mid);
    build_into(left, le, base, depth + 1, nodes);
    nodes[me].index = nodes.len() as u32;
    build_into(right, re, base + mid as u32, depth + 1, nodes);
}

/// Splits `prims` (more than `MAX_LEAF`, extent `ext`) in place; returns the left size and the
/// extents of both sides.
fn split(prims: &mut [Prim], ext: &Extent, depth: u32) -> (usize, Extent, Extent) {
    let cb = ext.cb;
    let binner = Binner::new(&cb, prims.len());
    if depth < MEDIAN_DEPTH {
        let bins = if prims.len() >= PAR_BIN {
            prims
                .par_chunks(8192)
                .map(|ch| binner.fill(ch))
                .reduce(Bins::empty, |a, b| a.merge(&b))
        } else {
            binner.fill(prims)
        };
        if let Some((axis, last)) = best_split(&binner, &bins) {
            // The bins already count each side, so the partition cannot leave a side empty
            // unless rounding disagrees; then fall through to the median split.
            let (mid, le, re) = partition(prims, |p| binner.bin(p, axis) <= last);
            if mid > 0 && mid < prims.len() {
                return (mid, le, re);
            }
        }
    }
    // Object median along the widest centroid axis (or by face index when all coincide).
    let w = [
        cb.hi[0] - cb.lo[0],
        cb.hi[1] - cb.lo[1],
        cb.hi[2] - cb.lo[2],
    ];
    let axis = if w[0] >= w[1] && w[0] >= w[2] {
        0
    } else if w[1] >= w[2] {
        1
    } else {
        2
    };
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        a.centroid2(axis)
            .total_cmp(&b.centroid2(axis))
            .then(a.face.cmp(&b.face))
    });
    let (left, right) = prims.split_at(mid);
    (mid, Extent::of(left), Extent::of(right))
}

#[inline(always)]
fn box_distance_squared(n: &Node, p: [f32; 3]) -> f32 {
    let dx = fmax(fmax(n.lo[0] - p[0], p[0] - n.hi[0]), 0.0);
    let dy = fmax(fmax(n.lo[1] - p[1], p[1] - n.hi[1]), 0.0);
    let dz = fmax(fmax(n.lo[2] - p[2], p[2] - n.hi[2]), 0.0);
    dx * dx + dy * dy + dz * dz
}

/// A ray prepared for slab tests.
struct Ray {
    origin: [f32; 3],
    inv: [f32; 3],
    /// Axes along which the direction is exactly 0.
    flat: [bool; 3],
}

impl Ray {
    /// Entry parameter of the ray into the node box within `[t0, t1]`, if it enters.
    #[inline(always)]
    fn enter(&self, n: &Node, mut t0: f32, mut t1: f32) -> Option<f32> {
        // Conservative widening of the slab interval against rounding.
        const WIDEN: f32 = 4.0 * f32::EPSILON;
        for k in 0..3 {
            if self.flat[k] {
                if self.origin[k] < n.lo[k] || self.origin[k] > n.hi[k] {
                    return None;
                }
                continue;
            }
            let a = (n.lo[k] - self.origin[k]) * self.inv[k];
            let b = (n.hi[k] - self.origin[k]) * self.inv[k];
            let (near, far) = if a <= b { (a, b) } else { (b, a) };
            t0 = fmax(t0, near - near.abs() * WIDEN);
            t1 = fmin(t1, far + far.abs() * WIDEN);
        }
        (t0 <= t1).then_some(t0)
    }
}

impl Bvh {
    /// Builds the hierarchy over `faces` (indices into `positions`). Empty `faces` give an empty
    /// hierarchy whose queries return `None`.
    ///
    /// # Panics
    /// If a face refers to a vertex index `>= positions.len()` or there are `>= 2³²` faces.
    pub fn build(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Bvh {
        assert!(
            faces.len() < u32::MAX as usize,
            "too many faces for a Bvh: {}",
            faces.len()
        );
        let mut prims: Vec<Prim> = faces
            .par_iter()
            .enumerate()
            .map(|(i, f)| {
                let [a, b, c] = f.map(|v| positions[v as usize]);
                let (a, b, c) = (Vec3A::from(a), Vec3A::from(b), Vec3A::from(c));
                let lo = a.min(b).min(c);
                let hi = a.max(b).max(c);
                Prim {
                    lo,
                    hi,
                    face: i as u32,
                }
            })
            .collect();
        let nodes = if prims.is_empty() {
            Vec::new()
        } else {
            let ext = Extent::of(&prims);
            build_subtree(&mut prims, ext, 0, 0)
        };
        let tris = prims
            .par_iter()
            .map(|p| faces[p.face as usize].map(|v| positions[v as usize]))
            .collect();
        let faces = prims.iter().map(|p| p.face).collect();
        Bvh { nodes, tris, faces }
    }

    /// Number of triangles.
    pub fn face_count(&self) -> usize {
        self.faces.len()
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Depth of the tree (1 for a single leaf, 0 when empty).
    pub fn depth(&self) -> usize {
        fn rec(nodes: &[Node], i: usize) -> usize {
            let n = &nodes[i];
            if n.count > 0 {
                1
            } else {
                1 + rec(nodes, i + 1).max(rec(nodes, n.index as usize))
            }
        }
        if self.nodes.is_empty() {
            0
        } else {
            rec(&self.nodes, 0)
        }
    }

    /// The exact closest point on any triangle within `max_distance` of `p` (inclusive;
    /// `f32::INFINITY` for no limit). Ties go to the lowest face index. `None` when no triangle is
    /// that close (or `max_distance` is negative or NaN).
    pub fn closest_point(&self, p: [f32; 3], max_distance: f32) -> Option<ClosestHit> {
        self.closest_impl(p, max_distance, |_| true)
    }

    /// Like [`Bvh::closest_point`], over only the faces for which `accept(face)` is true.
    pub fn closest_point_filtered(
        &self,
        p: [f32; 3],
        max_distance: f32,
        accept: impl Fn(u32) -> bool,
    ) -> Option<ClosestHit> {
        self.closest_impl(p, max_distance, accept)
    }

    #[inline]
    fn closest_impl(
        &self,
        p: [f32; 3],
        max_distance: f32,
        accept: impl Fn(u32) -> bool,
    ) -> Option<ClosestHit> {
        if self.nodes.is_empty() || max_distance.is_nan() || max_distance < 0.0 {
            return None;
        }
        let mut limit = max_distance * max_distance;
        let mut best: Option<ClosestHit> = None;
        let mut stack = [(0u32, 0.0f32); STACK];
        let mut sp = 0usize;
        let root_d = box_distance_squared(&self.nodes[0], p);
        if root_d > limit {
            return None;
        }
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            if n.count > 0 {
                let first = n.index as usize;
                for k in first..first + n.count as usize {
                    let face = self.faces[k];
                    if !accept(face) {
                        continue;
                    }
                    let [a, b, c] = self.tris[k];
                    let (q, bary) = closest_point_on_triangle(p, a, b, c);
                    let r = sub(p, q);
                    let d2 = dot(r, r);
                    let better = match &best {
                        None => d2 <= limit,
                        Some(h) => {
                            d2 < h.distance_squared || (d2 == h.distance_squared && face < h.face)
                        }
                    };
                    if better {
                        best = Some(ClosestHit {
                            face,
                            bary,
                            point: q,
                            distance_squared: d2,
                        });
                        limit = d2;
                    }
                }
            } else {
                let l = node + 1;
                let r = n.index as usize;
                let dl = box_distance_squared(&self.nodes[l], p);
                let dr = box_distance_squared(&self.nodes[r], p);
                let (near, dn, far, df) = if dl <= dr {
                    (l, dl, r, dr)
                } else {
                    (r, dr, l, dl)
                };
                if df <= limit {
                    stack[sp] = (far as u32, df);
                    sp += 1;
                }
                if dn <= limit {
                    node = near;
                    continue;
                }
            }
            // Pop the next node still within reach.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let (nd, d) = stack[sp];
                if d <= limit {
                    node = nd as usize;
                    break;
                }
            }
        }
    }

    /// The first hit of the ray `origin + t * dir` for `t` in `(t_min, t_max]`, either side of
    /// the triangles. Ties in `t` go to the lowest face index. `dir` need not be unit length (`t`
    /// is in units of `dir`).
    pub fn ray_cast(
        &self,
        origin: [f32; 3],
        dir: [f32; 3],
        t_min: f32,
        t_max: f32,
    ) -> Option<RayHit> {
        if self.nodes.is_empty() || t_min.is_nan() || t_max.is_nan() || t_max <= t_min {
            return None;
        }
        let inv = dir.map(|d| 1.0 / d);
        // Zero (or subnormal) components never leave their slab: test those by position.
        let flat = inv.map(|i| !i.is_finite());
        let ray = Ray { origin, inv, flat };
        let mut limit = t_max;
        let mut best: Option<RayHit> = None;
        let mut stack = [(0u32, 0.0f32); STACK];
        let mut sp = 0usize;
        ray.enter(&self.nodes[0], t_min, limit)?;
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            if n.count > 0 {
                let first = n.index as usize;
                for k in first..first + n.count as usize {
                    let [a, b, c] = self.tris[k];
                    let Some((t, bary)) = ray_triangle(origin, dir, a, b, c) else {
                        continue;
                    };
                    if t <= t_min {
                        continue;
                    }
                    let face = self.faces[k];
                    let better = match &best {
                        None => t <= limit,
                        Some(h) => t < h.t || (t == h.t && face < h.face),
                    };
                    if better {
                        best = Some(RayHit { face, t, bary });
                        limit = t;
                    }
                }
            } else {
                let l = node + 1;
                let r = n.index as usize;
                let el = ray.enter(&self.nodes[l], t_min, limit);
                let er = ray.enter(&self.nodes[r], t_min, limit);
                match (el, er) {
                    (Some(tl), Some(tr)) => {
                        let (near, far, tf) = if tl <= tr { (l, r, tr) } else { (r, l, tl) };
                        stack[sp] = (far as u32, tf);
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                let (nd, t) = stack[sp];
                if t <= limit {
                    node = nd as usize;
                    break;
                }
            }
        }
    }

    /// Calls `visit` for every hit of the ray `origin + t * dir` with `t` in `(t_min, t_max]`,
    /// either side of the triangles, in no particular order (traversal order, which is fixed for
    /// a given tree and ray). A ray through an edge or vertex shared by several triangles reports
    /// each of them. For crossing counts (inside/outside tests) and hit-distance lists.
    pub fn ray_for_each_hit(
        &self,
        origin: [f32; 3],
        dir: [f32; 3],
        t_min: f32,
        t_max: f32,
        mut visit: impl FnMut(RayHit),
    ) {
        self.ray_visit(origin, dir, t_min, t_max, |hit| {
            visit(hit);
            false
        });
    }

    /// Whether the ray `origin + t * dir` hits any triangle with `t` in `(t_min, t_max]` (either
    /// side). Stops at the first hit found, so it is cheaper than [`Bvh::ray_cast`] for
    /// visibility tests.
    pub fn ray_hits_any(&self, origin: [f32; 3], dir: [f32; 3], t_min: f32, t_max: f32) -> bool {
        let mut found = false;
        self.ray_visit(origin, dir, t_min, t_max, |_| {
            found = true;
            true
        });
        found
    }

    /// Visits hits in `(t_min, t_max]` until `visit` returns `true`.
    fn ray_visit(
        &self,
        origin: [f32; 3],
        dir: [f32; 3],
        t_min: f32,
        t_max: f32,
        mut visit: impl FnMut(RayHit) -> bool,
    ) {
        if self.nodes.is_empty() || t_min.is_nan() || t_max.is_nan() || t_max <= t_min {
            return;
        }
        let inv = dir.map(|d| 1.0 / d);
        let flat = inv.map(|i| !i.is_finite());
        let ray = Ray { origin, inv, flat };
        if ray.enter(&self.nodes[0], t_min, t_max).is_none() {
            return;
        }
        let mut stack = [0u32; STACK];
        let mut sp = 0usize;
        let mut node = 0usize;
        loop {
            let n = &self.nodes[node];
            if n.count > 0 {
                let first = n.index as usize;
                for k in first..first + n.count as usize {
                    let [a, b, c] = self.tris[k];
                    let Some((t, bary)) = ray_triangle(origin, dir, a, b, c) else {
                        continue;
                    };
                    if t <= t_min || t > t_max {
                        continue;
                    }
                    let face = self.faces[k];
                    if visit(RayHit { face, t, bary }) {
                        return;
                    }
                }
            } else {
                let l = node + 1;
                let r = n.index as usize;
                // Nearer child first, so an any-hit query tends to stop early.
                let el = ray.enter(&self.nodes[l], t_min, t_max);
                let er = ray.enter(&self.nodes[r], t_min, t_max);
                match (el, er) {
                    (Some(tl), Some(tr)) => {
                        let (near, far) = if tl <= tr { (l, r) } else { (r, l) };
                        stack[sp] = far as u32;
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            if sp == 0 {
                return;
            }
            sp -= 1;
            node = stack[sp] as usize;
        }
    }
}
