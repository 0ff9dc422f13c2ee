//! Exact point–triangle and ray–triangle primitives, in f32, used by the [`Bvh`](super::Bvh)
//! and usable directly as brute-force references.
//!
//! Conventions: a triangle is given by its corners `a, b, c`; barycentric coordinates are the
//! weights of `a, b, c` in that order and sum to 1. The closest point follows Ericson,
//! *Real-Time Collision Detection* (2005), §5.1.5 (Voronoi-region classification of `p` against
//! the corners, edges and face), with a fallback to the three edges for triangles of zero area.
//! The ray test is Möller & Trumbore, *Fast, Minimum Storage Ray/Triangle Intersection* (1997),
//! without back-face culling.

use crate::engine::math::{cross, dot, sub};

/// `a + s * d`.
#[inline(always)]
fn mad(a: [f32; 3], s: f32, d: [f32; 3]) -> [f32; 3] {
    [a[0] + s * d[0], a[1] + s * d[1], a[2] + s * d[2]]
}

/// The point of triangle `(a, b, c)` closest to `p` and its barycentric coordinates.
#[inline]
pub fn closest_point_on_triangle(
    p: [f32; 3],
    a: [f32; 3],
    b: [f32; 3],
    c: [f32; 3],
) -> ([f32; 3], [f32; 3]) {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, [1.0, 0.0, 0.0]);
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, [0.0, 1.0, 0.0]);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        // Edge ab; d1 - d3 = |ab|².
        let den = d1 - d3;
        if den <= 0.0 {
            return closest_on_edges(p, a, b, c);
        }
        let v = d1 / den;
        return (mad(a, v, ab), [1.0 - v, v, 0.0]);
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, [0.0, 0.0, 1.0]);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        // Edge ac; d2 - d6 = |ac|².
        let den = d2 - d6;
        if den <= 0.0 {
            return closest_on_edges(p, a, b, c);
        }
        let w = d2 / den;
        return (mad(a, w, ac), [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    let e43 = d4 - d3;
    let e56 = d5 - d6;
    if va <= 0.0 && e43 >= 0.0 && e56 >= 0.0 {
        // Edge bc; (d4 - d3) + (d5 - d6) = |bc|².
        let den = e43 + e56;
        if den <= 0.0 {
            return closest_on_edges(p, a, b, c);
        }
        let w = e43 / den;
        return (mad(b, w, sub(c, b)), [0.0, 1.0 - w, w]);
    }
    // Inside the face; va + vb + vc = |ab × ac|² (up to rounding).
    let sum = va + vb + vc;
    if sum <= 0.0 || !sum.is_finite() {
        return closest_on_edges(p, a, b, c);
    }
    let v = vb / sum;
    let w = vc / sum;
    let q = [
        a[0] + ab[0] * v + ac[0] * w,
        a[1] + ab[1] * v + ac[1] * w,
        a[2] + ab[2] * v + ac[2] * w,
    ];
    (q, [1.0 - v - w, v, w])
}

/// Closest point over the three edges (for triangles of zero area).
#[cold]
fn closest_on_edges(p: [f32; 3], a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let mut best: Option<(f32, [f32; 3], [f32; 3])> = None;
    let edges = [(a, b, 0usize, 1usize), (a, c, 0, 2), (b, c, 1, 2)];
    for (s, e, i, j) in edges {
        let d = sub(e, s);
        let len2 = dot(d, d);
        let t = if len2 > 0.0 {
            (dot(sub(p, s), d) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = mad(s, t, d);
        let r = sub(p, q);
        let d2 = dot(r, r);
        if best.is_none_or(|(bd, _, _)| d2 < bd) {
            let mut bary = [0.0; 3];
            bary[i] = 1.0 - t;
            bary[j] += t;
            best = Some((d2, q, bary));
        }
    }
    let (_, q, bary) = best.unwrap_or((0.0, a, [1.0, 0.0, 0.0]));
    (q, bary)
}

/// Squared distance from `p` to triangle `(a, b, c)`, with the closest point and its barycentric
/// coordinates.
#[inline]
pub fn point_triangle_distance_squared(
    p: [f32; 3],
    a: [f32; 3],
    b: [f32; 3],
    c: [f32; 3],
) -> (f32, [f32; 3], [f32; 3]) {
    let (q, bary) = closest_point_on_triangle(p, a, b, c);
    let r = sub(p, q);
    (dot(r, r), q, bary)
}

/// Intersection of the line `origin + t * dir` with triangle `(a, b, c)`, both sides: returns
/// `(t, [1 - u - v, u, v])`, or `None` when the line misses or is parallel to the triangle's plane.
/// The caller restricts `t` to its interval.
#[inline]
pub fn ray_triangle(
    origin: [f32; 3],
    dir: [f32; 3],
    a: [f32; 3],
    b: [f32; 3],
    c: [f32; 3],
) -> Option<(f32, [f32; 3])> {
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let pv = cross(dir, e2);
    let det = dot(e1, pv);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let tv = sub(origin, a);
    let u = dot(tv, pv) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let qv = cross(tv, e1);
    let v = dot(dir, qv) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = dot(e2, qv) * inv;
    Some((t, [1.0 - u - v, u, v]))
}
