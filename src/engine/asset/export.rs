//! Export: writes the target asset back as GLB (or .gltf with embedded buffers), unchanged except
//! for what a method replaced.
//!
//! The uploaded JSON is edited, not regenerated, so nodes, names, animations, skins, extensions
//! and materials' other properties survive. All buffers are merged into one binary buffer (each
//! original buffer at a 16-byte aligned offset, bufferViews re-pointed), external and data: URI
//! images are moved into bufferViews, and new data (baked PNGs, COLOR_0, refined primitives) is
//! appended. Edits follow glTF 2.0 section 3.9 (materials: `baseColorTexture` replaces the
//! previous texture and its `KHR_texture_transform`, `baseColorFactor` becomes white because the
//! bake already holds the final color) and section 3.7.2 (COLOR_0 multiplies base color, so a
//! stale COLOR_0 is removed from primitives whose material receives a baked texture).

use serde_json::{json, Value};

use super::constraints::OutputFormat;
use super::edits::Edit;
use super::model::Asset;

/// Export failures.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The output would exceed the 4 GiB GLB limit.
    #[error("output of {bytes} bytes exceeds the glTF binary limit of 4 GiB")]
    TooLarge {
        /// Size that was needed.
        bytes: u64,
    },
    /// The JSON could not be serialized.
    #[error("json serialization failed: {0}")]
    Json(#[from] serde_json::Error),
    /// An edit names something the asset does not have.
    #[error("edit refers to {what} {index}, which the asset does not have")]
    BadEdit {
        /// "primitive", "material" or "mesh".
        what: &'static str,
        /// The index.
        index: usize,
    },
    /// An edit's data does not fit what it edits (a count or a type).
    #[error("edit of {what}: {message}")]
    MismatchedEdit {
        /// What was edited (`primitive 3 attribute NORMAL`).
        what: String,
        /// What does not fit.
        message: String,
    },
}

/// The binary buffer under construction and the JSON arrays it feeds.
pub(super) struct Builder {
    pub(super) bin: Vec<u8>,
    pub(super) json: Value,
}

impl Builder {
    pub(super) fn array(&mut self, key: &str) -> &mut Vec<Value> {
        let obj = self.json.as_object_mut().expect("root is an object");
        let entry = obj.entry(key).or_insert_with(|| Value::Array(Vec::new()));
        if !entry.is_array() {
            *entry = Value::Array(Vec::new());
        }
        entry.as_array_mut().expect("just made an array")
    }

    pub(super) fn align(&mut self, to: usize) {
        while !self.bin.len().is_multiple_of(to) {
            self.bin.push(0);
        }
    }

    pub(super) fn push_view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        self.align(4);
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut view = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        let views = self.array("bufferViews");
        views.push(view);
        views.len() - 1
    }

    /// A float accessor of `N` components per element; `with_bounds` adds min/max (POSITION needs them).
    pub(super) fn push_f32<const N: usize>(
        &mut self,
        data: &[[f32; N]],
        ty: &str,
        with_bounds: bool,
    ) -> usize {
        let mut bytes = Vec::with_capacity(data.len() * N * 4);
        for v in data {
            for c in v {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
        }
        let view = self.push_view(&bytes, Some(34962));
        let mut acc =
            json!({"bufferView": view, "componentType": 5126, "count": data.len(), "type": ty});
        if with_bounds && !data.is_empty() {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for v in data {
                for k in 0..N {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
            acc["min"] = json!(lo.iter().map(|x| *x as f64).collect::<Vec<_>>());
            acc["max"] = json!(hi.iter().map(|x| *x as f64).collect::<Vec<_>>());
        }
        let accessors = self.array("accessors");
        accessors.push(acc);
        accessors.len() - 1
    }

    pub(super) fn push_indices(&mut self, triangles: &[[u32; 3]]) -> usize {
        let mut bytes = Vec::with_capacity(triangles.len() * 12);
        for t in triangles {
            for i in t {
                bytes.extend_from_slice(&i.to_le_bytes());
            }
        }
        let view = self.push_view(&bytes, Some(34963));
        let accessors = self.array("accessors");
        accessors.push(json!({"bufferView": view, "componentType": 5125, "count": triangles.len() * 3, "type": "SCALAR"}));
        accessors.len() - 1
    }
}

/// Writes `asset` with `edits` applied in order, as GLB or .gltf with embedded buffers.
///
/// # Errors
/// [`ExportError::BadEdit`] / [`ExportError::MismatchedEdit`] for an edit that does not fit the
/// asset, [`ExportError::TooLarge`] past the 4 GiB GLB limit.
pub fn export(asset: &Asset, edits: &[Edit], format: OutputFormat) -> Result<Vec<u8>, ExportError> {
    let mut b = Builder {
        bin: Vec::new(),
        json: asset.json.clone(),
    };
    if !b.json.is_object() {
        b.json = json!({"asset": {"version": "2.0"}});
    }
    merge_buffers(asset, &mut b);
    embed_images(asset, &mut b);
    for edit in edits {
        super::apply::apply(asset, &mut b, edit)?;
    }
    clean_extension_lists(&mut b.json);
    finish(b, format)
}

fn merge_buffers(asset: &Asset, b: &mut Builder) {
    let mut offsets = Vec::with_capacity(asset.buffers.len());
    for buf in &asset.buffers {
        b.align(16);
        offsets.push(b.bin.len());
        b.bin.extend_from_slice(buf);
    }
    if let Some(views) = b.json.get_mut("bufferViews").and_then(Value::as_array_mut) {
        for view in views {
            let buffer = view.get("buffer").and_then(Value::as_u64).unwrap_or(0) as usize;
            let old = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
            let base = offsets.get(buffer).copied().unwrap_or(0);
            view["buffer"] = json!(0);
            view["byteOffset"] = json!(base + old);
        }
    }
}

fn embed_images(asset: &Asset, b: &mut Builder) {
    let count = b
        .json
        .get("images")
        .and_then(Value::as_array)
        .map_or(0, Vec::len);
    for i in 0..count.min(asset.images.len()) {
        let has_uri = b.json["images"][i].get("uri").is_some();
        if !has_uri {
            continue;
        }
        let view = b.push_view(&asset.images[i].bytes, None);
        let img = b.json["images"][i]
            .as_object_mut()
            .expect("image is an object");
        img.remove("uri");
        img.insert("bufferView".into(), json!(view));
        img.insert("mimeType".into(), json!(asset.images[i].mime_type));
    }
}

/// Drops `KHR_texture_transform` and `KHR_materials_pbrSpecularGlossiness` from
/// extensionsUsed/Required when nothing uses them any more.
fn clean_extension_lists(json: &mut Value) {
    let text = serde_json::to_string(json.get("materials").unwrap_or(&Value::Null))
        .unwrap_or_default()
        + &serde_json::to_string(json.get("textures").unwrap_or(&Value::Null)).unwrap_or_default();
    for name in ["KHR_materials_pbrSpecularGlossiness"] {
        if !text.contains(&format!("\"{name}\"")) {
            for key in ["extensionsUsed", "extensionsRequired"] {
                if let Some(list) = json.get_mut(key).and_then(Value::as_array_mut) {
                    list.retain(|v| v.as_str() != Some(name));
                }
            }
        }
    }
    for key in ["extensionsUsed", "extensionsRequired"] {
        if json
            .get(key)
            .and_then(Value::as_array)
            .is_some_and(Vec::is_empty)
        {
            json.as_object_mut().expect("root object").remove(key);
        }
    }
}

fn finish(mut b: Builder, format: OutputFormat) -> Result<Vec<u8>, ExportError> {
    b.align(4);
    let obj = b.json.as_object_mut().expect("root object");
    if b.bin.is_empty() {
        obj.remove("buffers");
    } else {
        let mut buffer = json!({"byteLength": b.bin.len()});
        if format == OutputFormat::Gltf {
            use base64::Engine as _;
            let encoded = base64::engine::general_purpose::STANDARD.encode(&b.bin);
            buffer["uri"] = json!(format!("data:application/octet-stream;base64,{encoded}"));
        }
        obj.insert("buffers".into(), json!([buffer]));
    }
    let asset_info = obj.entry("asset").or_insert(json!({"version": "2.0"}));
    if asset_info.is_object() {
        asset_info["generator"] = json!(concat!("retex ", env!("CARGO_PKG_VERSION")));
    }
    let text = serde_json::to_vec(&b.json)?;
    if format == OutputFormat::Gltf {
        return Ok(text);
    }
    glb_container(text, b.bin)
}

/// Packs a glTF JSON document and its binary buffer into a GLB container (glTF 2.0 §4.4): the
/// JSON chunk padded with spaces and the BIN chunk with zeros to 4 bytes; no BIN chunk when
/// `bin` is empty. [`ExportError::TooLarge`] past the container's 4 GiB length field.
pub fn glb_container(mut text: Vec<u8>, mut bin: Vec<u8>) -> Result<Vec<u8>, ExportError> {
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let bin_chunk = if bin.is_empty() { 0 } else { 8 + bin.len() };
    let total = 12 + 8 + text.len() + bin_chunk;
    if total as u64 > u32::MAX as u64 {
        return Err(ExportError::TooLarge {
            bytes: total as u64,
        });
    }
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    Ok(out)
}

/// A GLB of one triangle mesh: POSITION (with the accessor bounds glTF requires) and u32
/// indices; no UVs, normals or material (a target for the methods that generate an atlas).
pub fn mesh_glb(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Result<Vec<u8>, ExportError> {
    triangle_mesh_glb(positions, faces, None, false)
}

/// A GLB of one triangle mesh with a plain white, non-metallic material and, when given,
/// per-vertex COLOR_0 (linear RGBA floats): a painted source or a bare target made in code
/// (benchmarks, tests).
pub fn colored_mesh_glb(
    positions: &[[f32; 3]],
    faces: &[[u32; 3]],
    colors: Option<&[[f32; 4]]>,
) -> Result<Vec<u8>, ExportError> {
    triangle_mesh_glb(positions, faces, colors, true)
}

fn triangle_mesh_glb(
    positions: &[[f32; 3]],
    faces: &[[u32; 3]],
    colors: Option<&[[f32; 4]]>,
    material: bool,
) -> Result<Vec<u8>, ExportError> {
    let mut bin = Vec::with_capacity(positions.len() * 28 + faces.len() * 12);
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
            bin.extend_from_slice(&p[k].to_le_bytes());
        }
    }
    let pos_len = bin.len();
    for v in faces.iter().flatten() {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    let idx_len = bin.len() - pos_len;
    let mut attributes = json!({"POSITION": 0});
    let mut views = vec![
        json!({"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962}),
        json!({"buffer": 0, "byteOffset": pos_len, "byteLength": idx_len, "target": 34963}),
    ];
    let mut accessors = vec![
        json!({"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3", "min": lo, "max": hi}),
        json!({"bufferView": 1, "componentType": 5125, "count": faces.len() * 3, "type": "SCALAR"}),
    ];
    if let Some(colors) = colors {
        let offset = bin.len();
        for c in colors.iter().flatten() {
            bin.extend_from_slice(&c.to_le_bytes());
        }
        attributes["COLOR_0"] = 2.into();
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bin.len() - offset, "target": 34962}));
        accessors.push(
            json!({"bufferView": 2, "componentType": 5126, "count": colors.len(), "type": "VEC4"}),
        );
    }
    let mut primitive = json!({"attributes": attributes, "indices": 1});
    let mut json = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors,
    });
    if material {
        json["materials"] = json!([{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0}}]);
        primitive["material"] = 0.into();
    }
    json["meshes"] = json!([{"primitives": [primitive]}]);
    glb_container(serde_json::to_vec(&json)?, bin)
}
