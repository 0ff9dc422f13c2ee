//! Properties of the `detail` pipeline from surfaces (Berkiten et al. 2017; issue 13, "Tests it
//! must have"): the detail keeps its world wavelength on a stretched target (the paper's reason
//! for synthesis over projection), and A → B → A keeps A's detail (Fig. 15's stability).

use retex::engine::control::Control;
use retex::engine::mesh::primitives::capsule;
use retex::engine::mesh::Surface;
use retex::engine::methods::detail::displacement::area_weighted_normals;
use retex::engine::methods::detail::params::DetailParams;
use retex::engine::methods::detail::pipeline::{transfer_detail, DetailTransfer};
use retex::engine::spatial::Bvh;

use crate::common_geometry::{jittered_sphere, stretch_beyond_two};

const RADIUS: f32 = 0.5;

/// Rings around the capsule's axis whose wavelength grows from 0.25 at x = 0 to 0.5 at x = 4:
/// phase φ(x) = ∫ dx / λ(x) with λ(x) = 0.25 + x / 16.
fn ring_phase(x: f64) -> f64 {
    16.0 * (1.0 + x / 4.0).ln()
}

fn ring_wavelength(x: f64) -> f64 {
    0.25 + x / 16.0
}

/// The source capsule (x ∈ [0, 4]) displaced radially by rings of amplitude 0.015 on its
/// cylinder, and its base.
fn ringed_capsule() -> (Surface, Surface) {
    let profile: Vec<f32> = (0..=100).map(|i| 4.0 * i as f32 / 100.0).collect();
    let base = capsule(RADIUS, &profile, 80, |x| x);
    let mut detailed = base.clone();
    for p in detailed.positions.iter_mut() {
        let x = p[0] as f64;
        if (0.0..=4.0).contains(&x) {
            let d = 0.015 * (std::f64::consts::TAU * ring_phase(x)).sin();
            let s = ((RADIUS as f64 + d) / RADIUS as f64) as f32;
            p[1] *= s;
            p[2] *= s;
        }
    }
    (detailed, base)
}

/// Displacement along the line (x, r, 0), x from `from` to `to` in steps of 0.005.
fn along_top(out: &DetailTransfer, from: f64, to: f64) -> Vec<f64> {
    let s = &out.surface;
    let bvh = Bvh::build(&s.positions, &s.faces);
    let n = ((to - from) / 0.005) as usize;
    (0..n)
        .map(|i| {
            let x = from + 0.005 * i as f64;
            let hit = bvh
                .closest_point([x as f32, RADIUS, 0.0], f32::INFINITY)
                .unwrap();
            let f = s.faces[hit.face as usize];
            (0..3)
                .map(|k| hit.bary[k] as f64 * out.displacement[f[k] as usize])
                .sum()
        })
        .collect()
}

/// Mean wavelength of a signal sampled every 0.005: twice the length over the sign changes,
/// counting a change only once the signal leaves ±0.25 std (hysteresis).
fn mean_wavelength(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
    let (mut last, mut changes) = (0i8, 0usize);
    for x in v {
        let s = if x - m > 0.25 * sd {
            1
        } else if x - m < -0.25 * sd {
            -1
        } else {
            0
        };
        if s != 0 && last != 0 && s != last {
            changes += 1;
        }
        if s != 0 {
            last = s;
        }
    }
    2.0 * 0.005 * v.len() as f64 / changes.max(1) as f64
}

fn params(levels: usize, finest: f64) -> retex::engine::methods::detail::pipeline::PipelineParams {
    let p = DetailParams {
        levels,
        ..DetailParams::default()
    };
    let mut out = p.pipeline(1.0, 1.0);
    out.hierarchy.finest_edge_length = Some(finest);
    out
}

#[test]
fn rings_keep_their_world_wavelength_on_a_target_stretched_twice() {
    let (detailed, base) = ringed_capsule();
    // The target: the same capsule, its right half (x > 2) stretched 2× (x ∈ [0, 6]).
    let profile: Vec<f32> = (0..=100).map(|i| 4.0 * i as f32 / 100.0).collect();
    let target = capsule(RADIUS, &profile, 80, stretch_beyond_two);
    let out = transfer_detail(
        &detailed,
        Some(&base),
        &target,
        &params(3, 0.035),
        &Control::new(),
    )
    .unwrap();
    // Source wavelengths: 0.25-0.375 over x ∈ [0, 2], 0.375-0.5 over [2, 4]. Projection maps
    // the target's x ∈ [2, 6] onto the source's [2, 4]: wavelengths 0.75-1.0 there.
    let left = mean_wavelength(&along_top(&out, 0.3, 1.7));
    let right = mean_wavelength(&along_top(&out, 2.5, 5.5));
    let source_left = mean_wavelength(
        &(0..280)
            .map(|i| (std::f64::consts::TAU * ring_phase(0.3 + 0.005 * i as f64)).sin())
            .collect::<Vec<_>>(),
    );
    println!(
        "wavelength: unstretched part {left:.3} (source there {source_left:.3}), stretched part \
         {right:.3} (source 0.31-0.5, projection 0.75-1.0)"
    );
    // Measured: unstretched 0.280 (source 0.311 there: ×0.90), stretched 0.500 (projection:
    // 0.75-1.0), the same at finest edges 0.03, 0.04 and 0.045. With 8 candidates instead of 16
    // the stretched part reads 0.667 at 0.03 and 0.035: the learned metric weights the box
    // coordinates (the source's wavelength grows along x), the 8 nearest samples lie around one
    // ring in one phase, and the patches drift into a stretched copy (README "detail", the sweep
    // of λ and K).
    assert!(
        (0.7..=1.4).contains(&(left / source_left)),
        "{left} vs {source_left}"
    );
    assert!(
        right < 0.6 && right > 0.8 * ring_wavelength(0.3),
        "stretched part {right}"
    );
}

fn std_dev(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len().max(1) as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Displacement std over vertices with the unit direction's y in `range`.
fn band_std(s: &Surface, d: &[f64], range: std::ops::Range<f64>) -> f64 {
    let v: Vec<f64> = (s.positions.iter().zip(d))
        .filter(|(p, _)| {
            let l = p.iter().map(|c| (*c as f64).powi(2)).sum::<f64>().sqrt();
            range.contains(&(p[1] as f64 / l))
        })
        .map(|(_, d)| *d)
        .collect();
    std_dev(&v)
}

/// Detail std on the upper and on the lower half.
type UpperLower = (f64, f64);

/// A unit sphere with bumps on its upper half (detailed, base, the bump field) and B, an
/// ellipsoid.
fn bumped_sphere_and_ellipsoid() -> (Surface, Surface, Surface, impl Fn([f64; 3]) -> f64) {
    let base_a = jittered_sphere(1.0, 32, 0.0);
    let bumps = |q: [f64; 3]| {
        let w = std::f64::consts::TAU / 0.25;
        0.02 * (q[1] / 0.2).clamp(0.0, 1.0) * (w * q[0]).sin() * (w * q[2]).sin()
    };
    let mut detailed_a = base_a.clone();
    for p in detailed_a.positions.iter_mut() {
        let q = p.map(f64::from);
        *p = q.map(|x| (x * (1.0 + bumps(q))) as f32);
    }
    let base_b = Surface::from_triangles(
        base_a
            .positions
            .iter()
            .map(|p| [1.2 * p[0], p[1], 0.85 * p[2]])
            .collect(),
        base_a.faces.clone(),
    );
    (detailed_a, base_a, base_b, bumps)
}

/// A → B → A (Fig. 15) with the default parameters. Returns the detail std (upper, lower) of
/// A → B and of A → B → A.
fn round_trip() -> (UpperLower, UpperLower) {
    let (detailed_a, base_a, base_b, bumps) = bumped_sphere_and_ellipsoid();
    let control = Control::new();
    let p = params(3, 0.04);
    let ab = transfer_detail(&detailed_a, Some(&base_a), &base_b, &p, &control).unwrap();
    let normals = area_weighted_normals(&ab.surface);
    let detailed_b = Surface::from_triangles(
        (ab.surface.positions.iter().zip(&normals))
            .zip(&ab.displacement)
            .map(|((q, n), d)| std::array::from_fn(|k| (q[k] as f64 + d * n[k]) as f32))
            .collect(),
        ab.surface.faces.clone(),
    );
    let aba = transfer_detail(&detailed_b, Some(&ab.surface), &base_a, &p, &control).unwrap();
    // A's own detail on the same hierarchy: A → A.
    let aa = transfer_detail(&detailed_a, Some(&base_a), &base_a, &p, &control).unwrap();
    let stats = |o: &DetailTransfer| {
        (
            band_std(&o.surface, &o.displacement, 0.3..0.95),
            band_std(&o.surface, &o.displacement, -0.95..-0.3),
        )
    };
    let (src_up, _) = {
        let d: Vec<f64> = base_a
            .positions
            .iter()
            .map(|q| bumps(q.map(f64::from)))
            .collect();
        (band_std(&base_a, &d, 0.3..0.95), 0.0)
    };
    let (aa_up, aa_low) = stats(&aa);
    let (ab_up, ab_low) = stats(&ab);
    let (aba_up, aba_low) = stats(&aba);
    println!(
        "detail std upper / lower: source {src_up:.5}; A→A \
         {aa_up:.5} / {aa_low:.5}; A→B {ab_up:.5} / {ab_low:.5}; A→B→A {aba_up:.5} / {aba_low:.5}"
    );
    ((ab_up, ab_low), (aba_up, aba_low))
}

#[test]
fn a_to_b_to_a_keeps_the_detail_on_the_upper_half() {
    // Fig. 15's stability. Measured: A→A 0.00758 / 0.00000, A→B 0.00739 / 0.00000, A→B→A
    // 0.00540 / 0.00000 (source 0.00998). With the absolute λ (whose metric is zero, below) and
    // 8 candidates it was A→B 0.00420 / 0.00080, A→B→A 0.00340 / 0.00240: the detail spread to
    // the lower half.
    let ((ab_up, ab_low), (aba_up, aba_low)) = round_trip();
    assert!(
        ab_up > 0.004 && ab_low < 0.1 * ab_up,
        "A→B: {ab_up} / {ab_low}"
    );
    assert!(
        aba_up > 0.003 && aba_low < 0.1 * aba_up,
        "A→B→A moved the detail: {aba_up} / {aba_low}"
    );
    assert!(
        (0.5..=1.5).contains(&(aba_up / ab_up)),
        "B→A changed the detail's energy: {aba_up} vs {ab_up}"
    );
}

#[test]
fn an_absolute_lambda_leaves_the_metric_zero_and_the_relative_one_does_not() {
    // The detail features are world-unit displacement deviations (bumps of 0.02 here), so with
    // λ = 0.1 absolute the ℓ1 term wins and `M` is solver residue: the report must say so. The
    // default (λ relative to `B̂`'s largest diagonal entry) learns a metric.
    let (detailed_a, base_a, base_b, _) = bumped_sphere_and_ellipsoid();
    let control = Control::new();
    for relative in [false, true] {
        let mut p = params(3, 0.04);
        p.lambda_relative = relative;
        let out = transfer_detail(&detailed_a, Some(&base_a), &base_b, &p, &control).unwrap();
        let m = &out.report.metric;
        println!(
            "lambda_relative {relative}: zero_metric {}, top eigenvalue {:.3e}, rank {}",
            m.zero_metric, m.top_eigenvalue, m.rank
        );
        assert_eq!(m.zero_metric, !relative, "lambda_relative {relative}");
    }
}

/// Detail std on the treads ÷ on the risers of a tiers surface (tread: y on an integer, z inside
/// its tread; riser: z on an integer, y inside its riser).
fn tread_ratio(s: &Surface, d: &[f64]) -> (f64, f64) {
    let frac = |x: f64| x - x.floor();
    let on = |x: f64| (x - x.round()).abs() < 0.01;
    let inside = |x: f64| (0.15..0.85).contains(&frac(x));
    let (mut tread, mut riser) = (Vec::new(), Vec::new());
    for (p, v) in s.positions.iter().zip(d) {
        let (y, z) = (p[1] as f64, p[2] as f64);
        if on(y) && inside(z) && y > 0.5 {
            tread.push(*v);
        } else if on(z) && inside(y) {
            riser.push(*v);
        }
    }
    (std_dev(&tread), std_dev(&riser))
}

#[test]
fn learned_and_equal_weights_both_put_tread_detail_on_treads_through_the_method() {
    // The paper's Fig. 16a case shape (detail follows one feature, not position), run through
    // the whole pipeline: source 5 tiers (width 2.5) with bumps on the treads, targets of 4 and
    // 5 tiers (width 2). Measured: treads / risers std, learned 0.00228 / 0.00000 (4 tiers) and
    // 0.00229 / 0.00000 (5), its diagonal 0.99 on the normals; identity 0.00140 / 0.00007 and
    // 0.00187 / 0.00007 (with 8 candidates 0.00194 / 0.00000 and 0.00214 / 0.00000). Both put the
    // detail where the normals say (the normals are bimodal here and decide for equal weights
    // too); the learned metric keeps 1.2-1.6 times the energy. Fig. 16a's case, where equal
    // weights fail, is `detail_equal_weights`.
    use crate::detail_features::metric_features::tiers;
    use retex::engine::methods::detail::metric::MetricKind;
    let (base, on_tread, _) = tiers(5, 1.0, 1.0, 2.5, 0.05);
    let mut detailed = base.clone();
    for (p, t) in detailed.positions.iter_mut().zip(&on_tread) {
        if *t {
            let w = std::f64::consts::TAU / 0.25;
            p[1] += (0.01 * (w * p[0] as f64).sin() * (w * p[2] as f64).sin()) as f32;
        }
    }
    let control = Control::new();
    for steps in [4usize, 5] {
        let (target, _, _) = tiers(steps, 1.0, 1.0, 2.0, 0.05);
        for kind in [MetricKind::Learned, MetricKind::Identity] {
            let mut p = params(3, 0.05);
            p.metric_kind = kind;
            let out = transfer_detail(&detailed, Some(&base), &target, &p, &control).unwrap();
            let (t, r) = tread_ratio(&out.surface, &out.displacement);
            println!(
                "{steps}-tier target, {kind:?}: treads {t:.5}, risers {r:.5} (metric diagonal by \
                 group {:?})",
                out.report.metric.diagonal_by_group
            );
            let least = match kind {
                MetricKind::Learned => 0.0015,
                MetricKind::Identity => 0.001,
            };
            assert!(t > least, "{steps} tiers, {kind:?}: treads {t}");
            assert!(
                t > 10.0 * r,
                "{steps} tiers, {kind:?}: treads {t}, risers {r}"
            );
        }
    }
}
