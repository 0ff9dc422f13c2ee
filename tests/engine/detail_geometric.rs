//! The `detail` method's 60-D geometric features (Berkiten et al. 2017, §3.2.2): each group on
//! meshes with known answers (sphere, cylinder), HKS / WKS invariant to scale under the shared
//! unit-area scaling, and agreement between two independent tessellations of one shape.

use retex::engine::control::Control;
use retex::engine::mesh::primitives::{capsule, cylinder, icosphere, uv_sphere};
use retex::engine::mesh::Surface;
use retex::engine::methods::detail::geometric_features::{
    geometric_features, geometric_features_pair, GeometricError, GeometricParams, DIM, GROUPS,
};
use retex::engine::methods::detail::metric::ZScore;

fn col(f: &[f64], j: usize) -> Vec<f64> {
    f.iter().skip(j).step_by(DIM).copied().collect()
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

fn max_abs_dev(x: &[f64], want: f64) -> f64 {
    x.iter().fold(0.0f64, |m, a| m.max((a - want).abs()))
}

#[test]
fn sphere_groups_match_their_analytic_values() {
    let r = 2.0;
    let s = icosphere(r, 24);
    let g = geometric_features(&s, &GeometricParams::default(), &Control::new()).unwrap();
    let v = &g.values;
    // Curvature: k1 = k2 = H = 1/r, K = 1/r², norm √2/r.
    for (j, want) in [(0, 1.0 / r), (1, 1.0 / r), (2, 1.0 / r), (3, 1.0 / (r * r))] {
        let dev = max_abs_dev(&col(v, j), want) / want;
        println!("sphere curvature column {j}: max relative error {dev:.2e}");
        assert!(dev < 0.02, "column {j}: {dev}");
    }
    assert!(max_abs_dev(&col(v, 4), 2f64.sqrt() / r) / (2f64.sqrt() / r) < 0.02);
    // Height and box coordinates exact.
    let (lo, hi) = s.bounding_box();
    for (i, p) in s.positions.iter().enumerate() {
        assert_eq!(v[i * DIM + 5], p[1] as f64);
        for k in 0..3 {
            let want = (p[k] as f64 - 0.5 * (hi[k] + lo[k]) as f64) / (hi[k] - lo[k]) as f64;
            assert!((v[i * DIM + 17 + k] - want).abs() < 1e-12);
        }
        // Smoothed normals stay radial on a sphere.
        let n = [v[i * DIM + 6], v[i * DIM + 7], v[i * DIM + 8]];
        let d = (n[0] * p[0] as f64 + n[1] * p[1] as f64 + n[2] * p[2] as f64) / r;
        assert!(d > 0.999, "normal of vertex {i}: cos {d}");
    }
    // SDF: constant 1.535 r (the cone-averaged diameter, see geometry::sdf).
    let sdf = col(v, 9);
    println!(
        "sphere SDF mean {:.4} r, max deviation {:.3} r",
        mean(&sdf) / r,
        max_abs_dev(&sdf, mean(&sdf)) / r
    );
    assert!((mean(&sdf) / r - 1.535).abs() < 0.03);
    // One thickness: one segment, so the distance to segment boundaries is 0.
    assert!(
        g.segments.iter().all(|&x| x == 0),
        "sphere cut into segments"
    );
    assert!(col(v, 10).iter().all(|&x| x == 0.0));
    // Geodesic statistics of uniform points on a sphere (θ with density sin θ / 2), ÷ √(4π r²):
    // mean π/2, median π/2, max π, std √(π²/4 − 2), 10th / 90th percentile acos(±0.8).
    let unit = (4.0 * std::f64::consts::PI).sqrt();
    let pi = std::f64::consts::PI;
    let want = [
        pi / 2.0,
        pi / 2.0,
        pi,
        (pi * pi / 4.0 - 2.0).sqrt(),
        0.8f64.acos(),
        (-0.8f64).acos(),
    ];
    for (k, w) in want.iter().enumerate() {
        let got = col(v, 11 + k);
        let err = (mean(&got) - w / unit).abs() / (w / unit);
        let worst = max_abs_dev(&got, w / unit) / (w / unit);
        println!(
            "sphere geodesic stat {k}: want {:.4}, mean {:.4} (rel {err:.3}), worst rel {worst:.3}",
            w / unit,
            mean(&got)
        );
        // The max is low by the distance from the antipode to its nearest of the 128 sources
        // (~0.18 r) plus the heat method's rounding at the cut point.
        let (e, w) = if k == 2 { (0.06, 0.10) } else { (0.03, 0.2) };
        assert!(
            err < e && worst < w,
            "stat {k}: mean rel {err}, worst {worst}"
        );
    }
    // HKS / WKS constant over a round sphere up to its tessellation.
    for j in [20, 30, 39, 40, 50, 59] {
        let c = col(v, j);
        let rel = max_abs_dev(&c, mean(&c)) / mean(&c).abs();
        assert!(rel < 0.05, "spectral column {j} varies by {rel}");
    }
}

#[test]
fn cylinder_curvature_is_one_over_r_and_zero() {
    let r = 0.5;
    let s = cylinder(r, 4.0, 64, 80);
    let g = geometric_features(&s, &GeometricParams::default(), &Control::new()).unwrap();
    // Away from the open rims (one-sided estimates there).
    let inner: Vec<usize> = (0..s.vertex_count())
        .filter(|&i| (0.5..3.5).contains(&s.positions[i][2]))
        .collect();
    let pick = |j: usize| {
        inner
            .iter()
            .map(|&i| g.values[i * DIM + j])
            .collect::<Vec<_>>()
    };
    let k1 = max_abs_dev(&pick(0), 1.0 / r) * r;
    let k2 = max_abs_dev(&pick(1), 0.0) * r;
    let h = max_abs_dev(&pick(2), 0.5 / r) * r;
    let k = max_abs_dev(&pick(3), 0.0) * r * r;
    println!("cylinder: k1 {k1:.2e}, k2 {k2:.2e}, H {h:.2e}, K {k:.2e} (relative to 1/r)");
    assert!(k1 < 0.01 && k2 < 0.01 && h < 0.01 && k < 0.01);
    // Normal z stays 0 on the side, height = y.
    assert!(max_abs_dev(&pick(8), 0.0) < 0.01);
}

/// An ellipsoid with a smooth bump, as a map of the unit sphere.
fn deform(u: [f64; 3], twist: f64) -> [f64; 3] {
    let h = 1.0
        + 0.25 * (-((u[0] - 0.6).powi(2) + (u[1] - 0.5).powi(2)) * 6.0).exp()
        + twist * (2.0 * u[2]).sin();
    [1.6 * u[0] * h, u[1] * h, 0.7 * u[2] * h]
}

fn shape(mut s: Surface, twist: f64) -> (Surface, Vec<[f64; 3]>) {
    let mut units = Vec::new();
    for p in &mut s.positions {
        let q = p.map(|x| x as f64);
        let l = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
        let u = q.map(|x| x / l);
        units.push(u);
        *p = deform(u, twist).map(|x| x as f32);
    }
    (s, units)
}

#[test]
fn hks_and_wks_agree_on_a_3x_scaled_copy() {
    let (a, _) = shape(icosphere(1.0, 14), 0.1);
    let mut b = a.clone();
    for p in &mut b.positions {
        *p = p.map(|x| 3.0 * x);
    }
    let (fa, fb) =
        geometric_features_pair(&a, &b, &GeometricParams::default(), &Control::new()).unwrap();
    assert_eq!(fa.hks_times, fb.hks_times);
    let mut worst = 0.0f64;
    for j in 20..60 {
        let (ca, cb) = (col(&fa.values, j), col(&fb.values, j));
        let spread = ca.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
            - ca.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(spread > 1e-6 * mean(&ca).abs(), "column {j} is constant");
        let dev = ca
            .iter()
            .zip(&cb)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        worst = worst.max(dev / spread);
    }
    println!("HKS/WKS of a shape and its 3x copy: max difference {worst:.2e} of the column range");
    assert!(worst < 1e-4);
    // Scale-invariant groups too (geodesic statistics ÷ √area, box), and curvature scales 1/3.
    for j in (11..20).chain([0]) {
        let f = if j == 0 { 3.0 } else { 1.0 };
        let (ca, cb) = (col(&fa.values, j), col(&fb.values, j));
        let dev = ca
            .iter()
            .zip(&cb)
            .fold(0.0f64, |m, (x, y)| m.max((x - f * y).abs()));
        assert!(
            dev < 1e-3 * ca.iter().fold(0.0f64, |m, x| m.max(x.abs())),
            "column {j}: {dev}"
        );
    }
}

fn pearson(a: &[f64], b: &[f64]) -> Option<f64> {
    let (ma, mb) = (mean(a), mean(b));
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    (saa > 1e-20 && sbb > 1e-20).then(|| sab / (saa * sbb).sqrt())
}

#[test]
fn a_retessellated_copy_gives_correlated_features() {
    for twist in [0.0, 0.1] {
        let (a, ua) = shape(icosphere(1.0, 20), twist);
        let (b, ub) = shape(uv_sphere(1.0, 60, 120), twist);
        let (fa, fb) =
            geometric_features_pair(&a, &b, &GeometricParams::default(), &Control::new()).unwrap();
        // Correspondence: the icosphere vertex nearest on the unit sphere.
        let map: Vec<usize> = (ub.iter())
            .map(|u| {
                (0..ua.len())
                    .min_by(|&i, &j| {
                        let d = |k: usize| (0..3).map(|c| (ua[k][c] - u[c]).powi(2)).sum::<f64>();
                        d(i).total_cmp(&d(j))
                    })
                    .unwrap()
            })
            .collect();
        for (name, range) in GROUPS.iter() {
            let mut cors = Vec::new();
            for j in range.clone() {
                let cb = col(&fb.values, j);
                let ca: Vec<f64> = map.iter().map(|&i| fa.values[i * DIM + j]).collect();
                // A column nearly constant over the shape (relative spread below 2 %) is
                // compared by its relative difference instead: its correlation is noise.
                let m = mean(&ca).abs().max(1e-12);
                let sd = (ca.iter().map(|x| (x - mean(&ca)).powi(2)).sum::<f64>()
                    / ca.len() as f64)
                    .sqrt();
                let diff = (ca
                    .iter()
                    .zip(&cb)
                    .map(|(x, y)| (x - y).powi(2))
                    .sum::<f64>()
                    / ca.len() as f64)
                    .sqrt()
                    / m;
                let c = pearson(&ca, &cb);
                println!("  column {j}: correlation {c:?}, relative spread {:.3}, relative rms difference {diff:.3}", sd / m);
                assert!(
                    diff < 0.1 || sd / m > 0.2,
                    "column {j}: relative difference {diff}"
                );
                if sd / m < 0.02 {
                    assert!(diff < 0.03, "column {j}: near-constant, differs by {diff}");
                } else if let Some(c) = c {
                    cors.push((j, c));
                }
            }
            if *name == "geo" {
                // The 10th percentile (column 15) varies by only ~5 % over this shape, less
                // than its estimate's noise from 128 sources: its correlation is not asserted
                // (see the README); the other five statistics are.
                cors.retain(|c| c.0 != 15);
            }
            let cors: Vec<f64> = cors.into_iter().map(|c| c.1).collect();
            let min = cors.iter().cloned().fold(f64::INFINITY, f64::min);
            println!(
                "twist {twist}: {name}: {} columns, min correlation {min:.3}, mean {:.3}",
                cors.len(),
                mean(&cors)
            );
            let bound = match *name {
                // The k-means stand-in for SSCO08's GMM + graph cut moves its boundaries
                // between tessellations (measured 0.79 and 0.32 on the two shapes).
                "seg" => 0.2,
                "sdf" => 0.8,
                _ => 0.9,
            };
            assert!(cors.is_empty() || min > bound, "{name}: {min}");
        }
    }
}

/// The z-scoring's constant-column floor (`metric::RELATIVE_STD_FLOOR`) against measured
/// noise: on round spheres every HKS and WKS column is constant in theory, so z-scoring must
/// treat them as constant (measured std ÷ |mean|: HKS ≤ 7e-4, WKS 2e-3-7.5e-3; a floor of 1e-3
/// kept the WKS noise, which this test fails on); on a capsule, whose spectrum varies along its
/// axis, the WKS and the HKS's finer times must stay (measured ≥ 0.2 and ≥ 1e-2).
#[test]
fn the_z_score_floor_drops_a_spheres_spectral_noise_and_keeps_a_capsules_spectrum() {
    let group = |name: &str| GROUPS.iter().find(|g| g.0 == name).unwrap().1.clone();
    let (hks, wks) = (group("hks"), group("wks"));
    let params = GeometricParams::default();
    let inv_std = |s: &Surface| {
        let g = geometric_features(s, &params, &Control::new()).unwrap();
        ZScore::fit(&g.values, DIM).inv_std
    };
    for (name, sphere) in [
        ("icosphere 16", icosphere(1.0, 16)),
        ("uv sphere 60 × 120", uv_sphere(1.0, 60, 120)),
    ] {
        let w = inv_std(&sphere);
        let kept: Vec<usize> = (hks.start..wks.end).filter(|&j| w[j] > 0.0).collect();
        println!("{name}: spectral columns kept {kept:?}");
        assert!(kept.is_empty(), "{name}: noise columns kept {kept:?}");
    }
    let profile: Vec<f32> = (0..=60).map(|i| -1.5 + 0.05 * i as f32).collect();
    let w = inv_std(&capsule(0.5, &profile, 48, |x| x));
    // The HKS's three largest times are left out (heat has spread over the whole shape there).
    let finer_hks = hks.start..hks.end - 3;
    let kept = |range: std::ops::Range<usize>| range.filter(|&j| w[j] > 0.0).count();
    let (h, k) = (kept(finer_hks.clone()), kept(wks.clone()));
    println!(
        "capsule: HKS columns {finer_hks:?} kept {h} of {}, WKS kept {k} of {}",
        finer_hks.len(),
        wks.len()
    );
    assert_eq!(k, wks.len(), "capsule WKS columns dropped");
    assert_eq!(h, finer_hks.len(), "capsule HKS columns dropped");
}

#[test]
fn bad_input_is_an_error() {
    let empty = Surface::from_triangles(vec![], vec![]);
    assert!(matches!(
        geometric_features(&empty, &GeometricParams::default(), &Control::new()),
        Err(GeometricError::Empty)
    ));
    let s = icosphere(1.0, 4);
    let bad = GeometricParams {
        geodesic_sources: 0,
        ..GeometricParams::default()
    };
    assert!(matches!(
        geometric_features(&s, &bad, &Control::new()),
        Err(GeometricError::Param(_))
    ));
}

#[test]
fn a_vertex_used_only_by_a_zero_area_face_does_not_break_the_features() {
    // Isotropic remeshing can leave such a vertex (found on a coarse level of Nefertiti with
    // `feature_vertices` 5,000): it has no mass and an empty Laplacian row, so the smoothed
    // normals' `M − tL` had a zero pivot ("matrix is not positive definite").
    let mut s = icosphere(1.0, 8);
    let [a, b, _] = s.faces[0];
    let (pa, pb) = (s.positions[a as usize], s.positions[b as usize]);
    s.positions.push([0, 1, 2].map(|k| 0.5 * (pa[k] + pb[k])));
    let v = (s.positions.len() - 1) as u32;
    s.faces.push([a, b, v]);
    let g = geometric_features(&s, &GeometricParams::default(), &Control::new()).unwrap();
    assert!(g.values.iter().all(|x| x.is_finite()));
    // The other vertices keep their sphere values (outward smoothed normals).
    let n = s.positions.len() - 1;
    let outward = (0..n)
        .filter(|&i| {
            let p = s.positions[i];
            let dot: f64 = (0..3)
                .map(|k| g.values[i * DIM + 6 + k] * p[k] as f64)
                .sum();
            dot > 0.99
        })
        .count();
    assert_eq!(outward, n);
}

/// Timing of both feature sets on a 20k-vertex shape:
/// `cargo test --release --test engine detail_geometric::bench_ -- --ignored --nocapture`.
#[test]
#[ignore = "benchmark"]
fn bench_features_on_20k_vertices() {
    use retex::engine::methods::detail::patches::{detail_features, PatchParams};
    let (s, units) = shape(icosphere(1.0, 45), 0.1);
    let field: Vec<f64> = units
        .iter()
        .map(|u| 0.01 * (20.0 * u[0]).sin() * (20.0 * u[1]).sin())
        .collect();
    println!("{} vertices, {} faces", s.vertex_count(), s.face_count());
    let control = Control::new();
    let g = geometric_features(&s, &GeometricParams::default(), &control).unwrap();
    let d = detail_features(&s, &field, &PatchParams::default(), &control).unwrap();
    assert_eq!(g.values.len(), s.vertex_count() * DIM);
    assert_eq!(d.len(), s.vertex_count() * 17);
    control.stage("done", 0).unwrap();
    for t in control.timings() {
        println!("{:>60}: {:8.1} ms", t.stage, t.ms);
    }
}
