//! The synthesis over surfaces (Berkiten et al. 2017, §3.3.1, Algorithms 1-2, eqs. 5-7):
//! the blending weights, the sweep order, self-transfer on a sphere against a random-patch
//! baseline, and the learned metric against `identity` on the tiers of the features → metric
//! test (the paper's Fig. 16a). Per-level timings are printed (`-- --nocapture`).

use faer::Mat;
use retex::engine::control::Control;
use retex::engine::mesh::primitives::icosphere;
use retex::engine::mesh::Surface;
use retex::engine::methods::detail::blend::{falloff, location_weight, Blend};
use retex::engine::methods::detail::geometric_features::{
    geometric_features_pair, GeometricParams, DIM,
};
use retex::engine::methods::detail::metric::{
    factor, learn_metric, transform, MetricParams, MetricProblem, ZScore,
};
use retex::engine::methods::detail::patches::{detail_features, PatchParams};
use retex::engine::methods::detail::steerable::FEATURES;
use retex::engine::methods::detail::sweep::sweep_order;
use retex::engine::methods::detail::synthesis::{
    synthesize, Choice, SourceLevel, Synthesis, SynthesisParams, TargetLevel,
};

use super::metric_features::tiers;
use crate::detail_method::std;

/// Pearson correlation of two equally long series (0 for a constant one).
pub(crate) fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt().max(1e-300)
}

fn print_levels(label: &str, s: &Synthesis) {
    for (l, st) in s.levels.iter().enumerate() {
        println!(
            "  {label} level {l}: n {:>2}, step {:.4}, {} samples, τ {:.3e}, seeds {:?}, \
             patches {}+{}, skipped {}+{}, step 2 changed {}+{}, times (s) upsample {:.3} \
             patches {:.3} order {:.3} forward {:.3} reverse {:.3}",
            st.patch_size,
            st.grid_step,
            st.source_samples,
            st.threshold,
            st.seeds,
            st.passes[0].patches,
            st.passes[1].patches,
            st.passes[0].skipped,
            st.passes[1].skipped,
            st.passes[0].step2_changed,
            st.passes[1].step2_changed,
            st.seconds[0],
            st.seconds[1],
            st.seconds[2],
            st.seconds[3],
            st.seconds[4],
        );
    }
}

#[test]
fn blending_weights_follow_eqs_5_to_7() {
    assert_eq!(falloff(0.0), 1.0);
    assert_eq!(falloff(1.0), 0.0);
    assert!((falloff(0.5) - 0.5).abs() < 1e-12);
    // Clamped outside [0, 1] (the cubic rises again past 1).
    assert_eq!(falloff(1.5), 0.0);
    assert_eq!(falloff(-0.5), 1.0);
    let xs: Vec<f64> = (0..=100).map(|i| falloff(i as f64 / 100.0)).collect();
    assert!(xs.windows(2).all(|w| w[1] < w[0]), "not decreasing");
    // w_loc: 1 at the centre, 0 at the corner of an n-patch (n/√2 away).
    assert_eq!(location_weight(0.0, 7), 1.0);
    assert!(location_weight(7.0 / 2f64.sqrt(), 7).abs() < 1e-12);
    // w_disp grows with every contribution; above 0.5 a vertex is skipped.
    let mut b = Blend::new(vec![0.2; 3], 0.5);
    assert!(!b.skip(0) && b.weight(0) == 0.0);
    assert_eq!(b.current(0), 0.2, "shows the base before any contribution");
    assert_eq!(b.context_weight(0), 0.5);
    let w1 = b.add(0, 0.6, 0.3);
    assert_eq!(w1, 0.3, "first contribution: w_val = 1");
    assert!(!b.skip(0));
    let w2 = b.add(0, 0.6, 0.3);
    assert!((w2 - 0.3).abs() < 1e-12, "agreeing value: w_val = 1");
    assert!(b.skip(0) && (b.weight(0) - 0.6).abs() < 1e-12);
    assert!((b.current(0) - 0.6).abs() < 1e-12);
    // A disagreeing value gets w_val = f(|0.6 − 0.1|) = 0.5.
    let w3 = b.add(0, 0.1, 1.0);
    assert!((w3 - 0.5).abs() < 1e-12, "{w3}");
    let expect = (0.6 * 0.6 + 0.5 * 0.1) / 1.1;
    assert!((b.current(0) - expect).abs() < 1e-12);
    assert_eq!(b.context_weight(0), 1.0);
    // A disagreement of the full range contributes nothing.
    let mut c = Blend::new(vec![0.0], 0.0);
    c.add(0, 0.0, 1.0);
    assert_eq!(c.add(0, 1.0, 1.0), 0.0);
}

#[test]
fn sweep_order_starts_at_the_fewest_correspondences_and_visits_all() {
    let s = icosphere(1.0, 6);
    let nv = s.vertex_count();
    // Counts grow with height: the seeds must be the lowest vertices.
    let counts: Vec<u32> = s
        .positions
        .iter()
        .map(|p| ((p[1] + 1.0) * 100.0) as u32)
        .collect();
    let (order, seeds) = sweep_order(&s, &counts, 3);
    assert_eq!(seeds.len(), 3);
    let mut sorted = order.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, (0..nv).collect::<Vec<_>>(), "a permutation");
    // The seeds have the fewest counts (every other vertex has at least as many).
    let top = seeds.iter().map(|&v| counts[v]).max().unwrap();
    assert!(
        (0..nv).all(|v| seeds.contains(&v) || counts[v] >= top),
        "{seeds:?}"
    );
    assert!(seeds.contains(&order[0]));
    // Ordered by distance from the seeds (the bottom): the last vertices are near the top.
    let last = order[nv - 1];
    assert!(s.positions[last][1] > 0.8, "{:?}", s.positions[last]);
    // Two components: the second gets its own seed.
    let mut faces = s.faces.clone();
    let mut pos = s.positions.clone();
    pos.extend(s.positions.iter().map(|p| [p[0] + 3.0, p[1], p[2]]));
    faces.extend(s.faces.iter().map(|f| f.map(|v| v + nv as u32)));
    let two = Surface::from_triangles(pos, faces);
    let c2: Vec<u32> = (0..2 * nv).map(|v| if v < nv { 0 } else { 5 }).collect();
    let (order, seeds) = sweep_order(&two, &c2, 2);
    assert_eq!(order.len(), 2 * nv);
    assert_eq!(seeds.len(), 3, "{seeds:?}");
}

/// The self-transfer pattern: a broad and a fine component (wavelengths ≈ 0.8 and 0.25).
fn sphere_pattern(p: [f32; 3]) -> f64 {
    let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
    0.02 * ((8.0 * x + 1.0).sin() * (7.0 * y).cos() + 0.5 * (25.0 * x).sin() * (25.0 * z).sin())
}

/// The self-transfer case: icospheres of frequency 8, 16, 32 (642 / 2562 / 10242 vertices;
/// edges halve) carrying [`sphere_pattern`], with features that locate a point (the position,
/// scaled: these tests are about the synthesis, not the metric). Runs `params` and returns
/// (Pearson r of the finest level against the source, std ratio, per-level r, the synthesis).
fn self_transfer(params: &SynthesisParams) -> (f64, f64, Vec<f64>, Synthesis) {
    let levels: Vec<Surface> = [8, 16, 32].iter().map(|&f| icosphere(1.0, f)).collect();
    let disp: Vec<Vec<f64>> = levels
        .iter()
        .map(|s| s.positions.iter().map(|&p| sphere_pattern(p)).collect())
        .collect();
    let feats: Vec<Vec<f64>> = levels
        .iter()
        .map(|s| {
            s.positions
                .iter()
                .flat_map(|p| p.map(|x| 4.0 * x as f64))
                .collect()
        })
        .collect();
    let src: Vec<SourceLevel> = (0..3)
        .map(|l| SourceLevel {
            surface: &levels[l],
            displacement: &disp[l],
            features: &feats[l],
        })
        .collect();
    let tgt: Vec<TargetLevel> = (0..3)
        .map(|l| TargetLevel {
            surface: &levels[l],
            features: &feats[l],
        })
        .collect();
    let out = synthesize(&src, &tgt, 3, params, &Control::new()).unwrap();
    let finest = &out.displacement[2];
    let per_level: Vec<f64> = (0..3)
        .map(|l| pearson(&out.displacement[l], &disp[l]))
        .collect();
    (
        pearson(finest, &disp[2]),
        std(finest) / std(&disp[2]),
        per_level,
        out,
    )
}

#[test]
fn self_transfer_reproduces_the_source_and_beats_random_patches() {
    let t0 = std::time::Instant::now();
    let (r, energy, per_level, matched) = self_transfer(&SynthesisParams::default());
    println!(
        "self-transfer, matched: {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    print_levels("matched", &matched);
    let random_r: Vec<f64> = [1u64, 2, 3]
        .iter()
        .map(|&seed| {
            let params = SynthesisParams {
                choice: Choice::Random(seed),
                ..SynthesisParams::default()
            };
            self_transfer(&params).0
        })
        .collect();
    let best_random = random_r.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    println!(
        "  Pearson r per level {per_level:.3?}; random patches (3 seeds) {random_r:.3?}; \
         energy ratio {energy:.3}"
    );
    // Measured: 0.914 with 16 candidates, 0.829 with 8 (random patches: −0.08 to 0.04), energy
    // ratio 0.95; 24 or 32 candidates fail (0.28, 0.18: README "detail", the sweep of K).
    assert!(r > 0.75, "r {r}");
    assert!(r > best_random + 0.5, "r {r} vs random {random_r:?}");
    assert!((0.7..=1.3).contains(&energy), "energy ratio {energy}");
}

#[test]
fn the_candidates_reach_closes_the_gaps_between_sparse_source_samples() {
    // 64 samples on the finest level's 10242 vertices lie about 12 edges apart: the shift range
    // (1 edge) reaches a fraction of the alignments, and the chosen patches are misplaced.
    let sparse = SynthesisParams {
        source_samples: 64,
        ..SynthesisParams::default()
    };
    let (off, off_energy, _, _) = self_transfer(&sparse);
    let (on, on_energy, _, out) = self_transfer(&SynthesisParams {
        max_reach: 8,
        ..sparse
    });
    let reach: Vec<usize> = out.levels.iter().map(|l| l.reach).collect();
    println!(
        "64 samples: r {off:.3} (energy {off_energy:.3}) without the reach, {on:.3} \
         (energy {on_energy:.3}) with it, reach per level {reach:?}"
    );
    // Measured: 0.089 (energy 0.76) without, 0.939 (0.95) with; reach 3 / 5 / 8 grid steps by
    // level (the finest capped). 1024 samples with the reach: 0.952 (0.914 without).
    assert!(on > 0.85, "with the reach: r {on}");
    assert!(
        off < 0.5,
        "without the reach the case does not discriminate: r {off}"
    );
    assert!(on > off + 0.4, "{on} vs {off}");
    assert!((0.8..=1.2).contains(&on_energy), "energy {on_energy}");
    assert!(reach[2] > 1 && reach.iter().all(|&r| r <= 8), "{reach:?}");
}

/// Geometric features of a source / target level pair, z-scored per shape.
fn zscored_pair(s: &Surface, t: &Surface, control: &Control) -> (Vec<f64>, Vec<f64>) {
    let (gs, gt) = geometric_features_pair(s, t, &GeometricParams::default(), control).unwrap();
    let z = |v: &[f64]| ZScore::fit(v, DIM).apply(v);
    (z(&gs.values), z(&gt.values))
}

/// Bumps (amplitude 0.01, wavelength 0.25) on the treads only.
fn tread_bumps(s: &Surface, tread: &[bool]) -> Vec<f64> {
    (s.positions.iter().zip(tread))
        .map(|(p, &t)| {
            let (x, z) = (p[0] as f64, p[2] as f64);
            let w = std::f64::consts::TAU / 0.25;
            if t {
                0.01 * (w * x).sin() * (w * z).sin()
            } else {
                0.0
            }
        })
        .collect()
}

#[test]
fn learned_and_identity_metrics_put_detail_on_the_treads_random_patches_do_not() {
    // Three levels at spacing 0.2 / 0.1 / 0.05 (four would add a 0.025 level of ~50k vertices
    // per shape, too slow for a test). Source: 5 tiers, width 2.5; target: 5 tiers, width 2.
    // Measured with the absolute λ's residue metric (README): with a 4-tier target it (rank 2, HKS-heavy: HKS
    // sees the position along the strip, which 4 and 5 tiers divide differently) put *less*
    // detail on the treads than `identity` (ratio 1.53 vs 7.06), so the paper's Fig. 16a claim
    // is not reproduced here (see the README); on 5 tiers both beat random patches clearly.
    let hs = [0.2, 0.1, 0.05];
    let control = Control::new();
    let src: Vec<(Surface, Vec<bool>, Vec<f64>)> =
        hs.iter().map(|&h| tiers(5, 1.0, 1.0, 2.5, h)).collect();
    let tgt: Vec<(Surface, Vec<bool>, Vec<f64>)> =
        hs.iter().map(|&h| tiers(5, 1.0, 1.0, 2.0, h)).collect();
    let disp: Vec<Vec<f64>> = src.iter().map(|(s, t, _)| tread_bumps(s, t)).collect();
    let t0 = std::time::Instant::now();
    let feats: Vec<(Vec<f64>, Vec<f64>)> = (0..3)
        .map(|l| zscored_pair(&src[l].0, &tgt[l].0, &control))
        .collect();
    println!(
        "geometric features, 3 level pairs: {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    // Learn on the finest source level, vertices whose patch stays on the surface (as the
    // features → metric test).
    let t0 = std::time::Instant::now();
    let (s2, _, border) = &src[2];
    let detail = detail_features(s2, &disp[2], &PatchParams::default(), &control).unwrap();
    let keep: Vec<usize> = (0..s2.vertex_count())
        .filter(|&v| border[v] > 0.8)
        .collect();
    let pick = |f: &[f64], d: usize| -> Vec<f64> {
        keep.iter()
            .flat_map(|&v| f[v * d..(v + 1) * d].to_vec())
            .collect()
    };
    let problem = MetricProblem::from_features(
        &pick(&feats[2].0, DIM),
        DIM,
        &pick(&detail, FEATURES),
        FEATURES,
    )
    .unwrap()
    .relative();
    let learned = learn_metric(&problem, &MetricParams::default()).unwrap();
    let a = factor(&learned.m).unwrap();
    for (name, r) in retex::engine::methods::detail::geometric_features::GROUPS {
        let m: f64 = r.clone().map(|j| learned.m[(j, j)]).sum();
        let tr: f64 = (0..DIM).map(|j| learned.m[(j, j)]).sum();
        println!("  {name}: {:.3}", m / tr);
    }
    println!(
        "metric: {:.2} s, {} ADMM iterations, rank {}",
        t0.elapsed().as_secs_f64(),
        learned.iterations,
        a.nrows()
    );
    let mut ratios = Vec::new();
    let random = SynthesisParams {
        choice: Choice::Random(7),
        ..SynthesisParams::default()
    };
    let runs = [
        ("learned", a.clone(), SynthesisParams::default()),
        (
            "identity",
            Mat::<f64>::identity(DIM, DIM),
            SynthesisParams::default(),
        ),
        ("random", a, random),
    ];
    for (name, a, params) in runs {
        let r = a.nrows();
        let tf: Vec<(Vec<f64>, Vec<f64>)> = feats
            .iter()
            .map(|(s, t)| (transform(&a, s), transform(&a, t)))
            .collect();
        let sl: Vec<SourceLevel> = (0..3)
            .map(|l| SourceLevel {
                surface: &src[l].0,
                displacement: &disp[l],
                features: &tf[l].0,
            })
            .collect();
        let tl: Vec<TargetLevel> = (0..3)
            .map(|l| TargetLevel {
                surface: &tgt[l].0,
                features: &tf[l].1,
            })
            .collect();
        let t0 = std::time::Instant::now();
        let out = synthesize(&sl, &tl, r, &params, &control).unwrap();
        println!("{name}: synthesis {:.2} s", t0.elapsed().as_secs_f64());
        print_levels(name, &out);
        let (t2, tread, _) = &tgt[2];
        let d = &out.displacement[2];
        let region = |inside: bool| -> Vec<f64> {
            (0..d.len())
                .filter(|&v| tread[v] == inside)
                .map(|v| d[v])
                .collect()
        };
        let (e_in, e_out) = (std(&region(true)), std(&region(false)));
        println!(
            "  {name}: {} target vertices, detail std inside {e_in:.5}, outside {e_out:.5}, \
             ratio {:.2} (source: inside {:.5})",
            t2.vertex_count(),
            e_in / e_out.max(1e-12),
            std(&(0..disp[2].len())
                .filter(|&v| src[2].1[v])
                .map(|v| disp[2][v])
                .collect::<Vec<_>>()),
        );
        ratios.push(e_in / e_out.max(1e-12));
    }
    // Measured (learned, identity, random): 5.51, 16.56, 0.95 with λ relative (the learned
    // metric all on the normals; 4.85 / 13.88 with the former z-score floor 1e-3, 3.72 with the
    // ADMM's former 1e-8 tolerance) and 16 candidates; with the absolute λ's residue metric 8.80
    // (16 candidates), 5.23 (8); see the README.
    assert!(ratios[0] > 3.5 && ratios[1] > 3.5, "{ratios:?}");
    assert!(
        ratios[0] > 2.0 * ratios[2],
        "learned vs random patches {ratios:?}"
    );
}

#[test]
fn bad_input_and_cancellation_are_errors_not_panics() {
    use retex::engine::methods::detail::synthesis::SynthesisError;
    let s = icosphere(1.0, 3);
    let nv = s.vertex_count();
    let (d, f) = (vec![0.01; nv], vec![0.0; nv * 2]);
    let src = [SourceLevel {
        surface: &s,
        displacement: &d,
        features: &f,
    }];
    let tgt = [TargetLevel {
        surface: &s,
        features: &f,
    }];
    let p = SynthesisParams::default();
    let c = Control::new();
    // Works (constant displacement, r = 2), and r = 0 is accepted.
    let out = synthesize(&src, &tgt, 2, &p, &c).unwrap();
    assert!(out.displacement[0].iter().all(|x| (x - 0.01).abs() < 1e-12));
    let empty_f: Vec<f64> = Vec::new();
    let src0 = [SourceLevel {
        features: &empty_f,
        ..src[0]
    }];
    let tgt0 = [TargetLevel {
        features: &empty_f,
        ..tgt[0]
    }];
    assert!(synthesize(&src0, &tgt0, 0, &p, &c).is_ok());
    // Wrong widths, level counts, empty surfaces, NaN, bad parameters.
    assert!(matches!(
        synthesize(&src, &tgt, 3, &p, &c),
        Err(SynthesisError::Shape { .. })
    ));
    assert!(matches!(
        synthesize(&src, &[], 2, &p, &c),
        Err(SynthesisError::Param(_))
    ));
    let nothing = Surface::from_triangles(vec![[0.0; 3]; 3], vec![]);
    let tgt_e = [TargetLevel {
        surface: &nothing,
        features: &f[..6],
    }];
    assert!(matches!(
        synthesize(&src, &tgt_e, 2, &p, &c),
        Err(SynthesisError::Empty { .. })
    ));
    let mut dn = d.clone();
    dn[3] = f64::NAN;
    let src_n = [SourceLevel {
        displacement: &dn,
        ..src[0]
    }];
    assert!(matches!(
        synthesize(&src_n, &tgt, 2, &p, &c),
        Err(SynthesisError::NonFinite { .. })
    ));
    let bad = SynthesisParams {
        initial_patch_size: 0,
        ..SynthesisParams::default()
    };
    assert!(matches!(
        synthesize(&src, &tgt, 2, &bad, &c),
        Err(SynthesisError::Param(_))
    ));
    let mut broken = s.clone();
    broken.faces[0][2] = nv as u32 + 5;
    let tgt_b = [TargetLevel {
        surface: &broken,
        ..tgt[0]
    }];
    assert!(matches!(
        synthesize(&src, &tgt_b, 2, &p, &c),
        Err(SynthesisError::Empty { .. })
    ));
    // Degenerate (all vertices at one point): an error, not a panic.
    let flat = Surface::from_triangles(vec![[1.0; 3]; nv], s.faces.clone());
    let src_flat = [SourceLevel {
        surface: &flat,
        ..src[0]
    }];
    assert!(synthesize(&src_flat, &tgt, 2, &p, &c).is_err());
    c.cancel();
    assert!(matches!(
        synthesize(&src, &tgt, 2, &p, &c),
        Err(SynthesisError::Cancelled)
    ));
}
