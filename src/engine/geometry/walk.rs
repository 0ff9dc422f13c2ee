//! Bounded geodesic walks: every vertex within distance `r` of a source vertex, with its
//! distance, as MeshMatch (Chen et al. 2012, section 4.1) needs for its surface patches.
//!
//! Two metrics ([`WalkMetric`]):
//! - `edges`: Dijkstra's algorithm on the edge graph (edge weight = Euclidean edge length).
//!   Exact graph distance; overestimates the geodesic distance (on a regular grid by up to
//!   about 8%, depending on direction), but is fast and exactly reproducible.
//! - `fast_marching` (default): Dijkstra ordering with a triangle update in the style of fast
//!   marching (Kimmel & Sethian 1998): when a vertex `a` is settled, every incident triangle
//!   `(a, b, c)` with `b` settled and `c` not gets the candidate distance of `c` from a virtual
//!   point source unfolded into the triangle's plane, `|c − s|` with `|s − a| = d_a` and
//!   `|s − b| = d_b` (the "exact" point-source update of Surazhsky et al. 2005, section 3), used
//!   only when the straight line from `s` to `c` crosses the edge `ab`; otherwise, and always in
//!   addition, the plain edge updates `d_a + |ac|`. The minimum is kept. On a plane the result is
//!   close to the Euclidean distance (the test bounds the error); it never exceeds the edge
//!   metric's distance.
//!
//! A [`Walker`] keeps O(V) scratch arrays that are reset in O(patch) after each walk, so walking
//! from every vertex costs O(Σ patch sizes · log), not O(V²).
//!
//! Written by hand: a bounded Dijkstra with a reusable workspace is a few dozen lines.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use super::laplacian::GeometryError;
use crate::engine::math::{dot, length, sub};
use crate::engine::mesh::csr::vertex_faces;
use crate::engine::mesh::Surface;

/// Distance metric of a walk.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WalkMetric {
    /// Shortest paths along mesh edges (Dijkstra).
    Edges,
    /// Dijkstra order plus fast-marching style triangle unfolding updates.
    #[default]
    FastMarching,
}

/// Parameters of [`Walker::walk`] / [`geodesic_walk`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WalkParams {
    /// Radius, world units. Default: 1. Range: [0, ∞).
    pub radius: f64,
    /// Metric. Default: `fast_marching`.
    pub metric: WalkMetric,
}

impl Default for WalkParams {
    fn default() -> Self {
        Self {
            radius: 1.0,
            metric: WalkMetric::FastMarching,
        }
    }
}

/// The edge graph and vertex–face incidence of a surface, for walks.
#[derive(Clone, Debug)]
pub struct WalkGraph {
    positions: Vec<[f64; 3]>,
    faces: Vec<[u32; 3]>,
    nbr_offsets: Vec<u32>,
    nbrs: Vec<u32>,
    nbr_lengths: Vec<f64>,
    vf_offsets: Vec<u32>,
    vf: Vec<u32>,
}

impl WalkGraph {
    /// Builds the graph (edges of faces without repeated vertices).
    pub fn new(surface: &Surface) -> Self {
        let positions: Vec<[f64; 3]> = surface
            .positions
            .iter()
            .map(|p| p.map(|c| c as f64))
            .collect();
        let (vf_offsets, vf) = vertex_faces(surface);
        let nv = positions.len();
        let mut nbr_offsets = Vec::with_capacity(nv + 1);
        nbr_offsets.push(0u32);
        let mut nbrs = Vec::new();
        let mut scratch = Vec::new();
        for v in 0..nv {
            scratch.clear();
            for &f in &vf[vf_offsets[v] as usize..vf_offsets[v + 1] as usize] {
                let face = surface.faces[f as usize];
                if face[0] == face[1] || face[1] == face[2] || face[0] == face[2] {
                    continue;
                }
                scratch.extend(face.iter().copied().filter(|&w| w as usize != v));
            }
            scratch.sort_unstable();
            scratch.dedup();
            nbrs.extend_from_slice(&scratch);
            nbr_offsets.push(nbrs.len() as u32);
        }
        let mut nbr_lengths = Vec::with_capacity(nbrs.len());
        for v in 0..nv {
            for &w in &nbrs[nbr_offsets[v] as usize..nbr_offsets[v + 1] as usize] {
                nbr_lengths.push(length(sub(positions[w as usize], positions[v])));
            }
        }
        Self {
            positions,
            faces: surface.faces.clone(),
            nbr_offsets,
            nbrs,
            nbr_lengths,
            vf_offsets,
            vf,
        }
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Entry(f64, u32);

impl Eq for Entry {}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        // Min-heap on distance, then vertex id.
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Reusable workspace for bounded walks over one [`WalkGraph`].
#[derive(Debug)]
pub struct Walker<'g> {
    graph: &'g WalkGraph,
    dist: Vec<f64>,
    settled: Vec<bool>,
    touched: Vec<u32>,
    heap: BinaryHeap<Entry>,
}

impl<'g> Walker<'g> {
    /// A workspace for `graph`.
    pub fn new(graph: &'g WalkGraph) -> Self {
        let n = graph.vertex_count();
        Self {
            graph,
            dist: vec![f64::INFINITY; n],
            settled: vec![false; n],
            touched: Vec::new(),
            heap: BinaryHeap::new(),
        }
    }

    /// All vertices within `params.radius` of `source` (source included, distance 0), with
    /// their distances, in the order they were settled (ascending distance, ties by vertex id).
    ///
    /// # Errors
    /// [`GeometryError::InvalidSource`] for a vertex out of range,
    /// [`GeometryError::InvalidParam`] for a negative or NaN radius.
    pub fn walk(
        &mut self,
        source: u32,
        params: &WalkParams,
    ) -> Result<Vec<(u32, f64)>, GeometryError> {
        if source as usize >= self.graph.vertex_count() {
            return Err(GeometryError::InvalidSource {
                index: 0,
                reason: format!("vertex {source} out of range"),
            });
        }
        if params.radius.is_nan() || params.radius < 0.0 {
            return Err(GeometryError::InvalidParam {
                name: "radius",
                value: params.radius,
                range: "[0, inf)",
            });
        }
        let g = self.graph;
        let r = params.radius;
        let mut out = Vec::new();
        self.relax(source, 0.0);
        while let Some(Entry(d, v)) = self.heap.pop() {
            let vi = v as usize;
            if self.settled[vi] || d > self.dist[vi] {
                continue;
            }
            if d > r {
                break;
            }
            self.settled[vi] = true;
            out.push((v, d));
            let (a, b) = (g.nbr_offsets[vi] as usize, g.nbr_offsets[vi + 1] as usize);
            for k in a..b {
                let w = g.nbrs[k];
                if !self.settled[w as usize] {
                    self.relax(w, d + g.nbr_lengths[k]);
                }
            }
            if params.metric == WalkMetric::FastMarching {
                for &f in &g.vf[g.vf_offsets[vi] as usize..g.vf_offsets[vi + 1] as usize] {
                    let face = g.faces[f as usize];
                    if face[0] == face[1] || face[1] == face[2] || face[0] == face[2] {
                        continue;
                    }
                    let c = face.iter().position(|&x| x == v).unwrap_or(0);
                    let (p, q) = (face[(c + 1) % 3], face[(c + 2) % 3]);
                    for (b, t) in [(p, q), (q, p)] {
                        if self.settled[b as usize] && !self.settled[t as usize] {
                            if let Some(cand) = self.unfold(v, b, t) {
                                self.relax(t, cand);
                            }
                        }
                    }
                }
            }
        }
        for &v in &self.touched {
            self.dist[v as usize] = f64::INFINITY;
            self.settled[v as usize] = false;
        }
        self.touched.clear();
        self.heap.clear();
        Ok(out)
    }

    fn relax(&mut self, v: u32, d: f64) {
        let slot = &mut self.dist[v as usize];
        if d < *slot {
            if slot.is_infinite() {
                self.touched.push(v);
            }
            *slot = d;
            self.heap.push(Entry(d, v));
        }
    }

    /// Point-source unfolding update of `c` from settled `a`, `b` (see the module docs).
    fn unfold(&self, a: u32, b: u32, c: u32) -> Option<f64> {
        let p = &self.graph.positions;
        let (pa, pb, pc) = (p[a as usize], p[b as usize], p[c as usize]);
        let (da, db) = (self.dist[a as usize], self.dist[b as usize]);
        let ab = sub(pb, pa);
        let len = length(ab);
        if len.is_nan() || len <= 0.0 {
            return None;
        }
        let ac = sub(pc, pa);
        // c in the 2D frame with a at the origin and b on the +x axis.
        let cx = dot(ac, ab) / len;
        let cy = (dot(ac, ac) - cx * cx).max(0.0).sqrt();
        if cy.is_nan() || cy <= 0.0 {
            return None;
        }
        let sx = (da * da - db * db + len * len) / (2.0 * len);
        let sy2 = da * da - sx * sx;
        if sy2.is_nan() || sy2 < 0.0 {
            return None;
        }
        let sy = -sy2.sqrt();
        // Where the segment s → c crosses the x axis.
        let t = -sy / (cy - sy);
        let x = sx + t * (cx - sx);
        if !(0.0..=len).contains(&x) {
            return None;
        }
        Some(((cx - sx).powi(2) + (cy - sy).powi(2)).sqrt())
    }
}

/// Convenience: one bounded walk on `surface` (builds a [`WalkGraph`] each call; use a
/// [`Walker`] for many walks).
///
/// # Errors
/// As [`Walker::walk`].
pub fn geodesic_walk(
    surface: &Surface,
    source: u32,
    params: &WalkParams,
) -> Result<Vec<(u32, f64)>, GeometryError> {
    let graph = WalkGraph::new(surface);
    Walker::new(&graph).walk(source, params)
}
