//! Analytic and invariant tests of the geometry core: cotan Laplacian and mass, sparse Cholesky
//! with reused symbolic analysis, heat-method geodesics, bounded walks, curvature.

use crate::common_geometry;

use crate::common_geometry::{great_circle, jittered_sphere, mean_relative_error, random_vec};

use std::collections::BTreeMap;

use retex::engine::control::Control;
use retex::engine::geometry::curvature::{principal_curvatures, CurvatureParams};
use retex::engine::geometry::heat::{HeatBoundary, HeatGeodesics, HeatParams, Source};
use retex::engine::geometry::laplacian::{
    cotan_laplacian, mass_matrix, GeometryError, LaplacianParams, MassKind,
};
use retex::engine::geometry::walk::{WalkGraph, WalkMetric, WalkParams, Walker};
use retex::engine::linalg::{LinalgError, SparsityPattern, SymbolicCholesky, SymmetricMatrix};
use retex::engine::mesh::primitives::{cylinder, grid, icosphere, jitter, uv_sphere};
use retex::engine::mesh::{topology, Surface};

fn test_meshes() -> Vec<(&'static str, Surface)> {
    let mut planar = grid(20, 15, 0.1);
    jitter(&mut planar, 0.03, [true, true, false], 3);
    vec![
        ("icosphere", icosphere(1.0, 12)),
        ("jittered sphere", jittered_sphere(2.0, 12, 0.04)),
        ("uv sphere (obtuse at poles)", uv_sphere(1.0, 30, 12)),
        ("jittered grid", planar),
        ("cylinder", cylinder(0.5, 2.0, 24, 10)),
    ]
}

#[test]
fn laplacian_constant_kernel_symmetry_and_semidefinite() {
    for (name, s) in test_meshes() {
        let lap = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
        let l = &lap.stiffness;
        let scale = l.diagonal().iter().fold(0.0f64, |a, b| a.max(b.abs()));
        let ones = vec![1.0; s.vertex_count()];
        let l1 = l.mul_vec(&ones);
        let worst = l1.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        assert!(worst <= 1e-12 * scale, "{name}: |L·1| = {worst}");
        assert!(l.asymmetry() <= 1e-15 * scale, "{name}: asymmetric");
        assert!(
            l.diagonal().iter().all(|&d| d <= 0.0),
            "{name}: positive diagonal"
        );
        for seed in 0..5 {
            let f = random_vec(s.vertex_count(), seed);
            let q = l.quadratic_form(&f);
            assert!(q <= 1e-12 * scale, "{name}: fᵀLf = {q} > 0");
        }
    }
}

#[test]
fn laplacian_of_linear_function_vanishes_inside_a_planar_grid() {
    for (seed, amount) in [(1u64, 0.0), (2, 0.02), (3, 0.035)] {
        let mut s = grid(24, 18, 0.1);
        jitter(&mut s, amount, [true, true, false], seed);
        let lap = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
        let f: Vec<f64> = s
            .positions
            .iter()
            .map(|p| 0.7 * p[0] as f64 - 1.3 * p[1] as f64 + 0.25)
            .collect();
        let lf = lap.stiffness.mul_vec(&f);
        let topo = topology(&s);
        let mut boundary = vec![false; s.vertex_count()];
        for v in topo.boundary_loops.iter().flatten() {
            boundary[*v as usize] = true;
        }
        let mut interior = 0;
        for (v, val) in lf.iter().enumerate() {
            if !boundary[v] {
                interior += 1;
                assert!(val.abs() < 1e-9, "jitter {amount}: (L f)_{v} = {val}");
            }
        }
        assert_eq!(interior, 23 * 17);
    }
}

#[test]
fn mass_sums_to_area_for_both_kinds() {
    for (name, s) in test_meshes() {
        let area = s.area();
        for kind in [MassKind::Barycentric, MassKind::MixedVoronoi] {
            let m = mass_matrix(&s, kind).unwrap();
            let total: f64 = m.iter().sum();
            assert!(
                ((total - area) / area).abs() < 1e-9,
                "{name} {kind:?}: {total} vs {area}"
            );
            assert!(m.iter().all(|&x| x > 0.0), "{name} {kind:?}: zero mass");
        }
        let lap = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
        let total: f64 = lap.mass.iter().sum();
        assert!(((total - area) / area).abs() < 1e-9);
    }
}

#[test]
fn a_needle_with_a_bounded_cotangent_keeps_the_laplacian_semidefinite() {
    // Angles about 1e-6 (its cotangent beyond the bound), 0.1 and π − 0.1: clamping the first
    // cotangent alone made the element matrix indefinite.
    let (a, b) = (1e-6f64, 0.1f64);
    let c = std::f64::consts::PI - a - b;
    // Side lengths by the law of sines; corner 0 at the origin, corner 1 on the x axis.
    let (lb, lc) = (b.sin(), c.sin());
    let positions = vec![
        [0.0, 0.0, 0.0],
        [lc as f32, 0.0, 0.0],
        [(lb * a.cos()) as f32, (lb * a.sin()) as f32, 0.0],
    ];
    let s = Surface::from_triangles(positions, vec![[0, 1, 2]]);
    for max_cotangent in [1e3, 1e5] {
        let lap = cotan_laplacian(
            &s,
            &LaplacianParams {
                max_cotangent,
                ..Default::default()
            },
        )
        .unwrap();
        let l = |i: usize, j: usize| lap.stiffness.get(i, j);
        // −L is PSD iff every principal minor of the 3 × 3 is ≥ 0; its kernel holds constants,
        // so the 2 × 2 minor of rows 1, 2 decides.
        let minor = l(1, 1) * l(2, 2) - l(1, 2) * l(2, 1);
        let scale = l(1, 1).abs().max(l(2, 2).abs()).powi(2);
        assert!(
            minor >= -1e-9 * scale,
            "max_cotangent {max_cotangent}: minor {minor:e}"
        );
        assert!(lap
            .stiffness
            .values()
            .iter()
            .all(|v| v.abs() <= 2.0 * max_cotangent));
    }
}

#[test]
fn laplacian_is_finite_on_degenerate_and_sliver_triangles() {
    // A fan with a zero-area face (collinear), a needle sliver, and an obtuse triangle.
    let positions = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, 1e-7, 0.0],
        [5.0, 0.3, 0.0],
    ];
    let faces = vec![[0, 1, 3], [0, 1, 2], [1, 2, 3], [0, 4, 1], [2, 5, 3]];
    let s = Surface::from_triangles(positions, faces);
    let params = LaplacianParams {
        max_cotangent: 1e3,
        ..Default::default()
    };
    let lap = cotan_laplacian(&s, &params).unwrap();
    assert!(lap.stiffness.values().iter().all(|v| v.is_finite()));
    assert!(lap
        .stiffness
        .values()
        .iter()
        .all(|v| v.abs() <= 2.0 * 1e3 + 10.0));
    let l1 = lap.stiffness.mul_vec(&[1.0; 6]);
    assert!(l1.iter().all(|v| v.abs() < 1e-9), "{l1:?}");
    // The collinear face 0-1-2 adds no mass.
    let m = mass_matrix(&s, MassKind::MixedVoronoi).unwrap();
    let total: f64 = m.iter().sum();
    assert!((total - s.area()).abs() < 1e-9 * s.area().max(1.0));
    let bad = LaplacianParams {
        max_cotangent: 0.5,
        ..Default::default()
    };
    assert!(matches!(
        cotan_laplacian(&s, &bad),
        Err(GeometryError::InvalidParam { .. })
    ));
    let empty = Surface::from_triangles(vec![], vec![]);
    assert!(matches!(
        cotan_laplacian(&empty, &LaplacianParams::default()),
        Err(GeometryError::EmptySurface)
    ));
}

#[test]
fn cholesky_solves_and_reuses_the_symbolic_analysis() {
    let s = jittered_sphere(1.0, 20, 0.02);
    let lap = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
    let n = s.vertex_count();
    let symbolic = SymbolicCholesky::new(lap.pattern().clone()).unwrap();
    let a1 = lap.stiffness.scaled_plus_diagonal(-1.0, 10.0, &lap.mass);
    let a2 = lap.stiffness.scaled_plus_diagonal(-0.01, 1.0, &lap.mass);
    let f1 = symbolic.factor(&a1).unwrap();
    let f2 = symbolic.factor(&a2).unwrap();
    assert!(f1.symbolic().same_analysis(&symbolic));
    assert!(f2.symbolic().same_analysis(f1.symbolic()));
    let other = SymbolicCholesky::new(lap.pattern().clone()).unwrap();
    assert!(!other.same_analysis(&symbolic));
    for (a, f) in [(&a1, &f1), (&a2, &f2)] {
        let x_true = random_vec(n, 11);
        let b = a.mul_vec(&x_true);
        let x = f.solve(&b).unwrap();
        let r = a.mul_vec(&x);
        let res = r
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - q).powi(2))
            .sum::<f64>()
            .sqrt();
        let bn = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(res / bn < 1e-10, "relative residual {}", res / bn);
        let mut many: Vec<Vec<f64>> = (0..6).map(|k| a.mul_vec(&random_vec(n, k))).collect();
        let singles: Vec<Vec<f64>> = many.iter().map(|b| f.solve(b).unwrap()).collect();
        f.solve_many(&mut many).unwrap();
        assert_eq!(many, singles, "parallel solves differ from sequential ones");
        let mut block: Vec<Vec<f64>> = (0..6).map(|k| a.mul_vec(&random_vec(n, k))).collect();
        f.solve_block(&mut block).unwrap();
        let worst = block
            .iter()
            .flatten()
            .zip(singles.iter().flatten())
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max);
        let scale = singles.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(
            worst <= 1e-12 * scale,
            "block solve differs by {worst} (scale {scale})"
        );
    }
    // A pattern from unsorted, one-sided columns is symmetrized and gets its diagonal.
    let p =
        std::sync::Arc::new(SparsityPattern::from_columns(&[vec![2], vec![], vec![1]]).unwrap());
    assert_eq!(
        (p.nnz(), p.column(0), p.column(2)),
        (7, &[0, 2][..], &[0, 1, 2][..])
    );
    let tiny = SymmetricMatrix::new(p.clone(), vec![4.0, 1.0, 3.0, 0.5, 1.0, 0.5, 5.0]).unwrap();
    let x = SymbolicCholesky::new(p)
        .unwrap()
        .factor(&tiny)
        .unwrap()
        .solve(&[1.0, 2.0, 3.0])
        .unwrap();
    let r = tiny.mul_vec(&x);
    assert!(
        (r[0] - 1.0).abs() + (r[1] - 2.0).abs() + (r[2] - 3.0).abs() < 1e-12,
        "{r:?}"
    );
    // L itself is only semi-definite (and negative): the factorization must refuse it.
    assert!(matches!(
        symbolic.factor(&lap.stiffness),
        Err(LinalgError::NotPositiveDefinite { .. })
    ));
    assert!(matches!(
        f1.solve(&[1.0; 3]),
        Err(LinalgError::RhsLength { .. })
    ));
    let small = cotan_laplacian(&icosphere(1.0, 3), &LaplacianParams::default()).unwrap();
    assert!(matches!(
        symbolic.factor(&small.stiffness),
        Err(LinalgError::InvalidPattern(_))
    ));
}

#[test]
fn heat_distance_on_a_unit_sphere_matches_great_circles() {
    let s = icosphere(1.0, 32);
    assert_eq!(s.vertex_count(), 10_242);
    let heat = HeatGeodesics::new(&s, &HeatParams::default(), &Control::new()).unwrap();
    let p0 = s.positions[0];
    let d = heat.distance(&[Source::Vertex(0)]).unwrap();
    let want: Vec<f64> = s
        .positions
        .iter()
        .map(|&q| great_circle(p0, q, 1.0))
        .collect();
    let err = mean_relative_error(&d, &want, 0.0);
    eprintln!("sphere vertex source: mean relative error {err:.4}");
    assert!(err < 0.02, "mean relative error {err}");
    assert_eq!(d[0], 0.0);

    // A point inside a face, and two sources at once (distance to the nearer one).
    let face = 1234usize;
    let bary = [0.2, 0.5, 0.3];
    let src = s.face_point(face, bary.map(|b| b as f32));
    let len = src.iter().map(|c| (*c as f64).powi(2)).sum::<f64>().sqrt();
    let src = src.map(|c| (c as f64 / len) as f32);
    let p1 = s.positions[5000];
    let queries = vec![
        vec![Source::Point {
            face: face as u32,
            bary,
        }],
        vec![Source::Vertex(0), Source::Vertex(5000)],
    ];
    let out = heat.distance_many(&queries, &Control::new()).unwrap();
    let want_point: Vec<f64> = s
        .positions
        .iter()
        .map(|&q| great_circle(src, q, 1.0))
        .collect();
    let want_two: Vec<f64> = s
        .positions
        .iter()
        .map(|&q| great_circle(p0, q, 1.0).min(great_circle(p1, q, 1.0)))
        .collect();
    let e1 = mean_relative_error(&out[0], &want_point, 0.0);
    let e2 = mean_relative_error(&out[1], &want_two, 0.0);
    eprintln!("point source {e1:.4}, two sources {e2:.4}");
    assert!(e1 < 0.02 && e2 < 0.02, "{e1} {e2}");
    assert!(heat.distance(&[]).is_err());
    assert!(heat
        .distance(&[Source::Point {
            face: u32::MAX,
            bary
        }])
        .is_err());
    let cancelled = Control::new();
    cancelled.cancel();
    assert!(matches!(
        heat.distance_many(&queries, &cancelled),
        Err(GeometryError::Cancelled(_))
    ));
}

#[test]
fn heat_distance_on_a_plane_matches_euclidean() {
    let mut s = grid(80, 80, 1.0 / 80.0);
    jitter(&mut s, 0.003, [true, true, false], 5);
    let c = 40 * 81 + 40;
    let pc = s.positions[c];
    let euclid: Vec<f64> = s
        .positions
        .iter()
        .map(|p| ((p[0] - pc[0]) as f64).hypot((p[1] - pc[1]) as f64))
        .collect();
    for boundary in [HeatBoundary::Averaged, HeatBoundary::Neumann] {
        let params = HeatParams {
            boundary,
            ..Default::default()
        };
        let heat = HeatGeodesics::new(&s, &params, &Control::new()).unwrap();
        let d = heat.distance(&[Source::Vertex(c as u32)]).unwrap();
        let err = mean_relative_error(&d, &euclid, 0.0);
        eprintln!("plane {boundary:?}: mean relative error {err:.4}");
        let limit = if boundary == HeatBoundary::Averaged {
            0.02
        } else {
            0.05
        };
        assert!(err < limit, "{boundary:?}: {err}");
    }
}

#[test]
fn heat_distance_agrees_with_fast_marching_on_a_real_mesh() {
    let path = crate::common::test_data("src_spot_keenan/spot_triangulated.obj");
    let s = common_geometry::read_obj(&path);
    let heat = HeatGeodesics::new(&s, &HeatParams::default(), &Control::new()).unwrap();
    let d = heat.distance(&[Source::Vertex(0)]).unwrap();
    assert!(d.iter().all(|x| x.is_finite() && *x >= 0.0));
    let graph = WalkGraph::new(&s);
    let all = WalkParams {
        radius: 1e9,
        metric: WalkMetric::FastMarching,
    };
    let mut fmm = vec![f64::NAN; s.vertex_count()];
    for (v, x) in Walker::new(&graph).walk(0, &all).unwrap() {
        fmm[v as usize] = x;
    }
    assert!(fmm.iter().all(|x| x.is_finite()), "spot is connected");
    let err = mean_relative_error(&d, &fmm, 5.0 * heat.mean_edge());
    eprintln!("spot: heat vs fast marching mean relative difference {err:.4}");
    assert!(err < 0.03, "{err}");
}

/// Graph distance on `grid(n, n, 1)` (diagonals (i, j)–(i+1, j+1)) between lattice points.
fn grid_graph_distance(dx: i64, dy: i64) -> f64 {
    if dx.signum() * dy.signum() > 0 {
        let (a, b) = (dx.abs().min(dy.abs()), dx.abs().max(dy.abs()));
        a as f64 * 2f64.sqrt() + (b - a) as f64
    } else {
        (dx.abs() + dy.abs()) as f64
    }
}

#[test]
fn dijkstra_walk_returns_exactly_the_vertices_within_the_radius() {
    let n = 40usize;
    let s = grid(n, n, 1.0);
    let graph = WalkGraph::new(&s);
    let mut walker = Walker::new(&graph);
    for (ci, cj, r) in [(20i64, 20i64, 7.3), (3, 5, 6.1), (20, 20, 0.0)] {
        let params = WalkParams {
            radius: r,
            metric: WalkMetric::Edges,
        };
        let got: BTreeMap<u32, f64> = walker
            .walk((cj as usize * (n + 1) + ci as usize) as u32, &params)
            .unwrap()
            .into_iter()
            .collect();
        let mut want = BTreeMap::new();
        for j in 0..=n as i64 {
            for i in 0..=n as i64 {
                let d = grid_graph_distance(i - ci, j - cj);
                if d <= r {
                    want.insert((j as usize * (n + 1) + i as usize) as u32, d);
                }
            }
        }
        assert_eq!(
            got.keys().collect::<Vec<_>>(),
            want.keys().collect::<Vec<_>>()
        );
        for (v, d) in &got {
            assert!((d - want[v]).abs() < 1e-9, "vertex {v}: {d} vs {}", want[v]);
        }
    }
    assert!(walker.walk(u32::MAX, &WalkParams::default()).is_err());
}

#[test]
fn fast_marching_walk_is_close_to_euclidean_on_a_plane() {
    let mut s = grid(60, 60, 0.1);
    jitter(&mut s, 0.02, [true, true, false], 9);
    let graph = WalkGraph::new(&s);
    let mut walker = Walker::new(&graph);
    let c = 30 * 61 + 30;
    let pc = s.positions[c];
    let r = 2.5;
    let fmm = walker
        .walk(
            c as u32,
            &WalkParams {
                radius: r,
                metric: WalkMetric::FastMarching,
            },
        )
        .unwrap();
    let edges: BTreeMap<u32, f64> = walker
        .walk(
            c as u32,
            &WalkParams {
                radius: 10.0,
                metric: WalkMetric::Edges,
            },
        )
        .unwrap()
        .into_iter()
        .collect();
    let (mut fmm_err, mut edge_err, mut count) = (0.0, 0.0, 0usize);
    for &(v, d) in &fmm {
        let p = s.positions[v as usize];
        let e = ((p[0] - pc[0]) as f64).hypot((p[1] - pc[1]) as f64);
        assert!(
            d <= edges[&v] + 1e-12,
            "fast marching exceeds the edge metric"
        );
        assert!(
            d >= e - 1e-9,
            "shorter than the straight line at {v}: {d} < {e}"
        );
        if e > 0.0 {
            fmm_err += (d - e) / e;
            edge_err += (edges[&v] - e) / e;
            count += 1;
        }
    }
    let (fmm_err, edge_err) = (fmm_err / count as f64, edge_err / count as f64);
    eprintln!("walk mean relative error: fast marching {fmm_err:.4}, edges {edge_err:.4}");
    assert!(fmm_err < 0.01, "{fmm_err}");
    assert!(fmm_err < 0.5 * edge_err);
}

#[test]
fn curvature_of_spheres() {
    for (rho, s) in [
        (0.5, icosphere(0.5, 32)),
        (2.0, icosphere(2.0, 24)),
        (1.0, jittered_sphere(1.0, 24, 0.01)),
    ] {
        let c = principal_curvatures(&s, &CurvatureParams::default()).unwrap();
        let (mut worst_h, mut worst_k) = (0.0f64, 0.0f64);
        for v in 0..s.vertex_count() {
            worst_h = worst_h.max((c.mean[v] * rho - 1.0).abs());
            worst_k = worst_k.max((c.gaussian[v] * rho * rho - 1.0).abs());
            assert!(c.k_max[v] >= c.k_min[v]);
        }
        eprintln!("sphere ρ={rho}: worst relative H error {worst_h:.4}, K {worst_k:.4}");
        assert!(
            worst_h < 0.03 && worst_k < 0.03,
            "ρ={rho}: {worst_h} {worst_k}"
        );
    }
}

#[test]
fn curvature_of_an_ellipsoid_matches_the_analytic_values() {
    // x²/a² + y²/b² + z²/c² = 1: with h² = x²/a⁴ + y²/b⁴ + z²/c⁴,
    // K = 1 / (a²b²c² h⁴) and H = (a² + b² + c² − |x|²) / (2 a²b²c² h³).
    let (a, b, c) = (1.0f64, 0.7f64, 0.5f64);
    let mut s = icosphere(1.0, 40);
    for p in &mut s.positions {
        *p = [
            (p[0] as f64 * a) as f32,
            (p[1] as f64 * b) as f32,
            (p[2] as f64 * c) as f32,
        ];
    }
    let curv = principal_curvatures(&s, &CurvatureParams::default()).unwrap();
    let (mut sum_h, mut sum_k, mut worst_h, mut worst_k) = (0.0, 0.0, 0.0f64, 0.0f64);
    let abc2 = (a * b * c).powi(2);
    for (v, p) in s.positions.iter().enumerate() {
        let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
        let h = (x * x / a.powi(4) + y * y / b.powi(4) + z * z / c.powi(4)).sqrt();
        let k_true = 1.0 / (abc2 * h.powi(4));
        let h_true = (a * a + b * b + c * c - x * x - y * y - z * z) / (2.0 * abc2 * h.powi(3));
        let eh = (curv.mean[v] / h_true - 1.0).abs();
        let ek = (curv.gaussian[v] / k_true - 1.0).abs();
        sum_h += eh;
        sum_k += ek;
        worst_h = worst_h.max(eh);
        worst_k = worst_k.max(ek);
    }
    let n = s.vertex_count() as f64;
    eprintln!(
        "ellipsoid: H mean {:.4} worst {worst_h:.4}; K mean {:.4} worst {worst_k:.4}",
        sum_h / n,
        sum_k / n
    );
    assert!(
        sum_h / n < 0.01 && sum_k / n < 0.02,
        "{} {}",
        sum_h / n,
        sum_k / n
    );
    assert!(worst_h < 0.05 && worst_k < 0.1, "{worst_h} {worst_k}");
}

#[test]
fn curvature_of_a_cylinder() {
    let rho = 0.5;
    let s = cylinder(rho, 2.0, 64, 40);
    let c = principal_curvatures(&s, &CurvatureParams::default()).unwrap();
    let topo = topology(&s);
    let mut boundary = vec![false; s.vertex_count()];
    for v in topo.boundary_loops.iter().flatten() {
        boundary[*v as usize] = true;
    }
    for v in (0..s.vertex_count()).filter(|&v| !boundary[v]) {
        assert!(
            (c.k_max[v] * rho - 1.0).abs() < 0.03,
            "k_max {}",
            c.k_max[v]
        );
        assert!((c.k_min[v] * rho).abs() < 0.03, "k_min {}", c.k_min[v]);
        assert!(
            (c.mean[v] * 2.0 * rho - 1.0).abs() < 0.03,
            "H {}",
            c.mean[v]
        );
        assert!(
            (c.gaussian[v] * rho * rho).abs() < 0.03,
            "K {}",
            c.gaussian[v]
        );
        // Direction of minimum curvature along the axis, maximum around it.
        assert!(c.dir_min[v][2].abs() > 0.99, "dir_min {:?}", c.dir_min[v]);
        assert!(c.dir_max[v][2].abs() < 0.1, "dir_max {:?}", c.dir_max[v]);
    }
}

#[test]
fn params_deserialize_from_empty_json_to_defaults() {
    let l: LaplacianParams = serde_json::from_str("{}").unwrap();
    assert_eq!(l.max_cotangent, LaplacianParams::default().max_cotangent);
    let h: HeatParams = serde_json::from_str(r#"{"boundary": "neumann"}"#).unwrap();
    assert_eq!(h.boundary, HeatBoundary::Neumann);
    assert_eq!(h.time_factor, 1.0);
    let w: WalkParams = serde_json::from_str(r#"{"radius": 2.0}"#).unwrap();
    assert_eq!(w.metric, WalkMetric::FastMarching);
    let _: CurvatureParams = serde_json::from_str("{}").unwrap();
    assert!(serde_json::from_str::<HeatParams>(r#"{"bogus": 1}"#).is_err());
}

/// Exports L, both mass matrices and curvatures of a few shared assets for
/// `scripts/crosscheck_libigl.py` (which runs this test and compares with libigl). Writes into
/// `$RETEX_CROSSCHECK_DIR` (default `target/crosscheck_libigl`).
#[test]
#[ignore = "run by scripts/crosscheck_libigl.py"]
fn crosscheck_libigl_export() {
    common_geometry::export_for_libigl();
}

#[test]
fn results_are_identical_for_any_thread_count() {
    let s = jittered_sphere(1.0, 40, 0.01);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let heat = HeatGeodesics::new(&s, &HeatParams::default(), &Control::new()).unwrap();
            let queries = vec![vec![Source::Vertex(3)], vec![Source::Vertex(9000)]];
            let d = heat.distance_many(&queries, &Control::new()).unwrap();
            let c = principal_curvatures(&s, &CurvatureParams::default()).unwrap();
            let l = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
            (d, c.mean, l.stiffness.values().to_vec(), l.mass)
        })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.0 == b.0, "heat distances differ between 1 and 2 threads");
    assert!(a.1 == b.1 && a.2 == b.2 && a.3 == b.3, "operators differ");
}
