//! `retex bench --method detail`: times the `detail` method (Berkiten et al. 2017) on a real
//! pair, the Nefertiti scan (70,000 faces, the detailed source, base derived) onto the
//! Lee Perry-Smith head (17,684 faces, with UVs: displacement and normal maps at 2048²), at the
//! default finest level (about 70k target faces) and at a finest level of about 400k target
//! faces, against the aims on two cores. Per-step seconds come from the method's report.
//! Prints Markdown for the README.

use std::path::Path;

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

const SOURCE: &str = "tgt_nefertiti_bust_odedstein/nefertiti-lowres_derived.glb";
const TARGET: &str = "src_lee_perry_smith_head/LeePerrySmith.glb";

/// (label, params, aim). The 400k case sets the finest edge (a fraction of the target's
/// diagonal) so that the target's finest level has about 400k faces. The last two set a finest
/// edge 2.2 times the scan's own, so that the texture-space refinement (§3.3.2) has a band to
/// fill, without and with it.
fn cases() -> [(&'static str, serde_json::Value, &'static str); 4] {
    [
        (
            "default finest level",
            serde_json::json!({}),
            "70k faces under 60 s",
        ),
        (
            "finest level ≈ 400k target faces",
            serde_json::json!({"finest_edge_length": 0.00222, "max_faces": 600000}),
            "400k faces under 5 min",
        ),
        (
            "coarse finest level (0.012 × diagonal), refine off",
            serde_json::json!({"finest_edge_length": 0.012, "refine": false}),
            "—",
        ),
        (
            "coarse finest level (0.012 × diagonal), refine on (§3.3.2)",
            serde_json::json!({"finest_edge_length": 0.012}),
            "—",
        ),
    ]
}

/// Runs the benchmark `runs` times per case and prints the table.
///
/// # Errors
/// A missing asset or a failed transfer, as a message.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let (smain, sblobs) =
        BlobSet::from_path(&assets.join(SOURCE)).map_err(|e| format!("{SOURCE}: {e}"))?;
    let (tmain, tblobs) =
        BlobSet::from_path(&assets.join(TARGET)).map_err(|e| format!("{TARGET}: {e}"))?;
    println!("| case | finest faces (source / target) | hierarchy | displacement | geometric features | metric | synthesis | outputs | whole transfer | aim (issue 13, 2 cores) |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (label, params, aim) in cases() {
        let mut whole = Vec::new();
        let mut last = serde_json::Value::Null;
        for _ in 0..runs.max(1) {
            let c: Constraints = serde_json::from_value(serde_json::json!({
                "version": 1, "method": "detail", "params": params
            }))
            .map_err(|e| e.to_string())?;
            let input = TransferInput::pair(
                ModelInput {
                    main: &smain,
                    blobs: &sblobs,
                },
                ModelInput {
                    main: &tmain,
                    blobs: &tblobs,
                },
                c,
            );
            let out = transfer(&input, &Control::new()).map_err(|e| e.to_string())?;
            whole.push(out.report.timings.iter().map(|s| s.ms).sum::<f64>() / 1000.0);
            last = out.report.method_report.clone();
        }
        let s = &last["seconds"];
        let finest = last["levels"]
            .as_array()
            .and_then(|l| l.last())
            .cloned()
            .unwrap_or_default();
        let f = |k: &str| s[k].as_f64().unwrap_or(f64::NAN);
        println!(
            "| {label} | {} / {} | {:.2} s | {:.2} s | {:.2} s | {:.2} s | {:.2} s | {:.2} s | {:.2} s | {aim} |",
            finest["source_faces"],
            finest["target_faces"],
            f("hierarchy") + f("base"),
            f("displacement"),
            f("geometric_features"),
            f("metric"),
            f("synthesis"),
            last["output_seconds"].as_f64().unwrap_or(f64::NAN),
            median(whole),
        );
    }
    println!(
        "\nNefertiti (70,000 faces) → Lee Perry-Smith (17,684 faces, UVs), 2048² maps, median of {} run(s).",
        runs.max(1)
    );
    if let Some(mib) = super::bench_meshmatch::peak_rss_mib() {
        println!("peak resident memory: {mib:.0} MiB");
    }
    Ok(())
}
