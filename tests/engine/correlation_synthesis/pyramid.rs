//! Surface pyramid (§3.1): even samples, quarter-size levels, exact Laplacian collapse, zero bands
//! of a constant, Gaussian smoothing as a low-pass filter, bad input.

use super::{normal, percentile, shapes};
use retex::engine::control::Control;
use retex::engine::mesh::primitives::icosphere;
use retex::engine::mesh::Surface;
use retex::engine::methods::correlation::pyramid::SurfacePyramid;
use retex::engine::rng::SplitMix64;

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
