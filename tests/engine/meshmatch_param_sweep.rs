//! Issue 14, item 1: parameter sweeps of `meshmatch` on three real pairs without
//! correspondences, measured on the output files (benchmark, ignored; run with
//! `cargo test --release --test engine bench_meshmatch_param_sweep -- --ignored --nocapture`).
//! For each pair, parameter set and seed it prints the output's colour statistics against the
//! source's (k-means k = 5 in sRGB on area-uniform samples; TV and the worst ratio of a ≥ 5%
//! cluster), the figures of the README's sweep table. `RETEX_MESHMATCH_SWEEP` replaces the
//! default sets with a JSON array of `params` objects.

use crate::common::{load_bytes, shared_asset};
use crate::meshmatch_common::{color_statistics, run_bytes};

const PAIRS: [(&str, &str, &str); 3] = [
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

fn bytes(rel: &str) -> (String, Vec<u8>) {
    let p = shared_asset(rel);
    (
        p.file_name().unwrap().to_string_lossy().into_owned(),
        std::fs::read(&p).unwrap(),
    )
}

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
    for (src, tgt, name) in PAIRS {
        let (sn, sb) = bytes(src);
        let (tn, tb) = bytes(tgt);
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
                        "output": {"texture_size": 512, "padding": 4, "uv": "keep"},
                        "params": params}),
                );
                let stats = color_statistics(&source, &load_bytes(&out.model, "out.glb"));
                println!(
                    "SWEEP {name} {set} seed {seed}: TV {:.3} worst {:.2} kept {} | {stats}",
                    stats.tv,
                    stats.worst_ratio,
                    stats.kept()
                );
            }
        }
    }
}
