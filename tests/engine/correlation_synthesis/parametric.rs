//! Parametric synthesis (§5.2): regimes per region, per-region histograms, band energies, 1-D and
//! 3-D guidance, determinism, bad input, the training mask, and the 64K / 512K benchmark.

use super::{bumpy_sphere, bumpy_torus, normal};
use retex::engine::control::Control;
use retex::engine::methods::correlation::parametric::{
    synthesize, ParametricParams, ParametricReport, SynthesisInput,
};
use retex::engine::methods::correlation::pyramid::SurfacePyramid;
use retex::engine::methods::correlation::quantiles::{match_to, Quantiles};
use retex::engine::rng::SplitMix64;

/// The test texture: red-ish noise where the guidance is below 0, blue-ish (noisier) above. The
/// guidance is the height z, scaled to [-1, 1] on each shape.
const RED: [f32; 3] = [0.7, 0.2, 0.15];
const BLUE: [f32; 3] = [0.15, 0.3, 0.7];
const RED_NOISE: f32 = 0.06;
const BLUE_NOISE: f32 = 0.1;

fn height_guidance(p: &SurfacePyramid) -> Vec<[f32; 3]> {
    guidance(p, 1)
}

/// Axis 0: the height scaled to [-1, 1] (it decides the regime); with `dims` = 3, axes 1 and 2 are
/// x and y scaled likewise (they do not change the texture).
fn guidance(p: &SurfacePyramid, dims: usize) -> Vec<[f32; 3]> {
    let m = p.mesh(0);
    let max = |k: usize| {
        m.positions
            .iter()
            .map(|q| q[k].abs())
            .fold(0.0f32, f32::max)
    };
    let (xm, ym, zm) = (max(0), max(1), max(2));
    m.positions
        .iter()
        .map(|q| {
            if dims == 1 {
                [q[2] / zm, 0.0, 0.0]
            } else {
                [q[2] / zm, q[0] / xm, q[1] / ym]
            }
        })
        .collect()
}

/// The regime colours plus noise with two scales: white per sample and a smooth field at the
/// scale of pyramid level 1 (from the pyramid's own collapse), each with half the variance.
fn regime_colours_on(p: &SurfacePyramid, g: &[[f32; 3]], seed: u64) -> Vec<[f32; 3]> {
    let mut rng = SplitMix64::new(seed);
    let coarse: Vec<[f32; 1]> = (0..p.len(1)).map(|_| [normal(&mut rng)]).collect();
    let mut bands: Vec<Vec<[f32; 1]>> = (0..p.level_count())
        .map(|l| vec![[0.0]; p.len(l)])
        .collect();
    bands[1] = coarse;
    let smooth = p.collapse(&bands);
    let sd = (smooth.iter().map(|x| x[0] * x[0]).sum::<f32>() / smooth.len() as f32).sqrt();
    g.iter()
        .zip(&smooth)
        .map(|(x, sm)| {
            let (base, s) = if x[0] < 0.0 {
                (RED, RED_NOISE)
            } else {
                (BLUE, BLUE_NOISE)
            };
            let n = std::f32::consts::FRAC_1_SQRT_2 * (normal(&mut rng) + sm[0] / sd);
            // Correlated (luminance-like) noise plus a little per channel.
            std::array::from_fn(|k| (base[k] + s * n + 0.3 * s * normal(&mut rng)).clamp(0.0, 1.0))
        })
        .collect()
}

/// 1-D Wasserstein distance of two weighted samples.
fn wasserstein(a: &[f32], wa: &[f32], b: &[f32], wb: &[f32]) -> f32 {
    let (qa, qb) = (Quantiles::new(a, Some(wa)), Quantiles::new(b, Some(wb)));
    (0..1000)
        .map(|i| {
            let u = (i as f32 + 0.5) / 1000.0;
            (qa.value_at(u) - qb.value_at(u)).abs()
        })
        .sum::<f32>()
        / 1000.0
}

/// Samples of a region (guidance below -0.2: red, above 0.2: blue).
fn region(g: &[[f32; 3]], blue: bool) -> Vec<usize> {
    region_beyond(g, blue, 0.2)
}

/// Samples whose guidance axis 0 is beyond ±`margin` on the regime's side.
fn region_beyond(g: &[[f32; 3]], blue: bool, margin: f32) -> Vec<usize> {
    (0..g.len())
        .filter(|&i| {
            if blue {
                g[i][0] > margin
            } else {
                g[i][0] < -margin
            }
        })
        .collect()
}

struct Measures {
    mean_err: f32,
    baseline_mean_err: f32,
    w1: f32,
    band_ratio: f32,
}

/// Band energy (area-weighted mean square over channels) of band `level` of a colour field, over
/// the samples of that level whose guidance axis 0 is beyond ±0.7 (so the jump between the regimes
/// at 0, a structure of the guidance and not of the texture, stays out of the coarser band).
fn band_energy(
    p: &SurfacePyramid,
    c: &[[f32; 3]],
    g: &[[f32; 3]],
    blue: bool,
    level: usize,
) -> f32 {
    let b = p.laplacian(c);
    let gl = p.gaussian(g);
    let a = p.area(level);
    let (mut s, mut w) = (0.0f64, 0.0f64);
    for i in region_beyond(&gl[level], blue, 0.7) {
        s += a[i] as f64 * (0..3).map(|k| (b[level][i][k] as f64).powi(2)).sum::<f64>();
        w += a[i] as f64;
    }
    (s / w) as f32
}

fn measure(
    sp: &SurfacePyramid,
    sg: &[[f32; 3]],
    sc: &[[f32; 3]],
    tp: &SurfacePyramid,
    tg: &[[f32; 3]],
    out: &[[f32; 3]],
) -> Measures {
    let (sa, ta) = (sp.area(0), tp.area(0));
    let mut global = [0.0f32; 3];
    for c in sc {
        for k in 0..3 {
            global[k] += c[k] / sc.len() as f32;
        }
    }
    let (mut mean_err, mut baseline_mean_err, mut w1, mut band_ratio) =
        (0.0f32, 0.0f32, 0.0f32, f32::INFINITY);
    for blue in [false, true] {
        let (si, ti) = (region(sg, blue), region(tg, blue));
        let truth = if blue { BLUE } else { RED };
        for k in 0..3 {
            let m = ti.iter().map(|&i| out[i][k]).sum::<f32>() / ti.len() as f32;
            mean_err = mean_err.max((m - truth[k]).abs());
            baseline_mean_err = baseline_mean_err.max((global[k] - truth[k]).abs());
            let a: Vec<f32> = si.iter().map(|&i| sc[i][k]).collect();
            let wa: Vec<f32> = si.iter().map(|&i| sa[i]).collect();
            let b: Vec<f32> = ti.iter().map(|&i| out[i][k]).collect();
            let wb: Vec<f32> = ti.iter().map(|&i| ta[i]).collect();
            w1 = w1.max(wasserstein(&a, &wa, &b, &wb));
        }
        for level in 0..2 {
            let r = band_energy(tp, out, tg, blue, level) / band_energy(sp, sc, sg, blue, level);
            // Keep the one farthest from 1.
            if !band_ratio.is_finite() || r.ln().abs() > band_ratio.ln().abs() {
                band_ratio = r;
            }
        }
    }
    Measures {
        mean_err,
        baseline_mean_err,
        w1,
        band_ratio,
    }
}

fn run_synthesis(
    sp: &SurfacePyramid,
    tp: &SurfacePyramid,
    sg: &[[f32; 3]],
    tg: &[[f32; 3]],
    sc: &[[f32; 3]],
    dims: usize,
    params: &ParametricParams,
) -> (Vec<[f32; 3]>, Vec<u32>, ParametricReport) {
    let weight = vec![1.0f32; sp.len(0)];
    let input = SynthesisInput {
        source: sp,
        target: tp,
        source_guidance: sg,
        target_guidance: tg,
        guidance_dims: dims,
        source_color: sc,
        source_weight: &weight,
    };
    synthesize(&input, params, &Control::new()).unwrap()
}

#[test]
fn parametric_reproduces_regimes_histograms_and_band_energy() {
    let control = Control::new();
    let sphere = bumpy_sphere(0.15, 4.0);
    let torus = bumpy_torus(64, 24, 0.3);
    let cases = [
        ("sphere→torus", &sphere, &torus),
        ("torus→sphere", &torus, &sphere),
    ];
    for (name, s, t) in cases {
        let sp = SurfacePyramid::build(s, 20_000, 3, &control).unwrap();
        let tp = SurfacePyramid::build(t, 16_000, 3, &control).unwrap();
        for dims in [1usize, 3] {
            let (sg, mut tg) = (guidance(&sp, dims), guidance(&tp, dims));
            // Axes 1 and 2 (x, y) take the source's marginals on the target, as the method's
            // feature matching (§4) does: guidance values the source never had are not what this
            // test is about.
            for a in 1..dims {
                let src_axis: Vec<f32> = sg.iter().map(|g| g[a]).collect();
                let q = Quantiles::new(&src_axis, Some(sp.area(0)));
                let mut axis: Vec<f32> = tg.iter().map(|g| g[a]).collect();
                match_to(&mut axis, Some(tp.area(0)), &q);
                for (g, x) in tg.iter_mut().zip(axis) {
                    g[a] = x;
                }
            }
            // With 3 axes, 50 clusters cut the regime axis more coarsely (clusters near the
            // regime boundary mix both), so the bounds are looser (sweep in the report).
            let (max_mean_err, max_w1) = if dims == 1 {
                (0.03, 0.015)
            } else {
                (0.045, 0.03)
            };
            for seed in 1..4u64 {
                let sc = regime_colours_on(&sp, &sg, seed);
                let params = ParametricParams {
                    seed,
                    ..Default::default()
                };
                let (out, labels, report) = run_synthesis(&sp, &tp, &sg, &tg, &sc, dims, &params);
                assert_eq!(out.len(), tp.len(0));
                assert_eq!(labels.len(), tp.len(0));
                assert!(out.iter().all(|c| c.iter().all(|x| x.is_finite())));
                assert_eq!(report.source_cluster_sizes.iter().sum::<usize>(), sp.len(0));
                assert_eq!(report.target_cluster_sizes.iter().sum::<usize>(), tp.len(0));
                assert!(report.source_cluster_sizes.len() >= 40, "{report:?}");
                let m = measure(&sp, &sg, &sc, &tp, &tg, &out);
                // Baseline: the regression alone (no noise, no H&B).
                let reg_params = ParametricParams {
                    iterations: 0,
                    noise: Some(0.0),
                    ..params.clone()
                };
                let (reg, _, _) = run_synthesis(&sp, &tp, &sg, &tg, &sc, dims, &reg_params);
                let r = measure(&sp, &sg, &sc, &tp, &tg, &reg);
                println!(
                    "{name} dims {dims} seed {seed}: mean err {:.4} (global-mean baseline {:.3}), \
                     W1 {:.4} (regression {:.4}), band energy ratio {:.3} (regression {:.3}), \
                     memberships {:.2}, k-means iterations {:?}",
                    m.mean_err,
                    m.baseline_mean_err,
                    m.w1,
                    r.w1,
                    m.band_ratio,
                    r.band_ratio,
                    report.target_memberships,
                    report.kmeans_iterations
                );
                assert!(
                    m.mean_err < max_mean_err && m.mean_err < 0.15 * m.baseline_mean_err,
                    "{name}"
                );
                assert!(
                    m.w1 < max_w1 && m.w1 < 0.4 * r.w1,
                    "{name}: W1 {} vs {}",
                    m.w1,
                    r.w1
                );
                // Level 1 reaches 0.74-0.86 of the source's energy after the paper's 3 H&B
                // iterations (it builds up from the white-noise start; parametric.rs docs).
                assert!(
                    (0.6..1.5).contains(&m.band_ratio),
                    "{name}: band ratio {}",
                    m.band_ratio
                );
                assert!(
                    r.band_ratio < 0.3,
                    "{name}: the regression baseline is smooth"
                );
            }
        }
    }
}

#[test]
fn parametric_is_deterministic_and_rejects_bad_input() {
    let control = Control::new();
    let sp = SurfacePyramid::build(&bumpy_sphere(0.15, 4.0), 6_000, 3, &control).unwrap();
    let tp = SurfacePyramid::build(&bumpy_torus(48, 16, 0.3), 5_000, 3, &control).unwrap();
    let (sg, tg) = (height_guidance(&sp), height_guidance(&tp));
    let sc = regime_colours_on(&sp, &sg, 9);
    let params = ParametricParams {
        seed: 5,
        ..Default::default()
    };
    let a = run_synthesis(&sp, &tp, &sg, &tg, &sc, 1, &params);
    let b = run_synthesis(&sp, &tp, &sg, &tg, &sc, 1, &params);
    assert_eq!(a.0, b.0);
    assert_eq!(a.1, b.1);
    let c = run_synthesis(
        &sp,
        &tp,
        &sg,
        &tg,
        &sc,
        1,
        &ParametricParams {
            seed: 6,
            ..params.clone()
        },
    );
    assert_ne!(a.0, c.0, "the seed changes the noise");

    // Everything masked out: a clear error, not a panic.
    let zero = vec![0.0f32; sp.len(0)];
    let input = SynthesisInput {
        source: &sp,
        target: &tp,
        source_guidance: &sg,
        target_guidance: &tg,
        guidance_dims: 1,
        source_color: &sc,
        source_weight: &zero,
    };
    assert!(synthesize(&input, &params, &control).is_err());
    let short = &sg[..10];
    let input = SynthesisInput {
        source_guidance: short,
        source_weight: &zero,
        ..input
    };
    assert!(synthesize(&input, &params, &control).is_err());
    // Cancelled: an error.
    let cancelled = Control::new();
    cancelled.cancel();
    let ones = vec![1.0f32; sp.len(0)];
    let input = SynthesisInput {
        source_guidance: &sg,
        source_weight: &ones,
        ..input
    };
    assert!(synthesize(&input, &params, &cancelled).is_err());
}

/// Timings of the pyramids and of the parametric synthesis at 64K and 512K samples (3-D guidance),
/// from Control's stage timings:
/// `cargo test --release --test engine correlation_synthesis::parametric::bench_ -- --ignored
/// --nocapture`
#[test]
#[ignore = "benchmark"]
fn bench_parametric_synthesis() {
    let sphere = bumpy_sphere(0.15, 4.0);
    let torus = bumpy_torus(64, 24, 0.3);
    for samples in [64_000usize, 512_000] {
        let build = Control::new();
        let sp = SurfacePyramid::build(&sphere, samples, 3, &build).unwrap();
        let tp = SurfacePyramid::build(&torus, samples, 3, &build).unwrap();
        let pyramid_ms: f64 = build.timings().iter().map(|t| t.ms).sum();
        let guidance = |p: &SurfacePyramid| -> Vec<[f32; 3]> {
            p.mesh(0)
                .positions
                .iter()
                .map(|q| [q[2], q[0] * q[1], (3.0 * q[0]).sin()])
                .collect()
        };
        let (sg, tg) = (guidance(&sp), guidance(&tp));
        let sc = regime_colours_on(&sp, &height_guidance(&sp), 1);
        let weight = vec![1.0f32; sp.len(0)];
        let input = SynthesisInput {
            source: &sp,
            target: &tp,
            source_guidance: &sg,
            target_guidance: &tg,
            guidance_dims: 3,
            source_color: &sc,
            source_weight: &weight,
        };
        let control = Control::new();
        let (_, _, report) = synthesize(&input, &ParametricParams::default(), &control).unwrap();
        control.finish();
        let total: f64 = control.timings().iter().map(|t| t.ms).sum();
        println!(
            "{samples} samples (source {}, target {}): pyramids {:.0} ms (both); parametric \
             synthesis {:.0} ms; k-means iterations {:?}",
            sp.len(0),
            tp.len(0),
            pyramid_ms,
            total,
            report.kmeans_iterations
        );
        for t in control.timings() {
            println!("  {:<40} {:>8.0} ms", t.stage, t.ms);
        }
    }
}

#[test]
fn parametric_mask_removes_a_painted_region_from_training() {
    let control = Control::new();
    let sp = SurfacePyramid::build(&bumpy_sphere(0.15, 4.0), 12_000, 3, &control).unwrap();
    let tp = SurfacePyramid::build(&bumpy_torus(64, 24, 0.3), 10_000, 3, &control).unwrap();
    let (sg, tg) = (height_guidance(&sp), height_guidance(&tp));
    for seed in 1..4u64 {
        let mut sc = regime_colours_on(&sp, &sg, seed);
        // Paint a green patch over part of the blue regime and mask it out.
        let mut weight = vec![1.0f32; sp.len(0)];
        for (i, p) in sp.mesh(0).positions.iter().enumerate() {
            if p[0] > 0.3 {
                sc[i] = [0.1, 0.9, 0.1];
                weight[i] = 0.0;
            }
        }
        let input = SynthesisInput {
            source: &sp,
            target: &tp,
            source_guidance: &sg,
            target_guidance: &tg,
            guidance_dims: 1,
            source_color: &sc,
            source_weight: &weight,
        };
        let params = ParametricParams {
            seed,
            ..Default::default()
        };
        let (out, _, _) = synthesize(&input, &params, &control).unwrap();
        let greenish = out
            .iter()
            .filter(|c| c[1] > 0.6 && c[1] > c[0] + 0.3 && c[1] > c[2])
            .count();
        let blue = region(&tg, true);
        let mean_g = blue.iter().map(|&i| out[i][1]).sum::<f32>() / blue.len() as f32;
        assert_eq!(greenish, 0, "seed {seed}");
        assert!(
            (mean_g - BLUE[1]).abs() < 0.03,
            "seed {seed}: mean G {mean_g}"
        );
        // Without the mask the paint leaks in (the check above is not vacuous).
        let ones = vec![1.0f32; sp.len(0)];
        let input = SynthesisInput {
            source_weight: &ones,
            ..input
        };
        let (leak, _, _) = synthesize(&input, &params, &control).unwrap();
        let leak_g = blue.iter().map(|&i| leak[i][1]).sum::<f32>() / blue.len() as f32;
        assert!(
            leak_g - BLUE[1] > 0.06,
            "seed {seed}: unmasked mean G {leak_g}"
        );
    }
}
