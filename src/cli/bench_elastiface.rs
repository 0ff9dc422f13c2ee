//! `retex bench --method elastiface`: times ElastiFace (Zell & Botsch 2013, §6 reports 19k → 10k
//! vertices in 7 s) stage by stage from the job report's stage timings (measured by `Control`;
//! the method keeps no stopwatch of its own), and prints the peak resident memory of the process.
//! Prints a Markdown table for the README.
//!
//! The case: the template is a smoothly, non-rigidly deformed, rotated and scaled copy of the Lee
//! Perry-Smith head (its own UVs; 9,279 stored / 8,844 welded vertices, built in memory by
//! re-exporting the head with new POSITIONs), the target is the textured head itself, with 18
//! correspondences at farthest-point samples (the same pair as the engine test
//! `elastiface_deformed_head_back_onto_the_textured_head`), a 9k → 9k case. The shared assets
//! hold no 19k-vertex textured head, so the second case is the head → the Nefertiti bust (35k
//! vertices, untextured, so without the texture stage) with the committed hand-placed landmarks:
//! a larger target than the paper's 19k. The third fits the bust (35k) onto the head and the fourth
//! the bust decimated to about 19k onto the head (8.8k): the paper's 19k → 10k.

use std::path::Path;
use std::time::Instant;

use retex::engine::asset::constraints::{Constraints, OutputFormat};
use retex::engine::asset::edits::{AttributeData, Edit};
use retex::engine::asset::export::{export, mesh_glb};
use retex::engine::asset::{load, BlobSet, IngestLimits};
use retex::engine::control::Control;
use retex::engine::mesh::{build_surface, WeldParams};
use retex::engine::multires::hierarchy::{build_hierarchy, HierarchyParams};
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

use super::bench_meshmatch::peak_rss_mib;

const HEAD: &str = "src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf";

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The test's deformation: smooth and non-rigid in units of the head's size `d`, then a rotation
/// of 0.4 rad about y and a scale of 0.5.
fn deform(p: [f64; 3], c: [f64; 3], d: f64) -> [f64; 3] {
    let q: [f64; 3] = std::array::from_fn(|k| (p[k] - c[k]) / d);
    let w = [
        q[0] * (1.0 + 0.3 * q[1]) + 0.08 * (3.0 * q[1]).sin(),
        q[1] * 1.2 + 0.1 * q[0] * q[0],
        q[2] * 0.8 + 0.06 * (4.0 * q[0]).cos(),
    ];
    let (s, co) = 0.4f64.sin_cos();
    [
        0.5 * (co * w[0] + s * w[2]),
        0.5 * w[1],
        0.5 * (-s * w[0] + co * w[2]),
    ]
}

/// The deformed template (GLB bytes) and the correspondences.
fn case(main: &str, blobs: &BlobSet) -> Result<(Vec<u8>, serde_json::Value), String> {
    let head = load(main, blobs, &IngestLimits::default()).map_err(|e| e.to_string())?;
    let (Some(prim), Some(inst)) = (head.primitives.first(), head.instances.first()) else {
        return Err(format!("{HEAD}: no mesh"));
    };
    let world: Vec<[f64; 3]> = prim
        .positions
        .iter()
        .map(|p| inst.transform_point(*p))
        .collect();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &world {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    // The head's node only scales by 1 + 1e-7: world positions are written as mesh-local ones.
    let deformed: Vec<[f32; 3]> = world
        .iter()
        .map(|p| deform(*p, centre, diag).map(|c| c as f32))
        .collect();
    let edit = Edit::SetAttribute {
        primitive: 0,
        name: "POSITION".into(),
        data: AttributeData::Vec3(deformed.clone()),
    };
    let source = export(&head, &[edit], OutputFormat::Glb).map_err(|e| e.to_string())?;
    let mut picked = vec![0usize];
    let mut near = vec![f64::INFINITY; world.len()];
    while picked.len() < 18 {
        let last = world[picked[picked.len() - 1]];
        for (i, p) in world.iter().enumerate() {
            near[i] = near[i].min((0..3).map(|k| (p[k] - last[k]).powi(2)).sum::<f64>());
        }
        let next = (0..world.len())
            .max_by(|a, b| near[*a].total_cmp(&near[*b]))
            .unwrap_or(0);
        picked.push(next);
    }
    let corr: Vec<serde_json::Value> = picked
        .iter()
        .map(|&i| {
            serde_json::json!({"source": {"point": deformed[i]}, "target": {"point": world[i]}})
        })
        .collect();
    Ok((source, serde_json::Value::Array(corr)))
}

/// Stage name → one time per run, and the quality line of the last run.
type Stages = (Vec<(String, Vec<f64>)>, String);

fn measure(
    source: (&str, &BlobSet),
    target: (&str, &BlobSet),
    constraints: &serde_json::Value,
    runs: usize,
) -> Result<Stages, String> {
    let mut stages: Vec<(String, Vec<f64>)> = Vec::new();
    let mut record = |name: &str, ms: f64| match stages.iter_mut().find(|(n, _)| n == name) {
        Some((_, v)) => v.push(ms),
        None => stages.push((name.to_string(), vec![ms])),
    };
    let mut quality = String::new();
    for _ in 0..runs {
        let c: Constraints =
            serde_json::from_value(constraints.clone()).map_err(|e| e.to_string())?;
        let input = TransferInput::pair(
            ModelInput {
                main: source.0,
                blobs: source.1,
            },
            ModelInput {
                main: target.0,
                blobs: target.1,
            },
            c,
        );
        let t0 = Instant::now();
        let out = transfer(&input, &Control::new()).map_err(|e| e.to_string())?;
        let whole = t0.elapsed().as_secs_f64() * 1e3;
        let mut core = 0.0;
        for t in &out.report.timings {
            record(&t.stage, t.ms);
            if t.stage != "load" && t.stage != "export" {
                core += t.ms;
            }
        }
        record("without load and export", core);
        record("whole transfer (load → export)", whole);
        let r = &out.report.method_report;
        quality = format!(
            "Hausdorff {:.4} of the target diagonal (fitted → target {:.4}), flipped area {:.2e}",
            r["hausdorff"]["max"].as_f64().unwrap_or(f64::NAN),
            r["hausdorff"]["source_to_target"]["max"]
                .as_f64()
                .unwrap_or(f64::NAN),
            r["flipped"]["area_fraction"].as_f64().unwrap_or(f64::NAN),
        );
    }
    Ok((stages, quality))
}

fn print_table(case: &str, runs: usize, (stages, quality): Stages) {
    println!("case: {case}\n");
    println!("| stage | retex (median of {runs}) | ElastiFace paper |");
    println!("|---|---|---|");
    for (stage, v) in stages {
        let reference = if stage.starts_with("whole") {
            "19k → 10k: 7 s (2013 Xeon, one thread)"
        } else {
            "—"
        };
        println!("| {stage} | {:.0} ms | {reference} |", median(v));
    }
    println!("\nquality: {quality}\n");
}

/// `main` welded and decimated to `ratio` of its vertices by one level of the MeshMatch
/// hierarchy (shortest edge first, midpoints), as an untextured GLB; and its vertex count.
fn decimated(main: &str, blobs: &BlobSet, ratio: f32) -> Result<(Vec<u8>, usize), String> {
    let asset = load(main, blobs, &IngestLimits::default()).map_err(|e| e.to_string())?;
    let surface = build_surface(&asset, &WeldParams::default()).map_err(|e| e.to_string())?;
    let params = HierarchyParams {
        target_ratio: ratio,
        // One level: its target n · ratio is above 0.75 of this, the next one's (n · ratio²) below.
        min_vertices: (surface.positions.len() as f32 * ratio / 0.8).ceil() as usize,
        ..HierarchyParams::default()
    };
    let hierarchy =
        build_hierarchy(&surface, &params, &Control::new()).map_err(|e| e.to_string())?;
    let coarse = &hierarchy.levels()[hierarchy.level_count().min(2) - 1].surface;
    let glb = mesh_glb(&coarse.positions, &coarse.faces).map_err(|e| e.to_string())?;
    Ok((glb, coarse.positions.len()))
}

/// The hand-placed head → Nefertiti landmarks of the engine test.
const NEFERTITI_LANDMARKS: &str =
    include_str!("../../tests/data/elastiface/head_to_nefertiti.json");

/// Runs the benchmark and prints the tables.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let runs = runs.max(1);
    let read = |rel: &str| {
        let p = assets.join(rel);
        BlobSet::from_path(&p).map_err(|e| format!("{}: {e}", p.display()))
    };
    let (hm, hb) = read(HEAD)?;
    let (source, corr) = case(&hm, &hb)?;
    let mut sb = BlobSet::new();
    sb.insert("template.glb", source);
    let c = serde_json::json!({
        "version": 1, "method": "elastiface", "correspondences": corr,
        "output": {"texture_size": 1024, "padding": 8}
    });
    let head = measure(("template.glb", &sb), (&hm, &hb), &c, runs)?;
    print_table(
        "deformed Lee Perry-Smith (8,844 welded vertices) → textured head (8,844), 18 \
         correspondences, 1024² texture",
        runs,
        head,
    );
    let (nm, nb) = read("tgt_nefertiti_bust_odedstein/nefertiti-lowres_derived.glb")?;
    let c: serde_json::Value =
        serde_json::from_str(NEFERTITI_LANDMARKS).map_err(|e| e.to_string())?;
    let nef = measure((&hm, &hb), (&nm, &nb), &c, runs)?;
    print_table(
        "Lee Perry-Smith head (8,844 welded vertices) → Nefertiti bust (35,002, no texture: no \
         bake), 19 hand-placed landmarks",
        runs,
        nef,
    );
    // The paper's size class and above: the 35k bust as the template (UV-less: the head's colour
    // on its vertices) fitted onto the 8.8k textured head, the same landmarks reversed.
    let mut reversed = c.clone();
    if let Some(list) = reversed["correspondences"].as_array_mut() {
        for pair in list {
            let (s, t) = (pair["source"].take(), pair["target"].take());
            pair["source"] = t;
            pair["target"] = s;
        }
    }
    let big = measure((&nm, &nb), (&hm, &hb), &reversed, runs)?;
    print_table(
        "Nefertiti bust (35,002 vertices) → textured head (8,844), the 19 landmarks reversed \
         (larger than the paper's 19k → 10k)",
        runs,
        big,
    );
    // The paper's size: the bust decimated to about 19k vertices (one level of the MeshMatch
    // hierarchy's shortest-edge collapse, ratio 0.55) as the template, the same landmarks (points,
    // so they stay valid on the coarser mesh).
    let (template, vertices) = decimated(&nm, &nb, 0.55)?;
    let mut tb = BlobSet::new();
    tb.insert("nefertiti19k.glb", template);
    let paper = measure(("nefertiti19k.glb", &tb), (&hm, &hb), &reversed, runs)?;
    print_table(
        &format!(
            "Nefertiti bust decimated to {vertices} vertices → textured head (8,844), the 19 \
             landmarks reversed (the paper's 19k → 10k)"
        ),
        runs,
        paper,
    );
    if let Some(p) = peak_rss_mib() {
        println!("peak resident memory of the process: {p:.0} MiB");
    }
    Ok(())
}
