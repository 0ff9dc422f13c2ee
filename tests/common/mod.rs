//! Shared test fixtures: the test data shipped in `tests/data`, where the shared assets live,
//! the glTF validator, loading and comparing models.
#![allow(dead_code)]

use std::path::PathBuf;

pub mod fuzz;
pub mod mutate;
pub mod planar_pattern;

/// The small, freely licensed assets committed with the repository (`tests/data`, listed with
/// their sources and licences in `tests/data/README.md`).
pub fn test_data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

/// Path of a file under `tests/data` (the same relative path as in the shared assets); panics
/// with a clear message when missing.
pub fn test_data(relative: &str) -> PathBuf {
    let p = test_data_dir().join(relative);
    assert!(
        p.exists(),
        "test data {} not found (tests/data is part of the repository; see tests/data/README.md)",
        p.display()
    );
    p
}

/// The shared asset folder: `$RETEX_SHARED_ASSETS`, else `../shared/assets` next to the crate.
pub fn shared_assets_dir() -> PathBuf {
    if let Ok(dir) = std::env::var("RETEX_SHARED_ASSETS") {
        return PathBuf::from(dir);
    }
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/assets")
}

/// Path of a file under the shared asset folder; panics with a clear message when missing. Only
/// for tests marked `#[ignore = "needs the shared assets ..."]`: the default suite uses
/// [`test_data`].
pub fn shared_asset(relative: &str) -> PathBuf {
    let p = shared_assets_dir().join(relative);
    assert!(
        p.exists(),
        "shared asset {} not found (set RETEX_SHARED_ASSETS)",
        p.display()
    );
    p
}

/// Writes `bytes` under `target/test-outputs/NAME` and asserts that the Khronos glTF-Validator
/// (npm `gltf-validator`, installed by `.ci/run` into `tests/validator/node_modules`) reports
/// zero errors. Set `RETEX_SKIP_VALIDATOR=1` to skip where node is not available.
///
/// Tests run in parallel and several may validate under the same `name`: each name has its own
/// lock, held while the file is written and validated, so the validator never reads a file that
/// another test is rewriting.
pub fn assert_validator_clean(bytes: &[u8], name: &str) {
    let name_lock = validator_name_lock(name);
    let _held = name_lock
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs");
    std::fs::create_dir_all(&dir).expect("create test output folder");
    let file = dir.join(name);
    std::fs::write(&file, bytes).expect("write test output");
    if std::env::var("RETEX_SKIP_VALIDATOR").is_ok_and(|v| v == "1") {
        eprintln!("validator skipped for {name} (RETEX_SKIP_VALIDATOR=1)");
        return;
    }
    let harness = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/validator");
    assert!(
        harness.join("node_modules/gltf-validator").exists(),
        "gltf-validator is not installed: run `npm install --prefix tests/validator --no-package-lock` (or set RETEX_SKIP_VALIDATOR=1)"
    );
    let out = std::process::Command::new("node")
        .arg(harness.join("validate.mjs"))
        .arg(&file)
        .output()
        .expect("run node");
    assert!(
        out.status.success(),
        "validator failed to run: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let line = String::from_utf8_lossy(&out.stdout);
    let report: serde_json::Value = serde_json::from_str(line.trim()).expect("validator json");
    assert_eq!(
        report["errors"], 0,
        "validator errors in {name}: {}",
        report["messages"]
    );
}

/// The lock of one output file name (one per name, for the life of the test process).
fn validator_name_lock(name: &str) -> std::sync::Arc<std::sync::Mutex<()>> {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex, OnceLock};
    static LOCKS: OnceLock<Mutex<HashMap<String, Arc<Mutex<()>>>>> = OnceLock::new();
    let mut locks = LOCKS
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    locks.entry(name.to_string()).or_default().clone()
}

/// Loads a model file from disk with default limits.
pub fn load_path(path: &std::path::Path) -> retex::engine::asset::Asset {
    let (main, blobs) = retex::engine::asset::BlobSet::from_path(path).expect("read model");
    retex::engine::asset::load(&main, &blobs, &Default::default()).expect("load model")
}

/// Loads a model from bytes (a GLB or a self-contained .gltf).
pub fn load_bytes(bytes: &[u8], name: &str) -> retex::engine::asset::Asset {
    let mut blobs = retex::engine::asset::BlobSet::new();
    blobs.insert(name, bytes.to_vec());
    retex::engine::asset::load(name, &blobs, &Default::default()).expect("load output")
}

/// PSNR in dB between two equally sized sRGB images over the texels where `mask` is true,
/// on the 8-bit RGB channels.
pub fn psnr_masked(a: &[[u8; 4]], b: &[[u8; 4]], mask: &[bool]) -> f64 {
    assert_eq!(a.len(), b.len());
    let mut se = 0.0f64;
    let mut n = 0usize;
    for i in 0..a.len() {
        if mask[i] {
            for k in 0..3 {
                let d = a[i][k] as f64 - b[i][k] as f64;
                se += d * d;
            }
            n += 3;
        }
    }
    assert!(n > 0, "empty mask");
    let mse = se / n as f64;
    if mse == 0.0 {
        return f64::INFINITY;
    }
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

/// Builds a GLB from a JSON document and a binary chunk (both padded to 4 bytes; no BIN chunk
/// when `bin` is empty), with the exporter's container writer.
pub fn glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let text = serde_json::to_vec(json).unwrap();
    retex::engine::asset::export::glb_container(text, bin.to_vec()).unwrap()
}

/// The CRC-32 (ISO-HDLC) PNG chunks carry, over a chunk's type and data.
pub fn png_crc32(data: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A PNG whose IHDR claims `w` x `h` RGBA8 but whose data is a few bytes: a decompression bomb.
pub fn bomb_png(w: u32, h: u32) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 6, 0, 0, 0]);
    for chunk in [
        ihdr,
        b"IDAT\x78\x9c\x63\x00\x00\x00\x01\x00\x01".to_vec(),
        b"IEND".to_vec(),
    ] {
        out.extend_from_slice(&(chunk.len() as u32 - 4).to_be_bytes());
        out.extend_from_slice(&chunk);
        out.extend_from_slice(&png_crc32(&chunk).to_be_bytes());
    }
    out
}

/// A GLB of `instances` nodes that each instantiate one textured triangle (POSITION and
/// TEXCOORD_0). Image `i` of `images` is the base colour of material `i` (texture `i`); the
/// triangle uses material 0, so every further image sits on a material no primitive uses. The
/// images are embedded through buffer views.
pub fn textured_triangle_glb(images: &[Vec<u8>], instances: usize) -> Vec<u8> {
    textured_triangle_glb_with(images, instances, |_| {})
}

/// [`textured_triangle_glb`] with its JSON edited by `patch` before it is written.
pub fn textured_triangle_glb_with(
    images: &[Vec<u8>],
    instances: usize,
    patch: impl FnOnce(&mut serde_json::Value),
) -> Vec<u8> {
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let mut views = vec![
        serde_json::json!({"buffer": 0, "byteOffset": 0, "byteLength": 36}),
        serde_json::json!({"buffer": 0, "byteOffset": 36, "byteLength": 24}),
        serde_json::json!({"buffer": 0, "byteOffset": 60, "byteLength": 6}),
    ];
    let mut json_images = Vec::new();
    for png in images {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        json_images.push(serde_json::json!({"bufferView": views.len(), "mimeType": "image/png"}));
        views.push(
            serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": png.len()}),
        );
        bin.extend_from_slice(png);
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let n = images.len();
    let mut json = serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "type": "VEC2", "count": 3},
            {"bufferView": 2, "componentType": 5123, "type": "SCALAR", "count": 3}
        ],
        "images": json_images,
        "textures": (0..n).map(|i| serde_json::json!({"source": i})).collect::<Vec<_>>(),
        "materials": (0..n)
            .map(|i| serde_json::json!({"pbrMetallicRoughness": {"baseColorTexture": {"index": i}}}))
            .collect::<Vec<_>>(),
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                                     "indices": 2, "material": 0}]}],
        "nodes": (0..instances)
            .map(|i| serde_json::json!({"mesh": 0, "translation": [i as f32 * 2.0, 0, 0]}))
            .collect::<Vec<_>>(),
        "scenes": [{"nodes": (0..instances).collect::<Vec<_>>()}]
    });
    patch(&mut json);
    glb(&json, &bin)
}

/// A small real PNG (RGBA8), `w` x `h` of a gradient.
pub fn small_png(w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbaImage::from_fn(w, h, |x, y| image::Rgba([x as u8, y as u8, 90, 255]));
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .unwrap();
    out
}
