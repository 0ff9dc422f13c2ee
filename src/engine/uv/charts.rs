//! Chart segmentation: region growing on normal deviation (the "feature-driven" charts of Lévy
//! et al. 2002, §4, replaced by a simpler growth, see below), a disc test per chart (Euler
//! characteristic 1, one boundary loop, manifold edges and vertices) and the split used when a
//! chart fails the disc test, the stretch bound or has a flipped triangle.
//!
//! Deviation from Lévy et al. 2002 §4 (feature detection, then charts grown from seeds far from
//! features with seams on the features): charts grow from the lowest-index unassigned face by a
//! best-first flood over manifold edges, accepting a face while its normal is within
//! `max_normal_deviation` of the chart's area-weighted mean normal (the "normal cone" criterion
//! of D-charts / Smart-UV-Project). Why: it needs no feature-curve extraction, is linear time,
//! deterministic, and with the stretch bound checked after LSCM (and a split when it fails) it
//! gives the same guarantee the feature step is there for (charts that flatten with bounded
//! distortion). Seams therefore fall where normals turn, i.e. at creases, not necessarily on
//! hidden edges.
//!
//! The split is a bisection: the chart's faces are ordered by their centroid's coordinate
//! along the chart's longest bounding-box axis (ties by face index) and cut at the median, then
//! each half is divided into its edge-connected components. Both halves are non-empty for two
//! or more faces, so repeated splits terminate at single triangles, which flatten isometrically.
//! Edges shared by more than two faces are never crossed (they become seams: the documented
//! fallback for non-manifold input).

use std::collections::BinaryHeap;

use rayon::prelude::*;

use crate::engine::mesh::Surface;

/// Face adjacency across manifold edges (exactly two faces on the edge).
pub struct Adjacency {
    /// Per face, per edge `(v_k, v_{k+1})`: the face on the other side.
    pub neighbors: Vec<[Option<u32>; 3]>,
    /// Unit face normals.
    pub normals: Vec<[f64; 3]>,
    /// Face areas.
    pub areas: Vec<f64>,
}

/// Undirected edge key.
pub fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// Undirected edge key packed in one integer (smaller vertex in the high half).
fn packed_key(a: u32, b: u32) -> u64 {
    let (lo, hi) = edge_key(a, b);
    (u64::from(lo) << 32) | u64::from(hi)
}

/// Builds the adjacency (edges with more than two faces are left unconnected).
pub fn adjacency(surface: &Surface) -> Adjacency {
    let nf = surface.faces.len();
    // (edge, face, corner), sorted: the faces of each edge are one run.
    let mut edges: Vec<(u64, u32, u8)> = Vec::with_capacity(nf * 3);
    for (f, fv) in surface.faces.iter().enumerate() {
        for k in 0..3 {
            edges.push((packed_key(fv[k], fv[(k + 1) % 3]), f as u32, k as u8));
        }
    }
    edges.par_sort_unstable();
    let mut neighbors = vec![[None; 3]; nf];
    let mut start = 0;
    while start < edges.len() {
        let mut end = start + 1;
        while end < edges.len() && edges[end].0 == edges[start].0 {
            end += 1;
        }
        if end - start == 2 {
            let ((_, f, k), (_, g, l)) = (edges[start], edges[start + 1]);
            neighbors[f as usize][k as usize] = Some(g);
            neighbors[g as usize][l as usize] = Some(f);
        }
        start = end;
    }
    let (normals, areas): (Vec<[f64; 3]>, Vec<f64>) = (0..nf)
        .into_par_iter()
        .map(|f| {
            let p = surface.face_positions(f).map(|c| c.map(f64::from));
            let e1 = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
            let e2 = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
            let n = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let normal = if len > 0.0 {
                n.map(|c| c / len)
            } else {
                [0.0; 3]
            };
            (normal, 0.5 * len)
        })
        .unzip();
    Adjacency {
        neighbors,
        normals,
        areas,
    }
}

/// Candidate of the best-first growth: smaller deviation first, then lower face index.
#[derive(PartialEq)]
struct Candidate {
    cos: f64,
    face: u32,
}

impl Eq for Candidate {}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.cos
            .total_cmp(&other.cos)
            .then(other.face.cmp(&self.face))
    }
}

/// Grows charts over all faces (see the module doc). Returns the faces of each chart, each list
/// sorted.
pub fn grow(adj: &Adjacency, max_normal_deviation_deg: f64) -> Vec<Vec<u32>> {
    let nf = adj.normals.len();
    let cos_max = max_normal_deviation_deg.to_radians().cos();
    let mut chart_of = vec![u32::MAX; nf];
    let mut charts: Vec<Vec<u32>> = Vec::new();
    for seed in 0..nf {
        if chart_of[seed] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let mut faces = vec![seed as u32];
        chart_of[seed] = id;
        let mut sum = adj.normals[seed].map(|c| c * adj.areas[seed].max(1e-300));
        let mut heap = BinaryHeap::new();
        let push = |heap: &mut BinaryHeap<Candidate>, f: usize, sum: [f64; 3]| {
            for g in adj.neighbors[f].iter().flatten() {
                let n = adj.normals[*g as usize];
                heap.push(Candidate {
                    cos: cosine(sum, n),
                    face: *g,
                });
            }
        };
        push(&mut heap, seed, sum);
        while let Some(c) = heap.pop() {
            let f = c.face as usize;
            if chart_of[f] != u32::MAX {
                continue;
            }
            // The key may be stale: the mean normal moved since it was pushed.
            if cosine(sum, adj.normals[f]) < cos_max {
                continue;
            }
            chart_of[f] = id;
            faces.push(f as u32);
            for k in 0..3 {
                sum[k] += adj.normals[f][k] * adj.areas[f].max(1e-300);
            }
            push(&mut heap, f, sum);
        }
        faces.sort_unstable();
        charts.push(faces);
    }
    charts
}

fn cosine(sum: [f64; 3], n: [f64; 3]) -> f64 {
    let len = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
    if len <= 0.0 {
        return 1.0;
    }
    (sum[0] * n[0] + sum[1] * n[1] + sum[2] * n[2]) / len
}

/// Whether the chart is a topological disc: connected (assumed, charts are grown or split
/// into components), no edge with more than two faces, every edge's two faces oriented
/// consistently, V − E + F = 1 and every boundary vertex on exactly two boundary edges (one
/// boundary loop, no pinched vertex).
pub fn is_disc(surface: &Surface, faces: &[u32]) -> bool {
    // (edge, +1 when the face runs along it from the smaller vertex, −1 otherwise), sorted.
    let mut edges: Vec<(u64, i8)> = Vec::with_capacity(faces.len() * 3);
    let mut vertices: Vec<u32> = Vec::with_capacity(faces.len() * 3);
    for f in faces {
        let fv = surface.faces[*f as usize];
        for k in 0..3 {
            let (a, b) = (fv[k], fv[(k + 1) % 3]);
            edges.push((packed_key(a, b), if a < b { 1 } else { -1 }));
        }
        vertices.extend_from_slice(&fv);
    }
    edges.sort_unstable();
    vertices.sort_unstable();
    vertices.dedup();
    let mut boundary: Vec<u32> = Vec::new();
    let mut edge_count = 0i64;
    let mut start = 0;
    while start < edges.len() {
        let mut end = start + 1;
        while end < edges.len() && edges[end].0 == edges[start].0 {
            end += 1;
        }
        edge_count += 1;
        match end - start {
            1 => {
                let key = edges[start].0;
                boundary.push((key >> 32) as u32);
                boundary.push(key as u32);
            }
            2 if edges[start].1 + edges[start + 1].1 == 0 => {}
            _ => return false,
        }
        start = end;
    }
    let chi = vertices.len() as i64 - edge_count + faces.len() as i64;
    if chi != 1 || boundary.is_empty() {
        return false;
    }
    boundary.sort_unstable();
    // Every boundary vertex exactly twice.
    boundary.chunks(2).all(|c| c[0] == c[1])
        && boundary.windows(3).all(|w| !(w[0] == w[1] && w[1] == w[2]))
}

/// Splits a chart of two or more faces into the connected components of its two median halves
/// (see the module doc).
pub fn split(surface: &Surface, adj: &Adjacency, faces: &[u32]) -> Vec<Vec<u32>> {
    let centroid = |f: u32| {
        let p = surface.face_positions(f as usize);
        [0, 1, 2].map(|k| (f64::from(p[0][k]) + f64::from(p[1][k]) + f64::from(p[2][k])) / 3.0)
    };
    let mut lo = [f64::MAX; 3];
    let mut hi = [f64::MIN; 3];
    for f in faces {
        let c = centroid(*f);
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let axis = (0..3)
        .max_by(|a, b| {
            (hi[*a] - lo[*a])
                .total_cmp(&(hi[*b] - lo[*b]))
                .then(b.cmp(a))
        })
        .unwrap_or(0);
    let mut order: Vec<(f64, u32)> = faces.iter().map(|f| (centroid(*f)[axis], *f)).collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let half = order.len() / 2;
    let mut parts = Vec::new();
    for side in [&order[..half], &order[half..]] {
        let mut list: Vec<u32> = side.iter().map(|x| x.1).collect();
        list.sort_unstable();
        parts.extend(components(adj, &list));
    }
    parts
}

/// [`components`] of every chart of a partition of some of the faces (`charts`, each sorted),
/// in chart order: the same lists, found with one label per face instead of a binary search
/// per neighbour (the first round of the atlas has charts of 80k faces).
pub fn components_of_charts(adj: &Adjacency, charts: &[Vec<u32>]) -> Vec<Vec<u32>> {
    const NONE: u32 = u32::MAX;
    let mut label = vec![NONE; adj.neighbors.len()];
    for (c, faces) in charts.iter().enumerate() {
        for f in faces {
            label[*f as usize] = c as u32;
        }
    }
    let mut out = Vec::new();
    for (c, faces) in charts.iter().enumerate() {
        for f in faces {
            if label[*f as usize] != c as u32 {
                continue;
            }
            // Visited faces are relabelled NONE.
            label[*f as usize] = NONE;
            let mut comp = vec![*f];
            let mut i = 0;
            while i < comp.len() {
                let g = comp[i];
                for h in adj.neighbors[g as usize].iter().flatten() {
                    if label[*h as usize] == c as u32 {
                        label[*h as usize] = NONE;
                        comp.push(*h);
                    }
                }
                i += 1;
            }
            comp.sort_unstable();
            out.push(comp);
        }
    }
    out
}

/// Edge-connected components of a sorted face list, each sorted, ordered by first face.
pub fn components(adj: &Adjacency, faces: &[u32]) -> Vec<Vec<u32>> {
    let mut seen = vec![false; faces.len()];
    let mut out = Vec::new();
    for (start, f) in faces.iter().enumerate() {
        if seen[start] {
            continue;
        }
        let mut comp = vec![*f];
        seen[start] = true;
        let mut i = 0;
        while i < comp.len() {
            let g = comp[i];
            for h in adj.neighbors[g as usize].iter().flatten() {
                if let Ok(at) = faces.binary_search(h) {
                    if !seen[at] {
                        seen[at] = true;
                        comp.push(*h);
                    }
                }
            }
            i += 1;
        }
        comp.sort_unstable();
        out.push(comp);
    }
    out
}
