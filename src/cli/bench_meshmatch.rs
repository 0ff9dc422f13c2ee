//! `retex bench --method meshmatch`: times MeshMatch (Chen et al. 2012, §5.5) at the paper's
//! size, a 64K-vertex target and source (Spot → remeshed Spot, 8 HKS + up features, 3 × 18 RGB
//! fans), stage by stage from the job report's stage timings (measured by `Control`; the method keeps
//! no stopwatch of its own), with exhaustive and randomized rotation search,
//! and prints the peak resident memory of the process. Prints a Markdown table for the README.

use std::path::Path;
use std::time::Instant;

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::{Control, StageTiming};
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

pub(super) fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Peak resident set size of this process, MiB (Linux `VmHWM`).
pub(super) fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// A run's stage timings (the job report's `timings`, measured by `Control`) summed by phase.
#[derive(Default)]
pub(super) struct Phases {
    /// From `meshmatch: hierarchy` up to `meshmatch: features`.
    pub hierarchy: f64,
    /// From `meshmatch: features` up to the first level.
    pub features: f64,
    /// Every `meshmatch level …` stage.
    pub levels: f64,
    /// Stages of the finest level outside its iterations (source fans, charts, target fan weights,
    /// stencil, first vote).
    pub finest_setup: f64,
    /// Per finest-level iteration: target fans, E-step, vote.
    pub fans: Vec<f64>,
    pub e_step: Vec<f64>,
    pub vote: Vec<f64>,
}

impl Phases {
    pub(super) fn of(timings: &[StageTiming]) -> Phases {
        // "meshmatch level a/b[ iteration k]: name": the finest level is a == b.
        let level = |stage: &str| -> Option<(bool, bool, String)> {
            let rest = stage.strip_prefix("meshmatch level ")?;
            let (head, name) = rest.split_once(": ")?;
            let (fraction, iteration) = match head.split_once(" iteration ") {
                Some((f, _)) => (f, true),
                None => (head, false),
            };
            let (a, b) = fraction.split_once('/')?;
            Some((a == b, iteration, name.to_string()))
        };
        let mut p = Phases::default();
        #[derive(PartialEq)]
        enum At {
            Before,
            Hierarchy,
            Features,
            Levels,
            After,
        }
        let mut at = At::Before;
        for t in timings {
            let lv = level(&t.stage);
            at = match (&at, t.stage.as_str(), &lv) {
                (_, "meshmatch: hierarchy", _) => At::Hierarchy,
                (_, "meshmatch: features", _) => At::Features,
                (_, _, Some(_)) => At::Levels,
                (At::Levels, _, None) => At::After,
                _ => at,
            };
            match at {
                At::Hierarchy => p.hierarchy += t.ms,
                At::Features => p.features += t.ms,
                At::Levels => p.levels += t.ms,
                At::Before | At::After => {}
            }
            match lv {
                Some((true, false, _)) => p.finest_setup += t.ms,
                Some((true, true, name)) => match name.as_str() {
                    "geodesic fans" => p.fans.push(t.ms),
                    "E-step" => p.e_step.push(t.ms),
                    "vote" => p.vote.push(t.ms),
                    _ => {}
                },
                _ => {}
            }
        }
        p
    }
}

/// Stage timings over the runs of one pair (every finest-level iteration of every run).
#[derive(Default)]
pub(super) struct Measured {
    pub whole: Vec<f64>,
    pub synth: Vec<f64>,
    pub hierarchy: Vec<f64>,
    pub features: Vec<f64>,
    pub e_step: Vec<f64>,
    pub vote: Vec<f64>,
    pub fans: Vec<f64>,
    pub level0_setup: Vec<f64>,
    pub energy: f64,
    pub coherence: f64,
    pub completeness: f64,
    /// Synthesis vertices of the finest level: (target, source).
    pub vertices: (usize, usize),
    /// Levels of the hierarchy.
    pub levels: usize,
}

/// A model for the benchmark: the name of its main file and the files.
pub(super) type Model = (String, BlobSet);

/// Reads a shared asset.
pub(super) fn read_asset(assets: &Path, rel: &str) -> Result<Model, String> {
    BlobSet::from_path(&assets.join(rel)).map_err(|e| format!("{rel}: {e}"))
}

/// Times `runs` MeshMatch transfers of `source` onto `target` (64K samples plus `params`), and,
/// when `fidelity`, one more untimed run that measures coherence and completeness.
pub(super) fn measure(
    (source, target): (&Model, &Model),
    params: serde_json::Value,
    runs: usize,
    fidelity: bool,
) -> Result<Measured, String> {
    let mut m = Measured {
        energy: f64::NAN,
        coherence: f64::NAN,
        completeness: f64::NAN,
        ..Measured::default()
    };
    // The last run also measures fidelity (not timed).
    for run in 0..runs + usize::from(fidelity) {
        let quality = run == runs;
        let mut all = serde_json::json!({"samples": 65536, "measure_fidelity": quality,
                                         "write_nnf": false});
        if let (Some(all), Some(extra)) = (all.as_object_mut(), params.as_object()) {
            all.extend(extra.clone());
        }
        let constraints: Constraints = serde_json::from_value(serde_json::json!({
            "version": 1, "method": "meshmatch", "params": all
        }))
        .map_err(|e| e.to_string())?;
        let input = TransferInput::pair(
            ModelInput {
                main: &source.0,
                blobs: &source.1,
            },
            ModelInput {
                main: &target.0,
                blobs: &target.1,
            },
            constraints,
        );
        let t0 = Instant::now();
        let out = transfer(&input, &Control::new()).map_err(|e| e.to_string())?;
        let whole = t0.elapsed().as_secs_f64() * 1e3;
        let s = &out.report.method_report["synthesis"];
        if quality {
            m.coherence = s["fidelity"]["coherence"].as_f64().unwrap_or(f64::NAN);
            m.completeness = s["fidelity"]["completeness"].as_f64().unwrap_or(f64::NAN);
            continue;
        }
        let p = Phases::of(&out.report.timings);
        m.whole.push(whole);
        m.synth.push(p.hierarchy + p.features + p.levels);
        m.hierarchy.push(p.hierarchy);
        m.features.push(p.features);
        m.level0_setup.push(p.finest_setup);
        m.e_step.extend(p.e_step);
        m.vote.extend(p.vote);
        m.fans.extend(p.fans);
        let levels = s["levels"].as_array().cloned().unwrap_or_default();
        m.levels = levels.len();
        let finest = levels.last().cloned().unwrap_or_default();
        let count = |key: &str| finest[key].as_u64().unwrap_or(0) as usize;
        m.vertices = (count("target_vertices"), count("source_vertices"));
        let its = finest["iterations"].as_array().cloned().unwrap_or_default();
        if let Some(it) = its.last() {
            m.energy = it["energy"].as_f64().unwrap_or(f64::NAN);
        }
    }
    Ok(m)
}

/// Runs the benchmark and prints the table.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let runs = runs.max(1);
    let source = read_asset(assets, "src_spot_keenan/spot_textured_derived.glb")?;
    let target = read_asset(assets, "tgt_spot_remeshed_odedstein/spot_derived.glb")?;
    let pair = (&source, &target);
    let exhaustive = measure(pair, serde_json::json!({}), runs, true)?;
    let randomized = measure(
        pair,
        serde_json::json!({"randomized_rotations": true}),
        runs,
        true,
    )?;
    let peak = peak_rss_mib();
    let input = "Spot → remeshed Spot, 64K-vertex target and source, 8 HKS + up, 3×18 RGB fans";
    println!("| stage | input | retex (median of {runs}) | MeshMatch paper |");
    println!("|---|---|---|---|");
    let rows: [(&str, f64, &str); 8] = [
        (
            "hierarchies (both meshes)",
            median(exhaustive.hierarchy.clone()),
            "120 s (one mesh)",
        ),
        (
            "shape features HKS + up (both)",
            median(exhaustive.features.clone()),
            "—",
        ),
        (
            "finest level: charts + source fans + target fan weights",
            median(exhaustive.level0_setup.clone()),
            "40 s fans",
        ),
        (
            "finest level: target fans, one pass",
            median(exhaustive.fans.clone()),
            "—",
        ),
        (
            "finest level: one E-step (propagation + random search), exhaustive rotations",
            median(exhaustive.e_step.clone()),
            "6.5 s",
        ),
        (
            "finest level: one vote (M-step)",
            median(exhaustive.vote.clone()),
            "5.5 s",
        ),
        (
            "whole synthesis, all levels",
            median(exhaustive.synth.clone()),
            "~100 s + 160 s preprocessing",
        ),
        (
            "whole transfer (load → export, base colour in a generated atlas)",
            median(exhaustive.whole.clone()),
            "—",
        ),
    ];
    for (stage, ms, reference) in rows {
        println!("| {stage} | {input} | {ms:.0} ms | {reference} |");
    }
    println!(
        "| finest level: one E-step, randomized rotations | {input} | {:.0} ms | — |",
        median(randomized.e_step.clone())
    );
    println!(
        "| whole transfer, randomized rotations | {input} | {:.0} ms | — |",
        median(randomized.whole.clone())
    );
    println!(
        "\nquality: exhaustive rotations: final energy {:.2}, coherence {:.4}, completeness {:.3}; randomized: final energy {:.2}, coherence {:.4}, completeness {:.3}",
        exhaustive.energy,
        exhaustive.coherence,
        exhaustive.completeness,
        randomized.energy,
        randomized.coherence,
        randomized.completeness
    );
    if let Some(p) = peak {
        println!("peak resident memory of the process: {p:.0} MiB");
    }
    super::bench_meshmatch_pairs::run(assets, source, runs)
}
