//! The `correlation` method's non-parametric synthesis (issue 11, item 6; Mertens et al. 2006
//! §5.1) on the procedural weathering case of `correlation.rs` (shared builders in
//! `correlation_common.rs`): the output's dirtiness follows f on the target (at least 0.7× the
//! source's own correlation) and beats a constant and a random-copy baseline; Ashikhmin
//! coherence makes larger coherent patches than none. And the half-scanned source (the paper's
//! Fig. 8): only the upper half of the source is present, so the target's down-facing parts
//! have guidance values the source never had; with feature matching the output's colours spread
//! over the source's whole range, without it they collapse onto the extremes it saw.

use retex::engine::mesh::Surface;
use retex::engine::rng::SplitMix64;
use serde_json::json;

use crate::correlation_common::{
    at_points, case, case_b, dirt_terms, luminance, pearson, source_shape, target_shape,
    tercile_shares, transfer_named, weathered, Case, Dirt,
};
use crate::meshmatch_common::glb_of;

fn neg_lum(c: &[[f32; 3]]) -> Vec<f32> {
    c.iter().map(|x| -luminance(*x)).collect()
}

fn source_rgb(c: &Case) -> Vec<[f32; 3]> {
    c.source_colors.iter().map(|x| [x[0], x[1], x[2]]).collect()
}

#[test]
fn nonparametric_weathering_follows_the_targets_geometry() {
    // Sweep (README, `correlation_sweep.rs`): both procedural cases, seeds 1-3 of the noise and
    // of the search; here seeds 1, 2 of the first case and seed 1 of the second.
    for (seed, c) in [(1u64, case(1)), (2, case(2)), (1, case_b(1))] {
        let src_lum = neg_lum(&source_rgb(&c));
        let r_source = pearson(&src_lum, &c.source_f);
        let np = json!({"synthesis": "nonparametric"});
        let (pts, colors, report) =
            transfer_named(&c, np, seed, Some(&format!("nonparametric_{seed}")));
        let f_out = at_points(&c.target, &c.target_f, &pts);
        let r_np = pearson(&neg_lum(&colors), &f_out);
        // Baselines: a constant, and every point copying a random source vertex's colour.
        let r_constant = pearson(&vec![0.5; f_out.len()], &f_out);
        let mut rng = SplitMix64::new(seed);
        let random: Vec<f32> = (0..f_out.len())
            .map(|_| src_lum[rng.below(src_lum.len() as u64) as usize])
            .collect();
        let r_random = pearson(&random, &f_out);
        let shares = tercile_shares(
            &src_lum.iter().map(|x| -x).collect::<Vec<_>>(),
            &colors.iter().map(|x| luminance(*x)).collect::<Vec<_>>(),
        );
        let npr = &report["nonparametric"];
        eprintln!(
            "seed {seed}: r source {r_source:.3}, nonparametric {r_np:.3}, constant {r_constant:.3}, random copy {r_random:.3}; tercile shares {shares:.3?}; coherent edges {}, mean patch {}",
            npr["coherent_edges"], npr["mean_patch_samples"]
        );
        assert!(
            r_np >= 0.7 * r_source,
            "seed {seed}: {r_np:.3} < 0.7 × {r_source:.3}"
        );
        assert!(r_constant.abs() < 0.1 && r_random.abs() < 0.1);
        assert!(r_np > r_random.abs() + 0.3);
        assert!(
            shares.iter().all(|s| (s - 1.0 / 3.0).abs() < 0.12),
            "seed {seed}: {shares:?}"
        );
        assert!(report.get("synthesis").is_none(), "no parametric report");
        assert_eq!(npr["levels"].as_array().unwrap().len(), 3);
    }
}

#[test]
fn coherence_makes_larger_coherent_patches() {
    let mut measured = Vec::new();
    for (seed, c) in [(3u64, case(3)), (4, case(4)), (3, case_b(3))] {
        let patch = |kappa: f32| {
            let (pts, colors, report) = transfer_named(
                &c,
                json!({"synthesis": "nonparametric", "nonparametric": {"coherence": kappa}}),
                seed,
                Some(&format!("coherence_{kappa}_{seed}")),
            );
            let f_out = at_points(&c.target, &c.target_f, &pts);
            let r = pearson(&neg_lum(&colors), &f_out);
            let npr = &report["nonparametric"];
            let p = npr["mean_patch_samples"].as_f64().unwrap();
            let e = npr["coherent_edges"].as_f64().unwrap();
            eprintln!("seed {seed}, κ {kappa}: mean patch {p:.1} samples, coherent edges {e:.3}, r {r:.3}");
            (p, e, r)
        };
        measured.push((seed, patch(0.0), patch(1.0), patch(4.0)));
    }
    for (seed, (p0, e0, _), (p1, e1, r1), (p4, _, _)) in measured {
        // Sweep (README, `correlation_sweep.rs`: both cases × seeds 1-4): κ = 1 over κ = 0
        // mean patch 1.58-2.35×, coherent edges +0.047 to +0.059, κ = 4 ≥ κ = 1 in every run.
        // Here: seeds 3, 4 of the first case (mean patch 137 / 176 → 269 / 305 → 322 / 774
        // samples at κ = 0 / 1 / 4) and seed 3 of the second (31 → 54 → 64).
        assert!(p1 > 1.4 * p0, "seed {seed}: κ=1 {p1:.1} vs κ=0 {p0:.1}");
        assert!(e1 > e0 + 0.03, "seed {seed}: {e1:.3} vs {e0:.3}");
        assert!(p4 >= p1, "seed {seed}: κ=4 {p4:.1} vs κ=1 {p1:.1}");
        assert!(
            r1 > 0.3,
            "seed {seed}: coherence lost the placement ({r1:.3})"
        );
    }
}

/// The faces of `s` whose three corners have y above `cut` (vertices renumbered).
fn upper_part(s: &Surface, colors: &[[f32; 4]], cut: f32) -> (Surface, Vec<[f32; 4]>) {
    let mut map = vec![u32::MAX; s.vertex_count()];
    let (mut pos, mut col, mut faces) = (Vec::new(), Vec::new(), Vec::new());
    for f in &s.faces {
        if f.iter().all(|&v| s.positions[v as usize][1] > cut) {
            faces.push(f.map(|v| {
                if map[v as usize] == u32::MAX {
                    map[v as usize] = pos.len() as u32;
                    pos.push(s.positions[v as usize]);
                    col.push(colors[v as usize]);
                }
                map[v as usize]
            }));
        }
    }
    (Surface::from_triangles(pos, faces), col)
}

/// Largest deviation from ⅓ of the output's area shares in the source's luminance terciles.
fn tercile_deviation(source_lum: &[f32], colors: &[[f32; 3]]) -> f64 {
    let lum: Vec<f32> = colors.iter().map(|c| luminance(*c)).collect();
    tercile_shares(source_lum, &lum)
        .iter()
        .map(|s| (s - 1.0 / 3.0).abs())
        .fold(0.0, f64::max)
}

#[test]
fn feature_matching_fills_what_a_half_scanned_source_never_saw() {
    // The source's colour is made on the whole shape (the real object); only its upper half is
    // "scanned". The target is the whole of a different shape: its lower half faces down, which
    // the scan never saw.
    let full = source_shape();
    let target = target_shape();
    let ts = dirt_terms(&full);
    let dirt = Dirt::fit(&ts);
    let full_f: Vec<f32> = ts.iter().map(|t| dirt.f(*t)).collect();
    let mut measured = Vec::new();
    for (seed, synthesis) in [
        (1u64, "parametric"),
        (2, "parametric"),
        (1, "nonparametric"),
    ] {
        let colors = weathered(&full_f, seed);
        let (half, half_colors) = upper_part(&full, &colors, 0.0);
        assert!(half.face_count() * 5 > full.face_count() * 2);
        let c = Case {
            source_glb: glb_of(&half.positions, &half.faces, Some(&half_colors)),
            target_glb: glb_of(&target.positions, &target.faces, None),
            source: half,
            target: target.clone(),
            source_f: Vec::new(),
            target_f: Vec::new(),
            source_colors: half_colors.clone(),
        };
        let src_lum: Vec<f32> = half_colors
            .iter()
            .map(|x| luminance([x[0], x[1], x[2]]))
            .collect();
        let mut dev = Vec::new();
        for matching in ["off", "marginals", "multiscale"] {
            let (_, out, _) = transfer_named(
                &c,
                json!({"synthesis": synthesis, "feature_matching": matching}),
                seed,
                Some(&format!("half_{synthesis}_{matching}_{seed}")),
            );
            dev.push(tercile_deviation(&src_lum, &out));
        }
        eprintln!(
            "seed {seed}, {synthesis}: tercile deviation off {:.3}, marginals {:.3}, multiscale {:.3}",
            dev[0], dev[1], dev[2]
        );
        measured.push((seed, dev));
    }
    for (seed, dev) in measured {
        // Measured: off 0.327 / 0.314 (parametric, seeds 1, 2), 0.381 (nonparametric); marginals
        // 0.117 / 0.111 / 0.111; multiscale 0.112 / 0.113 / 0.104. The matched outputs keep
        // the ~0.11 the interpolation from samples leaves on a whole source too (correlation.rs).
        assert!(dev[0] > 0.25, "seed {seed}: without matching {:.3}", dev[0]);
        assert!(dev[1] < 0.13 && dev[2] < 0.13, "seed {seed}: {dev:.3?}");
        assert!(dev[2] < 0.5 * dev[0], "seed {seed}: {dev:.3?}");
    }
}
