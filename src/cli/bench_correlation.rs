//! `retex bench --method correlation`: times the `correlation` method (Mertens et al. 2006) at
//! the paper's 512,000 samples per model on the Lee Perry-Smith head → Demosthenes bust, stage
//! by stage from the job report's stage timings (measured by `Control`; the method keeps no
//! stopwatch), against the aims on two cores. Prints a Markdown table for the README.
//! Then the non-parametric synthesis (§5.1) on the same pair, at the default 131,072 samples and
//! at 512,000 (one run each unless `runs` asks for more): the same table with the
//! non-parametric stages (its fans, exponential maps and search) in place of the parametric ones.

use std::path::Path;

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::{Control, StageTiming};
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

/// Samples per model (the paper's count).
const SAMPLES: usize = 512_000;
/// The method's default sample count (the non-parametric synthesis is timed there too).
const DEFAULT_SAMPLES: usize = 131_072;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The phase of a stage name.
fn phase(stage: &str) -> Option<usize> {
    Some(match stage {
        "surface" | "resample" | "hierarchy" | "pyramid" | "source_colour" => 0,
        "curvature" | "occlusion" | "solid angle curvature" | "directional occlusion" => 1,
        "cca" => 2,
        "feature_matching" => 3,
        s if s.starts_with("parametric") => 4,
        s if s.starts_with("nonparametric") => 6,
        "geodesic fans" | "exponential map" => 6,
        "bake" | "pad" | "vertex_colors" => 5,
        _ => return None,
    })
}

const PHASES: [(&str, &str); 7] = [
    ("samples + pyramids (both models)", "—"),
    ("12-D features (both models)", "under 10 s"),
    ("CCA", "under 0.5 s"),
    ("multiscale feature matching", "under 20 s"),
    ("parametric synthesis", "under 60 s"),
    ("output (COLOR_0)", "—"),
    ("non-parametric synthesis", "under 3 min"),
];

fn sums(timings: &[StageTiming]) -> [f64; 7] {
    let mut s = [0.0; 7];
    for t in timings {
        if let Some(p) = phase(&t.stage) {
            s[p] += t.ms;
        }
    }
    s
}

/// Median per-phase seconds and whole-transfer seconds of `runs` transfers.
fn measure(
    pair: &[(String, BlobSet); 2],
    samples: usize,
    synthesis: &str,
    runs: usize,
) -> Result<(Vec<f64>, f64), String> {
    let mut per_phase: Vec<Vec<f64>> = vec![Vec::new(); PHASES.len()];
    let mut whole = Vec::new();
    for _ in 0..runs.max(1) {
        let c: Constraints = serde_json::from_value(serde_json::json!({
            "version": 1, "method": "correlation",
            "params": {"samples": samples, "synthesis": synthesis}
        }))
        .map_err(|e| e.to_string())?;
        let out = transfer(
            &TransferInput::pair(
                ModelInput {
                    main: &pair[0].0,
                    blobs: &pair[0].1,
                },
                ModelInput {
                    main: &pair[1].0,
                    blobs: &pair[1].1,
                },
                c,
            ),
            &Control::new(),
        )
        .map_err(|e| e.to_string())?;
        let s = sums(&out.report.timings);
        for (p, v) in s.iter().enumerate() {
            per_phase[p].push(*v);
        }
        whole.push(out.report.timings.iter().map(|t| t.ms).sum::<f64>());
    }
    Ok((
        per_phase.into_iter().map(|v| median(v) / 1000.0).collect(),
        median(whole) / 1000.0,
    ))
}

/// Runs the benchmark `runs` times and prints the tables.
///
/// # Errors
/// A missing asset or a failed transfer, as a message.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let read = |rel: &str| -> Result<(String, BlobSet), String> {
        BlobSet::from_path(&assets.join(rel)).map_err(|e| format!("{rel}: {e}"))
    };
    let pair = [
        read("src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf")?,
        read("tgt_demosthenes_bust_odedstein/demosthenes-low-res_derived.glb")?,
    ];
    let (phases, whole) = measure(&pair, SAMPLES, "parametric", runs)?;
    println!(
        "Lee Perry-Smith head → Demosthenes bust, {SAMPLES} samples per model, median of {} run(s):\n",
        runs.max(1)
    );
    println!("| stage | retex (median) | aim on 2 cores (issue 11) |\n|---|---|---|");
    for (p, (name, aim)) in PHASES.iter().enumerate().take(6) {
        println!("| {name} | {:.2} s | {aim} |", phases[p]);
    }
    println!("| whole transfer | {whole:.2} s | — |");
    println!("\nNon-parametric synthesis (§5.1, default neighbourhood 5, κ = 1, feature weight 0.8), same pair:\n");
    println!("| stage | {DEFAULT_SAMPLES} samples | {SAMPLES} samples | aim on 2 cores (issue 11) |\n|---|---|---|---|");
    let small = measure(&pair, DEFAULT_SAMPLES, "nonparametric", runs)?;
    let large = measure(&pair, SAMPLES, "nonparametric", runs)?;
    for (p, (name, aim)) in PHASES.iter().enumerate() {
        if p == 4 {
            continue;
        }
        println!(
            "| {name} | {:.2} s | {:.2} s | {aim} |",
            small.0[p], large.0[p]
        );
    }
    println!(
        "| whole transfer | {:.2} s | {:.2} s | — |",
        small.1, large.1
    );
    if let Some(mib) = super::bench_meshmatch::peak_rss_mib() {
        println!("\npeak resident memory: {mib:.0} MiB");
    }
    Ok(())
}
