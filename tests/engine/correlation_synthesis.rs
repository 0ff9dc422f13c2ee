//! The `correlation` method's building blocks owned by helper syn (Mertens et al. 2006): the
//! surface pyramid (§3.1), weighted quantiles and exact quantile transfer (§4, §5.2), k-means and
//! the parametric synthesis (§5.2). Meshes are made in code.
//! `cargo test --release --test engine correlation_synthesis::`

use retex::engine::control::Control;
use retex::engine::mesh::primitives::icosphere;
use retex::engine::mesh::Surface;
use retex::engine::methods::correlation::pyramid::SurfacePyramid;
use retex::engine::methods::correlation::quantiles::{match_to, Quantiles};
use retex::engine::rng::SplitMix64;

// ---------------------------------------------------------------------------------------------
// Fixtures

/// A standard normal draw (Box-Muller).
fn normal(rng: &mut SplitMix64) -> f32 {
    let u1 = rng.unit_f64().max(1e-12);
    let u2 = rng.unit_f64();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// A sphere of radius 1 with radial bumps of relative height `bump` and angular frequency `freq`.
fn bumpy_sphere(bump: f32, freq: f32) -> Surface {
    let mut s = icosphere(1.0, 12);
    for p in &mut s.positions {
        let r = 1.0 + bump * (freq * p[0]).sin() * (freq * p[1]).sin() * (freq * p[2]).cos();
        *p = p.map(|c| c * r);
    }
    s
}

/// A torus (major radius 1, minor 0.35) with bumps, `nu × nv` quads.
fn bumpy_torus(nu: usize, nv: usize, bump: f32) -> Surface {
    let mut pos = Vec::with_capacity(nu * nv);
    for i in 0..nu {
        for j in 0..nv {
            let (u, v) = (
                std::f32::consts::TAU * i as f32 / nu as f32,
                std::f32::consts::TAU * j as f32 / nv as f32,
            );
            let r = 0.35 * (1.0 + bump * (5.0 * u).sin() * (3.0 * v).cos());
            pos.push([
                (1.0 + r * v.cos()) * u.cos(),
                (1.0 + r * v.cos()) * u.sin(),
                r * v.sin(),
            ]);
        }
    }
    let id = |i: usize, j: usize| ((i % nu) * nv + (j % nv)) as u32;
    let mut faces = Vec::with_capacity(2 * nu * nv);
    for i in 0..nu {
        for j in 0..nv {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Surface::from_triangles(pos, faces)
}

fn shapes() -> Vec<(&'static str, Surface)> {
    vec![
        ("sphere", icosphere(1.0, 10)),
        ("bumpy sphere", bumpy_sphere(0.15, 4.0)),
        ("bumpy torus", bumpy_torus(48, 16, 0.3)),
    ]
}

fn percentile(mut v: Vec<f32>, p: f32) -> f32 {
    v.sort_by(f32::total_cmp);
    v[((v.len() - 1) as f32 * p).round() as usize]
}

/// Area-weighted variance of one channel.
fn weighted_var(f: &[[f32; 1]], w: &[f32]) -> f64 {
    let sw: f64 = w.iter().map(|&x| x as f64).sum();
    let m: f64 = f
        .iter()
        .zip(w)
        .map(|(x, &w)| x[0] as f64 * w as f64)
        .sum::<f64>()
        / sw;
    f.iter()
        .zip(w)
        .map(|(x, &w)| w as f64 * (x[0] as f64 - m).powi(2))
        .sum::<f64>()
        / sw
}

// ---------------------------------------------------------------------------------------------
// Surface pyramid (§3.1)

#[test]
fn pyramid_samples_are_even_and_levels_quarter() {
    let control = Control::new();
    for (name, s) in shapes() {
        for samples in [4_000usize, 16_000, 64_000] {
            let p = SurfacePyramid::build(&s, samples, 3, &control).unwrap();
            assert_eq!(p.level_count(), 3, "{name} {samples}");
            let n0 = p.len(0);
            assert!(
                n0 >= samples && n0 <= samples + samples / 50,
                "{name}: {n0} samples for {samples}"
            );
            for l in 1..3 {
                let r = p.len(l) as f32 / p.len(l - 1) as f32;
                assert!(
                    (0.2..=0.32).contains(&r),
                    "{name} {samples}: level {l} ratio {r}"
                );
            }
            // Mean incident edge length per sample: 95th / 5th percentile.
            let m = p.mesh(0);
            let mut sum = vec![0.0f32; n0];
            let mut cnt = vec![0u32; n0];
            for f in &m.faces {
                for k in 0..3 {
                    let (a, b) = (f[k] as usize, f[(k + 1) % 3] as usize);
                    let d = (0..3)
                        .map(|c| (m.positions[a][c] - m.positions[b][c]).powi(2))
                        .sum::<f32>()
                        .sqrt();
                    sum[a] += d;
                    sum[b] += d;
                    cnt[a] += 1;
                    cnt[b] += 1;
                }
            }
            let mean: Vec<f32> = sum.iter().zip(&cnt).map(|(s, &c)| s / c as f32).collect();
            let spread = percentile(mean.clone(), 0.95) / percentile(mean, 0.05);
            println!(
                "{name} {samples}: n0 {n0}, levels {:?}, edge spread p95/p5 {spread:.3}",
                (0..3).map(|l| p.len(l)).collect::<Vec<_>>()
            );
            assert!(spread < 2.0, "{name} {samples}: spread {spread}");
            // Every sample has a place on the input and the areas add up to the surface's.
            assert_eq!(p.location().len(), n0);
            assert!(p
                .location()
                .iter()
                .all(|fp| (fp.face as usize) < s.face_count()));
            let a: f64 = p.area(0).iter().map(|&x| x as f64).sum();
            assert!((a / m.area() - 1.0).abs() < 1e-3);
        }
    }
}

#[test]
fn pyramid_collapse_inverts_laplacian_and_constant_has_zero_bands() {
    let control = Control::new();
    for (name, s) in shapes() {
        let p = SurfacePyramid::build(&s, 20_000, 3, &control).unwrap();
        let mut rng = SplitMix64::new(7);
        let f: Vec<[f32; 3]> = (0..p.len(0))
            .map(|_| [normal(&mut rng), 10.0 + normal(&mut rng), rng.unit_f32()])
            .collect();
        let bands = p.laplacian(&f);
        assert_eq!(bands.len(), 3);
        for (l, b) in bands.iter().enumerate() {
            assert_eq!(b.len(), p.len(l));
        }
        let back = p.collapse(&bands);
        let err = f
            .iter()
            .zip(&back)
            .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
            .fold(0.0f32, f32::max);
        assert!(err < 1e-5 * 11.0, "{name}: collapse error {err}");
        // Not the identity: the fine band carries most of white noise's variance.
        let b0: f64 = bands[0].iter().map(|x| (x[0] as f64).powi(2)).sum::<f64>() / p.len(0) as f64;
        assert!(b0 > 0.5, "{name}: band 0 energy {b0}");

        let c = vec![[0.25f32, -3.0]; p.len(0)];
        let bands = p.laplacian(&c);
        for b in &bands[..2] {
            assert!(
                b.iter().all(|x| x[0].abs() < 1e-5 && x[1].abs() < 1e-5),
                "{name}"
            );
        }
        assert!(bands[2]
            .iter()
            .all(|x| (x[0] - 0.25).abs() < 1e-5 && (x[1] + 3.0).abs() < 1e-5));
    }
}

#[test]
fn pyramid_gaussian_removes_noise_and_keeps_smooth_fields() {
    let control = Control::new();
    for (name, s) in shapes() {
        let p = SurfacePyramid::build(&s, 20_000, 3, &control).unwrap();
        for seed in 1..4u64 {
            let mut rng = SplitMix64::new(seed);
            let noise: Vec<[f32; 1]> = (0..p.len(0)).map(|_| [normal(&mut rng)]).collect();
            let g = p.gaussian(&noise);
            let v0 = weighted_var(&g[0], p.area(0));
            let v1 = weighted_var(&g[1], p.area(1));
            let v2 = weighted_var(&g[2], p.area(2));
            println!("{name} seed {seed}: noise variance by level {v0:.3} {v1:.4} {v2:.5}");
            assert!(v1 < 0.15 * v0 && v2 < 0.3 * v1, "{name}: {v0} {v1} {v2}");
        }
        // A smooth field (the height) passes almost unchanged.
        let smooth: Vec<[f32; 1]> = p.mesh(0).positions.iter().map(|q| [q[2]]).collect();
        let g = p.gaussian(&smooth);
        let (v0, v2) = (
            weighted_var(&g[0], p.area(0)),
            weighted_var(&g[2], p.area(2)),
        );
        assert!(v2 > 0.9 * v0, "{name}: smooth field variance {v0} -> {v2}");
    }
}

#[test]
fn pyramid_rejects_bad_input() {
    let control = Control::new();
    let empty = Surface::from_triangles(vec![], vec![]);
    assert!(SurfacePyramid::build(&empty, 1000, 3, &control).is_err());
    let s = icosphere(1.0, 4);
    assert!(SurfacePyramid::build(&s, 0, 3, &control).is_err());
    assert!(SurfacePyramid::build(&s, 1000, 0, &control).is_err());
    // A tiny mesh gives fewer levels, never a panic.
    let tri = Surface::from_triangles(
        vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        vec![[0, 1, 2]],
    );
    let p = SurfacePyramid::build(&tri, 3, 3, &control).unwrap();
    assert!(p.level_count() >= 1);
    let f = vec![[1.0f32]; p.len(0)];
    assert_eq!(p.collapse(&p.laplacian(&f)), f);
}

// ---------------------------------------------------------------------------------------------
// Quantiles

#[test]
fn quantiles_match_to_reproduces_the_target_exactly() {
    for seed in 0..5u64 {
        let mut rng = SplitMix64::new(seed);
        let n = 1000 + 37 * seed as usize;
        let target: Vec<f32> = (0..n).map(|_| normal(&mut rng).exp()).collect();
        let mut x: Vec<f32> = (0..n).map(|_| rng.unit_f32() * 5.0 - 1.0).collect();
        let order_before = {
            let mut i: Vec<usize> = (0..n).collect();
            i.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
            i
        };
        match_to(&mut x, None, &Quantiles::new(&target, None));
        let mut sx = x.clone();
        sx.sort_by(f32::total_cmp);
        let mut st = target.clone();
        st.sort_by(f32::total_cmp);
        let err = sx
            .iter()
            .zip(&st)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err < 1e-5, "seed {seed}: {err}");
        // Ranks are kept.
        assert!(order_before.windows(2).all(|w| x[w[0]] <= x[w[1]]));
    }
    // Ties are broken stably (all-equal input spreads over the target).
    let mut x = vec![1.0f32; 4];
    match_to(&mut x, None, &Quantiles::new(&[1.0, 2.0, 3.0, 4.0], None));
    assert_eq!(x, vec![1.0, 2.0, 3.0, 4.0]);
}

#[test]
fn quantiles_respect_weights() {
    // Values 0..n; the first half weighs 3, the second 1. Target uniform on [0, 1]: the weighted
    // median must land on 0.5 and the first half (75% of the weight) fill [0, 0.75].
    let n = 2000;
    let x0: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let w: Vec<f32> = (0..n).map(|i| if i < n / 2 { 3.0 } else { 1.0 }).collect();
    let target: Vec<f32> = (0..10_000).map(|i| (i as f32 + 0.5) / 10_000.0).collect();
    let mut x = x0.clone();
    match_to(&mut x, Some(&w), &Quantiles::new(&target, None));
    let edge = x[n / 2 - 1];
    assert!((edge - 0.75).abs() < 2e-3, "first half ends at {edge}");
    let wm: f32 = x.iter().zip(&w).map(|(a, b)| a * b).sum::<f32>() / w.iter().sum::<f32>();
    assert!((wm - 0.5).abs() < 2e-3, "weighted mean {wm}");
    // Zero weight: ignored for the distribution.
    let q = Quantiles::new(&[0.0, 1.0, 100.0], Some(&[1.0, 1.0, 0.0]));
    assert_eq!(q.len(), 2);
    assert!(q.value_at(1.0) <= 1.0);
    // Weighted distribution: the mean follows the weights.
    let q = Quantiles::new(&x0, Some(&w));
    let m = q.mean();
    let expect = x0.iter().zip(&w).map(|(a, b)| a * b).sum::<f32>() / w.iter().sum::<f32>();
    assert!((m - expect).abs() < 0.01 * n as f32, "mean {m} vs {expect}");
}

#[test]
fn quantiles_blend_of_shifted_distributions_is_the_mid_shift() {
    for seed in 0..4u64 {
        let mut rng = SplitMix64::new(100 + seed);
        // Small sizes blend on the union of knots, large ones on the fixed grid.
        let n = if seed % 2 == 0 { 500 } else { 3000 };
        let base: Vec<f32> = (0..n).map(|_| normal(&mut rng)).collect();
        // `a` holds every value twice (another knot count, the same distribution).
        let a: Vec<f32> = base.iter().chain(&base).map(|x| x - 2.0).collect();
        let b: Vec<f32> = base.iter().map(|x| 3.0 * x + 4.0).collect();
        let (qa, qb) = (Quantiles::new(&a, None), Quantiles::new(&b, None));
        let q0 = Quantiles::new(&base, None);
        for (wa, wb) in [(1.0f32, 1.0f32), (3.0, 1.0), (0.2, 0.8)] {
            let m = Quantiles::blend(&[(&qa, wa), (&qb, wb)]);
            let (ta, tb) = (wa / (wa + wb), wb / (wa + wb));
            for k in 1..20 {
                let u = k as f32 / 20.0;
                // The mean of the inverse CDFs: scale ta·1 + tb·3, shift ta·(-2) + tb·4.
                let expect = (ta + 3.0 * tb) * q0.value_at(u) + (-2.0 * ta + 4.0 * tb);
                let got = m.value_at(u);
                assert!(
                    (got - expect).abs() < 0.1,
                    "seed {seed} w {wa}/{wb} u {u}: {got} vs {expect}"
                );
            }
        }
        // Empty / zero-weight parts are ignored.
        let e = Quantiles::new(&[], None);
        let m = Quantiles::blend(&[(&qa, 1.0), (&e, 1.0), (&qb, 0.0)]);
        assert_eq!(m, qa);
        assert!(Quantiles::blend(&[]).is_empty());
    }
}
