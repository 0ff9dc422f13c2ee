//! `retex bench`: medians of ingest and whole transfers on the shared assets, printed as the
//! Markdown table the README carries. Timings come from the pipeline's own stage clock.

use std::path::Path;
use std::time::Instant;

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::{load, BlobSet, IngestLimits};
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn read(assets: &Path, rel: &str) -> Result<(String, BlobSet), String> {
    let p = assets.join(rel);
    BlobSet::from_path(&p).map_err(|e| format!("{}: {e}", p.display()))
}

struct Row {
    stage: String,
    input: String,
    ms: f64,
    reference: String,
}

fn transfer_case(
    assets: &Path,
    src: &str,
    tgt: &str,
    runs: usize,
    input: &str,
    reference: &str,
) -> Result<Vec<Row>, String> {
    let (sm, sb) = read(assets, src)?;
    let (tm, tb) = read(assets, tgt)?;
    // Stage name → one time per run.
    let mut stages: Vec<(String, Vec<f64>)> = Vec::new();
    let mut record = |name: &str, ms: f64| match stages.iter_mut().find(|(n, _)| n == name) {
        Some((_, v)) => v.push(ms),
        None => stages.push((name.to_string(), vec![ms])),
    };
    for _ in 0..runs {
        let ti = TransferInput::pair(
            ModelInput {
                main: &sm,
                blobs: &sb,
            },
            ModelInput {
                main: &tm,
                blobs: &tb,
            },
            Constraints::default(),
        );
        let t0 = Instant::now();
        let out = transfer(&ti, &Control::new()).map_err(|e| e.to_string())?;
        let total = t0.elapsed().as_secs_f64() * 1e3;
        for t in &out.report.timings {
            let label = match t.stage.as_str() {
                "load" => "load both models",
                "surface" => "surfaces (weld) + BVHs",
                "align" => "align",
                "bake" => "bake: rasterize + closest point + sample",
                "pad" => "pad + PNG encode",
                "vertex_colors" => "refine + COLOR_0",
                other => other,
            };
            record(label, t.ms);
        }
        record("whole transfer (load → export)", total);
    }
    Ok(stages
        .into_iter()
        .filter(|(name, v)| name.starts_with("whole") || median(v.clone()) >= 0.5)
        .map(|(stage, v)| {
            let reference = if stage.starts_with("whole") || stage.starts_with("bake") {
                reference
            } else {
                "—"
            };
            Row {
                ms: median(v),
                stage,
                input: input.into(),
                reference: reference.into(),
            }
        })
        .collect())
}

/// Runs the command.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let runs = runs.max(1);
    let mut rows = Vec::new();
    let (m, b) = read(assets, "perf_toy_car_khronos/glTF/ToyCar.gltf")?;
    let mut t = Vec::new();
    for _ in 0..runs {
        let t0 = Instant::now();
        load(&m, &b, &IngestLimits::default()).map_err(|e| e.to_string())?;
        t.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    rows.push(Row {
        stage: "ingest (parse, validate, decode base color)".into(),
        input: "ToyCar.gltf, 77k vertices / 109k triangles, 5.9 MB of PNGs".into(),
        ms: median(t),
        reference: "—".into(),
    });
    rows.extend(transfer_case(
        assets,
        "perf_toy_car_khronos/glTF/ToyCar.gltf",
        "perf_toy_car_khronos/glTF/ToyCar.gltf",
        runs,
        "ToyCar → ToyCar: 109k → 109k triangles, 3 materials × 2048²",
        "PyMeshLab closest-point transfer, 40k-vertex target, one 2048²: 1.8 s transfer, ~6 s end to end",
    )?);
    rows.extend(transfer_case(
        assets,
        "src_spot_keenan/spot_textured_derived.glb",
        "tgt_spot_remeshed_odedstein/spot_derived.glb",
        runs,
        "Spot → remeshed Spot (23k triangles, no UVs): COLOR_0 on a 100k-vertex refined copy",
        "—",
    )?);
    println!("| stage | input | retex (median of {runs}) | reference |");
    println!("|---|---|---|---|");
    for r in rows {
        println!(
            "| {} | {} | {:.0} ms | {} |",
            r.stage, r.input, r.ms, r.reference
        );
    }
    Ok(())
}
