//! Isotropic remeshing (Botsch & Kobbelt 2004) and the `detail` hierarchy (Berkiten et al. 2017,
//! §3.1): edge lengths in [4/5 L, 4/3 L], Hausdorff distance to the input under a stated bound,
//! manifold with the input's topology, no face turned against the input, boundaries and sharp
//! features kept; four levels halving the mean edge length with shared absolute lengths.

use std::collections::HashMap;

use retex::engine::control::Control;
use retex::engine::math::{cross, dot, normalize, sub, to_f64};
use retex::engine::mesh::halfedge::HalfEdgeMesh;
use retex::engine::mesh::primitives::{cylinder, uv_sphere};
use retex::engine::mesh::remesh::{remesh, RemeshError, RemeshParams};
use retex::engine::mesh::{topology, Surface};
use retex::engine::methods::detail::hierarchy::{build_pair, mean_edge_length, HierarchyParams};
use retex::engine::spatial::Bvh;

use crate::common_geometry::read_obj;
use crate::meshmatch_common::capsule;

struct Quality {
    in_band: f64,
    hausdorff: f64,
    min_normal_dot: f64,
    /// Faces whose normal points against the input face closest to their centroid.
    against: usize,
}

fn edges(s: &Surface) -> Vec<(u32, u32)> {
    let mut e: Vec<(u32, u32)> = s
        .faces
        .iter()
        .flat_map(|f| (0..3).map(move |i| (f[i].min(f[(i + 1) % 3]), f[i].max(f[(i + 1) % 3]))))
        .collect();
    e.sort_unstable();
    e.dedup();
    e
}

fn fraction_in_band(s: &Surface, l: f64) -> f64 {
    let e = edges(s);
    let ok = e
        .iter()
        .filter(|&&(a, b)| {
            let d = retex::engine::math::dist2(
                to_f64(s.positions[a as usize]),
                to_f64(s.positions[b as usize]),
            )
            .sqrt();
            d >= 0.8 * l * 0.999 && d <= 4.0 / 3.0 * l * 1.001
        })
        .count();
    ok as f64 / e.len() as f64
}

/// Symmetric Hausdorff distance, sampled at vertices and face centroids of each side.
fn hausdorff(a: &Surface, b: &Surface) -> f64 {
    let one = |x: &Surface, y: &Surface| {
        let bvh = Bvh::build(&y.positions, &y.faces);
        let mut pts: Vec<[f32; 3]> = x.positions.clone();
        pts.extend(x.faces.iter().map(|f| {
            let p = f.map(|v| x.positions[v as usize]);
            [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0)
        }));
        pts.iter()
            .map(|&p| {
                bvh.closest_point(p, f32::INFINITY)
                    .unwrap()
                    .distance_squared
                    .sqrt() as f64
            })
            .fold(0.0, f64::max)
    };
    one(a, b).max(one(b, a))
}

fn face_normal(s: &Surface, f: usize) -> [f64; 3] {
    let [a, b, c] = s.faces[f].map(|v| to_f64(s.positions[v as usize]));
    normalize(cross(sub(b, a), sub(c, a)))
}

/// Checks manifoldness and topology against the input and measures the quality numbers.
fn check(input: &Surface, out: &Surface, l: f64, name: &str) -> Quality {
    let ti = topology(input);
    let to = topology(out);
    assert_eq!(to.non_manifold_edges, 0, "{name}: non-manifold edges");
    assert_eq!(
        to.euler_characteristic, ti.euler_characteristic,
        "{name}: Euler characteristic changed"
    );
    assert_eq!(
        to.boundary_loops.len(),
        ti.boundary_loops.len(),
        "{name}: boundary loops"
    );
    assert_eq!(to.component_count, ti.component_count, "{name}: components");
    // Every output face agrees in orientation with the input face closest to its centroid.
    let bvh = Bvh::build(&input.positions, &input.faces);
    let mut min_dot = f64::INFINITY;
    let mut against = 0;
    for f in 0..out.faces.len() {
        let p = out.faces[f].map(|v| out.positions[v as usize]);
        let c = [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0);
        let hit = bvh.closest_point(c, f32::INFINITY).unwrap();
        let d = dot(face_normal(out, f), face_normal(input, hit.face as usize));
        min_dot = min_dot.min(d);
        against += usize::from(d < 0.0);
    }
    let q = Quality {
        in_band: fraction_in_band(out, l),
        hausdorff: hausdorff(input, out),
        min_normal_dot: min_dot,
        against,
    };
    println!(
        "{name}: L {l:.4}, {} → {} faces, in band {:.3} (input {:.3}), Hausdorff {:.5} ({:.4} L), \
         min normal dot {:.3}, {} faces against the input",
        input.faces.len(),
        out.faces.len(),
        q.in_band,
        fraction_in_band(input, l),
        q.hausdorff,
        q.hausdorff / l,
        q.min_normal_dot,
        q.against
    );
    q
}

fn run(s: &Surface, l: f64) -> Surface {
    let p = RemeshParams {
        target_edge_length: l,
        ..Default::default()
    };
    remesh(s, &p, &Control::new()).unwrap().0
}

#[test]
fn sphere_from_a_uv_sphere() {
    // UV spheres have slivers at the poles; the input is far from isotropic (the baseline).
    let input = uv_sphere(1.0, 40, 80);
    for l in [0.06, 0.1, 0.2] {
        let out = run(&input, l);
        let q = check(&input, &out, l, "uv sphere");
        assert!(q.in_band >= 0.95);
        assert!(
            fraction_in_band(&input, l) < 0.6,
            "baseline already isotropic"
        );
        // A sphere's chord depth: centroids of triangles with sides ≤ 4/3 L lie at most
        // (4/3 L)²/(6R) inside, plus the input's own tessellation error.
        let bound = (4.0 / 3.0 * l).powi(2) / 6.0 + 0.002;
        assert!(q.hausdorff < bound, "Hausdorff {} ≥ {bound}", q.hausdorff);
        assert!(q.min_normal_dot > 0.5);
        for p in &out.positions {
            let r = to_f64(*p).iter().map(|x| x * x).sum::<f64>().sqrt();
            assert!((r - 1.0).abs() < 0.002, "vertex off the sphere: r = {r}");
        }
    }
}

#[test]
fn capsule_with_long_thin_triangles() {
    // Only two rings on the cylinder: its triangles are 4 units long and 0.1 wide.
    let (p, t) = capsule(0.5, &[0.0, 4.0], 32, |x| x);
    let input = Surface::from_triangles(p, t);
    for l in [0.05, 0.08, 0.15] {
        let out = run(&input, l);
        let q = check(&input, &out, l, "capsule");
        assert!(q.in_band >= 0.95);
        assert!(q.hausdorff < 0.1 * l, "Hausdorff {}", q.hausdorff);
        assert!(q.min_normal_dot > 0.5);
    }
}

#[test]
fn open_cylinder_keeps_its_boundary() {
    let input = cylinder(0.5, 2.0, 48, 6);
    let l = 0.08;
    let out = run(&input, l);
    let q = check(&input, &out, l, "open cylinder");
    assert!(q.in_band >= 0.95);
    assert!(q.hausdorff < 0.1 * l);
    // Boundary vertices stay on the rims (z = 0 or 2, on the input's polygon).
    let to = topology(&out);
    for lp in &to.boundary_loops {
        let z0 = out.positions[lp[0] as usize][2];
        for &v in lp {
            let p = out.positions[v as usize];
            assert!(
                (p[2] - z0).abs() < 1e-5,
                "boundary vertex left its rim: {p:?}"
            );
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            assert!(r > 0.5 * (std::f32::consts::PI / 48.0).cos() - 1e-5 && r < 0.5 + 1e-5);
        }
    }
}

/// A unit cube, each face an `n × n` grid, welded.
fn cube(n: usize) -> Surface {
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    let mut vid = |p: [f64; 3]| {
        let key = p.map(|x| (x * 1e6).round() as i64);
        *index.entry(key).or_insert_with(|| {
            positions.push(p.map(|x| x as f32));
            positions.len() as u32 - 1
        })
    };
    for axis in 0..3 {
        for side in [0.0, 1.0] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let at = |i: usize, j: usize| {
                let mut p = [0.0; 3];
                p[axis] = side;
                p[u] = i as f64 / n as f64;
                p[v] = j as f64 / n as f64;
                p
            };
            for i in 0..n {
                for j in 0..n {
                    let q = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)].map(&mut vid);
                    // Outward winding: (u, v, axis) is right-handed, so flip on the low side.
                    if side == 1.0 {
                        faces.push([q[0], q[1], q[2]]);
                        faces.push([q[0], q[2], q[3]]);
                    } else {
                        faces.push([q[0], q[2], q[1]]);
                        faces.push([q[0], q[3], q[2]]);
                    }
                }
            }
        }
    }
    Surface::from_triangles(positions, faces)
}

#[test]
fn cube_keeps_its_sharp_edges_and_corners() {
    let input = cube(12);
    for l in [0.06, 0.1] {
        let out = run(&input, l);
        let q = check(&input, &out, l, "cube");
        assert!(q.in_band >= 0.95);
        // Rounded edges would be ~L/4 inside; kept ones are exact.
        assert!(
            q.hausdorff < 1e-4,
            "edges not kept: Hausdorff {}",
            q.hausdorff
        );
        for c in 0..8 {
            let corner = [c & 1, (c >> 1) & 1, (c >> 2) & 1].map(|b| b as f32);
            assert!(
                out.positions.iter().any(|p| p == &corner),
                "corner {corner:?} lost"
            );
        }
    }
}

/// Real meshes at L = the input's mean edge length. Measured: Spot Hausdorff 0.714 L, 99.2 % in
/// band, 1 of 5334 faces against the input face closest to it; koala 0.698 L, 99.3 %, 1 of
/// 6892. Small features (horn tips, ears) shrink by collapses, as in B&K, hence the stated
/// Hausdorff bound of 1.0 L. NOT met yet at coarser L (so not tested there): Spot at 2 L has
/// Hausdorff 1.22 L; the koala at 4 L has 78.5 % of edges in band and 21 faces against.
fn check_real(input: &Surface, factors: &[f64], name: &str) {
    let base = mean_edge_length(input);
    for &f in factors {
        let l = base * f;
        let out = run(input, l);
        let q = check(input, &out, l, name);
        assert!(q.in_band >= 0.95);
        assert!(q.hausdorff < 1.0 * l, "Hausdorff {}", q.hausdorff);
        assert!(
            q.against * 100 <= out.faces.len(),
            "{} faces against",
            q.against
        );
    }
}

#[test]
fn real_mesh_spot() {
    let input = read_obj(&crate::common::test_data(
        "src_spot_keenan/spot_triangulated.obj",
    ));
    check_real(&input, &[1.0], "spot");
}

#[test]
#[ignore = "needs ../shared/assets"]
fn real_mesh_koala() {
    let input = read_obj(&crate::common::shared_asset(
        "perf_koala_odedstein/koala_low_resolution.obj",
    ));
    check_real(&input, &[1.0], "koala");
}

#[test]
fn hierarchy_halves_the_edge_length_with_shared_lengths() {
    let source = uv_sphere(1.0, 60, 120);
    let (p, t) = capsule(0.5, &[0.0, 1.0, 2.0, 3.0, 4.0], 48, |x| x);
    let target = Surface::from_triangles(p, t);
    let params = HierarchyParams {
        finest_edge_length: Some(0.04),
        ..Default::default()
    };
    let (s, tl) = build_pair(&source, &target, &params, &Control::new()).unwrap();
    assert_eq!(s.len(), 4);
    assert_eq!(tl.len(), 4);
    for levels in [&s, &tl] {
        for i in 0..4 {
            assert_eq!(s[i].edge_length, tl[i].edge_length);
            let m = mean_edge_length(&levels[i].surface);
            println!(
                "level {i}: L {:.3}, mean edge {m:.4} ({:.3} L), {} faces, band {:.3}",
                levels[i].edge_length,
                m / levels[i].edge_length,
                levels[i].surface.faces.len(),
                fraction_in_band(&levels[i].surface, levels[i].edge_length)
            );
            assert!(fraction_in_band(&levels[i].surface, levels[i].edge_length) >= 0.95);
            if i > 0 {
                let ratio = mean_edge_length(&levels[i - 1].surface) / m;
                assert!((1.85..=2.15).contains(&ratio), "level ratio {ratio}");
            }
        }
    }
}

/// Random splits, collapses and flips on a capsule keep the half-edge invariants after every
/// operation (the remesher's topology is only as good as these).
#[test]
fn random_edits_keep_the_half_edge_mesh_valid() {
    for seed in [1u64, 2, 3] {
        let (p, t) = capsule(0.5, &[0.0, 1.0, 2.0], 12, |x| x);
        let mut open = Surface::from_triangles(p, t);
        if seed == 3 {
            // An open variant: drop the faces of one cap (boundary handling).
            let keep = open.faces.len() - 12;
            open.faces.truncate(keep);
        }
        let mut m = HalfEdgeMesh::build(&open).unwrap();
        m.validate().unwrap();
        let mut rng = retex::engine::rng::SplitMix64::new(seed);
        for step in 0..3000 {
            let edges = m.edges();
            let h = edges[rng.below(edges.len() as u64) as usize];
            let h = if rng.below(2) == 0 { h } else { h ^ 1 };
            let mid = {
                let (a, b) = (m.pos[m.from(h) as usize], m.pos[m.to[h as usize] as usize]);
                [0, 1, 2].map(|k| 0.5 * (a[k] + b[k]))
            };
            let op = match rng.below(3) {
                0 if m.faces().count() < 3000 => {
                    m.split(h, mid);
                    "split"
                }
                1 if m.collapse_ok(h) => {
                    m.collapse(h, mid);
                    "collapse"
                }
                2 if m.flip_ok(h) => {
                    m.flip(h);
                    "flip"
                }
                _ => continue,
            };
            if let Err(e) = m.validate() {
                panic!("seed {seed} step {step}: {op} of {h}: {e}");
            }
        }
        let (s, _) = m.to_surface();
        let to = topology(&s);
        assert_eq!(to.non_manifold_edges, 0);
        assert_eq!(
            to.euler_characteristic,
            topology(&open).euler_characteristic
        );
    }
}

#[test]
fn bad_input_is_an_error() {
    let s = uv_sphere(1.0, 8, 16);
    let bad = RemeshParams {
        target_edge_length: 0.0,
        ..Default::default()
    };
    assert!(matches!(
        remesh(&s, &bad, &Control::new()),
        Err(RemeshError::Param(_))
    ));
    let tiny = RemeshParams {
        target_edge_length: 1e-6,
        ..Default::default()
    };
    assert!(matches!(
        remesh(&s, &tiny, &Control::new()),
        Err(RemeshError::TooFine { .. })
    ));
    // Three triangles on one edge.
    let p = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let f = vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]];
    let nm = Surface::from_triangles(p, f);
    let ok = RemeshParams {
        target_edge_length: 0.3,
        ..Default::default()
    };
    assert!(matches!(
        remesh(&nm, &ok, &Control::new()),
        Err(RemeshError::Topology(_))
    ));
    let empty = Surface::from_triangles(vec![], vec![]);
    assert!(remesh(&empty, &ok, &Control::new()).is_err());
}

/// The smallest `|cross| / longest edge²` over the faces (about the smallest angle in radians
/// of a thin face; 0 for a face with a zero-length edge or collinear corners).
fn worst_shape(s: &Surface) -> f64 {
    s.faces
        .iter()
        .map(|f| {
            let q = f.map(|v| to_f64(s.positions[v as usize]));
            let l2 = |a: [f64; 3], b: [f64; 3]| {
                let d = sub(a, b);
                dot(d, d)
            };
            let c = cross(sub(q[1], q[0]), sub(q[2], q[0]));
            dot(c, c).sqrt() / l2(q[0], q[1]).max(l2(q[1], q[2])).max(l2(q[2], q[0]))
        })
        .fold(f64::INFINITY, f64::min)
}

/// A sphere with sharp spikes (single vertices pulled out to twice the radius): the spikes'
/// rings become feature chains (dihedral over 60°), and a whole cone of space has a spike's tip
/// as its closest point, so relaxation and back-projection used to put several vertices on
/// one point (the koala scan's hierarchy had 12-34 faces with a zero-length edge per level).
/// No face of the remeshed sphere may be degenerate.
#[test]
fn spikes_leave_no_degenerate_face() {
    let mut s = uv_sphere(1.0, 40, 80);
    let n = s.positions.len();
    for k in 0..12 {
        let v = (k * 7919 + 101) % n;
        s.positions[v] = s.positions[v].map(|c| 2.0 * c);
    }
    for l in [0.08, 0.15, 0.3] {
        let out = run(&s, l);
        let worst = worst_shape(&out);
        eprintln!(
            "spiked sphere at L {l}: {} faces, worst shape {worst:.2e}",
            out.faces.len()
        );
        assert!(worst > 1e-3, "L {l}: worst face shape {worst:.2e}");
    }
}

/// The koala scan's hierarchy (the `detail` pipeline's levels against its low-resolution copy):
/// no degenerate face on any level of either shape (before the guard in `remesh::project` and
/// `relax`: 32-102 angles of 0 per source level).
#[test]
#[ignore = "needs ../shared/assets"]
fn koala_scan_hierarchy_has_no_degenerate_face() {
    let s = read_obj(&crate::common::shared_asset(
        "perf_koala_odedstein/koala.obj",
    ));
    let t = read_obj(&crate::common::shared_asset(
        "perf_koala_odedstein/koala_low_resolution.obj",
    ));
    let (ls, lt) = build_pair(&s, &t, &HierarchyParams::default(), &Control::new()).unwrap();
    for (i, (a, b)) in ls.iter().zip(&lt).enumerate() {
        let (ws, wt) = (worst_shape(&a.surface), worst_shape(&b.surface));
        eprintln!("koala level {i}: worst face shape source {ws:.2e}, target {wt:.2e}");
        assert!(ws > 1e-3 && wt > 1e-3, "level {i}: {ws:.2e} / {wt:.2e}");
    }
}
