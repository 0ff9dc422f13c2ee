//! The `project` method end to end on Spot and its remeshes (`tests/data`): identity, round trip
//! between two tessellations, alignment from correspondences, determinism, coverage bookkeeping,
//! and the Khronos validator on every output.

use crate::common::glb;

use crate::common::*;
use retex::engine::asset::constraints::{Constraints, OutputFormat};
use retex::engine::asset::{Asset, BlobSet};
use retex::engine::control::Control;
use retex::engine::mesh::{build_surface, WeldParams};
use retex::engine::pipeline::{transfer, ModelInput, TransferError, TransferInput, TransferOutput};
use retex::engine::spatial::Bvh;
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
    let spot = load_path(&test_data(SPOT));
    let result = load_bytes(&out.model, "out.glb");
    let (w, h, expected) = base_color(&spot, 0);
    let (w2, h2, got) = base_color(&result, 0);
    assert_eq!((w, h), (w2, h2));
    psnr_masked(&expected, &got, &coverage(&spot, w))
}

#[test]
fn identity_on_spot_reproduces_the_texture() {
    let spot = blobs_of(&test_data(SPOT));
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
    let spot = blobs_of(&test_data(SPOT));
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

/// Texels of Spot's layout whose surface point lies within `band` (fraction of the bounding-box
/// diagonal) of the remeshed copy: where the two tessellations describe the same surface. The
/// remesh deviates by 0.66 % of the diagonal on average and up to 3.9 % at the horns and ears
/// (shared/assets/INDEX.md), where no projection can be expected to round-trip.
fn texels_where_surfaces_agree(
    spot: &Asset,
    remeshed: &Asset,
    size: u32,
    band: f32,
) -> (Vec<bool>, usize, usize) {
    let surf = build_surface(remeshed, &WeldParams::default()).unwrap();
    let bvh = Bvh::build(&surf.positions, &surf.faces);
    let limit = band * surf.diagonal();
    let prim = &spot.primitives[0];
    let inst = &spot.instances[0];
    let tris: Vec<[[f32; 2]; 3]> = prim
        .triangles
        .iter()
        .map(|t| t.map(|v| prim.tex_coords[0][v as usize]))
        .collect();
    let map = rasterize_uv_layout(&tris, size, size);
    let mut mask = vec![false; map.hits.len()];
    let (mut covered, mut kept) = (0, 0);
    for (i, hit) in map.hits.iter().enumerate() {
        let Some(h) = hit else { continue };
        covered += 1;
        let t = prim.triangles[h.triangle as usize];
        let mut p = [0.0f32; 3];
        for k in 0..3 {
            let w = inst.transform_point(prim.positions[t[k] as usize]);
            for c in 0..3 {
                p[c] += h.bary[k] * w[c] as f32;
            }
        }
        if bvh.closest_point(p, limit).is_some() {
            mask[i] = true;
            kept += 1;
        }
    }
    (mask, covered, kept)
}

/// A → B → A, where B has no UVs (so B carries COLOR_0 on a refined copy) and A is baked back
/// from B's vertex colors. Returns (PSNR over the texels where the surfaces agree, kept, covered).
fn round_trip(
    a: &std::path::Path,
    b: &std::path::Path,
    params: serde_json::Value,
    band: f32,
    name: &str,
) -> (f64, usize, usize) {
    let src = blobs_of(a);
    let tgt = blobs_of(b);
    let mut forward = params.clone();
    forward["vertex_color_samples"] = json!(400000);
    let ab = run(
        &src,
        &tgt,
        constraints(json!({"version": 1, "output": {"uv": "keep"}, "params": forward})),
    )
    .unwrap();
    assert_validator_clean(&ab.model, &format!("{name}_forward.glb"));
    let vc = &ab.report.method_report["vertex_colors"][0];
    assert_eq!(vc["refined"], true, "{vc}");
    assert!(vc["vertices"].as_u64().unwrap() >= 300_000, "{vc}");
    let a_asset = load_path(a);
    let (w, _, expected) = base_color(&a_asset, 0);
    let mid = blobs_from_bytes("b.glb", ab.model.clone());
    let ba = run(
        &mid,
        &src,
        constraints(json!({"version": 1, "output": {"texture_size": w}, "params": params})),
    )
    .unwrap();
    assert_validator_clean(&ba.model, &format!("{name}_back.glb"));
    let (_, _, got) = base_color(&load_bytes(&ba.model, "back.glb"), 0);
    let (mask, covered, kept) = texels_where_surfaces_agree(&a_asset, &load_path(b), w, band);
    let psnr = psnr_masked(&expected, &got, &mask);
    let psnr_all = psnr_masked(&expected, &got, &coverage(&a_asset, w));
    eprintln!("{name}: {psnr:.2} dB where the surfaces agree ({kept}/{covered} texels), {psnr_all:.2} dB everywhere");
    (psnr, kept, covered)
}

/// Blub and its low-resolution remesh agree to 0.03 % of the diagonal on average (INDEX.md: the
/// cleanest ground-truth pair), so the round trip must reproduce the 2048² texture.
#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn round_trip_through_a_remeshed_copy_keeps_the_texture() {
    let (psnr, kept, covered) = round_trip(
        &shared_asset("src_blub_keenan/blub_textured_derived.glb"),
        &shared_asset("tgt_fish_remeshed_odedstein/fish_low_resolution_derived.glb"),
        json!({}),
        1.0,
        "roundtrip_blub",
    );
    assert_eq!(kept, covered);
    assert!(psnr >= 30.0, "round trip PSNR {psnr:.2} dB");
}

/// Spot's remesh is a different subdivision level: 0.66 % mean and up to 3.9 % deviation, largest
/// at the thin ears and horns, where the closest point of one surface lies on the other side of
/// the ear plate of the other. Normal gating (30°) keeps sides apart; what remains is the ears'
/// different shape. A regression guard at the level closest-point projection reaches here.
#[test]
fn round_trip_on_spot_with_normal_gating_stays_close() {
    let (psnr, kept, covered) = round_trip(
        &test_data(SPOT),
        &test_data(SPOT_REMESHED),
        json!({"max_normal_angle": 30.0}),
        0.02,
        "roundtrip_spot",
    );
    assert!(
        kept as f64 >= 0.9 * covered as f64,
        "only {kept} of {covered} texels within the band"
    );
    assert!(psnr >= 24.0, "round trip PSNR {psnr:.2} dB");
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
    let spot_path = test_data(SPOT);
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
    let spot = blobs_of(&test_data(SPOT));
    let remeshed = blobs_of(&test_data(
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
    let spot = blobs_of(&test_data(SPOT));
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
    let spot = blobs_of(&test_data(SPOT));
    let sphere = blobs_of(&test_data(
        "tgt_primitives_odedstein_sphere/sphere_derived.glb",
    ));
    let out = run(
        &spot,
        &sphere,
        constraints(
            json!({"version": 1, "output": {"uv": "keep"}, "params": {"max_distance": 0.01, "vertex_color_samples": 5000}}),
        ),
    )
    .unwrap();
    assert_validator_clean(&out.model, "gated_sphere.glb");
    let vc = &out.report.method_report["vertex_colors"][0];
    assert!(vc["unmatched"].as_u64().unwrap() > 0, "{vc}");
}

#[test]
fn bad_requests_fail_with_clear_errors() {
    let spot = blobs_of(&test_data(SPOT));
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
