//! The texture-statistics metric of issue 14 (item 1) as a test helper
//! ([`crate::meshmatch_common::color_statistics`]: k-means k = 5 in sRGB on area-uniform samples,
//! area shares, total-variation distance), checked against known answers, and MeshMatch held to
//! it on a synthetic pair where a constant or a copy-free result fails.

use crate::common::{assert_validator_clean, load_bytes};
use crate::common_geometry::stretch_beyond_two;
use crate::meshmatch_common::{
    capsule, color_statistics, glb_of, run_bytes, statistics_of_samples,
};

/// Known answers: a set of samples against itself (TV 0, every ratio 1), against a constant
/// (the largest cluster only: TV = 1 − its share), and against the same colours in other
/// proportions (TV = the moved share).
#[test]
fn statistics_metric_known_answers() {
    let colors = [[0.9f32, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.9]];
    // 50% red, 30% green, 20% blue.
    let make = |shares: [usize; 3]| -> Vec<[f32; 3]> {
        (0..3)
            .flat_map(|k| std::iter::repeat_n(colors[k], shares[k] * 100))
            .collect()
    };
    let source = make([50, 30, 20]);
    let same = statistics_of_samples(&source, &source);
    assert!(
        same.tv < 1e-9 && same.worst_ratio == 1.0 && same.kept(),
        "{same}"
    );
    let constant = statistics_of_samples(&source, &make([100, 0, 0]));
    assert!((constant.tv - 0.5).abs() < 1e-9, "{constant}");
    assert!(!constant.kept(), "{constant}");
    let moved = statistics_of_samples(&source, &make([40, 40, 20]));
    assert!((moved.tv - 0.1).abs() < 1e-9, "{moved}");
    assert!(moved.kept(), "{moved}");
    let halved = statistics_of_samples(&source, &make([65, 30, 5]));
    assert!(!halved.kept(), "blue at a quarter of its share: {halved}");
}

/// Three-colour bands (red 50%, green 30%, blue 20% of every 0.8 period) on a capsule, transferred
/// onto the capsule with its far half stretched 2× (no correspondences, HKS features): the output
/// keeps the source's colour statistics (each cluster within 0.5-2×, TV ≤ 0.12), where a constant
/// output (the source's main colour everywhere) fails. Seeds 1-3.
#[test]
fn meshmatch_keeps_the_colour_statistics_of_bands() {
    let profile = |step: f32| -> Vec<f32> {
        let n = (4.0 / step).round() as usize;
        (0..=n).map(|i| 4.0 * i as f32 / n as f32).collect()
    };
    let band = |x: f32| -> [f32; 4] {
        let f = (x / 0.8).rem_euclid(1.0);
        if f < 0.5 {
            [0.8, 0.05, 0.05, 1.0]
        } else if f < 0.8 {
            [0.05, 0.6, 0.05, 1.0]
        } else {
            [0.05, 0.05, 0.8, 1.0]
        }
    };
    let (sp, st) = capsule(0.5, &profile(0.05), 48, |x| x);
    let colors: Vec<[f32; 4]> = sp.iter().map(|p| band(p[0])).collect();
    let source = glb_of(&sp, &st, Some(&colors));
    let (tp, tt) = capsule(0.5, &profile(0.03), 48, stretch_beyond_two);
    let target = glb_of(&tp, &tt, None);
    let source_asset = load_bytes(&source, "source.glb");
    for seed in 1..=3u64 {
        let out = run_bytes(
            ("source.glb", source.clone()),
            ("target.glb", target.clone()),
            serde_json::json!({"version": 1, "method": "meshmatch", "seed": seed,
                "output": {"vertex_colors": true},
                "params": {"samples": 8192, "scale": "world"}}),
        );
        assert_validator_clean(&out.model, "meshmatch_bands.glb");
        let stats = color_statistics(&source_asset, &load_bytes(&out.model, "out.glb"));
        eprintln!("seed {seed}: {stats}");
        assert!(stats.kept(), "seed {seed}: {stats}");
        // The constant baseline: the source's largest cluster everywhere.
        let main = (0..5)
            .max_by(|&a, &b| stats.source[a].total_cmp(&stats.source[b]))
            .unwrap();
        let constant = statistics_of_samples(
            &crate::meshmatch_common::area_uniform_colors(&source_asset, 20_000, 11),
            &vec![stats.centers[main]; 1000],
        );
        assert!(!constant.kept(), "{constant}");
    }
}
