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
    let mut totals = Vec::new();
    let mut project = Vec::new();
    for _ in 0..runs {
        let ti = TransferInput {
            source: ModelInput {
                main: &sm,
                blobs: &sb,
            },
            target: ModelInput {
                main: &tm,
                blobs: &tb,
            },
            constraints: Constraints::default(),
            limits: IngestLimits::default(),
        };
        let t0 = Instant::now();
        let out = transfer(&ti, &Control::new()).map_err(|e| e.to_string())?;
        totals.push(t0.elapsed().as_secs_f64() * 1e3);
        project.push(
            out.report
                .timings
                .iter()
                .filter(|t| t.stage == "project")
                .map(|t| t.ms)
                .sum(),
        );
    }
    Ok(vec![
        Row {
            stage: "project: surfaces + BVH + bake 2048² + pad".into(),
            input: input.into(),
            ms: median(project),
            reference: reference.into(),
        },
        Row {
            stage: "whole transfer (load → export)".into(),
            input: input.into(),
            ms: median(totals),
            reference: reference.into(),
        },
    ])
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
        "ToyCar → ToyCar, 109k → 109k triangles, 2048² per material",
        "PyMeshLab closest-point transfer, 40k-vertex target, 2048²: 1.8 s transfer, ~6 s end to end",
    )?);
    rows.extend(transfer_case(
        assets,
        "src_spot_keenan/spot_textured_derived.glb",
        "tgt_spot_remeshed_odedstein/spot_derived.glb",
        runs,
        "Spot → remeshed Spot (no UVs: COLOR_0 on a 100k-vertex refined copy)",
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
