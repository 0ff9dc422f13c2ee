//! Random restarts of MeshMatch's coarsest level (`params.coarsest_restarts`, ours; module
//! `coarse_to_fine::restarts`), on a striped capsule onto a copy whose far half is stretched 2×
//! (made in code, 4K samples): the coarsest level reports one final energy per start, keeps the
//! lowest, and its first start is the single start of `coarsest_restarts` 1. The quality effect is
//! tested on the real pairs (`meshmatch_real_pairs`: Blub → fish seed 4).

use crate::common_geometry::stretch_beyond_two;
use crate::meshmatch_common::{capsule, glb_of, profile, run_bytes, stripe_colors};

/// The coarsest level's report of a transfer with `restarts` starts and seed `seed`.
fn coarsest_level(restarts: usize, seed: u64) -> serde_json::Value {
    let make = |warp: fn(f32) -> f32| capsule(0.5, &profile(0.0, 4.0, 4.0 / 64.0), 48, warp);
    let (sp, sf) = make(|x| x);
    let colors = stripe_colors(&sp);
    let (tp, tf) = make(stretch_beyond_two);
    let out = run_bytes(
        ("source.glb", glb_of(&sp, &sf, Some(&colors))),
        ("target.glb", glb_of(&tp, &tf, None)),
        serde_json::json!({"version": 1, "method": "meshmatch", "seed": seed,
            "output": {"vertex_colors": true},
            "params": {"samples": 4096, "coarsest_restarts": restarts}}),
    );
    out.report.method_report["synthesis"]["levels"][0].clone()
}

fn final_energy(level: &serde_json::Value) -> f64 {
    let iterations = level["iterations"].as_array().unwrap();
    iterations.last().unwrap()["energy"].as_f64().unwrap()
}

#[test]
fn the_coarsest_level_keeps_the_lowest_energy_of_its_starts() {
    for seed in [1, 2] {
        let single = coarsest_level(1, seed);
        assert_eq!(single["restart_energies"].as_array().unwrap().len(), 0);
        let several = coarsest_level(4, seed);
        let energies: Vec<f64> = several["restart_energies"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e.as_f64().unwrap())
            .collect();
        eprintln!(
            "seed {seed}: single start {:.4}, starts {energies:?}, kept {:.4}",
            final_energy(&single),
            final_energy(&several)
        );
        assert_eq!(energies.len(), 4, "{several}");
        assert_eq!(
            energies[0],
            final_energy(&single),
            "the first start is the old one"
        );
        let lowest = energies.iter().copied().fold(f64::INFINITY, f64::min);
        assert_eq!(final_energy(&several), lowest, "{several}");
        assert!(
            energies.iter().any(|&e| e != energies[0]),
            "the starts differ: {energies:?}"
        );
    }
}
