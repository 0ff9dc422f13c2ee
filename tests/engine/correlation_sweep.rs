//! Sweeps of the `correlation` method's non-parametric synthesis (issue 11, §5.1) that the
//! README's tables and the thresholds of `correlation_nonparametric.rs` come from: the feature
//! weight (0.3, 0.5 = the paper's equal weights, 0.8 = its Fig. 11, 1.0) over both procedural
//! cases (bumpy → bumpy, ribbed → oblate) and seeds 1-3, measuring the output's correlation with
//! f on the target (relative to the source's own), the coherent patch size (the coherence run
//! length) and the largest tercile-share deviation; and the coherence κ (0, 1, 4) over both cases
//! and seeds 1-4 (the bounds of `correlation_nonparametric.rs`). Minutes of runtime: ignored, run with
//! `cargo test --release --test engine correlation_sweep -- --ignored --nocapture` (named `bench_` so
//! that `.ci/run` skips them).

use serde_json::json;

use crate::correlation_common::{
    at_points, case, case_b, luminance, pearson, tercile_shares, transfer, Case,
};

fn neg_lum(c: &[[f32; 3]]) -> Vec<f32> {
    c.iter().map(|x| -luminance(*x)).collect()
}

/// (r / r_source, mean patch samples, coherent edges, largest tercile deviation).
fn measure(c: &Case, weight: f64, seed: u64) -> (f64, f64, f64, f64) {
    measure_with(c, json!({"feature_weight": weight}), seed)
}

/// [`measure`] with any `nonparametric` options.
fn measure_with(c: &Case, options: serde_json::Value, seed: u64) -> (f64, f64, f64, f64) {
    let src: Vec<[f32; 3]> = c.source_colors.iter().map(|x| [x[0], x[1], x[2]]).collect();
    let r_source = pearson(&neg_lum(&src), &c.source_f);
    let (pts, colors, report) = transfer(
        c,
        json!({"synthesis": "nonparametric", "nonparametric": options}),
        seed,
    );
    let f_out = at_points(&c.target, &c.target_f, &pts);
    let r = pearson(&neg_lum(&colors), &f_out);
    let shares = tercile_shares(
        &src.iter().map(|x| luminance(*x)).collect::<Vec<_>>(),
        &colors.iter().map(|x| luminance(*x)).collect::<Vec<_>>(),
    );
    let dev = shares
        .iter()
        .map(|s| (s - 1.0 / 3.0).abs())
        .fold(0.0, f64::max);
    let npr = &report["nonparametric"];
    (
        r / r_source,
        npr["mean_patch_samples"].as_f64().unwrap(),
        npr["coherent_edges"].as_f64().unwrap(),
        dev,
    )
}

#[test]
#[ignore = "sweep for the README (minutes)"]
fn bench_nonparametric_feature_weight_sweep() {
    println!("| case | feature weight | seed | r / r_source | mean patch (samples) | coherent edges | tercile deviation |");
    println!("|---|---|---|---|---|---|---|");
    for (name, build) in [
        ("bumpy → bumpy", case as fn(u64) -> Case),
        ("ribbed → oblate", case_b as fn(u64) -> Case),
    ] {
        for seed in [1u64, 2, 3] {
            let c = build(seed);
            for weight in [0.3, 0.5, 0.8, 1.0] {
                let (r, p, e, d) = measure(&c, weight, seed);
                println!("| {name} | {weight} | {seed} | {r:.3} | {p:.0} | {e:.3} | {d:.3} |");
            }
        }
    }
}

#[test]
#[ignore = "sweep for the README (minutes)"]
fn bench_nonparametric_coherence_sweep() {
    println!("| case | seed | r / r_source κ = 0, 1, 4 | mean patch κ = 0, 1, 4 | coherent edges κ = 0, 1, 4 | tercile deviation κ = 1 |");
    println!("|---|---|---|---|---|---|");
    for (name, build) in [
        ("bumpy → bumpy", case as fn(u64) -> Case),
        ("ribbed → oblate", case_b as fn(u64) -> Case),
    ] {
        for seed in [1u64, 2, 3, 4] {
            let c = build(seed);
            let m: Vec<(f64, f64, f64, f64)> = [0.0, 1.0, 4.0]
                .iter()
                .map(|k| measure_with(&c, json!({"coherence": k}), seed))
                .collect();
            println!(
                "| {name} | {seed} | {:.3} / {:.3} / {:.3} | {:.0} / {:.0} / {:.0} | {:.3} / {:.3} / {:.3} | {:.3} |",
                m[0].0, m[1].0, m[2].0, m[0].1, m[1].1, m[2].1, m[0].2, m[1].2, m[2].2, m[1].3
            );
        }
    }
}
