//! Adjacency of a [`Surface`]: face neighbours across edges, vertex one-rings, boundary loops,
//! non-manifold edges, connected components and the Euler characteristic.
//!
//! Conventions:
//! - Edge `i` of a face runs from corner `i` to corner `(i + 1) % 3`.
//! - An edge used by exactly one face is a boundary edge; by exactly two faces a manifold edge
//!   (the faces are neighbours, whether or not their windings agree); by more than two a
//!   non-manifold edge (no neighbours recorded across it).
//! - Boundary loops follow the boundary edges in their faces' winding direction (for a
//!   counter-clockwise disk seen from its normal side, the boundary runs counter-clockwise). At a
//!   vertex where several boundary loops touch, the outgoing edge with the lowest (vertex, face)
//!   order is taken first, so the result is deterministic.
//! - Components connect faces that share an edge (manifold or not); they are numbered in the
//!   order of their lowest face index.
//! - The Euler characteristic is `V - E + F` with `V` the vertices used by at least one face, `E`
//!   the distinct undirected edges and `F` the faces.
//!
//! Written by hand: a sort-based edge table is all this needs.

use super::csr::group_by_key;
use super::surface::Surface;

/// Adjacency of a surface, built by [`topology`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Topology {
    /// Per face, per edge (corner i → corner i+1): the face across it; `None` on boundary and
    /// non-manifold edges.
    pub face_neighbors: Vec<[Option<u32>; 3]>,
    /// CSR offsets into `vertex_faces`, `vertex_count + 1` entries.
    pub vertex_faces_offsets: Vec<u32>,
    /// The faces around each vertex, ascending, each face once.
    pub vertex_faces: Vec<u32>,
    /// Boundary loops as vertex indices in boundary order (first vertex not repeated at the end).
    pub boundary_loops: Vec<Vec<u32>>,
    /// Number of edges used by more than two faces.
    pub non_manifold_edges: usize,
    /// Component index per face.
    pub face_component: Vec<u32>,
    /// Number of connected components (over faces).
    pub component_count: usize,
    /// `V - E + F` (see the module docs).
    pub euler_characteristic: i64,
}

impl Topology {
    /// The faces incident to vertex `v`, ascending.
    pub fn vertex_faces(&self, v: usize) -> &[u32] {
        let a = self.vertex_faces_offsets[v] as usize;
        let b = self.vertex_faces_offsets[v + 1] as usize;
        &self.vertex_faces[a..b]
    }
}

/// A directed edge occurrence: (low vertex, high vertex, face, edge index within the face).
type EdgeKey = (u32, u32, u32, u8);

/// Builds the [`Topology`] of `surface`.
pub fn topology(surface: &Surface) -> Topology {
    let nf = surface.faces.len();
    let nv = surface.positions.len();

    // Edge table sorted by undirected edge, then face and edge index (a total order, so the
    // unstable parallel sort is deterministic).
    let mut edges: Vec<EdgeKey> = Vec::with_capacity(nf * 3);
    for (f, face) in surface.faces.iter().enumerate() {
        for i in 0..3 {
            let (a, b) = (face[i], face[(i + 1) % 3]);
            if a != b {
                edges.push((a.min(b), a.max(b), f as u32, i as u8));
            }
        }
    }
    {
        use rayon::slice::ParallelSliceMut;
        edges.par_sort_unstable();
    }

    let mut face_neighbors = vec![[None; 3]; nf];
    let mut non_manifold_edges = 0;
    let mut undirected_edges: i64 = 0;
    let mut parent: Vec<u32> = (0..nf as u32).collect();
    // Boundary half-edges as (from, to, face).
    let mut boundary: Vec<(u32, u32, u32)> = Vec::new();
    let mut start = 0;
    while start < edges.len() {
        let (a, b, _, _) = edges[start];
        let mut end = start + 1;
        while end < edges.len() && edges[end].0 == a && edges[end].1 == b {
            end += 1;
        }
        let group = &edges[start..end];
        undirected_edges += 1;
        match group.len() {
            1 => {
                let (_, _, f, i) = group[0];
                let face = surface.faces[f as usize];
                boundary.push((face[i as usize], face[(i as usize + 1) % 3], f));
            }
            2 => {
                let (_, _, f0, i0) = group[0];
                let (_, _, f1, i1) = group[1];
                if f0 != f1 {
                    face_neighbors[f0 as usize][i0 as usize] = Some(f1);
                    face_neighbors[f1 as usize][i1 as usize] = Some(f0);
                }
            }
            _ => non_manifold_edges += 1,
        }
        for w in group.windows(2) {
            union(&mut parent, w[0].2, w[1].2);
        }
        start = end;
    }

    // Components numbered by lowest face.
    let mut face_component = vec![u32::MAX; nf];
    let mut root_label = vec![u32::MAX; nf];
    let mut component_count = 0usize;
    for (f, comp) in face_component.iter_mut().enumerate() {
        let r = find(&mut parent, f as u32) as usize;
        if root_label[r] == u32::MAX {
            root_label[r] = component_count as u32;
            component_count += 1;
        }
        *comp = root_label[r];
    }

    // Vertex → faces CSR (faces ascending, each face once per vertex).
    let distinct = |face: &[u32; 3]| {
        let mut out = [Some(face[0]), None, None];
        if face[1] != face[0] {
            out[1] = Some(face[1]);
        }
        if face[2] != face[0] && face[2] != face[1] {
            out[2] = Some(face[2]);
        }
        out
    };
    let corners = surface.faces.iter().enumerate().flat_map(|(f, face)| {
        distinct(face)
            .into_iter()
            .flatten()
            .map(move |v| (v, f as u32))
    });
    let (vertex_faces_offsets, vertex_faces) = group_by_key(nv, corners);
    let used_vertices = (0..nv)
        .filter(|&v| vertex_faces_offsets[v + 1] > vertex_faces_offsets[v])
        .count();

    let boundary_loops = trace_boundary_loops(boundary);
    let euler_characteristic = used_vertices as i64 - undirected_edges + nf as i64;

    Topology {
        face_neighbors,
        vertex_faces_offsets,
        vertex_faces,
        boundary_loops,
        non_manifold_edges,
        face_component,
        component_count,
        euler_characteristic,
    }
}

/// Chains boundary half-edges `(from, to, face)` into loops.
fn trace_boundary_loops(mut boundary: Vec<(u32, u32, u32)>) -> Vec<Vec<u32>> {
    boundary.sort_unstable();
    let mut used = vec![false; boundary.len()];
    let mut loops = Vec::new();
    for first in 0..boundary.len() {
        if used[first] {
            continue;
        }
        used[first] = true;
        let origin = boundary[first].0;
        let mut lp = vec![origin];
        let mut current = boundary[first].1;
        while current != origin {
            lp.push(current);
            // First unused outgoing boundary half-edge from `current`.
            let lo = boundary.partition_point(|e| e.0 < current);
            let next = (lo..boundary.len())
                .take_while(|&k| boundary[k].0 == current)
                .find(|&k| !used[k]);
            match next {
                Some(k) => {
                    used[k] = true;
                    current = boundary[k].1;
                }
                // Open chain (inconsistent winding along the boundary): end the loop here.
                None => break,
            }
        }
        loops.push(lp);
    }
    loops
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        // Lower root wins: keeps the structure independent of visiting order details.
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        parent[hi as usize] = lo;
    }
}
