//! `retex bench --method pattern`: times the `pattern` method (Soler et al. 2002) on a 5-10k-face
//! mesh and on a large general mesh with a 256² tileable pattern, stage by stage from the job
//! report's stage timings (measured by `Control`), with the FFT fits and clusters per level and
//! the mean seam error (random placement ≈ 1) from the method's report, against the aims on two cores. Prints Markdown for the README.

use std::path::Path;

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ImageInput, ModelInput, TransferInput};
use retex::engine::texture::encode::encode_png_srgb;

/// Pattern side in pixels (the 256²).
const PATTERN: u32 = 256;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A tileable colour pattern (integer frequencies) of `PATTERN`² pixels.
fn pattern_png() -> Vec<u8> {
    use std::f32::consts::TAU;
    let n = PATTERN;
    let px: Vec<[f32; 4]> = (0..n * n)
        .map(|i| {
            let (u, v) = (
                ((i % n) as f32 + 0.5) / n as f32,
                ((i / n) as f32 + 0.5) / n as f32,
            );
            [
                0.5 + 0.35 * (TAU * (2.0 * u + v)).sin() + 0.1 * (TAU * 5.0 * v).sin(),
                0.5 + 0.35 * (TAU * 3.0 * v).sin() * (TAU * u).cos(),
                0.5 + 0.35 * (TAU * (u - 2.0 * v)).cos() + 0.1 * (TAU * 4.0 * u).cos(),
                1.0,
            ]
        })
        .collect();
    encode_png_srgb(&px, n, n)
}

/// The cases: (label, asset path, aim).
const CASES: [(&str, &str, &str); 2] = [
    (
        "skull, low resolution (10,312 faces, genus 2)",
        "perf_skull_odedstein/skull_low_resolution_derived.glb",
        "under 3 s",
    ),
    (
        "hammer scan (60,160 faces)",
        "perf_hammer_scan_odedstein/hammer_derived.glb",
        "34k faces under 10 s",
    ),
];

/// Runs the benchmark `runs` times per case and prints the tables.
///
/// # Errors
/// A missing asset or a failed transfer, as a message.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let png = pattern_png();
    println!("| mesh | faces | FFT fits | patches | clusters per level (considered / textured / fits) | seam error | method | whole transfer | aim (issue 12, 2 cores) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for (label, rel, aim) in CASES {
        let (main, blobs) =
            BlobSet::from_path(&assets.join(rel)).map_err(|e| format!("{rel}: {e}"))?;
        let mut method_ms = Vec::new();
        let mut whole_ms = Vec::new();
        let mut last = serde_json::Value::Null;
        for _ in 0..runs.max(1) {
            let c: Constraints = serde_json::from_value(serde_json::json!({
                "version": 1, "method": "pattern", "seed": 1
            }))
            .map_err(|e| e.to_string())?;
            let input = TransferInput::new(
                ModelInput {
                    main: &main,
                    blobs: &blobs,
                },
                c,
            )
            .with_pattern(ImageInput {
                name: "pattern.png",
                bytes: &png,
            });
            let out = transfer(&input, &Control::new()).map_err(|e| e.to_string())?;
            let t = &out.report.timings;
            method_ms.push(
                t.iter()
                    .filter(|s| !matches!(s.stage.as_str(), "load" | "export"))
                    .map(|s| s.ms)
                    .sum::<f64>(),
            );
            whole_ms.push(t.iter().map(|s| s.ms).sum::<f64>());
            for s in t {
                eprintln!("{label}: {} {:.0} ms", s.stage, s.ms);
            }
            last = out.report.method_report.clone();
        }
        let d = &last["driver"];
        let levels: Vec<String> = d["levels"]
            .as_array()
            .map(|l| {
                l.iter()
                    .filter(|x| x["clusters"].as_u64().unwrap_or(0) > 0)
                    .map(|x| format!("{}/{}/{}", x["clusters"], x["textured"], x["fits"]))
                    .collect()
            })
            .unwrap_or_default();
        println!(
            "| {label} | {} | {} | {} | {} | {:.2} | {:.2} s | {:.2} s | {aim} |",
            last["faces"],
            d["fits"],
            d["patches"],
            levels.join(", "),
            last["mean_seam_error"].as_f64().unwrap_or(f64::NAN),
            median(method_ms) / 1000.0,
            median(whole_ms) / 1000.0,
        );
    }
    println!(
        "\n{PATTERN}² tileable pattern, default params (scale = a quarter of the bounding-box diagonal), median of {} run(s).",
        runs.max(1)
    );
    if let Some(mib) = super::bench_meshmatch::peak_rss_mib() {
        println!("peak resident memory: {mib:.0} MiB");
    }
    Ok(())
}
