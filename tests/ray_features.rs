//! Ray-cast shape features (issue 4, part 10): solid-angle curvature, SH directional occlusion,
//! shape diameter, deterministic ray sets and the BVH multi-hit queries, on analytic shapes.

use std::collections::HashMap;
use std::f64::consts::PI;

use retex::engine::control::Control;
use retex::engine::geometry::occlusion::{directional_occlusion, OcclusionParams};
use retex::engine::geometry::ray_sets::{cast_rays, fibonacci_sphere, RayContext, RayFeatureError};
use retex::engine::geometry::sdf::{sdf_cone, shape_diameter, SdfParams};
use retex::engine::geometry::solid_angle::{solid_angle_curvature, SolidAngleParams};
use retex::engine::mesh::surface::Surface;
use retex::engine::spatial::{ray_triangle, Bvh};

// ---------------------------------------------------------------- shape generators

fn normalize(p: [f64; 3]) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    p.map(|c| c / l)
}

/// Orients every face so that its normal points away from the origin (star-shaped shapes).
fn orient_outward(positions: &[[f32; 3]], faces: &mut [[u32; 3]]) {
    for f in faces.iter_mut() {
        let [a, b, c] = f.map(|v| positions[v as usize].map(|x| x as f64));
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let m: Vec<f64> = (0..3).map(|k| a[k] + b[k] + c[k]).collect();
        if n[0] * m[0] + n[1] * m[1] + n[2] * m[2] < 0.0 {
            f.swap(1, 2);
        }
    }
}

/// Icosahedron subdivided `levels` times, vertices on the sphere of radius `rho` at the origin.
fn icosphere(levels: u32, rho: f64) -> Surface {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut pos: Vec<[f64; 3]> = [
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
    ]
    .map(normalize)
    .to_vec();
    let mut faces: Vec<[u32; 3]> = vec![
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
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(faces.len() * 4);
        for f in &faces {
            let m: Vec<u32> = (0..3)
                .map(|k| {
                    let (a, b) = (f[k], f[(k + 1) % 3]);
                    *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                        let (pa, pb) = (pos[a as usize], pos[b as usize]);
                        pos.push(normalize(std::array::from_fn(|j| pa[j] + pb[j])));
                        (pos.len() - 1) as u32
                    })
                })
                .collect();
            next.push([f[0], m[0], m[2]]);
            next.push([f[1], m[1], m[0]]);
            next.push([f[2], m[2], m[1]]);
            next.push([m[0], m[1], m[2]]);
        }
        faces = next;
    }
    let positions: Vec<[f32; 3]> = pos.iter().map(|p| p.map(|c| (c * rho) as f32)).collect();
    orient_outward(&positions, &mut faces);
    Surface::from_triangles(positions, faces)
}

/// Latitude–longitude sphere with `rings` latitude bands and `segments` longitudes, radius
/// `radius(theta, phi)` (theta from +z).
fn uv_sphere(rings: u32, segments: u32, radius: impl Fn(f64, f64) -> f64) -> Surface {
    let mut pos = vec![[0.0, 0.0, radius(0.0, 0.0) as f32]];
    for i in 1..rings {
        let th = PI * i as f64 / rings as f64;
        for j in 0..segments {
            let ph = 2.0 * PI * j as f64 / segments as f64;
            let r = radius(th, ph);
            pos.push([
                (r * th.sin() * ph.cos()) as f32,
                (r * th.sin() * ph.sin()) as f32,
                (r * th.cos()) as f32,
            ]);
        }
    }
    pos.push([0.0, 0.0, -radius(PI, 0.0) as f32]);
    let south = (pos.len() - 1) as u32;
    let ring = |i: u32, j: u32| 1 + (i - 1) * segments + j % segments;
    let mut faces = Vec::new();
    for j in 0..segments {
        faces.push([0, ring(1, j), ring(1, j + 1)]);
        faces.push([south, ring(rings - 1, j + 1), ring(rings - 1, j)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            let (a, b, c, d) = (
                ring(i, j),
                ring(i, j + 1),
                ring(i + 1, j),
                ring(i + 1, j + 1),
            );
            faces.push([a, c, b]);
            faces.push([b, c, d]);
        }
    }
    orient_outward(&pos, &mut faces);
    Surface::from_triangles(pos, faces)
}

/// Square grid `n × n` cells over `[-half, half]²` at z = 0, normal +z.
fn plane(n: u32, half: f32) -> Surface {
    let mut pos = Vec::new();
    for i in 0..=n {
        for j in 0..=n {
            let x = -half + 2.0 * half * i as f32 / n as f32;
            let y = -half + 2.0 * half * j as f32 / n as f32;
            pos.push([x, y, 0.0]);
        }
    }
    let id = |i: u32, j: u32| i * (n + 1) + j;
    let mut faces = Vec::new();
    for i in 0..n {
        for j in 0..n {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Surface::from_triangles(pos, faces)
}

/// Box `[-1, 1]³` with each face an `n × n` grid, welded through a lattice key. `skip_top` leaves
/// the `z = 1` face out (an open cup); `inward` points the normals into the box.
fn lattice_box(n: u32, skip_top: bool, inward: bool) -> Surface {
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let mut pos: Vec<[f32; 3]> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut id = |k: [u32; 3], pos: &mut Vec<[f32; 3]>| {
        *ids.entry(k).or_insert_with(|| {
            pos.push(k.map(|c| -1.0 + 2.0 * c as f32 / n as f32));
            (pos.len() - 1) as u32
        })
    };
    for axis in 0..3 {
        for side in [0, n] {
            if skip_top && axis == 2 && side == n {
                continue;
            }
            let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
            for a in 0..n {
                for b in 0..n {
                    let key = |da: u32, db: u32| {
                        let mut k = [0u32; 3];
                        k[axis] = side;
                        k[u] = a + da;
                        k[w] = b + db;
                        k
                    };
                    let q = [key(0, 0), key(1, 0), key(1, 1), key(0, 1)].map(|k| id(k, &mut pos));
                    // (u, w, axis) is right-handed, so this winding faces +axis.
                    let mut t1 = [q[0], q[1], q[2]];
                    let mut t2 = [q[0], q[2], q[3]];
                    if (side == 0) != inward {
                        t1.swap(1, 2);
                        t2.swap(1, 2);
                    }
                    faces.push(t1);
                    faces.push(t2);
                }
            }
        }
    }
    Surface::from_triangles(pos, faces)
}

fn vertex_near(s: &Surface, p: [f32; 3]) -> usize {
    let d = |q: &[f32; 3]| (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f32>();
    (0..s.vertex_count())
        .min_by(|&a, &b| d(&s.positions[a]).total_cmp(&d(&s.positions[b])))
        .unwrap()
}

fn len(v: [f32; 3]) -> f32 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

// ---------------------------------------------------------------- BVH queries and ray sets

#[test]
fn generators_are_closed_and_outward() {
    // Signed volume of the icosphere is close to the ball's and positive (outward winding).
    let s = icosphere(3, 1.0);
    let vol: f64 = s
        .faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|v| s.positions[v as usize].map(|x| x as f64));
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum();
    // Inscribed: slightly less than the ball (by ~1% at this level).
    let ball = 4.0 * PI / 3.0;
    assert!(vol < ball && vol > 0.985 * ball, "volume {vol}");
    let b = lattice_box(4, false, false);
    assert_eq!(b.vertex_count(), 6 * 16 + 2);
    let n = b.vertex_normals();
    let top = vertex_near(&b, [0.0, 0.0, 1.0]);
    assert!(n[top][2] > 0.999, "{:?}", n[top]);
}

#[test]
fn fibonacci_set_is_unit_and_balanced() {
    let d = fibonacci_sphere(200);
    let mut mean = [0.0f64; 3];
    for v in &d {
        assert!((len(*v) - 1.0).abs() < 1e-5);
        for k in 0..3 {
            mean[k] += v[k] as f64 / 200.0;
        }
    }
    assert!(mean.iter().all(|m| m.abs() < 0.01), "{mean:?}");
    assert_eq!(d.iter().filter(|v| v[2] > 0.0).count(), 100);
}

#[test]
fn rays_from_inside_a_closed_sphere_always_hit_at_the_chord() {
    let rho = 1.5f32;
    let s = icosphere(4, rho as f64);
    let bvh = Bvh::build(&s.positions, &s.faces);
    let points = [[0.0, 0.0, 0.0], [0.3, -0.2, 0.5], [-0.7, 0.1, 0.0f32]];
    let dirs = fibonacci_sphere(997);
    let hits = cast_rays(&bvh, &points, &dirs, 0.0, f32::INFINITY);
    for (i, h) in hits.iter().enumerate() {
        let (p, d) = (points[i / dirs.len()], dirs[i % dirs.len()]);
        let h = h.unwrap_or_else(|| panic!("ray {i} from {p:?} along {d:?} missed"));
        // Distance to the sphere along d: t² + 2 t (p·d) + |p|² - ρ² = 0.
        let pd = p[0] * d[0] + p[1] * d[1] + p[2] * d[2];
        let pp = len(p).powi(2);
        let t = -pd + (pd * pd - pp + rho * rho).sqrt();
        assert!((h.t - t).abs() < 2e-3 * rho, "ray {i}: {} vs {t}", h.t);
        // Exactly one crossing to infinity from inside (a ray through a shared edge reports
        // both faces at the same t); an any-hit query agrees.
        let mut ts = Vec::new();
        bvh.ray_for_each_hit(p, d, 0.0, f32::INFINITY, |h| ts.push(h.t));
        assert!(!ts.is_empty() && ts.len() <= 2, "ray {i}: {ts:?}");
        assert!(
            ts.iter().all(|&x| (x - ts[0]).abs() < 1e-5),
            "ray {i}: {ts:?}"
        );
        assert!(bvh.ray_hits_any(p, d, 0.0, f32::INFINITY));
        assert!(!bvh.ray_hits_any(p, d, 0.0, 0.5 * t));
    }
}

#[test]
fn all_hits_match_brute_force() {
    let s = uv_sphere(12, 20, |th, ph| {
        1.0 + 0.3 * (3.0 * th).sin() * (2.0 * ph).cos()
    });
    let bvh = Bvh::build(&s.positions, &s.faces);
    for (i, d) in fibonacci_sphere(300).iter().enumerate() {
        let o = [3.0 * d[0], 3.0 * d[1], 3.0 * d[2]];
        let dir = [-d[0] + 0.1 * (i as f32).sin(), -d[1], -d[2]];
        let mut got = Vec::new();
        bvh.ray_for_each_hit(o, dir, 0.0, 5.0, |h| got.push(h.face));
        got.sort_unstable();
        let mut want: Vec<u32> = (0..s.face_count())
            .filter(|&f| {
                let [a, b, c] = s.face_positions(f);
                ray_triangle(o, dir, a, b, c).is_some_and(|(t, _)| t > 0.0 && t <= 5.0)
            })
            .map(|f| f as u32)
            .collect();
        want.sort_unstable();
        assert_eq!(got, want, "ray {i}");
        assert_eq!(bvh.ray_hits_any(o, dir, 0.0, 5.0), !want.is_empty());
    }
}

// ---------------------------------------------------------------- solid-angle curvature

fn solid(s: &Surface, radii: Vec<f32>, rays: usize) -> (Vec<f32>, Vec<f32>) {
    let p = SolidAngleParams {
        radii,
        rays,
        ..Default::default()
    };
    let out = solid_angle_curvature(s, None, &p, &Control::new()).unwrap();
    (out.radii, out.values)
}

#[test]
fn solid_angle_is_one_half_on_a_large_plane() {
    let s = plane(40, 10.0);
    let diag = s.diagonal();
    let (radii, values) = solid(&s, vec![0.5 / diag, 1.0 / diag, 3.0 / diag], 64);
    let k = radii.len();
    let mut checked = 0;
    for v in 0..s.vertex_count() {
        let p = s.positions[v];
        if p[0].abs().max(p[1].abs()) > 6.5 {
            continue;
        }
        for i in 0..k {
            assert!(
                (values[v * k + i] - 0.5).abs() < 1e-6,
                "v {v} r {}",
                radii[i]
            );
        }
        checked += 1;
    }
    assert!(checked > 500);
}

#[test]
fn solid_angle_on_a_flat_box_face_edge_and_corner() {
    let s = lattice_box(16, false, false);
    let diag = s.diagonal();
    let (_, values) = solid(&s, vec![0.25 / diag, 0.5 / diag], 256);
    for v in 0..s.vertex_count() {
        let p = s.positions[v];
        // On a face, at least 0.5 from its edges.
        let flat = p.iter().filter(|c| c.abs() > 0.99).count() == 1
            && p.iter().filter(|c| c.abs() <= 0.5).count() == 2;
        if flat {
            for i in 0..2 {
                assert!((values[v * 2 + i] - 0.5).abs() < 1e-6, "v {v} {p:?}");
            }
        }
    }
    // A convex right-angled edge encloses a quarter, a corner an eighth (quadrature ± 2/N).
    let edge = vertex_near(&s, [1.0, 1.0, 0.0]);
    let corner = vertex_near(&s, [1.0, 1.0, 1.0]);
    for i in 0..2 {
        assert!(
            (values[edge * 2 + i] - 0.25).abs() < 0.02,
            "{}",
            values[edge * 2 + i]
        );
        assert!(
            (values[corner * 2 + i] - 0.125).abs() < 0.02,
            "{}",
            values[corner * 2 + i]
        );
    }
}

/// Fraction of the sphere `S(p, r)` inside a ball of radius ρ, `p` on its boundary.
fn sphere_fraction(r: f32, rho: f32) -> f32 {
    0.5 - r / (4.0 * rho)
}

#[test]
fn solid_angle_on_spheres_matches_one_half_minus_r_over_4_rho() {
    let rho = 2.0f32;
    for (name, s) in [
        ("icosphere", icosphere(5, rho as f64)),
        ("uv sphere", uv_sphere(96, 192, |_, _| rho as f64)),
    ] {
        let diag = s.diagonal();
        let rel: Vec<f32> = [0.1, 0.25, 0.5, 1.0, 1.5]
            .iter()
            .map(|f| f * rho / diag)
            .collect();
        let k = rel.len();
        // Every vertex within 0.01 with 256 rays.
        let (radii, values) = solid(&s, rel.clone(), 256);
        for v in 0..s.vertex_count() {
            for i in 0..k {
                let want = sphere_fraction(radii[i], rho);
                let got = values[v * k + i];
                assert!(
                    (got - want).abs() < 0.01,
                    "{name} v {v} r {}: {got} vs {want}",
                    radii[i]
                );
            }
        }
        // Default 64 rays: the mean within 0.01 (per vertex the quadrature error is ≤ ~1/64).
        let (radii, values) = solid(&s, rel, 64);
        for i in 0..k {
            let want = sphere_fraction(radii[i], rho);
            let mean = (0..s.vertex_count())
                .map(|v| values[v * k + i])
                .sum::<f32>()
                / s.vertex_count() as f32;
            assert!(
                (mean - want).abs() < 0.01,
                "{name} r {}: mean {mean} vs {want}",
                radii[i]
            );
            let worst = (0..s.vertex_count())
                .map(|v| (values[v * k + i] - want).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 0.025, "{name} r {}: worst {worst}", radii[i]);
        }
    }
}

// ---------------------------------------------------------------- occlusion

#[test]
fn convex_shapes_see_their_full_hemisphere() {
    let rays = 256;
    let params = OcclusionParams {
        rays,
        ..Default::default()
    };
    // Sphere: band 0 is the full hemisphere (the polyhedron's vertices see slightly more), and
    // band 1 is √(3/4π)·π·n.
    // At a vertex of this icosphere the faces dip below the tangent plane by about half the
    // edge's central angle (0.033 rad), which bounds the extra visibility.
    let s = icosphere(4, 1.0);
    let occ = directional_occlusion(&s, None, &params, &Control::new()).unwrap();
    let normals = s.vertex_normals();
    for v in 0..s.vertex_count() {
        let vis = occ.visibility(v);
        assert!((1.0 - 1e-5..=1.05).contains(&vis), "v {v}: {vis}");
        let b = occ.band1_vector(v);
        let want = (3.0 / (4.0 * PI)).sqrt() as f32 * std::f32::consts::PI;
        assert!(
            (len(b) - want).abs() < 0.03 * want,
            "v {v}: |b1| {} vs {want}",
            len(b)
        );
        let n = normals[v];
        let cos = (b[0] * n[0] + b[1] * n[1] + b[2] * n[2]) / len(b);
        assert!(cos > 0.999, "v {v}: cos {cos}");
    }
    // Flat face of a box: exactly half of the rays, with the default count.
    let b = lattice_box(8, false, false);
    let occ =
        directional_occlusion(&b, None, &OcclusionParams::default(), &Control::new()).unwrap();
    let top = vertex_near(&b, [0.0, 0.0, 1.0]);
    assert!((occ.coefficients[top][0] - std::f32::consts::PI.sqrt()).abs() < 1e-5);
}

#[test]
fn the_bottom_of_a_cup_is_more_occluded() {
    let cup = lattice_box(8, true, true);
    let bottom = vertex_near(&cup, [0.0, 0.0, -1.0]);
    let occ =
        directional_occlusion(&cup, None, &OcclusionParams::default(), &Control::new()).unwrap();
    assert!(occ.visibility(bottom) < 0.5, "{}", occ.visibility(bottom));
    // Against the analytic solid angle of the opening: a square of side a at height d seen from
    // below its centre subtends 4 asin(a² / (a² + 4d²)); here a = d = 2.
    let fine = OcclusionParams {
        rays: 16384,
        ..Default::default()
    };
    let occ = directional_occlusion(&cup, None, &fine, &Control::new()).unwrap();
    let omega = 4.0 * (4.0f64 / 20.0).asin();
    let want = (omega / (2.0 * PI)) as f32;
    let got = occ.visibility(bottom);
    assert!((got - want).abs() < 0.03 * want, "{got} vs {want}");
    let b1 = occ.band1_vector(bottom);
    assert!(
        b1[2] > 0.0 && b1[0].abs() < 0.05 * b1[2] && b1[1].abs() < 0.05 * b1[2],
        "{b1:?}"
    );
}

// ---------------------------------------------------------------- shape diameter

/// The paper's estimator, written out independently: median ± 1 std filter, 1/θ weights.
fn expected_sdf(lengths: &[(f64, f64)]) -> f64 {
    let mut l: Vec<f64> = lengths.iter().map(|x| x.0).collect();
    l.sort_by(f64::total_cmp);
    let n = l.len();
    let med = if n % 2 == 1 {
        l[n / 2]
    } else {
        0.5 * (l[n / 2 - 1] + l[n / 2])
    };
    let mean = l.iter().sum::<f64>() / n as f64;
    let sd = (l.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
    let kept = lengths.iter().filter(|x| (x.0 - med).abs() <= sd);
    let (num, den) = kept.fold((0.0, 0.0), |(a, b), x| (a + x.0 / x.1, b + 1.0 / x.1));
    num / den
}

#[test]
fn sdf_on_a_sphere_is_its_diameter_up_to_cone_averaging() {
    let rho = 1.0f64;
    let s = icosphere(4, rho);
    // Default cone (120°, 30 rays): a ray at angle θ has length 2ρ cos θ, so the value is 2ρ
    // times the filtered weighted mean of cos θ (1.535ρ = 0.767 × 2ρ). The mesh is inscribed, so
    // chords are short by at most ~1e-3ρ; tolerance 1%.
    let params = SdfParams::default();
    let predicted = expected_sdf(
        &sdf_cone(&params)
            .iter()
            .map(|&(_, th)| (2.0 * rho * (th as f64).cos(), th as f64))
            .collect::<Vec<_>>(),
    );
    assert!(
        predicted > 1.5 * rho && predicted < 2.0 * rho,
        "{predicted}"
    );
    let sdf = shape_diameter(&s, None, &params, &Control::new()).unwrap();
    for (v, &x) in sdf.iter().enumerate() {
        assert!(
            ((x as f64) - predicted).abs() < 0.01 * predicted,
            "v {v}: {x} vs {predicted}"
        );
    }
    // A narrow cone (10°) removes the bias: within 1% of 2ρ.
    let narrow = SdfParams {
        cone_angle: 10.0,
        ..Default::default()
    };
    let sdf = shape_diameter(&s, None, &narrow, &Control::new()).unwrap();
    for (v, &x) in sdf.iter().enumerate() {
        assert!((x as f64 - 2.0 * rho).abs() < 0.02 * rho, "v {v}: {x}");
    }
}

#[test]
fn sdf_measures_the_thickness_of_a_slab() {
    // A flat box 4 × 4 × 0.5: at the centre of a big face every ray of the cone reaches the
    // opposite face, at 0.5 / cos θ; the value is the paper's estimator over those (1%).
    let mut s = lattice_box(16, false, false);
    for p in &mut s.positions {
        p[0] *= 2.0;
        p[1] *= 2.0;
        p[2] *= 0.25;
    }
    let v = vertex_near(&s, [0.0, 0.0, 0.25]);
    let sdf = shape_diameter(&s, None, &SdfParams::default(), &Control::new()).unwrap();
    let predicted = expected_sdf(
        &sdf_cone(&SdfParams::default())
            .iter()
            .map(|&(_, th)| (0.5 / (th as f64).cos(), th as f64))
            .collect::<Vec<_>>(),
    );
    assert!(predicted > 0.5 && predicted < 0.7, "{predicted}");
    assert!(
        (sdf[v] as f64 - predicted).abs() < 0.01 * predicted,
        "{} vs {predicted}",
        sdf[v]
    );
}

// ---------------------------------------------------------------- determinism, errors

#[test]
fn features_are_identical_for_one_and_two_threads() {
    let s = uv_sphere(24, 48, |th, ph| {
        1.0 + 0.2 * (4.0 * th).sin() * (3.0 * ph).cos()
    });
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let c = Control::new();
            let a = solid_angle_curvature(&s, None, &SolidAngleParams::default(), &c).unwrap();
            let o = directional_occlusion(&s, None, &OcclusionParams::default(), &c).unwrap();
            let d = shape_diameter(&s, None, &SdfParams::default(), &c).unwrap();
            (a.values, o.coefficients, d)
        })
    };
    let (a1, o1, d1) = run(1);
    let (a2, o2, d2) = run(2);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a1), bits(&a2));
    assert_eq!(o1, o2);
    assert_eq!(bits(&d1), bits(&d2));
    // The bumps make the features vary.
    let (lo, hi) = a1
        .iter()
        .fold((1.0f32, 0.0f32), |(l, h), &x| (l.min(x), h.max(x)));
    assert!(hi - lo > 0.2, "{lo}..{hi}");
}

#[test]
fn bad_params_normals_and_cancellation_are_errors() {
    let s = icosphere(1, 1.0);
    let c = Control::new();
    let bad = SolidAngleParams {
        rays: 0,
        ..Default::default()
    };
    assert!(matches!(
        solid_angle_curvature(&s, None, &bad, &c),
        Err(RayFeatureError::InvalidParam { name: "rays", .. })
    ));
    let normals = vec![[0.0, 0.0, 1.0]; 3];
    assert_eq!(
        RayContext::new(&s, Some(&normals)).err(),
        Some(RayFeatureError::NormalCount {
            expected: s.vertex_count(),
            got: 3
        })
    );
    c.cancel();
    assert_eq!(
        directional_occlusion(&s, None, &OcclusionParams::default(), &c).err(),
        Some(RayFeatureError::Cancelled)
    );
    let p: SdfParams = serde_json::from_str(r#"{"rays": 12}"#).unwrap();
    assert_eq!(p.rays, 12);
    assert_eq!(p.cone_angle, 120.0);
}

// ---------------------------------------------------------------- benchmark

fn vm_hwm_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse().ok())
        })
        .unwrap_or(0)
}

/// `cargo test --release --no-default-features --test ray_features -- --ignored --nocapture`
#[test]
#[ignore = "benchmark: run with --release"]
fn bench_solid_angle_4_radii_and_occlusion_64_rays_on_64k_vertices() {
    use std::time::Instant;
    // A bumpy sphere (concave and convex regions) with 65 516 vertices.
    let s = uv_sphere(180, 366, |th, ph| {
        1.0 + 0.15 * (5.0 * th).sin() * (4.0 * ph).cos()
            + 0.04 * (17.0 * th).sin() * (13.0 * ph).sin()
    });
    println!(
        "mesh: {} vertices, {} faces, {} threads",
        s.vertex_count(),
        s.face_count(),
        rayon::current_num_threads()
    );
    let c = Control::new();
    let mut totals = Vec::new();
    for run in 0..5 {
        let t0 = Instant::now();
        let ctx = RayContext::new(&s, None).unwrap();
        let t1 = Instant::now();
        let sa = retex::engine::geometry::solid_angle::solid_angle_curvature_with(
            &ctx,
            &SolidAngleParams::default(),
            &c,
        )
        .unwrap();
        let t2 = Instant::now();
        let occ = retex::engine::geometry::occlusion::directional_occlusion_with(
            &ctx,
            &OcclusionParams::default(),
            &c,
        )
        .unwrap();
        let t3 = Instant::now();
        let sdf =
            retex::engine::geometry::sdf::shape_diameter_with(&ctx, &SdfParams::default(), &c)
                .unwrap();
        let t4 = Instant::now();
        let total = (t3 - t0).as_secs_f64();
        totals.push(total);
        println!(
            "run {run}: context (bvh, normals) {:.3} s, solid angle 4 radii x 64 rays {:.3} s, \
             occlusion 64 rays {:.3} s => {total:.3} s; sdf 30 rays {:.3} s \
             (checks: {} {} {})",
            (t1 - t0).as_secs_f64(),
            (t2 - t1).as_secs_f64(),
            (t3 - t2).as_secs_f64(),
            (t4 - t3).as_secs_f64(),
            sa.values.len(),
            occ.coefficients.len(),
            sdf.len()
        );
    }
    totals.sort_by(f64::total_cmp);
    println!(
        "median solid angle + occlusion (incl. context): {:.3} s; VmHWM {} MiB",
        totals[2],
        vm_hwm_kib() / 1024
    );
}
