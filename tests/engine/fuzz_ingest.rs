//! Fuzzing the engine's input parsers with the stable harness (`tests/common/fuzz.rs`, issue 9):
//! GLB ingest, `.gltf` ingest with external files, images inside a textured asset, and the
//! constraints document with each method's params check.
//!
//! Every accepted input is also welded into a surface and exported, as a job would. A finding is
//! a panic (the loader turns its own panics into `IngestError::Internal`, which counts as one),
//! or an input slower than 20 s. The default run is a few hundred inputs per target (seconds);
//! the ignored `fuzz_long_*` campaign (run by `.ci/run`) seeds from the shared assets too and runs
//! several thousand. `RETEX_FUZZ_ITERATIONS=N` overrides the count for a longer local run.

use std::time::Duration;

use retex::engine::asset::constraints::{Constraints, OutputFormat};
use retex::engine::asset::export::export;
use retex::engine::asset::{load_with, BlobSet, Decode, IngestError, IngestLimits};
use retex::engine::control::Control;
use retex::engine::mesh::{build_surface, WeldParams};
use retex::engine::methods::{MethodError, Registry};
use retex::engine::pipeline::{checked_method, transfer, ModelInput, TransferError, TransferInput};
use serde_json::json;

use crate::common::fuzz::{self, Campaign, Verdict};
use crate::common::mutate::Format;
use crate::common::{glb, shared_assets_dir, test_data_dir};

const GLTF_TOKENS: &[&str] = &[
    "\"accessors\"",
    "\"bufferViews\"",
    "\"buffers\"",
    "\"byteOffset\":",
    "\"byteLength\":",
    "\"byteStride\":",
    "\"count\":",
    "\"componentType\":5126",
    "\"componentType\":5123",
    "\"type\":\"VEC3\"",
    "\"indices\":",
    "\"mode\":",
    "\"children\":[0]",
    "\"matrix\":[0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0]",
    "\"uri\":\"data:application/octet-stream;base64,AAAA\"",
    "\"uri\":\"../../etc/passwd\"",
    "\"sparse\":{\"count\":1}",
    "\"extensionsRequired\":[\"KHR_draco_mesh_compression\"]",
    "\"texCoord\":7",
    "null",
    "[]",
    "{}",
    "-1",
    "1e400",
];

const CONSTRAINT_TOKENS: &[&str] = &[
    "\"method\":\"meshmatch\"",
    "\"method\":\"project\"",
    "\"method\":\"pattern\"",
    "\"params\":{}",
    "\"samples\":",
    "\"texture_size\":",
    "\"padding\":",
    "\"correspondences\":[{\"source\":{\"point\":[0,0,0]},\"target\":{\"point\":[1,1,1]}}]",
    "{\"vertex\":4294967295}",
    "{\"triangle\":0,\"barycentric\":[1,0,0]}",
    "\"seed\":",
    "\"output\":{\"uv\":\"auto\"}",
    "\"version\":2",
    "null",
    "NaN",
    "1e400",
    "-0",
];

/// Least fraction of mutants each campaign must get accepted (see [`Campaign::min_accepted`]):
/// about half of what the default runs measured (GLB 11%, .gltf 9%, images 3.7%, constraints
/// 1.9%, whole transfers 2.7%; the long runs over the shared assets 11%, 10%, 3.7%, 1.9%, 7.8%).
const MIN_ACCEPTED_GLTF: f64 = 0.05;
const MIN_ACCEPTED_IMAGE: f64 = 0.015;
const MIN_ACCEPTED_CONSTRAINTS: f64 = 0.008;
const MIN_ACCEPTED_TRANSFER: f64 = 0.012;

/// Limits a little tighter than the defaults so that a mutated header cannot make one
/// iteration allocate a gigabyte; what is fuzzed is that the limits hold, not their values.
fn limits() -> IngestLimits {
    IngestLimits {
        max_image_side: 4096,
        max_image_pixels: 4096 * 4096,
        max_image_alloc_bytes: 128 << 20,
        max_vertices: 2_000_000,
        max_triangles: 2_000_000,
        ..IngestLimits::default()
    }
}

/// Loads `main` from `blobs` as a job does; if accepted, welds and exports it.
fn ingest_verdict(main: &str, blobs: &BlobSet) -> Verdict {
    match load_with(main, blobs, &limits(), Decode::BaseColor) {
        Err(IngestError::Internal(message)) => Verdict::Finding(format!("internal: {message}")),
        Err(_) => Verdict::Refused,
        Ok(asset) => {
            let _ = build_surface(&asset, &WeldParams::default());
            let _ = export(&asset, &[], OutputFormat::Glb);
            Verdict::Accepted
        }
    }
}

/// Files under `dir` (recursively) whose names end with one of `extensions` and are at most
/// `max_bytes` long.
fn files(dir: &std::path::Path, extensions: &[&str], max_bytes: u64) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                if p.file_name().is_some_and(|n| n != "fuzz") {
                    stack.push(p);
                }
            } else if p.metadata().is_ok_and(|m| m.len() <= max_bytes)
                && extensions.iter().any(|x| p.to_string_lossy().ends_with(x))
            {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

fn read_all(paths: &[std::path::PathBuf]) -> Vec<Vec<u8>> {
    paths.iter().map(|p| std::fs::read(p).unwrap()).collect()
}

fn glb_campaign(seeds: Vec<Vec<u8>>, iterations: usize, seed: u64) {
    fuzz::run(
        Campaign {
            name: "glb",
            format: Format::Glb,
            seeds,
            dictionary: GLTF_TOKENS,
            iterations,
            seed,
            liveness: Duration::from_secs(20),
            min_accepted: MIN_ACCEPTED_GLTF,
        },
        |bytes| {
            let mut blobs = BlobSet::new();
            blobs.insert("m.glb", bytes.to_vec());
            ingest_verdict("m.glb", &blobs)
        },
    );
}

/// The root property that names a `.gltf` mutant's seed.
const SEED_KEY: &str = "x_fuzz_seed";

/// A `.gltf` seed: its main JSON and the files it names. Mutations apply to the JSON.
struct GltfSeed {
    main: String,
    blobs: BlobSet,
}

fn gltf_campaign(paths: &[std::path::PathBuf], iterations: usize, seed: u64) {
    let seeds: Vec<GltfSeed> = paths
        .iter()
        .filter_map(|p| BlobSet::from_path(p).ok())
        .map(|(main, blobs)| GltfSeed { main, blobs })
        .collect();
    // Seed i carries its index in an extra root property (which glTF readers ignore), so the
    // target knows which files go with a mutant; a mutant that lost it uses seed 0's files.
    let texts: Vec<Vec<u8>> = seeds
        .iter()
        .enumerate()
        .filter_map(|(i, s)| {
            let mut doc: serde_json::Value = serde_json::from_slice(s.blobs.get(&s.main)?).ok()?;
            doc.as_object_mut()?.insert(SEED_KEY.into(), json!(i));
            serde_json::to_vec(&doc).ok()
        })
        .collect();
    fuzz::run(
        Campaign {
            name: "gltf",
            format: Format::Json,
            seeds: texts,
            dictionary: GLTF_TOKENS,
            iterations,
            seed,
            liveness: Duration::from_secs(20),
            min_accepted: MIN_ACCEPTED_GLTF,
        },
        |bytes| {
            let index = serde_json::from_slice::<serde_json::Value>(bytes)
                .ok()
                .and_then(|d| d[SEED_KEY].as_u64())
                .unwrap_or(0) as usize;
            let s = &seeds[index % seeds.len()];
            let mut blobs = BlobSet::new();
            for name in s.blobs.names() {
                blobs.insert(name, s.blobs.get(name).unwrap().to_vec());
            }
            blobs.insert(s.main.clone(), bytes.to_vec());
            ingest_verdict(&s.main, &blobs)
        },
    );
}

/// A one-triangle GLB whose material's base colour texture is `image` (so the loader reads its
/// header and decodes it).
fn textured_triangle(image: &[u8]) -> Vec<u8> {
    let mut bin = Vec::new();
    for p in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
        p.iter()
            .for_each(|x| bin.extend_from_slice(&x.to_le_bytes()));
    }
    for uv in [[0f32, 0.], [1., 0.], [0., 1.]] {
        uv.iter()
            .for_each(|x| bin.extend_from_slice(&x.to_le_bytes()));
    }
    let image_offset = bin.len();
    bin.extend_from_slice(image);
    let doc = json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 24},
            {"buffer": 0, "byteOffset": image_offset, "byteLength": image.len()}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}
        ],
        "images": [{"bufferView": 2, "mimeType": if image.starts_with(b"\x89PNG") {"image/png"} else {"image/jpeg"}}],
        "textures": [{"source": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    });
    glb(&doc, &bin)
}

fn image_campaign(seeds: Vec<Vec<u8>>, iterations: usize, seed: u64) {
    fuzz::run(
        Campaign {
            name: "image",
            format: Format::Png,
            seeds,
            dictionary: &["IHDR", "IDAT", "IEND", "PLTE", "tRNS", "\u{ff}\u{c0}"],
            iterations,
            seed,
            liveness: Duration::from_secs(20),
            min_accepted: MIN_ACCEPTED_IMAGE,
        },
        |bytes| {
            let mut blobs = BlobSet::new();
            blobs.insert("m.glb", textured_triangle(bytes));
            ingest_verdict("m.glb", &blobs)
        },
    );
}

fn constraint_seeds() -> Vec<Vec<u8>> {
    [
        r#"{"version": 1, "method": "project"}"#,
        r#"{"version": 1, "method": "project", "output": {"texture_size": 512, "padding": 4, "format": "gltf"},
            "correspondences": [{"source": {"point": [0, 0, 0]}, "target": {"point": [0, 0, 0.1]}},
                                {"source": {"vertex": 3}, "target": {"triangle": 2, "barycentric": [0.2, 0.3, 0.5]}}]}"#,
        r#"{"version": 1, "method": "meshmatch", "seed": 7,
            "params": {"samples": 4096, "iterations": 3, "rings": 3, "spokes": 18, "shape_weight": 0.5,
                       "randomized_rotations": true, "write_nnf": false}}"#,
        r#"{"version": 1, "method": "meshmatch", "params": {"features": "hks", "example": {"color_0_channel": 0}}}"#,
        r#"{"version": 1, "method": "elastiface", "params": {}}"#,
    ]
    .iter()
    .map(|s| s.as_bytes().to_vec())
    .collect()
}

fn constraints_campaign(iterations: usize, seed: u64) {
    let registry = Registry::builtin();
    fuzz::run(
        Campaign {
            name: "constraints",
            format: Format::Json,
            seeds: constraint_seeds(),
            dictionary: CONSTRAINT_TOKENS,
            iterations,
            seed,
            liveness: Duration::from_secs(5),
            min_accepted: MIN_ACCEPTED_CONSTRAINTS,
        },
        |bytes| match Constraints::from_json(bytes)
            .map(|c| checked_method(&registry, &c, &IngestLimits::default()).is_ok())
        {
            Ok(true) => Verdict::Accepted,
            _ => Verdict::Refused,
        },
    );
}

/// Mutated targets through a whole `project` transfer (load, weld, BVH, bake or COLOR_0,
/// export) from a fixed textured box: degenerate geometry that loads must not crash a method.
fn transfer_campaign(seeds: Vec<Vec<u8>>, iterations: usize, seed: u64) {
    let source = std::fs::read(
        test_data_dir().join("edge_box_textured_variants_khronos/glTF-Binary/BoxTextured.glb"),
    )
    .unwrap();
    let mut source_blobs = BlobSet::new();
    source_blobs.insert("s.glb", source);
    fuzz::run(
        Campaign {
            name: "transfer",
            format: Format::Glb,
            seeds,
            dictionary: GLTF_TOKENS,
            iterations,
            seed,
            liveness: Duration::from_secs(60),
            min_accepted: MIN_ACCEPTED_TRANSFER,
        },
        |bytes| {
            let mut blobs = BlobSet::new();
            blobs.insert("t.glb", bytes.to_vec());
            let constraints = Constraints::from_json(
                br#"{"version": 1, "method": "project", "output": {"texture_size": 32}}"#,
            )
            .unwrap();
            let input = TransferInput::pair(
                ModelInput {
                    main: "s.glb",
                    blobs: &source_blobs,
                },
                ModelInput {
                    main: "t.glb",
                    blobs: &blobs,
                },
                constraints,
            )
            .with_limits(limits());
            match transfer(&input, &Control::new()) {
                Ok(_) => Verdict::Accepted,
                Err(TransferError::Ingest {
                    source: IngestError::Internal(m),
                    ..
                })
                | Err(TransferError::Method(MethodError::Internal(m))) => {
                    Verdict::Finding(format!("internal: {m}"))
                }
                Err(TransferError::Export(e)) => Verdict::Finding(format!("export: {e}")),
                Err(_) => Verdict::Refused,
            }
        },
    );
}

fn local_glbs() -> Vec<Vec<u8>> {
    read_all(&files(&test_data_dir(), &[".glb"], 200_000))
}

fn local_images() -> Vec<Vec<u8>> {
    read_all(&files(&test_data_dir(), &[".png", ".jpg", ".jpeg"], 60_000))
}

#[test]
fn fuzz_glb_ingest() {
    glb_campaign(local_glbs(), fuzz::iterations(400), 1);
}

#[test]
fn fuzz_gltf_ingest() {
    let paths = files(&test_data_dir(), &[".gltf"], 100_000);
    gltf_campaign(&paths, fuzz::iterations(400), 2);
}

#[test]
fn fuzz_images_in_an_asset() {
    image_campaign(local_images(), fuzz::iterations(300), 3);
}

#[test]
fn fuzz_targets_through_a_transfer() {
    transfer_campaign(local_glbs(), fuzz::iterations(150), 5);
}

#[test]
fn fuzz_constraints_and_params() {
    constraints_campaign(fuzz::iterations(3000), 4);
}

/// Every committed finding still loads without a panic or an internal error.
#[test]
fn replay_regressions() {
    for target in ["glb", "image"] {
        for (name, bytes) in fuzz::regressions(target) {
            let blobs = {
                let mut b = BlobSet::new();
                let main = if target == "glb" {
                    bytes
                } else {
                    textured_triangle(&bytes)
                };
                b.insert("m.glb", main);
                b
            };
            if let Verdict::Finding(why) = ingest_verdict("m.glb", &blobs) {
                panic!("tests/data/fuzz/{target}/{name}: {why}");
            }
        }
    }
}

/// The longer campaign CI runs: seeds from the shared assets as well, several thousand inputs
/// per target.
#[test]
#[ignore = "needs the shared assets (../shared/assets); a longer fuzz campaign"]
fn fuzz_long_campaign_over_the_shared_assets() {
    let shared = shared_assets_dir();
    assert!(shared.is_dir(), "{} is missing", shared.display());
    let mut glbs = local_glbs();
    glbs.extend(read_all(&files(&shared, &[".glb"], 400_000)));
    glb_campaign(glbs, fuzz::iterations(20000), 11);
    let mut gltfs = files(&test_data_dir(), &[".gltf"], 100_000);
    gltfs.extend(files(&shared, &[".gltf"], 200_000));
    gltf_campaign(&gltfs, fuzz::iterations(20000), 12);
    let mut images = local_images();
    images.extend(read_all(&files(&shared, &[".png", ".jpg"], 100_000)));
    image_campaign(images, fuzz::iterations(8000), 13);
    constraints_campaign(fuzz::iterations(50000), 14);
    let mut targets = local_glbs();
    targets.extend(read_all(&files(&shared, &[".glb"], 400_000)));
    transfer_campaign(targets, fuzz::iterations(2000), 15);
}
