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

use serde_json::{json, Map, Value};

use super::constraints::OutputFormat;
use super::model::Asset;

/// A baked base-color texture for one material (or for primitives without a material).
#[derive(Clone, Debug)]
pub struct MaterialTexture {
    /// The material that receives the texture; `None` creates a new material for `primitives`.
    pub material: Option<usize>,
    /// Indices into [`Asset::primitives`] that use this texture (for `material: None`, they get
    /// the new material; for all, a stale COLOR_0 is removed).
    pub primitives: Vec<usize>,
    /// PNG bytes.
    pub png: Vec<u8>,
    /// The TEXCOORD set the texture was baked into.
    pub tex_coord: u32,
    /// Name of the new image and texture.
    pub name: String,
}

/// New per-vertex colors on a primitive's own vertices.
#[derive(Clone, Debug)]
pub struct VertexColors {
    /// Index into [`Asset::primitives`].
    pub primitive: usize,
    /// Linear RGBA per vertex (same count as the primitive's vertices).
    pub colors: Vec<[f32; 4]>,
}

/// A primitive replaced by a refined copy carrying COLOR_0.
#[derive(Clone, Debug)]
pub struct RefinedPrimitive {
    /// Index into [`Asset::primitives`].
    pub primitive: usize,
    /// Local-space positions.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals, when the original had normals.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Linear RGBA per vertex.
    pub colors: Vec<[f32; 4]>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
}

/// Everything a method replaces in the target.
#[derive(Clone, Debug, Default)]
pub struct Edits {
    /// Baked textures.
    pub textures: Vec<MaterialTexture>,
    /// COLOR_0 on original vertices.
    pub vertex_colors: Vec<VertexColors>,
    /// Refined copies with COLOR_0.
    pub refined: Vec<RefinedPrimitive>,
    /// Materials whose base-color texture is removed (their primitives got COLOR_0 instead).
    pub untextured_materials: Vec<usize>,
}

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
        /// "primitive" or "material".
        what: &'static str,
        /// The index.
        index: usize,
    },
}

/// The binary buffer under construction and the JSON arrays it feeds.
struct Builder {
    bin: Vec<u8>,
    json: Value,
}

impl Builder {
    fn array(&mut self, key: &str) -> &mut Vec<Value> {
        let obj = self.json.as_object_mut().expect("root is an object");
        let entry = obj.entry(key).or_insert_with(|| Value::Array(Vec::new()));
        if !entry.is_array() {
            *entry = Value::Array(Vec::new());
        }
        entry.as_array_mut().expect("just made an array")
    }

    fn align(&mut self, to: usize) {
        while self.bin.len() % to != 0 {
            self.bin.push(0);
        }
    }

    fn push_view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
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
    fn push_f32<const N: usize>(
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

    fn push_indices(&mut self, triangles: &[[u32; 3]]) -> usize {
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

/// Writes `asset` with `edits` applied, as GLB or .gltf with embedded buffers.
pub fn export(asset: &Asset, edits: &Edits, format: OutputFormat) -> Result<Vec<u8>, ExportError> {
    let mut b = Builder {
        bin: Vec::new(),
        json: asset.json.clone(),
    };
    if !b.json.is_object() {
        b.json = json!({"asset": {"version": "2.0"}});
    }
    merge_buffers(asset, &mut b);
    embed_images(asset, &mut b);
    for t in &edits.textures {
        apply_texture(asset, &mut b, t)?;
    }
    for &m in &edits.untextured_materials {
        let mat = b
            .json
            .pointer_mut(&format!("/materials/{m}"))
            .ok_or(ExportError::BadEdit {
                what: "material",
                index: m,
            })?;
        if let Some(pbr) = mat
            .get_mut("pbrMetallicRoughness")
            .and_then(Value::as_object_mut)
        {
            pbr.remove("baseColorTexture");
            pbr.insert("baseColorFactor".into(), json!([1.0, 1.0, 1.0, 1.0]));
        }
        drop_spec_gloss(mat);
    }
    for vc in &edits.vertex_colors {
        let acc = b.push_f32(&vc.colors, "VEC4", false);
        let prim = primitive_json(asset, &mut b.json, vc.primitive)?;
        prim["attributes"]["COLOR_0"] = json!(acc);
    }
    for r in &edits.refined {
        apply_refined(asset, &mut b, r)?;
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

fn primitive_json<'a>(
    asset: &Asset,
    json: &'a mut Value,
    primitive: usize,
) -> Result<&'a mut Value, ExportError> {
    let p = asset
        .primitives
        .get(primitive)
        .ok_or(ExportError::BadEdit {
            what: "primitive",
            index: primitive,
        })?;
    json.pointer_mut(&format!("/meshes/{}/primitives/{}", p.mesh, p.primitive))
        .ok_or(ExportError::BadEdit {
            what: "primitive",
            index: primitive,
        })
}

/// Removes the legacy spec-gloss extension from a material that now carries metallic-roughness
/// color (a viewer that knows the extension would otherwise keep showing the old diffuse).
fn drop_spec_gloss(mat: &mut Value) {
    if let Some(ext) = mat.get_mut("extensions").and_then(Value::as_object_mut) {
        if ext.remove("KHR_materials_pbrSpecularGlossiness").is_some() {
            let pbr = mat
                .as_object_mut()
                .expect("material object")
                .entry("pbrMetallicRoughness")
                .or_insert(json!({}));
            if pbr.get("metallicFactor").is_none() {
                pbr["metallicFactor"] = json!(0.0);
            }
        }
        if mat["extensions"].as_object().is_some_and(Map::is_empty) {
            mat.as_object_mut()
                .expect("material object")
                .remove("extensions");
        }
    }
}

fn apply_texture(asset: &Asset, b: &mut Builder, t: &MaterialTexture) -> Result<(), ExportError> {
    let view = b.push_view(&t.png, None);
    let image = {
        let images = b.array("images");
        images.push(json!({"bufferView": view, "mimeType": "image/png", "name": t.name}));
        images.len() - 1
    };
    let sampler = {
        let samplers = b.array("samplers");
        samplers.push(json!({"magFilter": 9729, "minFilter": 9987}));
        samplers.len() - 1
    };
    let texture = {
        let textures = b.array("textures");
        textures.push(json!({"source": image, "sampler": sampler, "name": t.name}));
        textures.len() - 1
    };
    let mut info = json!({"index": texture});
    if t.tex_coord != 0 {
        info["texCoord"] = json!(t.tex_coord);
    }
    let material = match t.material {
        Some(m) => {
            if b.json.pointer(&format!("/materials/{m}")).is_none() {
                return Err(ExportError::BadEdit {
                    what: "material",
                    index: m,
                });
            }
            m
        }
        None => {
            let materials = b.array("materials");
            materials.push(json!({"name": t.name}));
            let m = materials.len() - 1;
            for &p in &t.primitives {
                primitive_json(asset, &mut b.json, p)?["material"] = json!(m);
            }
            m
        }
    };
    let mat = &mut b.json["materials"][material];
    drop_spec_gloss(mat);
    let obj = mat.as_object_mut().expect("material object");
    let pbr = obj.entry("pbrMetallicRoughness").or_insert(json!({}));
    pbr["baseColorTexture"] = info;
    pbr["baseColorFactor"] = json!([1.0, 1.0, 1.0, 1.0]);
    for &p in &t.primitives {
        if let Some(attrs) = primitive_json(asset, &mut b.json, p)?
            .get_mut("attributes")
            .and_then(Value::as_object_mut)
        {
            attrs.remove("COLOR_0");
        }
    }
    Ok(())
}

fn apply_refined(asset: &Asset, b: &mut Builder, r: &RefinedPrimitive) -> Result<(), ExportError> {
    let pos = b.push_f32(&r.positions, "VEC3", true);
    let nrm = r.normals.as_ref().map(|n| b.push_f32(n, "VEC3", false));
    let col = b.push_f32(&r.colors, "VEC4", false);
    let idx = b.push_indices(&r.triangles);
    let prim = primitive_json(asset, &mut b.json, r.primitive)?;
    let mut attrs = json!({"POSITION": pos, "COLOR_0": col});
    if let Some(n) = nrm {
        attrs["NORMAL"] = json!(n);
    }
    prim["attributes"] = attrs;
    prim["indices"] = json!(idx);
    if let Some(o) = prim.as_object_mut() {
        o.remove("mode");
        o.remove("targets");
    }
    Ok(())
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
    let mut text = serde_json::to_vec(&b.json)?;
    if format == OutputFormat::Gltf {
        return Ok(text);
    }
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let bin_chunk = if b.bin.is_empty() { 0 } else { 8 + b.bin.len() };
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
    if !b.bin.is_empty() {
        out.extend_from_slice(&(b.bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b.bin);
    }
    Ok(out)
}
