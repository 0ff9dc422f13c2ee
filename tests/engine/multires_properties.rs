//! Properties of the multiresolution hierarchy (MeshMatch §4) and of refinement/resampling:
//! level sizes, manifoldness, topology, Hausdorff distance, orientation, the vertex tree and its
//! random descendants, prolongation, and (face, barycentric) back-links, on analytic meshes and
//! real assets. Benchmarks are `#[ignore]`d tests: run them with
//! `cargo test --release --no-default-features --test engine multires_properties::bench_ -- --ignored --nocapture`.

use crate::common;

use std::collections::HashMap;

use retex::engine::control::Control;
use retex::engine::mesh::{build_surface, topology, Surface, WeldParams};
use retex::engine::multires::{
    build_hierarchy, edge_length_for_vertex_count, refine, resample, FacePoint, Hierarchy,
    HierarchyError, HierarchyParams, RefineParams, Refined, ResampleParams,
};
use retex::engine::rng::SplitMix64;
use retex::engine::spatial::Bvh;

// ---------------------------------------------------------------------------------------------
// Fixtures

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: [f32; 3]) -> f32 {
    dot(a, a).sqrt()
}

/// Unit icosphere: the icosahedron with every face split in four `subdivisions` times, vertices
/// pushed to the sphere. `10·4^k + 2` vertices, outward counter-clockwise faces.
fn icosphere(subdivisions: u32) -> Surface {
    retex::engine::mesh::primitives::subdivided_icosphere(1.0, subdivisions)
}

/// A torus (major radius 1, minor 0.35) on an `nu × nv` grid: χ = 0.
fn torus(nu: u32, nv: u32) -> Surface {
    let (r0, r1) = (1.0f32, 0.35f32);
    let mut p = Vec::with_capacity((nu * nv) as usize);
    for i in 0..nu {
        let u = i as f32 / nu as f32 * std::f32::consts::TAU;
        for j in 0..nv {
            let v = j as f32 / nv as f32 * std::f32::consts::TAU;
            let r = r0 + r1 * v.cos();
            p.push([r * u.cos(), r * u.sin(), r1 * v.sin()]);
        }
    }
    let id = |i: u32, j: u32| (i % nu) * nv + (j % nv);
    let mut f = Vec::with_capacity((2 * nu * nv) as usize);
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            f.push([a, b, c]);
            f.push([a, c, d]);
        }
    }
    Surface::from_triangles(p, f)
}

/// A wavy height field over the unit square, `n × n` vertices: an open disk (χ = 1).
fn wavy_grid(n: u32) -> Surface {
    let mut p = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f32 / (n - 1) as f32, j as f32 / (n - 1) as f32);
            p.push([x, y, 0.05 * (6.0 * x).sin() * (5.0 * y).cos()]);
        }
    }
    let mut f = Vec::new();
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let (a, b, c, d) = (
                i * n + j,
                (i + 1) * n + j,
                (i + 1) * n + j + 1,
                i * n + j + 1,
            );
            f.push([a, b, c]);
            f.push([a, c, d]);
        }
    }
    Surface::from_triangles(p, f)
}

/// The welded surface of a model file.
fn surface_of(path: &std::path::Path) -> Surface {
    let asset = common::load_path(path);
    build_surface(&asset, &WeldParams::default()).expect("surface")
}

/// The welded surface of a shared asset (benchmarks only).
fn asset_surface(relative: &str) -> Surface {
    surface_of(&common::shared_asset(relative))
}

/// The remeshed Spot (11,533 vertices), from `tests/data`.
fn spot() -> Surface {
    surface_of(&common::test_data(
        "tgt_spot_remeshed_odedstein/spot_derived.glb",
    ))
}

// ---------------------------------------------------------------------------------------------
// Checks

/// Number of boundary edges; panics with a message unless the mesh is an oriented 2-manifold:
/// no repeated corner, every edge on one or two faces, consistent winding (each directed edge at
/// most once), and every vertex's faces forming one fan (a cycle inside, an open fan on the
/// boundary).
fn assert_oriented_manifold(s: &Surface, what: &str) -> usize {
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for (fi, f) in s.faces.iter().enumerate() {
        assert!(
            f[0] != f[1] && f[1] != f[2] && f[2] != f[0],
            "{what}: face {fi} {f:?} repeats a corner"
        );
        for k in 0..3 {
            let e = (f[k], f[(k + 1) % 3]);
            let c = directed.entry(e).or_default();
            *c += 1;
            assert!(*c == 1, "{what}: directed edge {e:?} used twice");
        }
    }
    let boundary = directed
        .keys()
        .filter(|(a, b)| !directed.contains_key(&(*b, *a)))
        .count();
    let topo = topology(s);
    assert_eq!(topo.non_manifold_edges, 0, "{what}: non-manifold edges");
    for v in 0..s.positions.len() {
        let fs = topo.vertex_faces(v);
        assert!(!fs.is_empty(), "{what}: vertex {v} unused");
        // next[i] / prev[i]: the corners after and before v in face i.
        let (mut next, mut prev) = (Vec::new(), Vec::new());
        for &f in fs {
            let face = s.faces[f as usize];
            let k = face.iter().position(|&x| x == v as u32).unwrap();
            next.push(face[(k + 1) % 3]);
            prev.push(face[(k + 2) % 3]);
        }
        // Walk the fan from a face with no predecessor (open) or from face 0 (closed).
        let start = (0..fs.len())
            .find(|&i| !next.contains(&prev[i]))
            .unwrap_or(0);
        let mut seen = vec![false; fs.len()];
        let mut i = start;
        let mut count = 0;
        while !seen[i] {
            seen[i] = true;
            count += 1;
            match prev.iter().position(|&p| p == next[i]) {
                Some(j) => i = j,
                None => break,
            }
        }
        assert_eq!(
            count,
            fs.len(),
            "{what}: vertex {v}'s faces form more than one fan"
        );
    }
    boundary
}

fn euler(s: &Surface) -> i64 {
    topology(s).euler_characteristic
}

/// Sampled one-sided Hausdorff distance from `a` to `b`: every vertex, every face centroid and
/// `extra` random points per face of `a`, measured exactly to `b`'s triangles.
fn one_sided_hausdorff(a: &Surface, b: &Surface, extra: usize, seed: u64) -> f32 {
    let bvh = Bvh::build(&b.positions, &b.faces);
    let mut rng = SplitMix64::new(seed);
    let mut worst = 0.0f32;
    let mut probe = |p: [f32; 3]| {
        let h = bvh.closest_point(p, f32::INFINITY).unwrap();
        worst = worst.max(h.distance_squared.sqrt());
    };
    for &p in &a.positions {
        probe(p);
    }
    for f in 0..a.faces.len() {
        probe(a.face_point(f, [1.0 / 3.0; 3]));
        for _ in 0..extra {
            let (mut u, mut v) = (rng.unit_f32(), rng.unit_f32());
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            probe(a.face_point(f, [1.0 - u - v, u, v]));
        }
    }
    worst
}

fn hausdorff(a: &Surface, b: &Surface) -> f32 {
    one_sided_hausdorff(a, b, 2, 1).max(one_sided_hausdorff(b, a, 2, 2))
}

/// Every face of `coarse` faces the same way as the input surface at its centroid's closest
/// point: returns the number of faces whose normal has a negative dot product with the input's
/// face normal there.
fn flipped_faces(coarse: &Surface, input: &Surface, input_bvh: &Bvh) -> usize {
    (0..coarse.faces.len())
        .filter(|&f| {
            let c = coarse.face_point(f, [1.0 / 3.0; 3]);
            let h = input_bvh.closest_point(c, f32::INFINITY).unwrap();
            dot(coarse.face_normal(f), input.face_normal(h.face as usize)) < 0.0
        })
        .count()
}

/// The structural and geometric properties every hierarchy must have, with the Hausdorff bound
/// `max_rel` relative to the bounding-box diagonal. Returns the per-level relative Hausdorff
/// distances.
fn check_hierarchy(
    input: &Surface,
    h: &Hierarchy,
    name: &str,
    max_rel: f32,
    max_edges: f32,
) -> Vec<f32> {
    let diag = input.diagonal();
    let chi = euler(input);
    let input_boundary = assert_oriented_manifold(input, name);
    let input_bvh = Bvh::build(&input.positions, &input.faces);
    assert!(
        h.level_count() >= 2,
        "{name}: only {} level(s)",
        h.level_count()
    );
    let coarsest = h.level(h.level_count() - 1).surface.positions.len();
    assert!(
        (96..=192).contains(&coarsest),
        "{name}: coarsest level has {coarsest} vertices"
    );
    let mut rels = Vec::new();
    for l in 1..h.level_count() {
        let (fine, coarse) = (&h.level(l - 1).surface, &h.level(l).surface);
        let what = format!("{name} level {l}");
        let ratio = coarse.positions.len() as f64 / fine.positions.len() as f64;
        assert!(
            (0.4..=0.6).contains(&ratio),
            "{what}: {} → {} vertices (ratio {ratio:.3})",
            fine.positions.len(),
            coarse.positions.len()
        );
        let boundary = assert_oriented_manifold(coarse, &what);
        if input_boundary == 0 {
            assert_eq!(boundary, 0, "{what}: not watertight");
        } else {
            assert!(boundary > 0, "{what}: lost its boundary");
        }
        assert_eq!(euler(coarse), chi, "{what}: Euler characteristic changed");
        // No collapse makes a face worse than min(min_triangle_quality, what it was), so the
        // worst face of a level is at least min(0.2, the finer level's worst).
        let (qf, qc) = (min_quality(fine), min_quality(coarse));
        assert!(
            qc >= qf.min(0.2) - 1e-4,
            "{what}: worst triangle quality {qc:.3} < min(0.2, finer level's {qf:.3})"
        );
        let flips = flipped_faces(coarse, input, &input_bvh);
        assert_eq!(flips, 0, "{what}: {flips} faces flipped against the input");
        let d = hausdorff(coarse, input) / diag;
        let edge = mean_edge(coarse) / diag;
        rels.push((d, edge));
        // Vertex tree: parents in range, children are exactly the vertices with that parent.
        let parent = &h.level(l - 1).parent;
        assert_eq!(parent.len(), fine.positions.len());
        let mut count = vec![0usize; coarse.positions.len()];
        for &p in parent {
            count[p as usize] += 1;
        }
        for u in 0..coarse.positions.len() as u32 {
            let ch = h.children(l, u);
            assert_eq!(ch.len(), count[u as usize], "{what}: children of {u}");
            assert!(!ch.is_empty(), "{what}: vertex {u} has no child");
            assert!(ch.iter().all(|&c| parent[c as usize] == u));
        }
    }
    eprintln!(
        "{name}: levels {:?}, (Hausdorff, mean edge) / diagonal {:?}",
        h.levels()
            .iter()
            .map(|l| l.surface.positions.len())
            .collect::<Vec<_>>(),
        rels.iter()
            .map(|(d, e)| format!("({d:.4}, {e:.4})"))
            .collect::<Vec<_>>()
    );
    for (l, &(d, e)) in rels.iter().enumerate() {
        assert!(
            d <= max_rel && d <= max_edges * e,
            "{name} level {}: Hausdorff {d:.4} of the diagonal > min({max_rel}, {max_edges} × mean edge {e:.4})",
            l + 1
        );
    }
    rels.iter().map(|r| r.0).collect()
}

/// Every face's quality `4√3·area / Σ edge²` (1 = equilateral).
fn qualities(m: &Surface) -> Vec<f32> {
    (0..m.faces.len())
        .map(|f| {
            let [a, b, c] = m.face_positions(f);
            let l2 =
                dot(sub(b, a), sub(b, a)) + dot(sub(c, b), sub(c, b)) + dot(sub(a, c), sub(a, c));
            2.0 * 3f32.sqrt() * norm(cross(sub(b, a), sub(c, a))) / l2
        })
        .collect()
}

/// Smallest triangle quality.
fn min_quality(m: &Surface) -> f32 {
    qualities(m).into_iter().fold(1.0f32, f32::min)
}

/// Median triangle quality.
fn median_quality(m: &Surface) -> f32 {
    let mut q = qualities(m);
    q.sort_by(f32::total_cmp);
    q[q.len() / 2]
}

/// Mean edge length (each face's three edges).
fn mean_edge(m: &Surface) -> f32 {
    let total: f64 = m
        .faces
        .iter()
        .flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3])))
        .map(|(a, b)| norm(sub(m.positions[a as usize], m.positions[b as usize])) as f64)
        .sum();
    (total / (3 * m.faces.len()) as f64) as f32
}

// ---------------------------------------------------------------------------------------------
// Hierarchy

/// A ~40k-vertex icosphere: every level halves, stays a watertight oriented sphere (χ = 2) within
/// a sampled two-sided Hausdorff distance of 1.5% of the diagonal and 0.25 mean edge lengths of
/// the level (measured: 0.01%–1.4%, at most 0.16 edges), with no flipped face.
#[test]
fn icosphere_hierarchy_halves_and_stays_a_sphere() {
    let s = icosphere(6);
    assert_eq!(s.positions.len(), 40_962);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    check_hierarchy(&s, &h, "icosphere", 0.015, 0.25);
    // Every level's vertices stay close to the unit sphere (midpoints shrink inward slightly).
    for l in h.levels() {
        for p in &l.surface.positions {
            let r = norm(*p);
            assert!((0.9..=1.0001).contains(&r), "radius {r}");
        }
    }
}

/// The remeshed Spot (a real watertight genus-0 asset, 11.5k vertices): as the icosphere, with
/// Hausdorff at most 6.5% of the diagonal and one mean edge length of the level (measured: 0.5%
/// at level 1 rising to 5.8% at the 181-vertex level, where the ears and horns are one or two
/// triangles wide; 0.42–0.85 edges).
#[test]
fn spot_hierarchy_is_manifold_watertight_and_close() {
    let s = spot();
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    check_hierarchy(&s, &h, "spot", 0.065, 1.0);
}

/// A genus-1 surface keeps χ = 0 (Hausdorff ≤ 3% of the diagonal and ≤ 0.5 mean edges).
#[test]
fn torus_hierarchy_keeps_genus() {
    let s = torus(96, 48);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    check_hierarchy(&s, &h, "torus", 0.03, 0.5);
}

/// A capsule with valence-256 poles (a UV-sphere-like layout, as Blender and most modellers
/// make them; the striped MeshMatch benchmark uses it): the hierarchy must still halve down to
/// about 128 vertices rather than stall at a few thousand around the poles, and keep triangles
/// usable (median quality of every level ≥ 0.5, no coarsest-level vertex with more than 12
/// faces). Hausdorff ≤ 3% of the diagonal and ≤ 1 mean edge of the level. Measured: levels
/// 24,322 → 96, median quality 0.70-0.88, at most 8 faces per coarsest vertex. Before the
/// worst-face rule (a collapse may not make the worst face around it worse, rather than no single
/// face worse) every collapse next to the poles' slivers was refused: the hierarchy stalled at
/// 3,843 vertices with 256-face poles and median quality 0.15.
#[test]
fn capsule_with_high_valence_poles_decimates_to_128() {
    let profile: Vec<f32> = (0..=80).map(|i| i as f32 / 80.0).collect();
    let s = retex::engine::mesh::primitives::capsule(0.5, &profile, 256, |x| x);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    let medians: Vec<f32> = h
        .levels()
        .iter()
        .map(|l| median_quality(&l.surface))
        .collect();
    eprintln!("capsule: median triangle quality per level {medians:.2?}");
    check_hierarchy(&s, &h, "capsule", 0.03, 1.0);
    for (l, &q) in medians.iter().enumerate() {
        assert!(
            q >= 0.5,
            "capsule level {l}: median triangle quality {q:.2} < 0.5"
        );
    }
    // The poles' fans (256 faces each) are thinned out with the rest.
    let coarsest = &h.level(h.level_count() - 1).surface;
    let mut faces_at = vec![0usize; coarsest.positions.len()];
    for f in &coarsest.faces {
        for &v in f {
            faces_at[v as usize] += 1;
        }
    }
    let most = faces_at.iter().max().copied().unwrap_or(0);
    assert!(
        most <= 12,
        "capsule: a coarsest-level vertex has {most} faces"
    );
}

/// An open surface: boundary vertices of every level lie on the input's boundary polyline (here
/// the square's edges), the boundary survives, χ = 1 (Hausdorff ≤ 1% of the diagonal and ≤ 0.25
/// mean edges).
#[test]
fn open_grid_keeps_its_boundary_on_the_boundary() {
    let s = wavy_grid(120);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    check_hierarchy(&s, &h, "wavy grid", 0.01, 0.25);
    for (l, level) in h.levels().iter().enumerate().skip(1) {
        let topo = topology(&level.surface);
        for lp in &topo.boundary_loops {
            for &v in lp {
                let p = level.surface.positions[v as usize];
                let on_edge = p[0].abs() < 1e-6
                    || (p[0] - 1.0).abs() < 1e-6
                    || p[1].abs() < 1e-6
                    || (p[1] - 1.0).abs() < 1e-6;
                assert!(
                    on_edge,
                    "level {l}: boundary vertex {v} at {p:?} left the square's edge"
                );
            }
        }
        // The bounding square is preserved (the corners cannot move inward).
        let (lo, hi) = level.surface.bounding_box();
        assert!(lo[0] < 1e-6 && lo[1] < 1e-6 && hi[0] > 1.0 - 1e-6 && hi[1] > 1.0 - 1e-6);
    }
}

/// Non-manifold input: a fin triangle on an edge of a sphere (an edge with three faces). The
/// vertices of that edge are locked, so the fin and the non-manifold edge survive every level;
/// the rest still halves and χ is kept.
#[test]
fn non_manifold_edge_is_kept_and_the_rest_decimates() {
    let mut s = icosphere(4);
    let [a, b, _] = s.faces[0];
    let (pa, pb) = (s.positions[a as usize], s.positions[b as usize]);
    let out = [
        0.5 * (pa[0] + pb[0]) * 1.5,
        0.5 * (pa[1] + pb[1]) * 1.5,
        0.5 * (pa[2] + pb[2]) * 1.5,
    ];
    s.positions.push(out);
    s.faces.push([a, b, s.positions.len() as u32 - 1]);
    let chi = euler(&s);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    assert!(h.level_count() >= 4);
    for l in 1..h.level_count() {
        let (fine, coarse) = (&h.level(l - 1).surface, &h.level(l).surface);
        let ratio = coarse.positions.len() as f64 / fine.positions.len() as f64;
        assert!((0.4..=0.6).contains(&ratio), "level {l}: ratio {ratio}");
        let topo = topology(coarse);
        assert_eq!(topo.non_manifold_edges, 1, "level {l}");
        assert_eq!(topo.euler_characteristic, chi, "level {l}");
        assert!(
            coarse.positions.contains(&out),
            "level {l}: the fin tip moved"
        );
    }
}

/// Random descendants are uniform over the subtree at the requested level: every descendant is
/// drawn, the draws pass a chi-square test at about 5 standard deviations, and the max/min
/// frequency ratio stays under 1.5 with at least 400 expected draws per descendant. Draws are
/// reproducible for a seed.
#[test]
fn random_descendants_cover_the_subtree_uniformly() {
    let s = icosphere(5);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    let top = h.level_count() - 1;
    let mut rng = SplitMix64::new(42);
    for (level, j) in [(top, 1), (top, 3), (top.min(4), top.min(4)), (2, 2)] {
        for vertex in [0u32, 7, 31] {
            let d = h.descendants(level, vertex, j);
            let m = d.len();
            // The subtree, brute force: vertices of level - j whose ancestor j up is `vertex`.
            let n = h.level(level - j).surface.positions.len() as u32;
            let mut brute: Vec<u32> = (0..n)
                .filter(|&v| h.ancestor(level - j, v, j) == vertex)
                .collect();
            let mut sorted = d.to_vec();
            sorted.sort_unstable();
            brute.sort_unstable();
            assert_eq!(sorted, brute, "level {level} vertex {vertex} j {j}");
            let draws = 400 * m;
            let mut freq: HashMap<u32, usize> = HashMap::new();
            for _ in 0..draws {
                *freq
                    .entry(h.random_descendant(level, vertex, j, &mut rng))
                    .or_default() += 1;
            }
            assert_eq!(freq.len(), m, "not every descendant drawn");
            assert!(freq.keys().all(|v| d.contains(v)));
            let expected = draws as f64 / m as f64;
            let chi2: f64 = freq
                .values()
                .map(|&c| (c as f64 - expected).powi(2) / expected)
                .sum();
            let df = (m - 1) as f64;
            if m > 1 {
                assert!(
                    chi2 < df + 5.0 * (2.0 * df).sqrt(),
                    "chi² {chi2:.1} with {df} dof (level {level} vertex {vertex} j {j})"
                );
                let (lo, hi) = (
                    *freq.values().min().unwrap() as f64,
                    *freq.values().max().unwrap() as f64,
                );
                assert!(hi / lo < 1.5, "max/min frequency {hi}/{lo}");
            }
        }
    }
    // Same seed, same draws.
    let a: Vec<u32> = {
        let mut r = SplitMix64::new(7);
        (0..100)
            .map(|_| h.random_descendant(top, 3, top, &mut r))
            .collect()
    };
    let b: Vec<u32> = {
        let mut r = SplitMix64::new(7);
        (0..100)
            .map(|_| h.random_descendant(top, 3, top, &mut r))
            .collect()
    };
    assert_eq!(a, b);
}

/// A biased walk (uniform child at each step) would fail the chi-square test above: check the
/// test has teeth by drawing that way on a subtree with unequal branches.
#[test]
fn chi_square_rejects_the_biased_child_walk() {
    let s = icosphere(5);
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    let top = h.level_count() - 1;
    let mut rng = SplitMix64::new(3);
    let vertex = 0u32;
    let j = top;
    let m = h.descendants(top, vertex, j).len();
    let draws = 400 * m;
    let mut freq: HashMap<u32, usize> = HashMap::new();
    for _ in 0..draws {
        let mut v = vertex;
        for l in (1..=top).rev() {
            let ch = h.children(l, v);
            v = ch[rng.below(ch.len() as u64) as usize];
        }
        *freq.entry(v).or_default() += 1;
    }
    let expected = draws as f64 / m as f64;
    let chi2: f64 = (0..m)
        .map(|i| {
            let v = h.descendants(top, vertex, j)[i];
            let c = *freq.get(&v).unwrap_or(&0) as f64;
            (c - expected).powi(2) / expected
        })
        .sum();
    let df = (m - 1) as f64;
    assert!(
        chi2 > df + 5.0 * (2.0 * df).sqrt(),
        "biased walk passed: chi² {chi2:.1}, dof {df}"
    );
}

/// Projections lie on the coarser level, close to the fine vertex; prolongating a linear function
/// is exact up to that projection distance.
#[test]
fn prolongation_of_a_linear_function_is_exact_up_to_projection() {
    let s = spot();
    let h = build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap();
    let diag = s.diagonal();
    let a = [0.3f32, -1.2, 0.7];
    let lin = |p: [f32; 3]| dot(a, p) + 0.25;
    let grad = norm(a);
    for l in 1..h.level_count() {
        let coarse = &h.level(l).surface;
        let fine = &h.level(l - 1).surface;
        let field: Vec<[f32; 1]> = coarse.positions.iter().map(|&p| [lin(p)]).collect();
        let flat: Vec<f32> = field.iter().map(|v| v[0]).collect();
        let out = h.prolongate(l, &field);
        let out_flat = h.prolongate_flat(l, 1, &flat);
        assert_eq!(out.len(), fine.positions.len());
        let mut max_proj = 0.0f32;
        for (v, p) in fine.positions.iter().enumerate() {
            let fp: FacePoint = h.project_to_coarser(l - 1, v as u32);
            assert!(fp.bary.iter().all(|&w| (-1e-5..=1.0 + 1e-5).contains(&w)));
            let q = coarse.face_point(fp.face as usize, fp.bary);
            let dist = norm(sub(*p, q));
            max_proj = max_proj.max(dist);
            let err = (out[v][0] - lin(*p)).abs();
            assert!(
                err <= grad * dist + 1e-4,
                "level {l} vertex {v}: error {err} > |∇f|·{dist}"
            );
            assert!((out[v][0] - lin(q)).abs() < 1e-4);
            assert!((out_flat[v] - out[v][0]).abs() < 1e-6);
        }
        let edge = mean_edge(coarse);
        eprintln!(
            "level {l}: max projection distance {:.4} of the diagonal, {:.3} mean coarse edges",
            max_proj / diag,
            max_proj / edge
        );
        assert!(
            max_proj <= 1.5 * edge,
            "level {l}: projection distance {max_proj} > 1.5 × mean coarse edge {edge}"
        );
    }
}

/// The same input gives the same hierarchy with one thread or two.
#[test]
fn hierarchy_is_identical_for_any_thread_count() {
    let s = spot();
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| build_hierarchy(&s, &HierarchyParams::default(), &Control::new()).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.level_count(), b.level_count());
    for (x, y) in a.levels().iter().zip(b.levels()) {
        assert_eq!(x.surface, y.surface);
        assert_eq!(x.parent, y.parent);
        assert_eq!(x.projection, y.projection);
    }
}

#[test]
fn cancellation_progress_and_bad_input() {
    let s = icosphere(4);
    // Progress: the "hierarchy" stage counts collapses (about one per input vertex in all).
    let c = Control::new();
    build_hierarchy(&s, &HierarchyParams::default(), &c).unwrap();
    let p = c.progress();
    assert_eq!(p.stage, "hierarchy");
    assert!(p.stage_fraction > 0.9, "{p:?}");
    let c = Control::new();
    c.cancel();
    assert_eq!(
        resample(
            &s.positions,
            &s.faces,
            &ResampleParams {
                max_vertices: 10_000,
                ..Default::default()
            },
            &c
        )
        .unwrap_err(),
        retex::engine::multires::ResampleError::Cancelled
    );
    let c = Control::new();
    c.cancel();
    assert_eq!(
        build_hierarchy(&s, &HierarchyParams::default(), &c).unwrap_err(),
        HierarchyError::Cancelled
    );
    let bad = HierarchyParams {
        target_ratio: 0.95,
        ..Default::default()
    };
    assert!(matches!(
        build_hierarchy(&s, &bad, &Control::new()),
        Err(HierarchyError::InvalidParam {
            name: "target_ratio",
            ..
        })
    ));
    let mut loose = s.clone();
    loose.positions.push([5.0, 5.0, 5.0]);
    assert_eq!(
        build_hierarchy(&loose, &HierarchyParams::default(), &Control::new()).unwrap_err(),
        HierarchyError::UnreferencedVertex {
            vertex: s.positions.len()
        }
    );
    // Too small to decimate: a single level.
    let tiny = icosphere(1);
    let h = build_hierarchy(&tiny, &HierarchyParams::default(), &Control::new()).unwrap();
    assert_eq!(h.level_count(), 1);
    assert!(h.children(0, 0).is_empty());
}

// ---------------------------------------------------------------------------------------------
// Refinement and resampling

/// Every vertex's (face, barycentric) on the input reproduces its position to 1e-5 (relative to
/// the diagonal), every refined triangle lies in its recorded input face, and the parents
/// interpolate positions exactly.
fn check_sources(input: &Surface, r: &Refined, what: &str) {
    let diag = input.diagonal();
    assert_eq!(r.sources.len(), r.positions.len());
    assert_eq!(r.triangle_faces.len(), r.triangles.len());
    for (v, (p, src)) in r.positions.iter().zip(&r.sources).enumerate() {
        assert_ne!(src.face, u32::MAX, "{what}: vertex {v} has no source");
        let sum: f32 = src.bary.iter().sum();
        assert!((sum - 1.0).abs() < 1e-5, "{what}: weights sum {sum}");
        let q = input.face_point(src.face as usize, src.bary);
        let e = norm(sub(*p, q)) / diag;
        assert!(e < 1e-5, "{what}: vertex {v} off by {e} of the diagonal");
    }
    for (t, &f) in r.triangles.iter().zip(&r.triangle_faces) {
        let n = input.face_normal(f as usize);
        let a = input.positions[input.faces[f as usize][0] as usize];
        for &v in t {
            let off = dot(sub(r.positions[v as usize], a), n).abs() / diag;
            assert!(
                off < 1e-5,
                "{what}: refined corner off its input face plane by {off}"
            );
        }
    }
    let interp = r.interpolate(&input.positions);
    for (x, y) in interp.iter().zip(&r.positions) {
        assert!(norm(sub(*x, *y)) / diag < 1e-5);
    }
}

fn refined_surface(r: &Refined) -> Surface {
    Surface::from_triangles(r.positions.clone(), r.triangles.clone())
}

#[test]
fn refine_records_input_face_points() {
    let s = icosphere(2);
    let l = edge_length_for_vertex_count(s.area(), 5_000);
    let r = refine(
        &s.positions,
        &s.faces,
        &RefineParams {
            max_edge_length: l,
            ..Default::default()
        },
    );
    assert!(r.positions.len() > 2_000, "{}", r.positions.len());
    check_sources(&s, &r, "refine icosphere");
    let out = refined_surface(&r);
    assert_eq!(assert_oriented_manifold(&out, "refined"), 0);
    assert!((out.area() - s.area()).abs() / s.area() < 1e-5);
}

/// Longest-edge bisection reaches an exact count, keeps the area and topology, bounds edges,
/// and records sources.
#[test]
fn resample_reaches_the_count_and_records_sources() {
    let s = spot();
    let target = 40_000;
    let r = resample(
        &s.positions,
        &s.faces,
        &ResampleParams {
            max_vertices: target,
            ..Default::default()
        },
        &Control::new(),
    )
    .unwrap();
    assert_eq!(r.positions.len(), target);
    check_sources(&s, &r, "resample spot");
    let out = refined_surface(&r);
    assert_eq!(assert_oriented_manifold(&out, "resampled spot"), 0);
    assert_eq!(euler(&out), euler(&s));
    assert!((out.area() - s.area()).abs() / s.area() < 1e-5);
    // Longest-first: at 3.5× the input's vertices, the longest edge is under 0.6 of the input's.
    let edges = |m: &Surface| -> Vec<f32> {
        m.faces
            .iter()
            .flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3])))
            .map(|(a, b)| norm(sub(m.positions[a as usize], m.positions[b as usize])))
            .collect()
    };
    let (e_in, e_out) = (edges(&s), edges(&out));
    let max_in = e_in.iter().cloned().fold(0.0, f32::max);
    let max_out = e_out.iter().cloned().fold(0.0, f32::max);
    assert!(
        max_out < 0.6 * max_in,
        "longest edge {max_out} vs input {max_in}"
    );
    // Length bound: stop when no edge exceeds it.
    let r2 = resample(
        &s.positions,
        &s.faces,
        &ResampleParams {
            max_edge_length: 0.5 * max_in,
            ..Default::default()
        },
        &Control::new(),
    )
    .unwrap();
    let out2 = refined_surface(&r2);
    assert!(edges(&out2).iter().all(|&e| e <= 0.5 * max_in));
    check_sources(&s, &r2, "resample by length");
    // Minimum angle does not collapse (longest-edge bisection keeps shapes).
    assert!(
        min_quality(&out) > 0.3 * min_quality(&s),
        "{} vs {}",
        min_quality(&out),
        min_quality(&s)
    );
    // Errors.
    assert!(resample(
        &s.positions,
        &s.faces,
        &ResampleParams::default(),
        &Control::new()
    )
    .is_err());
}

// ---------------------------------------------------------------------------------------------
// Benchmarks (ignored): median of 5 runs, peak resident memory.

fn vm_hwm_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).map(|x| x.parse().unwrap_or(0)))
        })
        .unwrap_or(0)
}

/// Process CPU time (user + system) in milliseconds, from /proc/self/stat (10 ms ticks).
fn cpu_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<u64> = rest
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    // Fields 14 and 15 of the stat line are the 12th and 13th after the command name.
    f.get(11)
        .zip(f.get(12))
        .map(|(u, s)| (u + s) as f64 * 10.0)
        .unwrap_or(0.0)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

fn median_ms(mut f: impl FnMut()) -> f64 {
    let mut times: Vec<f64> = (0..5)
        .map(|_| {
            let t = std::time::Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(|a, b| a.partial_cmp(b).unwrap());
    times[2]
}

fn bench_hierarchy_on(name: &str, s: &Surface) {
    let before = vm_hwm_kib();
    let mut levels = Vec::new();
    let cpu0 = cpu_ms();
    let ms = median_ms(|| {
        let h = build_hierarchy(s, &HierarchyParams::default(), &Control::new()).unwrap();
        levels = h
            .levels()
            .iter()
            .map(|l| l.surface.positions.len())
            .collect();
    });
    let cpu = (cpu_ms() - cpu0) / 5.0;
    eprintln!(
        "BENCH hierarchy {name} ({} vertices): median {ms:.1} ms wall over 5 runs, mean CPU {cpu:.0} ms/run, levels {levels:?}, VmHWM {} MiB (before {} MiB), threads {}, loadavg {}",
        s.positions.len(),
        vm_hwm_kib() / 1024,
        before / 1024,
        rayon::current_num_threads(),
        load_average()
    );
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_hierarchy_torus_64k() {
    bench_hierarchy_on("torus 256x256", &torus(256, 256));
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_hierarchy_skull_50k() {
    bench_hierarchy_on(
        "skull",
        &asset_surface("perf_skull_odedstein/skull_derived.glb"),
    );
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_hierarchy_koala_50k() {
    bench_hierarchy_on(
        "koala",
        &asset_surface("perf_koala_odedstein/koala_derived.glb"),
    );
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_resample_5k_to_64k() {
    let s = asset_surface("perf_skull_odedstein/skull_low_resolution_derived.glb");
    let before = vm_hwm_kib();
    let cpu0 = cpu_ms();
    let ms = median_ms(|| {
        let r = resample(
            &s.positions,
            &s.faces,
            &ResampleParams {
                max_vertices: 65_536,
                ..Default::default()
            },
            &Control::new(),
        )
        .unwrap();
        assert_eq!(r.positions.len(), 65_536);
    });
    let cpu = (cpu_ms() - cpu0) / 5.0;
    let mut n = 0;
    let ms_refine = median_ms(|| {
        let l = edge_length_for_vertex_count(s.area(), 65_536);
        let r = refine(
            &s.positions,
            &s.faces,
            &RefineParams {
                max_edge_length: l,
                ..Default::default()
            },
        );
        n = r.positions.len();
    });
    eprintln!(
        "BENCH resample skull_low ({} vertices) → 65536 vertices: median {ms:.1} ms wall, mean CPU {cpu:.0} ms/run; refine (passes, edge length for 64K) → {n} vertices: median {ms_refine:.1} ms; VmHWM {} MiB (before {} MiB), loadavg {}",
        s.positions.len(),
        vm_hwm_kib() / 1024,
        before / 1024,
        load_average()
    );
}
