//! Mask extraction (Soler et al. 2002, §4.1): which triangles of the already-textured
//! neighbours form the mask of the current cluster, and where they lie in its frame.
//!
//! For each textured neighbour patch sharing edges with the current cluster, the shared border
//! vertices are known both in the neighbour's placement (pattern pixels) and in the current
//! cluster's flattening (frame pixels); the rigid map between the two (least squares over the
//! shared vertices: rotation and translation, no scale since both are at the user's scale)
//! places the neighbour's band triangles in the current frame. This is the paper's "rigid map of
//! the shared control vertices", taken over every shared border vertex (more points, less
//! noise).
//!
//! Deviation from the paper: the position value that selects the band is not the topological
//! barycentric coordinate of §4.1 (its recursion is garbled in the available text) but the
//! geodesic (Dijkstra over edges) distance from the shared border inside the neighbour patch,
//! divided by the neighbour's extent (the diagonal of its placed bounding box): a face is in the
//! band when a corner's value is below `band`. Both are 0 on the shared border and grow towards
//! the neighbour's far side. Weights are 1 inside the band.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::flatten::Flat;
use super::hierarchy::NONE;
use super::mask::MaskTriangle;
use super::relax::{Corner, SeamEdge};
use crate::engine::mesh::{Surface, Topology};

/// An accepted patch: a cluster with its placement into the pattern.
#[derive(Clone, Debug)]
pub struct Patch {
    /// The cluster.
    pub cluster: u32,
    /// Its vertices (sorted surface indices).
    pub vertices: Vec<u32>,
    /// Their pattern-pixel positions.
    pub px: Vec<[f32; 2]>,
}

impl Patch {
    /// Pattern-pixel position of a vertex of the patch.
    pub fn px_of(&self, v: u32) -> Option<[f32; 2]> {
        self.vertices.binary_search(&v).ok().map(|i| self.px[i])
    }

    /// Diagonal of the placed bounding box, pixels.
    pub fn extent_px(&self) -> f32 {
        let mut lo = [f32::MAX; 2];
        let mut hi = [f32::MIN; 2];
        for p in &self.px {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2)).sqrt()
    }
}

/// An edge of the current cluster shared with a textured patch.
#[derive(Clone, Copy, Debug)]
pub struct SharedEdge {
    /// Its vertices.
    pub vertices: [u32; 2],
    /// The textured patch on the other side.
    pub patch: u32,
}

/// Edges of `faces` whose other side belongs to a textured patch.
pub fn shared_edges(
    surface: &Surface,
    topo: &Topology,
    face_patch: &[u32],
    faces: &[u32],
) -> Vec<SharedEdge> {
    let mut out = Vec::new();
    for f in faces {
        let fv = surface.faces[*f as usize];
        for e in 0..3 {
            if let Some(o) = topo.face_neighbors[*f as usize][e] {
                let p = face_patch[o as usize];
                if p != NONE {
                    out.push(SharedEdge {
                        vertices: [fv[e], fv[(e + 1) % 3]],
                        patch: p,
                    });
                }
            }
        }
    }
    out
}

/// Distinct textured patches across the shared edges.
pub fn neighbour_patches(edges: &[SharedEdge]) -> Vec<u32> {
    let mut p: Vec<u32> = edges.iter().map(|e| e.patch).collect();
    p.sort_unstable();
    p.dedup();
    p
}

/// Least-squares rigid map (rotation, translation) taking `from[i]` onto `to[i]`.
pub fn rigid_fit(from: &[[f64; 2]], to: &[[f64; 2]]) -> impl Fn([f64; 2]) -> [f64; 2] {
    let n = from.len().max(1) as f64;
    let mean = |s: &[[f64; 2]]| {
        let mut m = [0.0; 2];
        for p in s {
            m[0] += p[0] / n;
            m[1] += p[1] / n;
        }
        m
    };
    let (cf, ct) = (mean(from), mean(to));
    let (mut sc, mut ss) = (0.0, 0.0);
    for (a, b) in from.iter().zip(to) {
        let (ax, ay) = (a[0] - cf[0], a[1] - cf[1]);
        let (bx, by) = (b[0] - ct[0], b[1] - ct[1]);
        sc += ax * bx + ay * by;
        ss += ax * by - ay * bx;
    }
    let th = ss.atan2(sc);
    let (s, c) = th.sin_cos();
    move |p: [f64; 2]| {
        let (x, y) = (p[0] - cf[0], p[1] - cf[1]);
        [c * x - s * y + ct[0], s * x + c * y + ct[1]]
    }
}

/// Inputs shared by the band extraction of one cluster.
pub struct BandInput<'a> {
    /// The surface.
    pub surface: &'a Surface,
    /// Its adjacency.
    pub topo: &'a Topology,
    /// Accepted patches.
    pub patches: &'a [Patch],
    /// Patch of each face, or [`NONE`].
    pub face_patch: &'a [u32],
    /// Pattern pixels per world unit.
    pub px_per_world: f64,
    /// Band width (fraction of a neighbour's extent).
    pub band: f32,
}

/// The mask triangles of the current cluster (flattened as `flat`) from its textured
/// neighbours across `edges`.
pub fn band_triangles(
    input: &BandInput<'_>,
    flat: &Flat,
    edges: &[SharedEdge],
) -> Vec<MaskTriangle> {
    let mut out = Vec::new();
    for p in neighbour_patches(edges) {
        let patch = &input.patches[p as usize];
        let mut shared: Vec<u32> = edges
            .iter()
            .filter(|e| e.patch == p)
            .flat_map(|e| e.vertices)
            .collect();
        shared.sort_unstable();
        shared.dedup();
        let (mut from, mut to) = (Vec::new(), Vec::new());
        for v in &shared {
            if let (Some(a), Some(b)) = (patch.px_of(*v), flat.at(*v)) {
                from.push([f64::from(a[0]), f64::from(a[1])]);
                to.push([b[0] * input.px_per_world, b[1] * input.px_per_world]);
            }
        }
        if from.len() < 2 {
            continue;
        }
        let map = rigid_fit(&from, &to);
        let limit = f64::from(input.band) * f64::from(patch.extent_px()) / input.px_per_world;
        for f in band_faces(input, p, &shared, limit) {
            let fv = input.surface.faces[f as usize];
            let Some(pat) = fv
                .iter()
                .map(|v| patch.px_of(*v))
                .collect::<Option<Vec<_>>>()
            else {
                continue;
            };
            let pattern_px = [pat[0], pat[1], pat[2]];
            let frame_px = pattern_px.map(|q| {
                let m = map([f64::from(q[0]), f64::from(q[1])]);
                [m[0] as f32, m[1] as f32]
            });
            out.push(MaskTriangle {
                frame_px,
                pattern_px,
                weight: [1.0; 3],
            });
        }
    }
    out
}

/// Faces of patch `p` with a corner closer than `limit` (world units, along edges inside the
/// patch) to the shared vertices.
fn band_faces(input: &BandInput<'_>, p: u32, shared: &[u32], limit: f64) -> Vec<u32> {
    let (surface, topo) = (input.surface, input.topo);
    let mut dist: std::collections::HashMap<u32, f64> = std::collections::HashMap::new();
    let mut heap = BinaryHeap::new();
    for v in shared {
        dist.insert(*v, 0.0);
        heap.push(Reverse((0u64, *v)));
    }
    let mut faces = Vec::new();
    while let Some(Reverse((d, v))) = heap.pop() {
        let d = f64::from_bits(d);
        if dist.get(&v).is_some_and(|x| *x < d) {
            continue;
        }
        for f in topo.vertex_faces(v as usize) {
            if input.face_patch[*f as usize] != p {
                continue;
            }
            faces.push(*f);
            for w in surface.faces[*f as usize] {
                if w == v {
                    continue;
                }
                let a = surface.positions[v as usize];
                let b = surface.positions[w as usize];
                let l = (0..3)
                    .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let nd = d + l;
                if nd < limit && dist.get(&w).is_none_or(|x| nd < *x) {
                    dist.insert(w, nd);
                    heap.push(Reverse((nd.to_bits(), w)));
                }
            }
        }
    }
    faces.sort_unstable();
    faces.dedup();
    faces
}

/// The seam edges of the relaxation: every shared edge, our corners movable (index into
/// `movable`), theirs at the neighbour's placement.
pub fn seam_edges(patches: &[Patch], edges: &[SharedEdge], movable: &[u32]) -> Vec<SeamEdge> {
    let mut out = Vec::new();
    for e in edges {
        let patch = &patches[e.patch as usize];
        let (Some(a), Some(b)) = (patch.px_of(e.vertices[0]), patch.px_of(e.vertices[1])) else {
            continue;
        };
        let corner = |v: u32| movable.binary_search(&v).ok().map(Corner::Movable);
        let (Some(ca), Some(cb)) = (corner(e.vertices[0]), corner(e.vertices[1])) else {
            continue;
        };
        out.push(SeamEdge {
            ours: [ca, cb],
            theirs_px: [a, b],
            weight: 1.0,
        });
    }
    out
}
