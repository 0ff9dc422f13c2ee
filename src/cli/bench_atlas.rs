//! `retex bench --method atlas`: the UV atlas of issue 15 (`src/engine/uv/`) and the whole
//! `retex transfer` (`project`, Spot → a UV-less target: load, align, atlas, 2048² bake, pad,
//! export) on geodesic spheres of 10k / 40k / 160k vertices and on the shared UV-less targets,
//! next to the peers' whole-process figures that issue 15 gives (Blender 4.5 Smart UV Project +
//! bake; PyMeshLab Voronoi atlas + transfer). The atlas time is the sum of the transfer's
//! `atlas_*` stages (weld, charts, packing and the split primitives), measured by `Control`;
//! `atlas_pack` is that stage alone (orientation, packing, layout); the whole time is the wall
//! clock around `transfer`. Prints Markdown for the README.

use std::path::Path;
use std::time::Instant;

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::export::mesh_glb;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::mesh::primitives::icosphere;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

/// The textured source of every transfer.
const SOURCE: &str = "src_spot_keenan/spot_textured_derived.glb";

/// Shared UV-less targets: (label, path).
const TARGETS: [(&str, &str); 6] = [
    ("cat", "tgt_cat_odedstein/cat-low-resolution_derived.glb"),
    ("fish", "tgt_fish_remeshed_odedstein/fish_derived.glb"),
    (
        "Demosthenes (scan, open)",
        "tgt_demosthenes_bust_odedstein/demosthenes-low-res_derived.glb",
    ),
    (
        "Nefertiti (scan)",
        "tgt_nefertiti_bust_odedstein/nefertiti-lowres_derived.glb",
    ),
    ("koala", "perf_koala_odedstein/koala_derived.glb"),
    ("skull (genus 2)", "perf_skull_odedstein/skull_derived.glb"),
];

/// Peers' whole-process times from issue 15 (Blender 4.5, PyMeshLab), per sphere size.
const PEERS: [(&str, &str); 3] = [("4.9 s", "5.1 s"), ("5.5 s", "5.5 s"), ("9.6 s", "10.6 s")];

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The constraints of every transfer: the defaults, with `output.atlas_parameterization` from
/// `$RETEX_ATLAS_PARAMETERIZATION` (`lscm` or `arap`) when set, to compare the two.
fn constraints() -> Constraints {
    let mut c = Constraints::default();
    if let Ok(p) = std::env::var("RETEX_ATLAS_PARAMETERIZATION") {
        c.output.atlas_parameterization = match p.as_str() {
            "arap" => retex::engine::asset::constraints::AtlasParameterization::Arap,
            _ => retex::engine::asset::constraints::AtlasParameterization::Lscm,
        };
    }
    c
}

/// Medians of one target over `runs` transfers.
struct Row {
    atlas_ms: f64,
    pack_ms: f64,
    bake_ms: f64,
    whole_ms: f64,
    figures: String,
}

fn measure(
    source: &(String, BlobSet),
    target: &(String, BlobSet),
    runs: usize,
) -> Result<Row, String> {
    let (mut atlas, mut bake, mut whole) = (Vec::new(), Vec::new(), Vec::new());
    let mut pack = Vec::new();
    let mut figures = String::new();
    for _ in 0..runs {
        let input = TransferInput::pair(
            ModelInput {
                main: &source.0,
                blobs: &source.1,
            },
            ModelInput {
                main: &target.0,
                blobs: &target.1,
            },
            constraints(),
        );
        let t0 = Instant::now();
        let out = transfer(&input, &Control::new()).map_err(|e| e.to_string())?;
        whole.push(t0.elapsed().as_secs_f64() * 1e3);
        let stages = |prefix: &str| -> f64 {
            (out.report.timings.iter())
                .filter(|t| t.stage.starts_with(prefix))
                .map(|t| t.ms)
                .sum()
        };
        atlas.push(stages("atlas_"));
        pack.push(stages("atlas_pack"));
        bake.push(stages("bake") + stages("pad"));
        let a = &out.report.method_report["atlas"];
        let vertices = &out.report.method_report["target_surface"]["vertices"];
        figures = if a.is_null() {
            format!("{vertices} | no atlas")
        } else {
            format!(
                "{vertices} | {} | {:.3} (L∞ {:.2}) | {:.2} | {:.4}",
                a["chart_count"],
                a["l2_stretch"].as_f64().unwrap_or(f64::NAN),
                a["linf_stretch"].as_f64().unwrap_or(f64::NAN),
                a["packing_efficiency"].as_f64().unwrap_or(f64::NAN),
                // World length × texels per unit / texels per texture width.
                a["seam_length"].as_f64().unwrap_or(f64::NAN)
                    * a["texels_per_unit"].as_f64().unwrap_or(f64::NAN)
                    / a["texture_size"].as_f64().unwrap_or(f64::NAN),
            )
        };
    }
    Ok(Row {
        atlas_ms: median(atlas),
        pack_ms: median(pack),
        bake_ms: median(bake),
        whole_ms: median(whole),
        figures,
    })
}

/// Runs the benchmark `runs` times per target and prints the tables.
pub fn run(assets: &Path, runs: usize) -> Result<(), String> {
    let runs = runs.max(1);
    let read = |rel: &str| {
        let p = assets.join(rel);
        BlobSet::from_path(&p).map_err(|e| format!("{}: {e}", p.display()))
    };
    let source = read(SOURCE)?;
    println!("Spot → target, `project` with default constraints (output.uv = auto, 2048², padding 4), median of {runs}:\n");
    println!("| target | atlas | atlas_pack | bake + pad | whole transfer | Blender 4.5 bake | PyMeshLab atlas + transfer | vertices | charts | L2 | packing | seams (texture widths) |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (frequency, peers) in [32usize, 63, 127].into_iter().zip(PEERS) {
        let sphere = icosphere(1.0, frequency);
        let glb = mesh_glb(&sphere.positions, &sphere.faces).map_err(|e| e.to_string())?;
        let mut blobs = BlobSet::new();
        blobs.insert("sphere.glb", glb);
        let target = ("sphere.glb".to_string(), blobs);
        let row = measure(&source, &target, runs)?;
        println!(
            "| sphere | {:.0} ms | {:.0} ms | {:.0} ms | {:.0} ms | {} | {} | {} |",
            row.atlas_ms, row.pack_ms, row.bake_ms, row.whole_ms, peers.0, peers.1, row.figures
        );
    }
    for (label, rel) in TARGETS {
        let target = read(rel)?;
        let row = measure(&source, &target, runs)?;
        println!(
            "| {label} | {:.0} ms | {:.0} ms | {:.0} ms | {:.0} ms | | | {} |",
            row.atlas_ms, row.pack_ms, row.bake_ms, row.whole_ms, row.figures
        );
    }
    Ok(())
}
