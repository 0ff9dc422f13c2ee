//! Ray-cast shape features (issue 4, part 10): solid-angle curvature, SH directional occlusion,
//! shape diameter, deterministic ray sets and the BVH multi-hit queries, on analytic shapes.

use std::collections::HashMap;
use std::f64::consts::PI;

use retex::engine::control::Control;
use retex::engine::geometry::occlusion::{
    directional_occlusion, directional_occlusion_with, OcclusionParams,
};
use retex::engine::geometry::ray_sets::{cast_rays, fibonacci_sphere, RayContext, RayFeatureError};
use retex::engine::geometry::sdf::{sdf_cone, shape_diameter, shape_diameter_with, SdfParams};
use retex::engine::geometry::solid_angle::{
    solid_angle_curvature, solid_angle_curvature_with, SolidAngleParams,
};
use retex::engine::mesh::surface::Surface;
use retex::engine::spatial::{ray_triangle, Bvh};

use crate::common_geometry::orient_outward;

/// Asserts `|got - want| <= tol`, naming the case.
macro_rules! near {
    ($got:expr, $want:expr, $tol:expr, $($ctx:tt)*) => {{
        let (g, w, t) = ($got, $want, $tol);
        assert!((g - w).abs() <= t, "{}: {g} vs {w} (tol {t})", format!($($ctx)*));
    }};
}

fn normalize(p: [f64; 3]) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    p.map(|c| c / l)
}

/// Radius `1 + a sin(m θ) cos(n φ)` for [`uv_sphere`].
fn bumpy(a: f64, m: f64, n: f64) -> impl Fn(f64, f64) -> f64 {
    move |th, ph| 1.0 + a * (m * th).sin() * (n * ph).cos()
}

/// Icosahedron subdivided `levels` times, vertices on the sphere of radius `rho` at the origin.
fn icosphere(levels: u32, rho: f64) -> Surface {
    // The 12 cyclic permutations of (0, ±1, ±φ); faces are the triples at mutual distance 2.
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut base = Vec::new();
    for k in 0..3 {
        for (u, w) in [(1.0, t), (-1.0, t), (1.0, -t), (-1.0, -t)] {
            let mut p = [0.0; 3];
            p[(k + 1) % 3] = u;
            p[(k + 2) % 3] = w;
            base.push(p);
        }
    }
    let edge = |a: usize, b: usize| {
        let d: f64 = (0..3).map(|j| (base[a][j] - base[b][j]).powi(2)).sum();
        (d - 4.0).abs() < 1e-9
    };
    let mut faces: Vec<[u32; 3]> = Vec::new();
    for i in 0..12 {
        for j in i + 1..12 {
            for k in j + 1..12 {
                if edge(i, j) && edge(j, k) && edge(i, k) {
                    faces.push([i as u32, j as u32, k as u32]);
                }
            }
        }
    }
    assert_eq!(faces.len(), 20);
    let mut pos: Vec<[f64; 3]> = base.into_iter().map(normalize).collect();
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
            let q = [j, j + 1].map(|j| [ring(i, j), ring(i + 1, j)]);
            faces.push([q[0][0], q[0][1], q[1][0]]);
            faces.push([q[1][0], q[0][1], q[1][1]]);
        }
    }
    orient_outward(&pos, &mut faces);
    Surface::from_triangles(pos, faces)
}

/// Box `[-1, 1]³` with each face an `n × n` grid, welded through a lattice key. Only the faces
/// `(axis, side)` with `keep(axis, side)` are made (`side` 0 or `n`); `inward` points the
/// normals into the box.
fn lattice_box(n: u32, keep: impl Fn(usize, u32) -> bool, inward: bool) -> Surface {
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
            if !keep(axis, side) {
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

#[test]
fn fibonacci_set_is_unit_and_balanced() {
    let d = fibonacci_sphere(200);
    assert!(d.iter().all(|v| (len(*v) - 1.0).abs() < 1e-5));
    let mean = (0..3).map(|k| d.iter().map(|v| v[k]).sum::<f32>() / 200.0);
    assert!(
        mean.clone().all(|m| m.abs() < 0.01),
        "{:?}",
        mean.collect::<Vec<_>>()
    );
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
    let s = uv_sphere(12, 20, bumpy(0.3, 3.0, 2.0));
    let bvh = Bvh::build(&s.positions, &s.faces);
    for (i, d) in fibonacci_sphere(300).iter().enumerate() {
        let o = [3.0 * d[0], 3.0 * d[1], 3.0 * d[2]];
        let dir = [-d[0] + 0.1 * (i as f32).sin(), -d[1], -d[2]];
        let mut got = Vec::new();
        bvh.ray_for_each_hit(o, dir, 0.0, 5.0, |h| got.push(h.face));
        got.sort_unstable();
        let want: Vec<u32> = (0..s.face_count())
            .filter(|&f| {
                let [a, b, c] = s.face_positions(f);
                ray_triangle(o, dir, a, b, c).is_some_and(|(t, _)| t > 0.0 && t <= 5.0)
            })
            .map(|f| f as u32)
            .collect();
        assert_eq!(got, want, "ray {i}");
        assert_eq!(bvh.ray_hits_any(o, dir, 0.0, 5.0), !want.is_empty());
    }
}

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
    // The z = 1 face of a 40 × 40 lattice box, made 20 × 20 and flat at z = 0 (an open sheet).
    let mut s = lattice_box(40, |axis, side| axis == 2 && side > 0, false);
    for p in &mut s.positions {
        *p = [10.0 * p[0], 10.0 * p[1], 0.0];
    }
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
            near!(values[v * k + i], 0.5, 1e-6, "v {v} r {}", radii[i]);
        }
        checked += 1;
    }
    assert!(checked > 500);
}

#[test]
fn solid_angle_on_a_flat_box_face_edge_and_corner() {
    let s = lattice_box(16, |_, _| true, false);
    let diag = s.diagonal();
    let (_, values) = solid(&s, vec![0.25 / diag, 0.5 / diag], 256);
    for v in 0..s.vertex_count() {
        let p = s.positions[v];
        // On a face, at least 0.5 from its edges.
        let flat = p.iter().filter(|c| c.abs() > 0.99).count() == 1
            && p.iter().filter(|c| c.abs() <= 0.5).count() == 2;
        if flat {
            near!(values[v * 2], 0.5, 1e-6, "v {v} {p:?}");
            near!(values[v * 2 + 1], 0.5, 1e-6, "v {v} {p:?}");
        }
    }
    // A convex right-angled edge encloses a quarter, a corner an eighth (quadrature ± 2/N).
    let edge = vertex_near(&s, [1.0, 1.0, 0.0]);
    let corner = vertex_near(&s, [1.0, 1.0, 1.0]);
    for i in 0..2 {
        near!(values[edge * 2 + i], 0.25, 0.02, "edge {i}");
        near!(values[corner * 2 + i], 0.125, 0.02, "corner {i}");
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
                near!(values[v * k + i], want, 0.01, "{name} v {v} r {}", radii[i]);
            }
        }
        // Default 64 rays: the mean within 0.01 (per vertex the quadrature error is ≤ ~1/64).
        let (radii, values) = solid(&s, rel, 64);
        for i in 0..k {
            let want = sphere_fraction(radii[i], rho);
            let col: Vec<f32> = values.iter().skip(i).step_by(k).copied().collect();
            let mean = col.iter().sum::<f32>() / col.len() as f32;
            near!(mean, want, 0.01, "{name} mean at r {}", radii[i]);
            let worst = col.iter().map(|x| (x - want).abs()).fold(0.0f32, f32::max);
            near!(worst, 0.0, 0.025, "{name} worst at r {}", radii[i]);
        }
    }
}

#[test]
fn convex_shapes_see_their_full_hemisphere() {
    let rays = 256;
    let params = OcclusionParams {
        rays,
        ..Default::default()
    };
    // Sphere: band 0 is the full hemisphere (the polyhedron's vertices see slightly more), and
    // band 1 is √(3/4π)·π·n. At a vertex of this icosphere the faces dip below the tangent plane by about half the
    // edge's central angle (0.033 rad), which bounds the extra visibility.
    let s = icosphere(4, 1.0);
    let occ = directional_occlusion(&s, None, &params, &Control::new()).unwrap();
    let normals = s.vertex_normals();
    for v in 0..s.vertex_count() {
        let vis = occ.visibility(v);
        assert!((1.0 - 1e-5..=1.05).contains(&vis), "v {v}: {vis}");
        let b = occ.band1_vector(v);
        let want = (3.0 / (4.0 * PI)).sqrt() as f32 * std::f32::consts::PI;
        near!(len(b), want, 0.03 * want, "v {v}: |b1|");
        let n = normals[v];
        let cos = (b[0] * n[0] + b[1] * n[1] + b[2] * n[2]) / len(b);
        assert!(cos > 0.999, "v {v}: cos {cos}");
    }
    // Flat face of a box: exactly half of the rays, with the default count.
    let b = lattice_box(8, |_, _| true, false);
    let occ =
        directional_occlusion(&b, None, &OcclusionParams::default(), &Control::new()).unwrap();
    let top = vertex_near(&b, [0.0, 0.0, 1.0]);
    assert!((occ.coefficients[top][0] - std::f32::consts::PI.sqrt()).abs() < 1e-5);
}

#[test]
fn the_bottom_of_a_cup_is_more_occluded() {
    let cup = lattice_box(8, |axis, side| axis != 2 || side == 0, true);
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
    let want = (4.0 * (4.0f64 / 20.0).asin() / (2.0 * PI)) as f32;
    near!(
        occ.visibility(bottom),
        want,
        0.03 * want,
        "cup bottom visibility"
    );
    let b1 = occ.band1_vector(bottom);
    assert!(
        b1[2] > 0.0 && b1[0].abs() < 0.05 * b1[2] && b1[1].abs() < 0.05 * b1[2],
        "{b1:?}"
    );
}

/// The paper's estimator over the default cone when a ray at angle θ has length `len(θ)`,
/// written out independently: median ± 1 std filter, 1/θ weights.
fn expected_sdf(len: impl Fn(f64) -> f64) -> f64 {
    let cone = sdf_cone(&SdfParams::default());
    let lengths: Vec<(f64, f64)> = cone.iter().map(|c| (len(c.1 as f64), c.1 as f64)).collect();
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
    let predicted = expected_sdf(|th| 2.0 * rho * th.cos());
    near!(predicted, 1.535 * rho, 1e-3, "prediction");
    let sdf = shape_diameter(&s, None, &SdfParams::default(), &Control::new()).unwrap();
    for (v, &x) in sdf.iter().enumerate() {
        near!(x as f64, predicted, 0.01 * predicted, "v {v}");
    }
    // A narrow cone (10°) removes the bias: within 1% of 2ρ.
    let narrow = SdfParams {
        cone_angle: 10.0,
        ..Default::default()
    };
    let sdf = shape_diameter(&s, None, &narrow, &Control::new()).unwrap();
    for (v, &x) in sdf.iter().enumerate() {
        near!(x as f64, 2.0 * rho, 0.02 * rho, "v {v}");
    }
}

#[test]
fn sdf_measures_the_thickness_of_a_slab() {
    // A flat box 4 × 4 × 0.5: at the centre of a big face every ray of the cone reaches the
    // opposite face, at 0.5 / cos θ; the value is the paper's estimator over those (1%).
    let mut s = lattice_box(16, |_, _| true, false);
    for p in &mut s.positions {
        p[0] *= 2.0;
        p[1] *= 2.0;
        p[2] *= 0.25;
    }
    let v = vertex_near(&s, [0.0, 0.0, 0.25]);
    let sdf = shape_diameter(&s, None, &SdfParams::default(), &Control::new()).unwrap();
    let predicted = expected_sdf(|th| 0.5 / th.cos());
    assert!(predicted > 0.5 && predicted < 0.7, "{predicted}");
    near!(sdf[v] as f64, predicted, 0.01 * predicted, "slab centre");
}

#[test]
fn features_are_identical_for_one_and_two_threads() {
    let s = uv_sphere(24, 48, bumpy(0.2, 4.0, 3.0));
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

/// Peak resident memory (VmHWM, MiB) and process CPU seconds (user + system: fields 14 and 15
/// of /proc/self/stat, 100 ticks/s). The machine is shared, so wall time overstates the cost.
fn usage() -> (u64, f64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let hwm = status.lines().find_map(|l| l.strip_prefix("VmHWM:"));
    let hwm: u64 = hwm
        .and_then(|x| x.split_whitespace().next()?.parse().ok())
        .unwrap_or(0);
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .skip(11)
        .take(2);
    (
        hwm / 1024,
        f.filter_map(|x| x.parse::<f64>().ok()).sum::<f64>() / 100.0,
    )
}

/// `cargo test --release --no-default-features --test engine ray_features::bench_ -- --ignored --nocapture`
#[test]
#[ignore = "benchmark: run with --release"]
fn bench_solid_angle_4_radii_and_occlusion_64_rays_on_64k_vertices() {
    // A bumpy sphere (concave and convex regions) with 65 516 vertices.
    let s = uv_sphere(180, 366, |th, ph| {
        1.0 + 0.15 * (5.0 * th).sin() * (4.0 * ph).cos()
            + 0.04 * (17.0 * th).sin() * (13.0 * ph).sin()
    });
    let threads = rayon::current_num_threads();
    println!("mesh: {} vertices, {threads} threads", s.vertex_count());
    let (c, mut totals) = (Control::new(), Vec::new());
    let secs = |t: std::time::Instant| t.elapsed().as_secs_f64();
    for run in 0..5 {
        let (t, c0) = (std::time::Instant::now(), usage().1);
        let ctx = RayContext::new(&s, None).unwrap();
        let (t_ctx, t) = (secs(t), std::time::Instant::now());
        solid_angle_curvature_with(&ctx, &SolidAngleParams::default(), &c).unwrap();
        let (t_sa, t) = (secs(t), std::time::Instant::now());
        directional_occlusion_with(&ctx, &OcclusionParams::default(), &c).unwrap();
        let (t_occ, t, cpu_total) = (secs(t), std::time::Instant::now(), usage().1 - c0);
        shape_diameter_with(&ctx, &SdfParams::default(), &c).unwrap();
        let (t_sdf, total) = (secs(t), t_ctx + t_sa + t_occ);
        totals.push(total);
        println!(
            "run {run}: context {t_ctx:.3} s, solid angle (4 radii, 64 rays) {t_sa:.3} s, \
             occlusion (64 rays) {t_occ:.3} s, total {total:.3} s wall, {cpu_total:.2} s cpu; \
             sdf (30 rays) {t_sdf:.3} s"
        );
    }
    totals.sort_by(f64::total_cmp);
    println!(
        "median total {:.3} s wall; VmHWM {} MiB",
        totals[2],
        usage().0
    );
}
