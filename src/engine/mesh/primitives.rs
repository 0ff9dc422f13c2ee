//! Analytic meshes for tests and benchmarks: geodesic icosphere, UV sphere, planar grid, open
//! cylinder, capsule. All are [`Surface::from_triangles`] surfaces (no back-links), wound
//! counter-clockwise around the outward normal (for the grid: `+z`).
//!
//! Vertex counts: [`icosphere`] with frequency `n` has `10 n² + 2` vertices (n = 32 → 10 242,
//! n = 80 → 64 002); [`uv_sphere`] has `(rings - 1) · segments + 2`; [`grid`] has
//! `(nx + 1)(ny + 1)`; [`cylinder`] has `segments · (rings + 1)`.
//!
//! Written by hand: a few loops; no crate provides Class I geodesic spheres with exact edge
//! sharing.

use std::collections::HashMap;

use super::surface::Surface;
use crate::engine::math::normalize;
use crate::engine::rng::{SplitMix64, GOLDEN};

/// The 12 vertices (unit length) and 20 counter-clockwise faces of a regular icosahedron.
fn icosahedron() -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let raw = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let v = raw.iter().map(|p| normalize(*p)).collect();
    let f = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    (v, f)
}

/// An icosphere by recursive midpoint subdivision: the icosahedron with every face split in four
/// `subdivisions` times, new points pushed onto the sphere of `radius` (in f64, then stored as
/// f32). `10 · 4^k + 2` vertices, outward counter-clockwise faces; each face `[a, b, c]` becomes
/// `[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]`.
pub fn subdivided_icosphere(radius: f64, subdivisions: u32) -> Surface {
    let (mut pos, mut faces) = icosahedron();
    for _ in 0..subdivisions {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(faces.len() * 4);
        for f in &faces {
            let mut m = [0u32; 3];
            for i in 0..3 {
                let (a, b) = (f[i], f[(i + 1) % 3]);
                m[i] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    let (pa, pb) = (pos[a as usize], pos[b as usize]);
                    pos.push(normalize([pa[0] + pb[0], pa[1] + pb[1], pa[2] + pb[2]]));
                    (pos.len() - 1) as u32
                });
            }
            next.push([f[0], m[0], m[2]]);
            next.push([f[1], m[1], m[0]]);
            next.push([f[2], m[2], m[1]]);
            next.push([m[0], m[1], m[2]]);
        }
        faces = next;
    }
    let positions = pos
        .into_iter()
        .map(|p| p.map(|c| (c * radius) as f32))
        .collect();
    Surface::from_triangles(positions, faces)
}

/// A Class I geodesic sphere: every icosahedron face split into `frequency²` triangles, points
/// projected onto the sphere of `radius` centred at the origin. `10 f² + 2` vertices, `20 f²`
/// faces, closed and manifold. `frequency` is clamped to at least 1.
pub fn icosphere(radius: f64, frequency: usize) -> Surface {
    let n = frequency.max(1);
    let (iv, ifaces) = icosahedron();
    let mut positions: Vec<[f32; 3]> = Vec::with_capacity(10 * n * n + 2);
    // Canonical key of a lattice point: (a, b, c, ia, ib) with a <= b <= c icosahedron vertex
    // ids and ia, ib the lattice steps towards them, sorted so shared points get one key.
    let mut index: HashMap<[usize; 6], u32> = HashMap::new();
    let mut faces = Vec::with_capacity(20 * n * n);
    for f in &ifaces {
        let corner = f.map(|v| v as usize);
        // Lattice point (i, j): weights (n - i - j, i, j) on corners (0, 1, 2).
        let mut ids = vec![vec![0u32; n + 1]; n + 1];
        for i in 0..=n {
            for j in 0..=(n - i) {
                let mut w = [(corner[0], n - i - j), (corner[1], i), (corner[2], j)];
                w.sort_unstable();
                let key = [w[0].0, w[0].1, w[1].0, w[1].1, w[2].0, w[2].1];
                let key = canonical(key);
                let id = *index.entry(key).or_insert_with(|| {
                    let p: [f64; 3] = std::array::from_fn(|k| {
                        (w[0].1 as f64 * iv[w[0].0][k]
                            + w[1].1 as f64 * iv[w[1].0][k]
                            + w[2].1 as f64 * iv[w[2].0][k])
                            / n as f64
                    });
                    let p = normalize(p);
                    positions.push(p.map(|c| (c * radius) as f32));
                    (positions.len() - 1) as u32
                });
                ids[i][j] = id;
            }
        }
        for i in 0..n {
            for j in 0..(n - i) {
                faces.push([ids[i][j], ids[i + 1][j], ids[i][j + 1]]);
                if i + j + 1 < n {
                    faces.push([ids[i + 1][j], ids[i + 1][j + 1], ids[i][j + 1]]);
                }
            }
        }
    }
    Surface::from_triangles(positions, faces)
}

/// Zero-weight corners carry no information: drop their vertex id so that points on an edge or
/// a corner get the same key from every face that contains them.
fn canonical(mut key: [usize; 6]) -> [usize; 6] {
    for k in 0..3 {
        if key[2 * k + 1] == 0 {
            key[2 * k] = usize::MAX;
        }
    }
    let mut pairs = [(key[0], key[1]), (key[2], key[3]), (key[4], key[5])];
    pairs.sort_unstable();
    [
        pairs[0].0, pairs[0].1, pairs[1].0, pairs[1].1, pairs[2].0, pairs[2].1,
    ]
}

/// A latitude–longitude sphere of `radius`: `rings` latitude bands (>= 2) and `segments`
/// longitude segments (>= 3), with single pole vertices.
pub fn uv_sphere(radius: f64, rings: usize, segments: usize) -> Surface {
    let rings = rings.max(2);
    let segments = segments.max(3);
    let mut positions = vec![[0.0, 0.0, radius as f32]];
    for r in 1..rings {
        let theta = std::f64::consts::PI * r as f64 / rings as f64;
        for s in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * s as f64 / segments as f64;
            positions.push([
                (radius * theta.sin() * phi.cos()) as f32,
                (radius * theta.sin() * phi.sin()) as f32,
                (radius * theta.cos()) as f32,
            ]);
        }
    }
    positions.push([0.0, 0.0, -radius as f32]);
    let south = (positions.len() - 1) as u32;
    let ring = |r: usize, s: usize| (1 + (r - 1) * segments + s % segments) as u32;
    let mut faces = Vec::new();
    for s in 0..segments {
        faces.push([0, ring(1, s), ring(1, s + 1)]);
        faces.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b) = (ring(r, s), ring(r, s + 1));
            let (c, d) = (ring(r + 1, s), ring(r + 1, s + 1));
            faces.push([a, c, d]);
            faces.push([a, d, b]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// A planar grid in `z = 0` from `(0, 0)` to `(nx·spacing, ny·spacing)`; vertex `(i, j)` has
/// index `j (nx + 1) + i`; each cell is split along its `(i, j)–(i+1, j+1)` diagonal. Normal `+z`.
pub fn grid(nx: usize, ny: usize, spacing: f64) -> Surface {
    let (nx, ny) = (nx.max(1), ny.max(1));
    let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut positions = Vec::with_capacity((nx + 1) * (ny + 1));
    for j in 0..=ny {
        for i in 0..=nx {
            positions.push([
                (i as f64 * spacing) as f32,
                (j as f64 * spacing) as f32,
                0.0,
            ]);
        }
    }
    let mut faces = Vec::with_capacity(2 * nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// An open cylinder of `radius` around the z axis from `z = 0` to `z = height`: `segments`
/// vertices per ring (>= 3), `rings` bands along the axis (>= 1); normals point outward.
pub fn cylinder(radius: f64, height: f64, segments: usize, rings: usize) -> Surface {
    let (segments, rings) = (segments.max(3), rings.max(1));
    let id = |s: usize, r: usize| (r * segments + s % segments) as u32;
    let mut positions = Vec::with_capacity(segments * (rings + 1));
    for r in 0..=rings {
        let z = height * r as f64 / rings as f64;
        for s in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * s as f64 / segments as f64;
            positions.push([
                (radius * phi.cos()) as f32,
                (radius * phi.sin()) as f32,
                z as f32,
            ]);
        }
    }
    let mut faces = Vec::with_capacity(2 * segments * rings);
    for r in 0..rings {
        for s in 0..segments {
            faces.push([id(s, r), id(s + 1, r), id(s + 1, r + 1)]);
            faces.push([id(s, r), id(s + 1, r + 1), id(s, r + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// A capsule along +x: a cylinder of `radius` whose rings sit at the x of `profile` (increasing),
/// `around` segments around, closed by hemispherical caps of 7 rings each plus a pole; `warp`
/// moves x afterwards (a stretched copy with the same connectivity). Outward counter-clockwise
/// faces; `2 + around · (profile.len() + 14)` vertices.
pub fn capsule(radius: f32, profile: &[f32], around: usize, warp: impl Fn(f32) -> f32) -> Surface {
    const CAP_RINGS: usize = 8;
    let around = around.max(3);
    let (x0, x1) = (profile[0], profile[profile.len() - 1]);
    let quarter = |k: usize| std::f32::consts::FRAC_PI_2 * k as f32 / CAP_RINGS as f32;
    // Rings as (x, ring radius), from the left pole to the right pole (poles excluded).
    let mut rings: Vec<(f32, f32)> = (1..CAP_RINGS)
        .map(|k| (x0 - radius * quarter(k).cos(), radius * quarter(k).sin()))
        .collect();
    rings.extend(profile.iter().map(|&x| (x, radius)));
    rings.extend(
        (1..CAP_RINGS)
            .rev()
            .map(|k| (x1 + radius * quarter(k).cos(), radius * quarter(k).sin())),
    );
    let mut positions = vec![[warp(x0 - radius), 0.0, 0.0]];
    for &(x, r) in &rings {
        for j in 0..around {
            let t = std::f32::consts::TAU * j as f32 / around as f32;
            positions.push([warp(x), r * t.cos(), r * t.sin()]);
        }
    }
    positions.push([warp(x1 + radius), 0.0, 0.0]);
    let last = positions.len() as u32 - 1;
    let at = |ring: usize, j: usize| (1 + ring * around + j % around) as u32;
    let mut faces = Vec::with_capacity(2 * around * rings.len());
    faces.extend((0..around).map(|j| [0, at(0, j + 1), at(0, j)]));
    for ring in 0..rings.len() - 1 {
        for j in 0..around {
            let (a, b) = (at(ring, j), at(ring, j + 1));
            let (c, d) = (at(ring + 1, j), at(ring + 1, j + 1));
            faces.push([a, b, d]);
            faces.push([a, d, c]);
        }
    }
    let r = rings.len() - 1;
    faces.extend((0..around).map(|j| [last, at(r, j), at(r, j + 1)]));
    Surface::from_triangles(positions, faces)
}

/// Moves every vertex of `surface` by a deterministic pseudo-random offset of at most
/// `amplitude` per coordinate along the axes in `axes` (e.g. `[true, true, false]` keeps a grid
/// planar). `seed` selects the offsets. For robustness tests on irregular meshes.
pub fn jitter(surface: &mut Surface, amplitude: f64, axes: [bool; 3], seed: u64) {
    let mut rng = SplitMix64::new(seed ^ GOLDEN);
    for p in &mut surface.positions {
        for k in 0..3 {
            let d = rng.signed_unit_f64() * amplitude;
            if axes[k] {
                p[k] = (p[k] as f64 + d) as f32;
            }
        }
    }
}
