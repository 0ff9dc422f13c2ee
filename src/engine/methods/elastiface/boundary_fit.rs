//! Boundary onto boundary in the registration of the originals (ours; the paper's §3.1 /
//! Fig. 5 pairs boundary loops only through the derived correspondences).
//!
//! The derived pairs of a paired loop ([`super::boundary`]) weigh little by design (all of them
//! together no more than the hand-placed pairs), and in the originals' stage the reference term
//! has the paper's μ3 = 0.1 against a fitting weight of 300. The closest point of a source
//! boundary vertex on the target *surface* then decides where it goes, and a boundary vertex
//! that the earlier stages left inside the target's boundary stays inside: the open disc of the
//! tests kept one boundary vertex folded 4 % of the diagonal inward (README "elastiface").
//!
//! So in the closest-point rounds of [`super::originals`], every vertex of a paired source loop
//! takes as its fitting target its closest point on the **paired target loop** (a polyline)
//! instead of on the surface: a user who pairs two loops says that one lies on the other.
//! Loops with no anchor, such as a template's neck where the target goes on to the shoulders,
//! keep the surface's closest point. `params.boundary_to_boundary = false` turns this off.
//!
//! The polylines are searched with the project's triangle hierarchy, each edge a degenerate
//! triangle `[a, b, a]`, filtered to the vertex's own target loop.

use crate::engine::spatial::Bvh;

use super::boundary::LoopPair;

/// The paired target loops as one searchable set of edges.
pub struct BoundaryFit {
    bvh: Bvh,
    /// Per edge (degenerate triangle of `bvh`): the index of its loop pair.
    edge_loop: Vec<u32>,
    /// Source vertices on a paired loop, with that loop pair's index.
    vertices: Vec<(u32, u32)>,
}

impl std::fmt::Debug for BoundaryFit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BoundaryFit")
            .field("edges", &self.edge_loop.len())
            .field("vertices", &self.vertices.len())
            .finish()
    }
}

impl BoundaryFit {
    /// The set for `pairs`, the target at `target_x` (solve frame). `None` when no loop is
    /// paired.
    pub fn new(pairs: &[LoopPair], target_x: &[[f64; 3]]) -> Option<BoundaryFit> {
        if pairs.is_empty() {
            return None;
        }
        let x32: Vec<[f32; 3]> = target_x.iter().map(|p| p.map(|c| c as f32)).collect();
        let mut edges = Vec::new();
        let mut edge_loop = Vec::new();
        let mut vertices = Vec::new();
        for (k, pair) in pairs.iter().enumerate() {
            let n = pair.target.len();
            for i in 0..n {
                let (a, b) = (pair.target[i], pair.target[(i + 1) % n]);
                edges.push([a, b, a]);
                edge_loop.push(k as u32);
            }
            vertices.extend(pair.source.iter().map(|&v| (v, k as u32)));
        }
        Some(BoundaryFit {
            bvh: Bvh::build(&x32, &edges),
            edge_loop,
            vertices,
        })
    }

    /// Replaces the fitting target `c[v]` of every paired source boundary vertex by its
    /// closest point (from `x[v]`) on its paired target loop.
    pub fn snap(&self, x: &[[f64; 3]], c: &mut [[f64; 3]]) {
        for &(v, k) in &self.vertices {
            let q = x[v as usize].map(|c| c as f32);
            let hit = self
                .bvh
                .closest_point_filtered(q, f32::INFINITY, |e| self.edge_loop[e as usize] == k);
            if let Some(h) = hit {
                c[v as usize] = h.point.map(f64::from);
            }
        }
    }

    /// Number of source vertices snapped by [`Self::snap`].
    pub fn vertex_count(&self) -> usize {
        self.vertices.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two square loops at heights 0 and 1; source vertices of loop 0 snap onto the square at
    /// height 0 only, even when the other square is nearer.
    #[test]
    fn snaps_onto_the_paired_loop_only() {
        let square = |z: f64| [[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]];
        let mut tx = square(0.0).to_vec();
        tx.extend(square(1.0));
        let pairs = [
            LoopPair {
                source: vec![0, 1],
                target: vec![0, 1, 2, 3],
            },
            LoopPair {
                source: vec![2],
                target: vec![4, 5, 6, 7],
            },
        ];
        let fit = BoundaryFit::new(&pairs, &tx).unwrap();
        assert_eq!(fit.vertex_count(), 3);
        // Vertex 0 sits just below the upper square: it still snaps onto the lower one.
        let x = [
            [0.5, -0.2, 0.9],
            [1.3, 0.5, 0.1],
            [0.5, 0.5, 0.2],
            [9.0, 9.0, 9.0],
        ];
        let mut c = [[7.0; 3]; 4];
        fit.snap(&x, &mut c);
        let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6);
        assert!(near(c[0], [0.5, 0.0, 0.0]), "{:?}", c[0]);
        assert!(near(c[1], [1.0, 0.5, 0.0]), "{:?}", c[1]);
        // Vertex 2 (inside the upper square's outline, nearer the lower) goes to the upper
        // square's nearest edge.
        assert!((c[2][2] - 1.0).abs() < 1e-6, "{:?}", c[2]);
        // A vertex on no paired loop keeps its target.
        assert_eq!(c[3], [7.0; 3]);
        assert!(BoundaryFit::new(&[], &tx).is_none());
    }
}
