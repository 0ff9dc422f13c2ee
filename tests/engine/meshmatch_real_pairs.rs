//! Issue 14, item 1, with correspondences: the three real pairs of the parameter sweep, each with
//! semantic landmarks placed by hand, keep the source's colour statistics (k-means k = 5 in sRGB
//! on area-uniform samples: every cluster covering at least 5% of the source keeps 0.5-2× its
//! share, TV distance of the shares ≤ 0.12, the issue's own targets). With correspondences the
//! shape features are geodesic affinities and the vote is the paper's σ = 0.5 with histogram
//! matching at λ = 2 (`vote_schedule`); without histogram matching the Fox → koala pair loses
//! the fox's white (17.8% → 4%, TV 0.14), which this test catches.

use crate::common::{assert_validator_clean, load_bytes};
use crate::meshmatch_common::{color_statistics, run_bytes};
use crate::meshmatch_transfer::shared_bytes;
use retex::engine::pipeline::TransferOutput;

/// The real pairs: (source, target, name), paths under the shared assets.
pub const PAIRS: [(&str, &str, &str); 3] = [
    (
        "src_spot_keenan/spot_textured_derived.glb",
        "tgt_cat_odedstein/cat-low-resolution_derived.glb",
        "spot→cat",
    ),
    (
        "src_blub_keenan/blub_textured_derived.glb",
        "tgt_fish_remeshed_odedstein/fish_low_resolution_derived.glb",
        "blub→fish",
    ),
    (
        "src_fox_khronos/glTF-Binary/Fox.glb",
        "perf_koala_odedstein/koala_low_resolution_derived.glb",
        "fox→koala",
    ),
];

/// Semantic landmarks of the real pairs, placed on previews with markers (2026-12-05):
/// `(source point, target point)` in each file's world frame.
/// - Spot faces −z with its left at −x; the cat faces −x with its left at +z: nose, left and
///   right ear tips, the four feet (front left, front right, hind left, hind right), the tail's
///   end.
/// - Blub and the fish share one frame and one shape: the extremes along six axes (snout, tail
///   fin, top fin, belly, both sides).
/// - The Fox and the koala both stand facing +z with their left at +x: nose, ear tips, the four
///   feet, the hind end (the fox's tail tip, the koala's rump).
pub fn pair_correspondences(name: &str) -> Option<serde_json::Value> {
    let pairs: &[([f32; 3], [f32; 3])] = match name {
        "spot→cat" => &[
            ([0.0, 0.301, -0.669], [-0.942, 0.987, -0.116]),
            ([-0.472, 0.709, -0.199], [-0.421, 1.251, 0.015]),
            ([0.472, 0.709, -0.199], [-0.4, 1.194, -0.401]),
            ([-0.289, -0.705, -0.033], [-1.499, 0.132, 0.035]),
            ([0.289, -0.705, -0.033], [-1.516, 0.106, -0.186]),
            ([-0.247, -0.712, 0.845], [1.235, 0.03, 0.472]),
            ([0.247, -0.712, 0.845], [1.169, 0.007, -0.46]),
            ([0.0, -0.069, 1.048], [1.003, 3.458, -0.157]),
        ],
        "blub→fish" => &[
            ([0.0, -0.063, 0.997], [-0.037, -0.07, 0.999]),
            ([0.0, 0.397, -1.911], [0.013, 0.386, -1.915]),
            ([0.0, 1.078, -0.038], [-0.017, 1.083, -0.05]),
            ([0.653, -0.669, -0.469], [0.647, -0.672, -0.462]),
            ([0.711, -0.375, -0.521], [0.712, -0.395, -0.537]),
            ([-0.711, -0.375, -0.521], [-0.71, -0.326, -0.548]),
        ],
        "fox→koala" => &[
            ([0.0, 53.72, 66.625], [-0.088, 2.056, 4.979]),
            ([12.593, 78.907, 50.617], [1.365, 3.953, 3.397]),
            ([-12.593, 78.907, 50.617], [-1.475, 3.884, 3.288]),
            ([7.095, 0.225, 25.209], [1.075, -1.357, 2.106]),
            ([-7.095, 0.225, 25.209], [-1.287, -1.361, 1.897]),
            ([9.313, -0.102, -31.926], [1.134, -1.374, -3.418]),
            ([-9.313, -0.102, -31.926], [-1.078, -1.366, -3.493]),
            ([0.0, 20.145, -88.095], [0.059, 1.578, -4.234]),
        ],
        _ => return None,
    };
    Some(serde_json::Value::Array(
        pairs
            .iter()
            .map(|(s, t)| serde_json::json!({"source": {"point": s}, "target": {"point": t}}))
            .collect(),
    ))
}

/// One real-pair transfer as the statistics tests and the parameter sweep run it: 16K samples,
/// `params` over the defaults, `corr` the correspondences, a 512² texture in the target's UVs.
pub fn run_pair(
    source: (&str, &[u8]),
    target: (&str, &[u8]),
    corr: &serde_json::Value,
    params: &serde_json::Value,
    seed: u64,
) -> TransferOutput {
    let mut p = serde_json::json!({"samples": 16384});
    for (k, v) in params.as_object().unwrap() {
        p[k] = v.clone();
    }
    run_bytes(
        (source.0, source.1.to_vec()),
        (target.0, target.1.to_vec()),
        serde_json::json!({"version": 1, "method": "meshmatch", "seed": seed,
            "correspondences": corr,
            "output": {"texture_size": 512, "padding": 4, "uv": "keep"},
            "params": p}),
    )
}

/// Runs every pair at 16K samples on each of `seeds`, with `params` and the pair's landmarks
/// when `with_correspondences`, and asserts the statistics targets (TV ≤ 0.12, every
/// ≥ 5% cluster within 0.5-2×) on the output file.
fn assert_pairs_keep_the_statistics(
    with_correspondences: bool,
    params: serde_json::Value,
    label: &str,
    seeds: &[u64],
) {
    let mut failures = Vec::new();
    for (src, tgt, name) in PAIRS {
        let corr = if with_correspondences {
            pair_correspondences(name).unwrap()
        } else {
            serde_json::json!([])
        };
        let (sn, sb) = shared_bytes(src);
        let (tn, tb) = shared_bytes(tgt);
        for &seed in seeds {
            let out = run_pair((&sn, &sb), (&tn, &tb), &corr, &params, seed);
            let file = format!("meshmatch_{label}_{}_{seed}.glb", name.replace('→', "_"));
            assert_validator_clean(&out.model, &file);
            let stats = color_statistics(&load_bytes(&sb, &sn), &load_bytes(&out.model, &file));
            eprintln!("{name} {label} seed {seed}: {stats}");
            if !(stats.tv <= 0.12 && stats.worst_ratio <= 2.0) {
                failures.push(format!(
                    "{name} {label} seed {seed}: TV {:.3}, worst ratio {:.2}",
                    stats.tv, stats.worst_ratio
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "statistics targets (TV ≤ 0.12, worst ratio ≤ 2) missed: {failures:?}"
    );
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn real_pairs_with_correspondences_keep_the_source_statistics() {
    assert_pairs_keep_the_statistics(true, serde_json::json!({}), "corr", &[1]);
}

/// Without correspondences, at the defaults (HKS features in the source's unit, times up to a
/// quarter of `t_max`, clamped to the source's range; region flips on the two coarsest levels;
/// the finest-colour histogram cost at 0.3, README "Finest-colour histogram cost"), seeds 1, 7
/// and 8, "TV / worst ratio": Spot → cat 0.029 / 1.12, 0.058 / 1.80, 0.034 / 1.20; Blub → fish
/// 0.039 / 1.58, 0.029 / 1.27, 0.037 / 1.50; Fox → koala 0.085 / 1.79, 0.100 / 1.88,
/// 0.099 / 1.87. Seeds 7 and 8 are the first two where the defaults missed before the
/// finest-colour cost (Spot → cat's black patches shrank to dots: worst ratio 8.69 and 3.00),
/// so the test fails with `fine_histogram_cost` 0. Over seeds 1-30 the defaults meet the
/// targets on 87 of 90 runs (81 before the restarts on a deviation removed Blub's orange face,
/// `blub_orange_face_seed_is_restarted_on_its_deviation`); the misses are two Blub runs at
/// 2.01-2.04 and Fox → koala's seed 2 (TV 0.127), all listed in the README.
#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn real_pairs_without_correspondences_keep_the_source_statistics() {
    assert_pairs_keep_the_statistics(false, serde_json::json!({}), "plain", &[1, 7, 8]);
}

/// Blub → fish seed 11 without correspondences, one of the six seeds whose coarsest level
/// settles in the orange-face basin (README "Restarts on a deviation"): its first start's
/// finest-colour deviation is beyond the default limit, so the coarsest level runs four starts
/// and the output keeps the source's statistics; with the restarts on a deviation off
/// (`coarsest_restart_deviation` 0) the fish's face comes out orange (orange 23 % → 36 %, TV
/// 0.137).
#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn blub_orange_face_seed_is_restarted_on_its_deviation() {
    let (src, tgt, name) = PAIRS[1];
    let (sn, sb) = shared_bytes(src);
    let (tn, tb) = shared_bytes(tgt);
    let none = serde_json::json!([]);
    let run = |params: serde_json::Value, label: &str| {
        let out = run_pair((&sn, &sb), (&tn, &tb), &none, &params, 11);
        let file = format!("meshmatch_{label}_blub_fish_11.glb");
        assert_validator_clean(&out.model, &file);
        let stats = color_statistics(&load_bytes(&sb, &sn), &load_bytes(&out.model, &file));
        eprintln!("{name} {label} seed 11: {stats}");
        let levels = out.report.method_report["synthesis"]["levels"].clone();
        (stats, levels[0].clone())
    };
    let (stats, coarsest) = run(serde_json::json!({}), "deviation");
    let deviation = coarsest["first_start_deviation"].as_f64().unwrap();
    assert!(deviation > 0.916, "{coarsest}");
    assert_eq!(coarsest["restart_energies"].as_array().unwrap().len(), 4);
    assert!(stats.tv <= 0.12 && stats.worst_ratio <= 2.0, "{stats}");
    let (off, coarsest) = run(
        serde_json::json!({"coarsest_restart_deviation": 0}),
        "nodeviation",
    );
    assert_eq!(coarsest["restart_energies"].as_array().unwrap().len(), 0);
    assert!(off.tv > 0.12, "without the restarts the orange face: {off}");
}

/// With four random starts of the coarsest level (`coarsest_restarts` 4, an option; README
/// "Coarsest restarts"), seeds 1 and 4: Spot → cat 0.041 / 1.32, 0.075 / 1.57; Blub → fish
/// 0.042 / 1.71, 0.035 / 1.42; Fox → koala 0.096 / 1.83, 0.095 / 1.79 (measured before the
/// finest-colour cost). It failed with one start then (Blub → fish seed 4 came out with an
/// orange face, TV 0.127); the defaults now restart that seed on its deviation.
#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn real_pairs_with_coarsest_restarts_keep_the_source_statistics() {
    assert_pairs_keep_the_statistics(
        false,
        serde_json::json!({"coarsest_restarts": 4}),
        "restarts",
        &[1, 4],
    );
}

/// The E-step's histogram cost at 0.1 with four coarsest starts (two options; together they
/// bend the stripe cases' rings: 22 of 30 runs in bounds against the defaults' 29, README "Both
/// options for organic pairs"). Over seeds 1-30 they meet the targets on 89 of 90 runs without
/// correspondences (the defaults: 74; the one miss is Spot → cat's seed 3, an orange ring on
/// the cat's tail) and 89 of 90 with the landmarks (the defaults: 85). Seeds 4 and 7 are where
/// the defaults miss (Blub → fish seed 4: an orange face, TV 0.127; Spot → cat seed 7: the
/// black patches shrink to dots); four restarts alone miss on seed 7 too (worst ratio 8.69).
/// Seeds 1, 4, 7, "TV / worst ratio": Spot → cat 0.057 / 1.26, 0.051 / 1.31, 0.061 / 1.36;
/// Blub → fish 0.022 / 1.68, 0.021 / 1.63, 0.027 / 1.57; Fox → koala 0.061 / 1.35,
/// 0.079 / 1.52, 0.078 / 1.49. The setting was measured before the finest-colour histogram
/// cost became a default, and it is run here with that cost off (`fine_histogram_cost` 0): on
/// top of it the two costs over-correct Blub → fish (seeds 4 and 7: worst ratio 2.21, 2.24).
#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn real_pairs_with_the_histogram_cost_and_restarts_keep_the_source_statistics() {
    assert_pairs_keep_the_statistics(
        false,
        serde_json::json!({"histogram_cost": 0.1, "coarsest_restarts": 4, "fine_histogram_cost": 0}),
        "hcost",
        &[1, 4, 7],
    );
}
