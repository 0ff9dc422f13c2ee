//! Issue 14, item 1: parameter sweeps of `meshmatch` on three real pairs without
//! correspondences, measured on the output files (benchmark, ignored; run with
//! `cargo test --release --test engine bench_meshmatch_param_sweep -- --ignored --nocapture`).
//! For each pair, parameter set and seed it prints the output's colour statistics against the
//! source's (k-means k = 5 in sRGB on area-uniform samples; TV and the worst ratio of a ≥ 5%
//! cluster), the figures of the README's sweep table. `RETEX_MESHMATCH_SWEEP` replaces the
//! default sets with a JSON array of `params` objects; `RETEX_MESHMATCH_SWEEP_CORR=1` adds the
//! pairs' hand-placed correspondences (`meshmatch_real_pairs`) to every run;
//! `RETEX_MESHMATCH_SWEEP_SEEDS` replaces the seeds (a JSON array, default `[1, 2]`).

use crate::common::load_bytes;
use crate::meshmatch_common::color_statistics;
use crate::meshmatch_real_pairs::{pair_correspondences, run_pair, PAIRS};
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
    let seeds: Vec<u64> = match std::env::var("RETEX_MESHMATCH_SWEEP_SEEDS") {
        Ok(text) => serde_json::from_str(&text).expect("RETEX_MESHMATCH_SWEEP_SEEDS: a JSON array"),
        Err(_) => vec![1, 2],
    };
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
            for &seed in &seeds {
                let out = run_pair((&sn, &sb), (&tn, &tb), &corr, set, seed);
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

/// Scores output files made elsewhere (e.g. by the CLI): `RETEX_SCORE_FILES` is a JSON array of
/// `[source, output]` path pairs; prints each output's colour statistics against its source.
#[test]
#[ignore = "benchmark tool: scores the files named in RETEX_SCORE_FILES"]
fn bench_score_meshmatch_outputs() {
    let text = std::env::var("RETEX_SCORE_FILES").expect("RETEX_SCORE_FILES: [[source, output]]");
    let pairs: Vec<(String, String)> = serde_json::from_str(&text).expect("a JSON array of pairs");
    assert!(!pairs.is_empty(), "RETEX_SCORE_FILES names no files");
    for (source, output) in pairs {
        let read = |p: &str| load_bytes(&std::fs::read(p).expect(p), p);
        let stats = color_statistics(&read(&source), &read(&output));
        println!(
            "SCORE {output}: TV {:.3} worst {:.2} kept {}",
            stats.tv,
            stats.worst_ratio,
            stats.kept()
        );
        for ((c, a), b) in stats.centers.iter().zip(&stats.source).zip(&stats.output) {
            println!("SHARE {output}: centre {c:.2?} source {a:.3} output {b:.3}");
        }
    }
}
