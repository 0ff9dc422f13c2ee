//! Refinement by edge splitting: every edge longer than a threshold is split at its midpoint and
//! each triangle is re-triangulated according to how many of its edges were split (1 → 2, 2 → 3,
//! 3 → 4 triangles), which keeps the mesh conforming (no T-junctions) because the split decision
//! is made per edge. Passes repeat until no edge is too long. The geometry does not change: new
//! vertices lie on the old edges, and each records its two parents so any per-vertex attribute
//! can be interpolated (DESIGN.md: "refine edges until a requested sample count or texel size").
//!
//! Every vertex also records where it lies on the *input* mesh as a [`FacePoint`] (input face and
//! barycentric weights), so a field computed on the refined mesh can be baked back onto the input
//! surface (and its texture). A new vertex takes the input face of the first refined triangle
//! (in triangle order) that contains its edge; its weights are the mean of its two parents'
//! weights in that face (a parent recorded on a neighbouring input face lies on the shared edge or
//! corner, and its non-zero weights are carried over to the matching corners). Input vertices
//! record the lowest-numbered face that uses them, with weight 1 on their own corner.
//!
//! Used where a target has too few vertices to carry a per-vertex field (COLOR_0 on a target
//! without UVs). Deterministic: new vertices are numbered in order of first appearance.
//! [`super::resample`] splits longest-first to an exact vertex count instead of in passes.

use std::collections::HashMap;

use super::FacePoint;
use crate::engine::math::dist2;

/// Parameters of [`refine`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineParams {
    /// Split edges longer than this, in the mesh's units. Default: f32::INFINITY (no split).
    pub max_edge_length: f32,
    /// Stop once the mesh has this many triangles. Default 4,000,000. Range 1..=50,000,000.
    pub max_triangles: usize,
    /// At most this many passes. Default 24.
    pub max_passes: usize,
}

impl Default for RefineParams {
    fn default() -> Self {
        Self {
            max_edge_length: f32::INFINITY,
            max_triangles: 4_000_000,
            max_passes: 24,
        }
    }
}

/// The refined mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct Refined {
    /// Positions: the input's, then the new midpoints.
    pub positions: Vec<[f32; 3]>,
    /// Triangles of the refined mesh.
    pub triangles: Vec<[u32; 3]>,
    /// For vertex `input_count + k`, the two vertices whose midpoint it is (which may themselves
    /// be new vertices with smaller indices).
    pub parents: Vec<[u32; 2]>,
    /// Number of input vertices.
    pub input_count: usize,
    /// For every vertex (input and new): its point on the input mesh. Input vertices used by no
    /// triangle get [`FacePoint::NONE`].
    pub sources: Vec<FacePoint>,
    /// For every refined triangle: the input triangle it lies in.
    pub triangle_faces: Vec<u32>,
}

impl Refined {
    /// Interpolates a per-vertex attribute of the input onto all refined vertices (midpoint
    /// average, parents first). `values.len()` must equal the input vertex count.
    pub fn interpolate<const N: usize>(&self, values: &[[f32; N]]) -> Vec<[f32; N]> {
        let mut out = values.to_vec();
        out.reserve(self.parents.len());
        for [a, b] in &self.parents {
            let (va, vb) = (out[*a as usize], out[*b as usize]);
            let mut m = [0.0; N];
            for k in 0..N {
                m[k] = 0.5 * (va[k] + vb[k]);
            }
            out.push(m);
        }
        out
    }
}

/// The sources of the input vertices: the lowest-numbered face using each, weight 1 on its corner.
pub(crate) fn input_sources(vertex_count: usize, triangles: &[[u32; 3]]) -> Vec<FacePoint> {
    let mut out = vec![FacePoint::NONE; vertex_count];
    for (f, t) in triangles.iter().enumerate().rev() {
        for k in 0..3 {
            let mut bary = [0.0; 3];
            bary[k] = 1.0;
            out[t[k] as usize] = FacePoint {
                face: f as u32,
                bary,
            };
        }
    }
    out
}

/// Weights of `src` (a point on an input face) with respect to input face `face`, where the point
/// lies on `face` or on its boundary; `None` when a non-zero weight falls on a corner `face` lacks.
pub(crate) fn weights_in(input: &[[u32; 3]], face: u32, src: FacePoint) -> Option<[f32; 3]> {
    if src.face == face {
        return Some(src.bary);
    }
    let from = input.get(src.face as usize)?;
    let to = input[face as usize];
    let mut out = [0.0f32; 3];
    for k in 0..3 {
        if src.bary[k] != 0.0 {
            let j = to.iter().position(|&v| v == from[k])?;
            out[j] += src.bary[k];
        }
    }
    Some(out)
}

/// Source of the midpoint of `a` and `b`, both on (or on the boundary of) input face `face`.
pub(crate) fn midpoint_source(
    input: &[[u32; 3]],
    face: u32,
    sa: FacePoint,
    sb: FacePoint,
) -> FacePoint {
    match (weights_in(input, face, sa), weights_in(input, face, sb)) {
        (Some(wa), Some(wb)) => FacePoint {
            face,
            bary: std::array::from_fn(|k| 0.5 * (wa[k] + wb[k])),
        },
        // Unreachable for conforming input (both ends lie on the face); keep the nearer record.
        _ => sa,
    }
}

/// Splits edges longer than `params.max_edge_length` until none is, or a cap is reached.
pub fn refine(positions: &[[f32; 3]], triangles: &[[u32; 3]], params: &RefineParams) -> Refined {
    let mut out = Refined {
        positions: positions.to_vec(),
        triangles: triangles.to_vec(),
        parents: Vec::new(),
        input_count: positions.len(),
        sources: input_sources(positions.len(), triangles),
        triangle_faces: (0..triangles.len() as u32).collect(),
    };
    let limit2 = params.max_edge_length * params.max_edge_length;
    if limit2.is_nan() || limit2 <= 0.0 {
        return out;
    }
    for _ in 0..params.max_passes {
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
        let mut any = false;
        // Decide splits per edge; assign indices in order of first appearance.
        for (ti, t) in out.triangles.iter().enumerate() {
            let origin = out.triangle_faces[ti];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                if midpoints.contains_key(&key) {
                    continue;
                }
                if dist2(out.positions[a as usize], out.positions[b as usize]) > limit2 {
                    let (pa, pb) = (out.positions[key.0 as usize], out.positions[key.1 as usize]);
                    let m = [
                        0.5 * (pa[0] + pb[0]),
                        0.5 * (pa[1] + pb[1]),
                        0.5 * (pa[2] + pb[2]),
                    ];
                    midpoints.insert(key, out.positions.len() as u32);
                    out.positions.push(m);
                    out.parents.push([key.0, key.1]);
                    out.sources.push(midpoint_source(
                        triangles,
                        origin,
                        out.sources[key.0 as usize],
                        out.sources[key.1 as usize],
                    ));
                    any = true;
                }
            }
        }
        if !any {
            break;
        }
        let mid = |a: u32, b: u32| midpoints.get(&(a.min(b), a.max(b))).copied();
        let mut next = Vec::with_capacity(out.triangles.len() * 2);
        let mut next_faces = Vec::with_capacity(out.triangles.len() * 2);
        for (ti, &[a, b, c]) in out.triangles.iter().enumerate() {
            let (mab, mbc, mca) = (mid(a, b), mid(b, c), mid(c, a));
            match (mab, mbc, mca) {
                (None, None, None) => next.push([a, b, c]),
                (Some(x), Some(y), Some(z)) => {
                    next.extend_from_slice(&[[a, x, z], [x, b, y], [z, y, c], [x, y, z]]);
                }
                (Some(x), None, None) => next.extend_from_slice(&[[a, x, c], [x, b, c]]),
                (None, Some(y), None) => next.extend_from_slice(&[[a, b, y], [a, y, c]]),
                (None, None, Some(z)) => next.extend_from_slice(&[[a, b, z], [z, b, c]]),
                // Two split edges: rotate so the unsplit edge is (c, a) and cut along the shorter
                // diagonal of the remaining quad.
                (Some(x), Some(y), None) => split_two(&out.positions, [a, b, c], x, y, &mut next),
                (None, Some(y), Some(z)) => split_two(&out.positions, [b, c, a], y, z, &mut next),
                (Some(x), None, Some(z)) => split_two(&out.positions, [c, a, b], z, x, &mut next),
            }
            next_faces.resize(next.len(), out.triangle_faces[ti]);
        }
        out.triangles = next;
        out.triangle_faces = next_faces;
        if out.triangles.len() >= params.max_triangles {
            break;
        }
    }
    out
}

/// Triangle (a, b, c) with midpoints x on ab and y on bc; edge ca unsplit.
fn split_two(p: &[[f32; 3]], [a, b, c]: [u32; 3], x: u32, y: u32, out: &mut Vec<[u32; 3]>) {
    out.push([x, b, y]);
    // Quad a, x, y, c: choose the shorter diagonal.
    if dist2(p[a as usize], p[y as usize]) <= dist2(p[x as usize], p[c as usize]) {
        out.extend_from_slice(&[[a, x, y], [a, y, c]]);
    } else {
        out.extend_from_slice(&[[a, x, c], [x, y, c]]);
    }
}

/// The edge length that gives about `vertices` vertices when a surface of `area` is covered by
/// equilateral triangles (faces ≈ 2·vertices, each of area √3/4·l²).
pub fn edge_length_for_vertex_count(area: f64, vertices: usize) -> f32 {
    if vertices == 0 || area <= 0.0 {
        return f32::INFINITY;
    }
    ((2.0 * area) / (3f64.sqrt() * vertices as f64)).sqrt() as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(p: &[[f32; 3]], t: &[[u32; 3]]) -> f64 {
        t.iter()
            .map(|&[a, b, c]| {
                let (a, b, c) = (p[a as usize], p[b as usize], p[c as usize]);
                let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
                let n = [
                    u[1] * v[2] - u[2] * v[1],
                    u[2] * v[0] - u[0] * v[2],
                    u[0] * v[1] - u[1] * v[0],
                ];
                0.5 * ((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) as f64).sqrt()
            })
            .sum()
    }

    #[test]
    fn splitting_keeps_area_bounds_edges_and_stays_conforming() {
        let p = vec![
            [0.0, 0.0, 0.0],
            [4.0, 0.0, 0.0],
            [4.0, 1.0, 0.0],
            [0.0, 3.0, 0.0],
        ];
        let t = vec![[0, 1, 2], [0, 2, 3]];
        let r = refine(
            &p,
            &t,
            &RefineParams {
                max_edge_length: 0.3,
                ..Default::default()
            },
        );
        assert!((area(&r.positions, &r.triangles) - area(&p, &t)).abs() < 1e-4);
        for tri in &r.triangles {
            for k in 0..3 {
                let d = dist2(
                    r.positions[tri[k] as usize],
                    r.positions[tri[(k + 1) % 3] as usize],
                )
                .sqrt();
                assert!(d <= 0.3 + 1e-5, "edge {d}");
            }
        }
        // Conforming: every interior edge is shared by exactly two triangles, and the boundary is
        // the original square's perimeter.
        let mut count: HashMap<(u32, u32), u32> = HashMap::new();
        for tri in &r.triangles {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let boundary: f32 = count
            .iter()
            .filter(|(_, c)| **c == 1)
            .map(|((a, b), _)| dist2(r.positions[*a as usize], r.positions[*b as usize]).sqrt())
            .sum();
        let perimeter = 4.0 + 1.0 + (16.0f32 + 4.0).sqrt() + 3.0;
        assert!(
            (boundary - perimeter).abs() < 1e-3,
            "{boundary} vs {perimeter}"
        );
        assert!(count.values().all(|c| *c <= 2));
    }

    #[test]
    fn interpolation_follows_parents() {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let r = refine(
            &p,
            &[[0, 1, 2]],
            &RefineParams {
                max_edge_length: 0.2,
                ..Default::default()
            },
        );
        let attr: Vec<[f32; 1]> = p.iter().map(|q| [q[0] * 2.0 + q[1]]).collect();
        let out = r.interpolate(&attr);
        for (q, a) in r.positions.iter().zip(&out) {
            assert!((a[0] - (q[0] * 2.0 + q[1])).abs() < 1e-5);
        }
    }

    #[test]
    fn requested_count_is_roughly_met() {
        let p = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let l = edge_length_for_vertex_count(1.0, 10_000);
        let r = refine(
            &p,
            &[[0, 1, 2], [0, 2, 3]],
            &RefineParams {
                max_edge_length: l,
                ..Default::default()
            },
        );
        let n = r.positions.len();
        assert!((3_000..40_000).contains(&n), "{n}");
    }
}
