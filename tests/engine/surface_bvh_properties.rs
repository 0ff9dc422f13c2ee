//! Properties of the Surface (welding, back-links, topology) and of the BVH queries, checked
//! against brute force and analytic shapes.

use retex::engine::asset::{Asset, MeshInstance, Primitive, TriangleMode};
use retex::engine::mesh::{build_surface, topology, FaceOrigin, MeshError, Surface, WeldParams};
use retex::engine::rng::SplitMix64;
use retex::engine::spatial::{point_triangle_distance_squared, ray_triangle, Bvh, ClosestHit};

// ---------------------------------------------------------------------------------------------
// Fixtures

/// Test data from the engine's seeded SplitMix64.
struct Rng(SplitMix64);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(SplitMix64::new(seed))
    }
    fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// Uniform in [lo, hi).
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        let u = self.0.unit_f32();
        lo + (hi - lo) * u
    }
    fn point(&mut self, lo: f32, hi: f32) -> [f32; 3] {
        [self.range(lo, hi), self.range(lo, hi), self.range(lo, hi)]
    }
    fn unit(&mut self) -> [f32; 3] {
        loop {
            let p = self.point(-1.0, 1.0);
            let l = norm(p);
            if l > 0.1 && l <= 1.0 {
                return p.map(|c| c / l);
            }
        }
    }
    fn bary(&mut self) -> [f32; 3] {
        let (mut u, mut v) = (self.range(0.0, 1.0), self.range(0.0, 1.0));
        if u + v > 1.0 {
            u = 1.0 - u;
            v = 1.0 - v;
        }
        [1.0 - u - v, u, v]
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn norm(a: [f32; 3]) -> f32 {
    dot(a, a).sqrt()
}

/// An icosphere of radius 1: an icosahedron subdivided `level` times, counter-clockwise outward.
fn icosphere(level: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let s = retex::engine::mesh::primitives::subdivided_icosphere(1.0, level);
    (s.positions, s.faces)
}

/// A random triangle soup inside [-1, 1]³, with triangles of very different sizes and one
/// zero-area triangle.
fn soup(rng: &mut Rng, n: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut pos = Vec::new();
    let mut faces = Vec::new();
    for i in 0..n {
        let c = rng.point(-1.0, 1.0);
        let size = if i % 7 == 0 { 0.5 } else { 0.05 };
        let base = pos.len() as u32;
        for _ in 0..3 {
            let d = rng.point(-size, size);
            pos.push([c[0] + d[0], c[1] + d[1], c[2] + d[2]]);
        }
        faces.push([base, base + 1, base + 2]);
    }
    // A collinear (zero-area) triangle.
    let base = pos.len() as u32;
    pos.extend([[0.1, 0.2, 0.3], [0.3, 0.4, 0.5], [0.7, 0.8, 0.9]]);
    faces.push([base, base + 1, base + 2]);
    (pos, faces)
}

fn identity() -> [[f64; 4]; 4] {
    [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

fn scale_translate(s: [f64; 3], t: [f64; 3]) -> [[f64; 4]; 4] {
    [
        [s[0], 0.0, 0.0, 0.0],
        [0.0, s[1], 0.0, 0.0],
        [0.0, 0.0, s[2], 0.0],
        [t[0], t[1], t[2], 1.0],
    ]
}

fn primitive(
    mesh: usize,
    index: usize,
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
) -> Primitive {
    Primitive {
        mesh,
        primitive: index,
        material: None,
        mode: TriangleMode::Triangles,
        positions,
        normals: None,
        tex_coords: Vec::new(),
        colors: None,
        triangles,
    }
}

fn asset(primitives: Vec<Primitive>, instances: Vec<MeshInstance>) -> Asset {
    Asset {
        json: serde_json::Value::Null,
        buffers: Vec::new(),
        images: Vec::new(),
        textures: Vec::new(),
        materials: Vec::new(),
        primitives,
        instances,
        warnings: Vec::new(),
    }
}

fn instance(node: usize, mesh: usize, world: [[f64; 4]; 4]) -> MeshInstance {
    MeshInstance { node, mesh, world }
}

/// A unit cube [0,1]³ as 6 separate quads (24 vertices, as with UV seams), counter-clockwise
/// seen from outside.
fn cube_quads() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    // Each face: 4 corners counter-clockwise seen from outside.
    let quads: [[[f32; 3]; 4]; 6] = [
        [[0., 0., 0.], [0., 1., 0.], [1., 1., 0.], [1., 0., 0.]], // z = 0, normal -z
        [[0., 0., 1.], [1., 0., 1.], [1., 1., 1.], [0., 1., 1.]], // z = 1, normal +z
        [[0., 0., 0.], [1., 0., 0.], [1., 0., 1.], [0., 0., 1.]], // y = 0, normal -y
        [[0., 1., 0.], [0., 1., 1.], [1., 1., 1.], [1., 1., 0.]], // y = 1, normal +y
        [[0., 0., 0.], [0., 0., 1.], [0., 1., 1.], [0., 1., 0.]], // x = 0, normal -x
        [[1., 0., 0.], [1., 1., 0.], [1., 1., 1.], [1., 0., 1.]], // x = 1, normal +x
    ];
    let mut pos = Vec::new();
    let mut tris = Vec::new();
    for q in quads {
        let b = pos.len() as u32;
        pos.extend(q);
        tris.push([b, b + 1, b + 2]);
        tris.push([b, b + 2, b + 3]);
    }
    (pos, tris)
}

/// Signed enclosed volume (positive when faces wind counter-clockwise around outward normals).
fn signed_volume(s: &Surface) -> f64 {
    s.faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|v| s.positions[v as usize].map(|x| x as f64));
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum()
}

// ---------------------------------------------------------------------------------------------
// Independent references

/// Closest point on a triangle in f64, computed differently from the library: projection onto
/// the plane if inside, else the best of the three clamped edge projections.
fn reference_distance(p: [f32; 3], a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> f64 {
    let f = |v: [f32; 3]| v.map(|x| x as f64);
    let (p, a, b, c) = (f(p), f(a), f(b), f(c));
    let s = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let d = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let cr = |x: [f64; 3], y: [f64; 3]| {
        [
            x[1] * y[2] - x[2] * y[1],
            x[2] * y[0] - x[0] * y[2],
            x[0] * y[1] - x[1] * y[0],
        ]
    };
    let seg = |p: [f64; 3], a: [f64; 3], b: [f64; 3]| {
        let ab = s(b, a);
        let l2 = d(ab, ab);
        let t = if l2 > 0.0 {
            (d(s(p, a), ab) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]];
        d(s(p, q), s(p, q)).sqrt()
    };
    let edges = seg(p, a, b).min(seg(p, b, c)).min(seg(p, c, a));
    let n = cr(s(b, a), s(c, a));
    let n2 = d(n, n);
    if n2 <= 1e-30 {
        return edges;
    }
    let dist_plane = d(s(p, a), n) / n2;
    let q = [
        p[0] - dist_plane * n[0],
        p[1] - dist_plane * n[1],
        p[2] - dist_plane * n[2],
    ];
    let inside = [(a, b), (b, c), (c, a)]
        .iter()
        .all(|&(u, v)| d(cr(s(v, u), s(q, u)), n) >= 0.0);
    if inside {
        d(s(p, q), s(p, q)).sqrt()
    } else {
        edges
    }
}

/// Brute force over all faces with `accept`, using the library's exact primitive; ties → lowest face.
fn brute_closest(
    pos: &[[f32; 3]],
    faces: &[[u32; 3]],
    p: [f32; 3],
    max_distance: f32,
    accept: impl Fn(u32) -> bool,
) -> Option<(u32, f32)> {
    let mut best: Option<(u32, f32)> = None;
    for (i, f) in faces.iter().enumerate() {
        if !accept(i as u32) {
            continue;
        }
        let [a, b, c] = f.map(|v| pos[v as usize]);
        let (d2, _, _) = point_triangle_distance_squared(p, a, b, c);
        if d2 <= max_distance * max_distance && best.is_none_or(|(_, bd)| d2 < bd) {
            best = Some((i as u32, d2));
        }
    }
    best
}

fn brute_ray(
    pos: &[[f32; 3]],
    faces: &[[u32; 3]],
    o: [f32; 3],
    d: [f32; 3],
    t_min: f32,
    t_max: f32,
) -> Option<(u32, f32)> {
    let mut best: Option<(u32, f32)> = None;
    for (i, f) in faces.iter().enumerate() {
        let [a, b, c] = f.map(|v| pos[v as usize]);
        if let Some((t, _)) = ray_triangle(o, d, a, b, c) {
            if t > t_min && t <= t_max && best.is_none_or(|(_, bt)| t < bt) {
                best = Some((i as u32, t));
            }
        }
    }
    best
}

/// The hit's barycentric coordinates reproduce its point on its face, and sum to 1.
fn assert_bary_consistent(pos: &[[f32; 3]], faces: &[[u32; 3]], hit: &ClosestHit) {
    let [a, b, c] = faces[hit.face as usize].map(|v| pos[v as usize]);
    let w = hit.bary;
    assert!(
        w.iter().all(|&x| (-1e-5..=1.0 + 1e-5).contains(&x)),
        "bary {w:?}"
    );
    assert!((w[0] + w[1] + w[2] - 1.0).abs() < 1e-5, "bary sum {w:?}");
    let q: [f32; 3] = std::array::from_fn(|k| w[0] * a[k] + w[1] * b[k] + w[2] * c[k]);
    assert!(
        norm(sub(q, hit.point)) < 1e-5,
        "bary point {q:?} vs {:?}",
        hit.point
    );
}

fn check_closest_against_brute_force(
    pos: &[[f32; 3]],
    faces: &[[u32; 3]],
    rng: &mut Rng,
    lo: f32,
    hi: f32,
) {
    let bvh = Bvh::build(pos, faces);
    assert_eq!(bvh.face_count(), faces.len());
    for _ in 0..1500 {
        let p = rng.point(lo, hi);
        let hit = bvh
            .closest_point(p, f32::INFINITY)
            .expect("infinite range always hits");
        let (bf, bd2) = brute_closest(pos, faces, p, f32::INFINITY, |_| true).unwrap();
        let (d, bd) = (hit.distance_squared.sqrt(), bd2.sqrt());
        assert!(
            (d - bd).abs() <= 1e-5 * bd.max(1e-3),
            "p {p:?}: bvh {d} (face {}) vs brute {bd} (face {bf})",
            hit.face
        );
        // The library's distance agrees with an independent f64 computation.
        let [a, b, c] = faces[hit.face as usize].map(|v| pos[v as usize]);
        let r = reference_distance(p, a, b, c);
        assert!(
            (d as f64 - r).abs() <= 1e-4 * r.max(1e-2),
            "p {p:?}: {d} vs reference {r}"
        );
        assert!((norm(sub(p, hit.point)) - d).abs() <= 1e-5 * d.max(1.0));
        assert_bary_consistent(pos, faces, &hit);
    }
}

// ---------------------------------------------------------------------------------------------
// Closest point

#[test]
fn closest_point_matches_brute_force_on_random_soup() {
    let mut rng = Rng::new(1);
    let (pos, faces) = soup(&mut rng, 3000);
    check_closest_against_brute_force(&pos, &faces, &mut rng, -1.5, 1.5);
}

#[test]
fn closest_point_matches_brute_force_on_sphere() {
    let (pos, faces) = icosphere(4);
    let mut rng = Rng::new(2);
    check_closest_against_brute_force(&pos, &faces, &mut rng, -2.0, 2.0);
    // Points on the sphere's radius lines: distance ≈ |r - 1| (up to the facet sagitta).
    let bvh = Bvh::build(&pos, &faces);
    for _ in 0..500 {
        let u = rng.unit();
        let r = rng.range(0.3, 3.0);
        let hit = bvh.closest_point(u.map(|c| c * r), f32::INFINITY).unwrap();
        assert!(
            (hit.distance_squared.sqrt() - (r - 1.0).abs()).abs() < 5e-3,
            "r {r}"
        );
    }
}

#[test]
fn closest_point_of_points_on_the_surface_is_themselves() {
    let mut rng = Rng::new(3);
    let (pos, faces) = icosphere(3);
    let s = Surface::from_triangles(pos.clone(), faces.clone());
    let bvh = Bvh::build(&pos, &faces);
    for _ in 0..1000 {
        let f = (rng.next_u64() % faces.len() as u64) as usize;
        let p = s.face_point(f, rng.bary());
        let hit = bvh.closest_point(p, f32::INFINITY).unwrap();
        assert!(
            hit.distance_squared.sqrt() < 1e-6,
            "distance {}",
            hit.distance_squared.sqrt()
        );
        assert!(norm(sub(hit.point, p)) < 1e-6);
        // Also found with a zero search radius tolerance of float error only.
        assert!(bvh.closest_point(p, 1e-5).is_some());
    }
}

#[test]
fn closest_point_respects_max_distance() {
    let mut rng = Rng::new(4);
    let (pos, faces) = soup(&mut rng, 500);
    let bvh = Bvh::build(&pos, &faces);
    for _ in 0..1000 {
        let p = rng.point(-2.0, 2.0);
        let d = bvh
            .closest_point(p, f32::INFINITY)
            .unwrap()
            .distance_squared
            .sqrt();
        assert!(
            bvh.closest_point(p, d * 0.999).is_none(),
            "found something closer than {d}"
        );
        let hit = bvh.closest_point(p, d * 1.001).expect("within range");
        assert!(hit.distance_squared.sqrt() <= d * 1.001);
        let limit = rng.range(0.0, 0.3);
        let got = bvh.closest_point(p, limit).map(|h| h.distance_squared);
        let want = brute_closest(&pos, &faces, p, limit, |_| true).map(|b| b.1);
        assert_eq!(got.is_some(), want.is_some(), "p {p:?} limit {limit}");
        if let Some(g) = got {
            assert!(g.sqrt() <= limit);
        }
    }
    assert!(bvh.closest_point([0.0; 3], -1.0).is_none());
    assert!(bvh.closest_point([0.0; 3], f32::NAN).is_none());
}

#[test]
fn closest_point_filter_is_respected() {
    let mut rng = Rng::new(5);
    let (pos, faces) = soup(&mut rng, 1000);
    let bvh = Bvh::build(&pos, &faces);
    let accept = |f: u32| f % 3 == 1;
    for _ in 0..1000 {
        let p = rng.point(-1.5, 1.5);
        let hit = bvh
            .closest_point_filtered(p, f32::INFINITY, accept)
            .unwrap();
        assert!(accept(hit.face), "face {} rejected by the filter", hit.face);
        let (_, bd2) = brute_closest(&pos, &faces, p, f32::INFINITY, accept).unwrap();
        assert!((hit.distance_squared.sqrt() - bd2.sqrt()).abs() <= 1e-5 * bd2.sqrt().max(1e-3));
        assert_bary_consistent(&pos, &faces, &hit);
    }
    assert!(bvh
        .closest_point_filtered([0.0; 3], f32::INFINITY, |_| false)
        .is_none());
}

#[test]
fn empty_bvh_answers_none() {
    let bvh = Bvh::build(&[], &[]);
    assert_eq!(bvh.face_count(), 0);
    assert!(bvh.closest_point([0.0; 3], f32::INFINITY).is_none());
    assert!(bvh
        .ray_cast([0.0; 3], [1.0, 0.0, 0.0], 0.0, f32::INFINITY)
        .is_none());
}

#[test]
fn coincident_triangles_build_and_tie_to_lowest_face() {
    // 50 copies of the same triangle: all centroids coincide (median-split path).
    let pos = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let faces = vec![[0, 1, 2]; 50];
    let bvh = Bvh::build(&pos, &faces);
    let hit = bvh.closest_point([0.2, 0.2, 1.0], f32::INFINITY).unwrap();
    assert_eq!(hit.face, 0);
    assert!((hit.distance_squared - 1.0).abs() < 1e-6);
    let ray = bvh
        .ray_cast([0.2, 0.2, 1.0], [0.0, 0.0, -1.0], 0.0, 10.0)
        .unwrap();
    assert_eq!(ray.face, 0);
    assert!((ray.t - 1.0).abs() < 1e-6);
}

// ---------------------------------------------------------------------------------------------
// Ray casts

#[test]
fn ray_cast_matches_brute_force_on_random_rays() {
    let mut rng = Rng::new(6);
    let (pos, faces) = soup(&mut rng, 3000);
    let bvh = Bvh::build(&pos, &faces);
    let mut hits = 0;
    for i in 0..3000 {
        let o = rng.point(-2.0, 2.0);
        let mut d = rng.unit();
        if i % 10 == 0 {
            d[i % 3] = 0.0; // axis-parallel components exercise the flat-slab path
        }
        let t_min = if i % 2 == 0 {
            0.0
        } else {
            rng.range(-1.0, 1.0)
        };
        let t_max = if i % 3 == 0 {
            f32::INFINITY
        } else {
            rng.range(0.5, 4.0)
        };
        let got = bvh.ray_cast(o, d, t_min, t_max);
        let want = brute_ray(&pos, &faces, o, d, t_min, t_max);
        match (got, want) {
            (None, None) => {}
            (Some(g), Some((_, bt))) => {
                hits += 1;
                assert!(
                    (g.t - bt).abs() <= 1e-5 * bt.abs().max(1.0),
                    "ray {i}: t {} vs {bt}",
                    g.t
                );
                assert!(g.t > t_min && g.t <= t_max);
                let [a, b, c] = faces[g.face as usize].map(|v| pos[v as usize]);
                let q: [f32; 3] =
                    std::array::from_fn(|k| g.bary[0] * a[k] + g.bary[1] * b[k] + g.bary[2] * c[k]);
                let on_ray: [f32; 3] = std::array::from_fn(|k| o[k] + g.t * d[k]);
                assert!(
                    norm(sub(q, on_ray)) < 1e-4,
                    "ray {i}: bary point off the ray"
                );
            }
            (g, w) => panic!("ray {i}: bvh {g:?} vs brute force {w:?}"),
        }
    }
    assert!(hits > 300, "too few hits ({hits}) to be a meaningful test");
}

#[test]
fn ray_at_unit_sphere_hits_at_distance_minus_one() {
    let (pos, faces) = icosphere(5);
    let bvh = Bvh::build(&pos, &faces);
    let mut rng = Rng::new(7);
    for _ in 0..500 {
        let u = rng.unit();
        let dist = rng.range(1.5, 10.0);
        let o = u.map(|c| c * dist);
        let d = u.map(|c| -c);
        let hit = bvh
            .ray_cast(o, d, 0.0, f32::INFINITY)
            .expect("aimed at the centre");
        assert!(
            (hit.t - (dist - 1.0)).abs() < 1e-3,
            "t {} vs {}",
            hit.t,
            dist - 1.0
        );
        // From inside (both sides count): the far wall at t = 1.
        let inside = bvh.ray_cast([0.0; 3], u, 0.0, f32::INFINITY).unwrap();
        assert!((inside.t - 1.0).abs() < 1e-3);
        // A ray pointing away misses; a short ray stops before the surface.
        assert!(bvh.ray_cast(o, u, 0.0, f32::INFINITY).is_none());
        assert!(bvh.ray_cast(o, d, 0.0, dist - 1.01).is_none());
    }
}

// ---------------------------------------------------------------------------------------------
// Welding and topology

#[test]
fn cube_of_six_quads_welds_closed() {
    let (pos, tris) = cube_quads();
    let a = asset(
        vec![primitive(0, 0, pos, tris)],
        vec![instance(0, 0, identity())],
    );
    let s = build_surface(&a, &WeldParams::default()).unwrap();
    assert_eq!(s.vertex_count(), 8);
    assert_eq!(s.face_count(), 12);
    assert_eq!(s.degenerate_removed, 0);
    let t = topology(&s);
    assert!(t.boundary_loops.is_empty(), "{:?}", t.boundary_loops);
    assert_eq!(t.component_count, 1);
    assert_eq!(t.euler_characteristic, 2);
    assert_eq!(t.non_manifold_edges, 0);
    assert!(t
        .face_neighbors
        .iter()
        .all(|n| n.iter().all(Option::is_some)));
    // Neighbours are mutual.
    for (f, ns) in t.face_neighbors.iter().enumerate() {
        for n in ns.iter().flatten() {
            assert!(t.face_neighbors[*n as usize].contains(&Some(f as u32)));
        }
    }
    // Each cube corner touches 4 or 5... at least 3 faces; one-rings contain the vertex.
    for v in 0..s.vertex_count() {
        let ring = t.vertex_faces(v);
        assert!(ring.len() >= 3);
        assert!(ring
            .iter()
            .all(|&f| s.faces[f as usize].contains(&(v as u32))));
    }
    assert_eq!(t.vertex_faces.len(), 36);
    assert!((s.area() - 6.0).abs() < 1e-9);
    assert!((signed_volume(&s) - 1.0).abs() < 1e-9);
    assert!((s.diagonal() - 3f32.sqrt()).abs() < 1e-6);
    assert_eq!(s.bounding_box(), ([0.0; 3], [1.0; 3]));
}

#[test]
fn grid_has_one_boundary_loop_of_forty_vertices() {
    let n = 10;
    let mut pos = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            pos.push([i as f32, j as f32, 0.0]);
        }
    }
    let mut tris = Vec::new();
    let id = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let a = asset(
        vec![primitive(0, 0, pos, tris)],
        vec![instance(0, 0, identity())],
    );
    let s = build_surface(&a, &WeldParams::default()).unwrap();
    assert_eq!(s.face_count(), 200);
    let t = topology(&s);
    assert_eq!(t.boundary_loops.len(), 1);
    let lp = &t.boundary_loops[0];
    assert_eq!(lp.len(), 40);
    // Consecutive loop vertices are one unit apart on the border of the square.
    for k in 0..lp.len() {
        let (p, q) = (
            s.positions[lp[k] as usize],
            s.positions[lp[(k + 1) % lp.len()] as usize],
        );
        assert!((norm(sub(p, q)) - 1.0).abs() < 1e-6);
        assert!(p[0] == 0.0 || p[0] == 10.0 || p[1] == 0.0 || p[1] == 10.0);
    }
    // The loop runs counter-clockwise seen from +z (the faces' normal side): positive signed area.
    let signed: f32 = (0..lp.len())
        .map(|k| {
            let (p, q) = (
                s.positions[lp[k] as usize],
                s.positions[lp[(k + 1) % lp.len()] as usize],
            );
            p[0] * q[1] - q[0] * p[1]
        })
        .sum();
    assert!(signed > 0.0);
    assert_eq!(t.euler_characteristic, 1);
    assert_eq!(t.component_count, 1);
    assert!(s.face_normal(0)[2] > 0.999);
}

#[test]
fn two_cubes_are_two_components() {
    let (pos, tris) = cube_quads();
    let a = asset(
        vec![primitive(0, 0, pos, tris)],
        vec![
            instance(0, 0, identity()),
            instance(1, 0, scale_translate([1.0; 3], [3.0, 0.0, 0.0])),
        ],
    );
    let s = build_surface(&a, &WeldParams::default()).unwrap();
    assert_eq!(s.vertex_count(), 16);
    assert_eq!(s.face_count(), 24);
    let t = topology(&s);
    assert_eq!(t.component_count, 2);
    assert_eq!(t.euler_characteristic, 4);
    assert!(t.face_component[..12].iter().all(|&c| c == 0));
    assert!(t.face_component[12..].iter().all(|&c| c == 1));
}

#[test]
fn degenerate_triangles_are_removed_and_counted() {
    let pos = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [2.0, 0.0, 0.0],  // collinear with 0 and 1
        [1.0, 1e-9, 0.0], // welds onto vertex 1 with a tolerance of 1e-6 of the diagonal
        [5.0, 5.0, 5.0],  // only used by a degenerate triangle: must not survive as a vertex
    ];
    let tris = vec![
        [0, 1, 2], // good
        [0, 0, 2], // repeated vertex
        [0, 1, 3], // zero area
        [1, 4, 2], // repeated after welding
        [5, 5, 5], // repeated
    ];
    let a = asset(
        vec![primitive(0, 0, pos, tris)],
        vec![instance(0, 0, identity())],
    );
    let s = build_surface(&a, &WeldParams::default()).unwrap();
    assert_eq!(s.face_count(), 1);
    assert_eq!(s.degenerate_removed, 4);
    assert_eq!(s.vertex_count(), 3, "unused vertices are dropped");
    assert_eq!(s.origins[0].triangle, 0);
    let lookup = s.face_lookup();
    assert_eq!(lookup.len(), 1);
    assert!(!lookup.contains_key(&FaceOrigin {
        instance: 0,
        primitive: 0,
        triangle: 1
    }));

    // Only degenerate triangles: an error, not an empty surface.
    let bad = asset(
        vec![primitive(
            0,
            0,
            vec![[0.0; 3], [1.0, 0.0, 0.0]],
            vec![[0, 1, 1]],
        )],
        vec![instance(0, 0, identity())],
    );
    assert!(matches!(
        build_surface(&bad, &WeldParams::default()),
        Err(MeshError::AllDegenerate { removed: 1 })
    ));
}

#[test]
fn weld_tolerance_merges_within_and_keeps_beyond() {
    // Two triangles sharing an edge whose copies differ by 1e-4 (diagonal ≈ 1.414).
    let e = 1e-4;
    let pos = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0 + e, e, 0.0],
        [1.0, 1.0, 0.0],
        [e, 1.0, 0.0],
    ];
    let tris = vec![[0, 1, 2], [3, 4, 5]];
    let a = asset(
        vec![primitive(0, 0, pos, tris)],
        vec![instance(0, 0, identity())],
    );
    let tight = build_surface(
        &a,
        &WeldParams {
            relative_tolerance: 1e-6,
        },
    )
    .unwrap();
    assert_eq!(tight.vertex_count(), 6);
    assert_eq!(topology(&tight).component_count, 2);
    let loose = build_surface(
        &a,
        &WeldParams {
            relative_tolerance: 1e-3,
        },
    )
    .unwrap();
    assert_eq!(loose.vertex_count(), 4);
    assert!((loose.weld_tolerance - 1e-3 * 2f32.sqrt()).abs() < 1e-6);
    let t = topology(&loose);
    assert_eq!(t.component_count, 1);
    assert_eq!(t.boundary_loops.len(), 1);
    assert_eq!(t.boundary_loops[0].len(), 4);
}

#[test]
fn mirrored_instance_keeps_outward_normals() {
    let (pos, tris) = cube_quads();
    let mirror = scale_translate([-1.0, 1.0, 1.0], [-2.0, 0.0, 0.0]);
    let inst = instance(0, 0, mirror);
    assert!(inst.mirrors());
    let a = asset(vec![primitive(0, 0, pos, tris)], vec![inst]);
    let s = build_surface(&a, &WeldParams::default()).unwrap();
    assert_eq!(s.vertex_count(), 8);
    let center = [-2.5f32, 0.5, 0.5];
    for f in 0..s.face_count() {
        let n = s.face_normal(f);
        let c = s.face_point(f, [1.0 / 3.0; 3]);
        assert!(
            dot(n, sub(c, center)) > 0.4,
            "face {f} normal {n:?} points inward"
        );
    }
    assert!((signed_volume(&s) - 1.0).abs() < 1e-6);
    let t = topology(&s);
    assert!(t.boundary_loops.is_empty());
    assert_eq!(t.euler_characteristic, 2);
}

#[test]
fn corners_and_origins_link_back_to_the_asset() {
    let (cube_pos, cube_tris) = cube_quads();
    let (sp, sf) = icosphere(1);
    // Mesh 0: cube; mesh 1: two primitives (sphere halves by face order). Instance 1 mirrors.
    let half = sf.len() / 2;
    let a = asset(
        vec![
            primitive(0, 0, cube_pos, cube_tris),
            primitive(1, 0, sp.clone(), sf[..half].to_vec()),
            primitive(1, 1, sp, sf[half..].to_vec()),
        ],
        vec![
            instance(0, 1, scale_translate([2.0, 2.0, 2.0], [5.0, 0.0, 0.0])),
            instance(1, 1, scale_translate([1.0, -1.0, 1.0], [-5.0, 0.0, 0.0])),
            instance(2, 0, identity()),
        ],
    );
    let s = build_surface(&a, &WeldParams::default()).unwrap();
    assert_eq!(s.face_count(), a.instanced_triangle_count());
    assert_eq!(s.corners.len(), s.face_count());
    assert_eq!(s.origins.len(), s.face_count());
    for f in 0..s.face_count() {
        let o = s.origins[f];
        let inst = &a.instances[o.instance as usize];
        let prim = &a.primitives[o.primitive as usize];
        assert_eq!(prim.mesh, inst.mesh);
        let mut tri = prim.triangles[o.triangle as usize];
        if inst.mirrors() {
            tri.swap(1, 2);
        }
        for (k, &vertex) in tri.iter().enumerate() {
            let c = s.corners[f][k];
            assert_eq!((c.instance, c.primitive), (o.instance, o.primitive));
            assert_eq!(c.vertex, vertex, "face {f} corner {k}");
            let w = inst.transform_point(prim.positions[c.vertex as usize]);
            let p = s.positions[s.faces[f][k] as usize];
            for j in 0..3 {
                assert!((w[j] as f32 - p[j]).abs() <= s.weld_tolerance + 1e-6);
            }
        }
    }
    // Round trip through the lookup.
    let lookup = s.face_lookup();
    assert_eq!(lookup.len(), s.face_count());
    for (f, o) in s.origins.iter().enumerate() {
        assert_eq!(lookup[o], f as u32);
    }
    // Two spheres and a cube, each closed.
    let t = topology(&s);
    assert_eq!(t.component_count, 3);
    assert_eq!(t.euler_characteristic, 6);
    assert!(t.boundary_loops.is_empty());
    assert!(signed_volume(&s) > 0.0);
}

#[test]
fn non_manifold_edge_is_counted() {
    // Three triangles on the edge (0, 1), plus a fourth attached normally to one of them.
    let pos = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.5, 1.0, 0.0],
        [0.5, -1.0, 0.0],
        [0.5, 0.0, 1.0],
        [1.5, 1.0, 0.0],
    ];
    let faces = vec![[0, 1, 2], [1, 0, 3], [0, 1, 4], [1, 5, 2]];
    let s = Surface::from_triangles(pos, faces);
    let t = topology(&s);
    assert_eq!(t.non_manifold_edges, 1);
    assert_eq!(t.face_neighbors[0][0], None);
    assert_eq!(t.face_neighbors[1][0], None);
    assert_eq!(t.face_neighbors[0][1], Some(3));
    assert_eq!(t.component_count, 1);
    // V - E + F = 6 - 9 + 4.
    assert_eq!(t.euler_characteristic, 1);
    assert!(!t.boundary_loops.is_empty());
}

#[test]
fn bad_parameters_and_empty_scenes_are_errors() {
    let (pos, tris) = cube_quads();
    let a = asset(
        vec![primitive(0, 0, pos, tris)],
        vec![instance(0, 0, identity())],
    );
    for bad in [-1e-6, 0.1, f32::NAN] {
        assert!(matches!(
            build_surface(
                &a,
                &WeldParams {
                    relative_tolerance: bad
                }
            ),
            Err(MeshError::InvalidParam {
                name: "relative_tolerance",
                ..
            })
        ));
    }
    assert!(
        build_surface(
            &a,
            &WeldParams {
                relative_tolerance: 0.0
            }
        )
        .unwrap()
        .vertex_count()
            == 8
    );
    let empty = asset(Vec::new(), Vec::new());
    assert!(matches!(
        build_surface(&empty, &WeldParams::default()),
        Err(MeshError::EmptySurface)
    ));
    let out_of_range = asset(
        vec![primitive(0, 0, vec![[0.0; 3]], vec![[0, 1, 2]])],
        vec![instance(0, 0, identity())],
    );
    assert!(matches!(
        build_surface(&out_of_range, &WeldParams::default()),
        Err(MeshError::VertexIndexOutOfRange { index: 1, .. })
    ));
    let params: WeldParams = serde_json::from_str("{}").unwrap();
    assert_eq!(params.relative_tolerance, 1e-6);
    assert!(serde_json::from_str::<WeldParams>(r#"{"tolerance": 1}"#).is_err());
}

#[test]
fn sphere_normals_area_and_lookup() {
    let (pos, faces) = icosphere(4);
    let s = Surface::from_triangles(pos, faces);
    let normals = s.vertex_normals();
    for (p, n) in s.positions.iter().zip(&normals) {
        assert!(dot(*p, *n) > 0.999, "normal {n:?} at {p:?}");
    }
    for f in 0..s.face_count() {
        let c = s.face_point(f, [1.0 / 3.0; 3]);
        assert!(dot(s.face_normal(f), c) > 0.99);
        assert!(s.face_area(f) > 0.0);
    }
    let area = s.area();
    assert!(
        (area - 4.0 * std::f64::consts::PI).abs() / (4.0 * std::f64::consts::PI) < 0.01,
        "area {area}"
    );
    assert!(s.face_lookup().is_empty());
    let t = topology(&s);
    assert_eq!(t.euler_characteristic, 2);
    assert_eq!(t.component_count, 1);
}

// ---------------------------------------------------------------------------------------------
// Determinism

#[test]
fn results_are_identical_with_one_and_two_threads() {
    // A sphere big enough for the parallel build paths, split over primitives and instances,
    // with seam duplicates and sub-tolerance jitter.
    let (sp, sf) = icosphere(6);
    let mut rng = Rng::new(8);
    let jittered: Vec<[f32; 3]> = sp
        .iter()
        .map(|p| p.map(|c| c + rng.range(-1e-6, 1e-6)))
        .collect();
    let third = sf.len() / 3;
    let a = asset(
        vec![
            primitive(0, 0, sp.clone(), sf[..third].to_vec()),
            primitive(0, 1, jittered, sf[third..2 * third].to_vec()),
            primitive(0, 2, sp, sf[2 * third..].to_vec()),
        ],
        vec![
            instance(0, 0, identity()),
            instance(1, 0, scale_translate([-1.0, 1.0, 1.0], [3.0, 0.0, 0.0])),
        ],
    );
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let s = build_surface(&a, &WeldParams::default()).unwrap();
            let t = topology(&s);
            let bvh = Bvh::build(&s.positions, &s.faces);
            let mut rng = Rng::new(9);
            let hits: Vec<_> = (0..2000)
                .map(|_| bvh.closest_point(rng.point(-2.0, 5.0), f32::INFINITY))
                .collect();
            (s, t, bvh, hits)
        })
    };
    let (s1, t1, b1, h1) = run(1);
    let (s2, t2, b2, h2) = run(2);
    assert_eq!(s1.vertex_count(), 2 * sp_vertex_count(6));
    assert_eq!(t1.component_count, 2);
    assert!(t1.boundary_loops.is_empty());
    assert!(s1 == s2, "surfaces differ between 1 and 2 threads");
    assert!(t1 == t2, "topologies differ");
    assert!(b1 == b2, "BVHs differ");
    assert_eq!(h1, h2);
    assert!(b1.depth() < 80);
}

/// Vertex count of `icosphere(level)`: 10·4^level + 2.
fn sp_vertex_count(level: u32) -> usize {
    10 * 4usize.pow(level) + 2
}

// ---------------------------------------------------------------------------------------------
// Primitives and odd inputs

#[test]
fn zero_area_triangles_measure_distance_to_their_segment() {
    // Collinear corners: the triangle is the segment from (0,0,0) to (2,0,0).
    let (a, b, c) = ([0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
    for (p, want) in [
        ([1.5f32, 1.0, 0.0], 1.0f32),
        ([3.0, 0.0, 1.0], 2f32.sqrt()),
        ([-1.0, 0.0, 0.0], 1.0),
        ([0.5, -2.0, 0.0], 2.0),
    ] {
        let (d2, q, bary) = point_triangle_distance_squared(p, a, b, c);
        assert!(
            (d2.sqrt() - want).abs() < 1e-6,
            "p {p:?}: {} vs {want}",
            d2.sqrt()
        );
        let r: [f32; 3] = std::array::from_fn(|k| bary[0] * a[k] + bary[1] * b[k] + bary[2] * c[k]);
        assert!(norm(sub(r, q)) < 1e-6);
    }
    // All three corners equal: a point.
    let (d2, q, _) = point_triangle_distance_squared([0.0, 3.0, 4.0], [0.0; 3], [0.0; 3], [0.0; 3]);
    assert_eq!((d2, q), (25.0, [0.0; 3]));
}

#[test]
fn ray_triangle_hits_both_sides_and_misses_parallel_rays() {
    let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let front = ray_triangle([0.25, 0.25, 1.0], [0.0, 0.0, -1.0], a, b, c).unwrap();
    let back = ray_triangle([0.25, 0.25, -2.0], [0.0, 0.0, 1.0], a, b, c).unwrap();
    assert!((front.0 - 1.0).abs() < 1e-6 && (back.0 - 2.0).abs() < 1e-6);
    assert!((front.1[1] - 0.25).abs() < 1e-6 && (front.1[2] - 0.25).abs() < 1e-6);
    assert!(ray_triangle([0.25, 0.25, 1.0], [1.0, 0.0, 0.0], a, b, c).is_none());
    assert!(ray_triangle([0.9, 0.9, 1.0], [0.0, 0.0, -1.0], a, b, c).is_none());
}

#[test]
fn bowtie_and_flipped_faces_do_not_panic() {
    // Two triangles touching at one vertex (a non-manifold vertex), and a third glued to the
    // second with opposite winding.
    let pos = vec![
        [0.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, -1.0, 0.0],
        [-1.0, 1.0, 0.0],
        [-1.0, -1.0, 0.0],
        [-2.0, 0.0, 0.0],
    ];
    let faces = vec![[0, 2, 1], [0, 3, 4], [3, 4, 5]];
    let s = Surface::from_triangles(pos, faces);
    let t = topology(&s);
    assert_eq!(t.non_manifold_edges, 0);
    assert_eq!(
        t.component_count, 2,
        "a shared vertex does not connect components"
    );
    assert_eq!(t.face_neighbors[1][1], Some(2));
    let boundary_vertices: usize = t.boundary_loops.iter().map(Vec::len).sum();
    assert!(boundary_vertices >= 6);
    assert_eq!(t.vertex_faces(0), &[0, 1]);
}
