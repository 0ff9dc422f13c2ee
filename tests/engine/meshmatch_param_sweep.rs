//! Issue 14, item 1: parameter sweeps of `meshmatch` on three real pairs without
//! correspondences, measured on the output files (benchmark, ignored; run with
//! `cargo test --release --test engine bench_meshmatch_param_sweep -- --ignored --nocapture`).
//! For each pair, parameter set and seed it prints the output's colour statistics against the
//! source's (k-means k = 5 in sRGB on area-uniform samples; TV and the worst ratio of a ≥ 5%
//! cluster), the figures of the README's sweep table. `RETEX_MESHMATCH_SWEEP` replaces the
//! default sets with a JSON array of `params` objects; `RETEX_MESHMATCH_SWEEP_CORR=1` adds the
//! pairs' hand-placed correspondences (`meshmatch_real_pairs`) to every run.

use crate::common::load_bytes;
use crate::meshmatch_common::{color_statistics, run_bytes};
use crate::meshmatch_real_pairs::{pair_correspondences, PAIRS};
use crate::meshmatch_transfer::shared_bytes;

#[test]
#[ignore = "benchmark: needs the shared assets; prints the parameter sweep"]
fn bench_meshmatch_param_sweep() {
    let sets: Vec<serde_json::Value> = match std::env::var("RETEX_MESHMATCH_SWEEP") {
        Ok(text) => serde_json::from_str(&text).expect("RETEX_MESHMATCH_SWEEP: a JSON array"),
        Err(_) => serde_json::from_str(
            r#"[{}, {"vote_sigma": 0.1}, {"completeness_weight": 1},
                {"vote_sigma": 0.1, "completeness_weight": 1}]"#,
        )
        .unwrap(),
    };
    let with_correspondences = std::env::var("RETEX_MESHMATCH_SWEEP_CORR").is_ok_and(|v| v == "1");
    for (src, tgt, name) in PAIRS {
        let corr = if with_correspondences {
            match pair_correspondences(name) {
                Some(c) => c,
                None => continue,
            }
        } else {
            serde_json::json!([])
        };
        let (sn, sb) = shared_bytes(src);
        let (tn, tb) = shared_bytes(tgt);
        let source = load_bytes(&sb, &sn);
        for set in &sets {
            for seed in [1u64, 2] {
                let mut params = serde_json::json!({"samples": 16384});
                for (k, v) in set.as_object().unwrap() {
                    params[k] = v.clone();
                }
                let out = run_bytes(
                    (&sn, sb.clone()),
                    (&tn, tb.clone()),
                    serde_json::json!({"version": 1, "method": "meshmatch", "seed": seed,
                        "correspondences": corr,
                        "output": {"texture_size": 512, "padding": 4, "uv": "keep"},
                        "params": params}),
                );
                let stats = color_statistics(&source, &load_bytes(&out.model, "out.glb"));
                println!(
                    "SWEEP {name}{} {set} seed {seed}: TV {:.3} worst {:.2} kept {} | {stats}",
                    if with_correspondences { " (corr.)" } else { "" },
                    stats.tv,
                    stats.worst_ratio,
                    stats.kept()
                );
            }
        }
    }
}
