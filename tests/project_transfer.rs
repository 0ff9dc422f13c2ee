//! The `project` method end to end on the shared assets: identity, round trip between two
//! tessellations, alignment from correspondences, determinism, coverage bookkeeping, and the
//! Khronos validator on every output.

mod common;

use common::*;
use retex::engine::asset::constraints::{Constraints, OutputFormat};
use retex::engine::asset::{Asset, BlobSet, IngestLimits};
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferError, TransferInput, TransferOutput};
use retex::engine::texture::bake::rasterize_uv_layout;
use serde_json::json;

const SPOT: &str = "src_spot_keenan/spot_textured_derived.glb";
const SPOT_REMESHED: &str = "tgt_spot_remeshed_odedstein/spot_derived.glb";

fn blobs_of(path: &std::path::Path) -> (String, BlobSet) {
    BlobSet::from_path(path).expect("read model")
}

fn blobs_from_bytes(name: &str, bytes: Vec<u8>) -> (String, BlobSet) {
    let mut b = BlobSet::new();
    b.insert(name, bytes);
    (name.to_string(), b)
}

fn run(
    source: &(String, BlobSet),
    target: &(String, BlobSet),
    constraints: Constraints,
) -> Result<TransferOutput, TransferError> {
    let input = TransferInput {
        source: ModelInput {
            main: &source.0,
            blobs: &source.1,
        },
        target: ModelInput {
            main: &target.0,
            blobs: &target.1,
        },
        constraints,
        limits: IngestLimits::default(),
    };
    transfer(&input, &Control::new())
}

fn constraints(value: serde_json::Value) -> Constraints {
    Constraints::from_json(value.to_string().as_bytes()).expect("valid constraints")
}

/// The decoded base-color image of material `m`.
fn base_color(asset: &Asset, m: usize) -> (u32, u32, Vec<[u8; 4]>) {
    let t = asset.materials[m]
        .base_color_texture
        .expect("material has a base color texture");
    let img = asset.textures[t.texture]
        .image
        .expect("texture has an image");
    let d = asset.images[img]
        .decoded
        .as_ref()
        .expect("base color decoded");
    (d.width, d.height, d.pixels.clone())
}

/// Texels covered by the UV layout (TEXCOORD_0) of every primitive.
fn coverage(asset: &Asset, size: u32) -> Vec<bool> {
    let tris: Vec<[[f32; 2]; 3]> = asset
        .primitives
        .iter()
        .flat_map(|p| {
            p.triangles
                .iter()
                .map(move |t| t.map(|v| p.tex_coords[0][v as usize]))
        })
        .collect();
    rasterize_uv_layout(&tris, size, size).mask()
}

fn spot_psnr(out: &TransferOutput, name: &str) -> f64 {
    assert_validator_clean(&out.model, name);
    let spot = load_path(&shared_asset(SPOT));
    let result = load_bytes(&out.model, "out.glb");
    let (w, h, expected) = base_color(&spot, 0);
    let (w2, h2, got) = base_color(&result, 0);
    assert_eq!((w, h), (w2, h2));
    psnr_masked(&expected, &got, &coverage(&spot, w))
}

#[test]
fn identity_on_spot_reproduces_the_texture() {
    let spot = blobs_of(&shared_asset(SPOT));
    let out = run(
        &spot,
        &spot,
        constraints(json!({"version": 1, "output": {"texture_size": 1024}})),
    )
    .unwrap();
    let psnr = spot_psnr(&out, "identity_spot.glb");
    assert!(psnr >= 40.0, "identity PSNR {psnr:.2} dB");
}

#[test]
fn coverage_report_adds_up() {
    let spot = blobs_of(&shared_asset(SPOT));
    let out = run(
        &spot,
        &spot,
        constraints(json!({"version": 1, "output": {"texture_size": 256, "padding": 4}})),
    )
    .unwrap();
    let tex = &out.report.method_report["textures"][0];
    let n = |k: &str| tex[k].as_u64().unwrap();
    assert!(n("covered") > 256 * 256 / 4, "{tex}");
    assert!(n("unmatched") <= n("covered"));
    assert_eq!(
        n("covered") - n("unmatched") + n("padded") + n("filled"),
        256 * 256,
        "{tex}"
    );
    assert!(n("padded") > 0);
    assert_eq!(n("triangles"), 5856);
}

#[test]
fn round_trip_through_a_remeshed_copy_keeps_the_texture() {
    let spot = blobs_of(&shared_asset(SPOT));
    let remeshed = blobs_of(&shared_asset(SPOT_REMESHED));
    // A → B: B has no UVs, so the color goes to COLOR_0 on a refined copy.
    let ab = run(
        &spot,
        &remeshed,
        constraints(json!({"version": 1, "params": {"vertex_color_samples": 400000}})),
    )
    .unwrap();
    assert_validator_clean(&ab.model, "roundtrip_spot_to_remeshed.glb");
    let vc = &ab.report.method_report["vertex_colors"][0];
    assert_eq!(vc["refined"], true, "{vc}");
    assert!(vc["vertices"].as_u64().unwrap() >= 300_000, "{vc}");
    // B → A: sampled from B's COLOR_0.
    let b = blobs_from_bytes("b.glb", ab.model.clone());
    let ba = run(
        &b,
        &spot,
        constraints(json!({"version": 1, "output": {"texture_size": 1024}})),
    )
    .unwrap();
    let psnr = spot_psnr(&ba, "roundtrip_back_to_spot.glb");
    assert!(psnr >= 30.0, "round trip PSNR {psnr:.2} dB");
}

/// Builds a GLB from JSON and a binary chunk.
fn glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(json).unwrap();
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let mut bin = bin.to_vec();
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// Splits a GLB into its JSON and BIN chunks.
fn unglb(bytes: &[u8]) -> (serde_json::Value, Vec<u8>) {
    let jlen = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json = serde_json::from_slice(&bytes[20..20 + jlen]).unwrap();
    let rest = &bytes[20 + jlen..];
    let blen = u32::from_le_bytes(rest[0..4].try_into().unwrap()) as usize;
    (json, rest[8..8 + blen].to_vec())
}

#[test]
fn alignment_from_four_correspondences_transfers_like_the_unmoved_case() {
    let spot_path = shared_asset(SPOT);
    let spot_bytes = std::fs::read(&spot_path).unwrap();
    let spot_asset = load_path(&spot_path);
    // Target: Spot under a node with scale 2.5, a rotation of 1.1 rad about (0.3, 1, 0.2), and a
    // translation.
    let (s, angle) = (2.5f64, 1.1f64);
    let axis = {
        let a = [0.3f64, 1.0, 0.2];
        let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        a.map(|x| x / n)
    };
    let (c, si) = (angle.cos(), angle.sin());
    let [x, y, z] = axis;
    let r = [
        [
            c + x * x * (1.0 - c),
            x * y * (1.0 - c) - z * si,
            x * z * (1.0 - c) + y * si,
        ],
        [
            y * x * (1.0 - c) + z * si,
            c + y * y * (1.0 - c),
            y * z * (1.0 - c) - x * si,
        ],
        [
            z * x * (1.0 - c) - y * si,
            z * y * (1.0 - c) + x * si,
            c + z * z * (1.0 - c),
        ],
    ];
    let t = [3.0, -1.0, 2.0];
    let apply = |p: [f32; 3]| -> [f64; 3] {
        let p = p.map(f64::from);
        std::array::from_fn(|i| s * (r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2]) + t[i])
    };
    let (mut doc, bin) = unglb(&spot_bytes);
    let roots = doc["scenes"][doc["scene"].as_u64().unwrap_or(0) as usize]["nodes"].clone();
    let matrix: Vec<f64> = (0..16)
        .map(|k| {
            let (col, row) = (k / 4, k % 4);
            match (row, col) {
                (3, 3) => 1.0,
                (3, _) => 0.0,
                (_, 3) => t[row],
                _ => s * r[row][col],
            }
        })
        .collect();
    let nodes = doc["nodes"].as_array_mut().unwrap();
    nodes.push(json!({"name": "moved", "matrix": matrix, "children": roots}));
    let new_root = nodes.len() - 1;
    let scene = doc["scene"].as_u64().unwrap_or(0) as usize;
    doc["scenes"][scene]["nodes"] = json!([new_root]);
    let moved = blobs_from_bytes("moved.glb", glb(&doc, &bin));
    let spot = blobs_of(&spot_path);

    let prim = &spot_asset.primitives[0];
    let picks = [0usize, 700, 1600, 3000];
    let corr: Vec<serde_json::Value> = picks
        .iter()
        .map(|&i| {
            json!({"source": {"vertex": {"mesh": prim.mesh, "primitive": prim.primitive, "index": i}},
                   "target": {"point": apply(prim.positions[i])}})
        })
        .collect();
    let aligned = run(
        &spot,
        &moved,
        constraints(
            json!({"version": 1, "correspondences": corr, "output": {"texture_size": 1024}}),
        ),
    )
    .unwrap();
    let al = &aligned.report.method_report["alignment"];
    assert!(
        (al["transform"]["scale"].as_f64().unwrap() - 2.5).abs() < 1e-3,
        "{al}"
    );
    assert!(al["rms_error"].as_f64().unwrap() < 1e-3, "{al}");
    let psnr_aligned = spot_psnr(&aligned, "aligned_spot.glb");
    let unmoved = run(
        &spot,
        &spot,
        constraints(json!({"version": 1, "output": {"texture_size": 1024}})),
    )
    .unwrap();
    let psnr_unmoved = spot_psnr(&unmoved, "unmoved_spot.glb");
    assert!(
        psnr_aligned >= 40.0 && psnr_aligned >= psnr_unmoved - 1.0,
        "aligned {psnr_aligned:.2} vs unmoved {psnr_unmoved:.2}"
    );
    // Without correspondences the moved target cannot be matched: the test above is meaningful.
    let naive = run(
        &spot,
        &moved,
        constraints(json!({"version": 1, "output": {"texture_size": 1024}})),
    )
    .unwrap();
    let psnr_naive = spot_psnr(&naive, "naive_moved_spot.glb");
    assert!(psnr_naive < 25.0, "naive {psnr_naive:.2}");
}

#[test]
fn output_is_byte_identical_across_runs_and_thread_counts() {
    let spot = blobs_of(&shared_asset(SPOT));
    let remeshed = blobs_of(&shared_asset(
        "tgt_spot_remeshed_odedstein/spot_low_resolution_derived.glb",
    ));
    let c = constraints(
        json!({"version": 1, "output": {"texture_size": 256}, "params": {"vertex_color_samples": 20000}}),
    );
    let once = |threads: usize, target: &(String, BlobSet)| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| run(&spot, target, c.clone()).unwrap().model)
    };
    for target in [&spot, &remeshed] {
        let a = once(1, target);
        let b = once(2, target);
        let c2 = once(2, target);
        assert!(a == b && b == c2, "outputs differ for {}", target.0);
    }
}

#[test]
fn gltf_output_with_embedded_buffers_validates() {
    let spot = blobs_of(&shared_asset(SPOT));
    let out = run(
        &spot,
        &spot,
        constraints(json!({"version": 1, "output": {"texture_size": 128, "format": "gltf"}})),
    )
    .unwrap();
    assert_eq!(out.format, OutputFormat::Gltf);
    assert!(out.model.starts_with(b"{"));
    assert_validator_clean(&out.model, "spot_embedded.gltf");
    let back = load_bytes(&out.model, "spot_embedded.gltf");
    assert_eq!(base_color(&back, 0).0, 128);
}

#[test]
fn gating_by_distance_leaves_far_texels_unmatched() {
    let spot = blobs_of(&shared_asset(SPOT));
    let sphere = blobs_of(&shared_asset(
        "tgt_primitives_odedstein_sphere/sphere_derived.glb",
    ));
    let out = run(
        &spot,
        &sphere,
        constraints(
            json!({"version": 1, "params": {"max_distance": 0.01, "vertex_color_samples": 5000}}),
        ),
    )
    .unwrap();
    assert_validator_clean(&out.model, "gated_sphere.glb");
    let vc = &out.report.method_report["vertex_colors"][0];
    assert!(vc["unmatched"].as_u64().unwrap() > 0, "{vc}");
}

#[test]
fn bad_requests_fail_with_clear_errors() {
    let spot = blobs_of(&shared_asset(SPOT));
    let e = run(
        &spot,
        &spot,
        constraints(json!({"version": 1, "method": "meshmatch"})),
    )
    .unwrap_err();
    assert!(e.to_string().contains("not implemented"), "{e}");
    let e = run(
        &spot,
        &spot,
        constraints(json!({"version": 1, "params": {"max_distanse": 1}})),
    )
    .unwrap_err();
    assert!(
        matches!(&e, TransferError::Constraints(c) if c.path.starts_with("params")),
        "{e}"
    );
    let far = json!({"version": 1, "correspondences": [
        {"source": {"point": [0.0, 0.0, 0.0]}, "target": {"point": [100.0, 0.0, 0.0]}},
        {"source": {"point": [0.0, 0.0, 0.0]}, "target": {"point": [0.0, 0.0, 0.0]}}]});
    let e = run(&spot, &spot, constraints(far)).unwrap_err();
    match &e {
        TransferError::Constraints(c) => assert!(c.path.starts_with("correspondences[0]"), "{e}"),
        other => panic!("unexpected {other}"),
    }
    let idx = json!({"version": 1, "correspondences": [
        {"source": {"vertex": {"mesh": 0, "primitive": 0, "index": 99999999}}, "target": {"point": [0.0, 0.0, 0.0]}}]});
    let e = run(&spot, &spot, constraints(idx)).unwrap_err();
    assert!(
        e.to_string()
            .contains("correspondences[0].source.vertex.index"),
        "{e}"
    );
}
