//! Applying one [`Edit`] to the glTF JSON and binary buffer under construction in
//! [`super::export`].
//!
//! glTF 2.0 rules followed: material texture slots §3.9.2–3.9.5 (`baseColorTexture` holds the
//! final colour, so `baseColorFactor` becomes white; `normalTexture.scale`,
//! `occlusionTexture.strength`, `emissiveFactor`); COLOR_0 multiplies the base colour (§3.7.2.1),
//! so a stale COLOR_0 is removed where a base-colour texture is set; POSITION accessors carry
//! min/max, also in morph targets (§3.6.2.2, §3.7.2.2); every primitive of a mesh has the same
//! number of morph targets and `mesh.weights` has one entry per target (§3.7.2.2); target names
//! go to `mesh.extras.targetNames` (the convention three.js, Blender and Babylon read).

use serde_json::{json, Map, Value};

use super::edits::{
    AttributeData, Edit, EncodedImage, MorphDeltas, PrimitiveGeometry, TextureSlot, TextureWrap,
};
use super::export::{Builder, ExportError};
use super::model::Asset;

/// Removes every texture reference (keys ending in `Texture`, at any depth) from a material
/// copied for primitives whose texture coordinates were replaced: they pointed into UV sets
/// that no longer exist.
fn strip_textures(material: &mut Value) {
    if let Some(obj) = material.as_object_mut() {
        obj.retain(|k, _| !k.ends_with("Texture"));
        obj.values_mut().for_each(strip_textures);
    }
}

/// Applies one edit.
pub(super) fn apply(asset: &Asset, b: &mut Builder, edit: &Edit) -> Result<(), ExportError> {
    match edit {
        Edit::SetTexture {
            material,
            slot,
            image,
            tex_coord,
            wrap,
            primitives,
        } => set_texture(
            asset, b, *material, *slot, image, *tex_coord, *wrap, primitives,
        ),
        Edit::ClearTexture { material, slot } => clear_texture(b, *material, *slot),
        Edit::SetAttribute {
            primitive,
            name,
            data,
        } => set_attribute(asset, b, *primitive, name, data),
        Edit::RemoveAttribute { primitive, name } => {
            if let Some(attrs) = primitive_json(asset, &mut b.json, *primitive)?
                .get_mut("attributes")
                .and_then(Value::as_object_mut)
            {
                attrs.remove(name);
            }
            Ok(())
        }
        Edit::AddMorphTarget {
            mesh,
            name,
            weight,
            deltas,
        } => add_morph_target(asset, b, *mesh, name, *weight, deltas),
        Edit::ReplacePrimitive {
            primitive,
            geometry,
        } => replace_primitive(asset, b, *primitive, geometry),
        Edit::SetMaterialExtra {
            material,
            key,
            value,
        } => {
            let mat = material_json(&mut b.json, *material)?;
            let obj = mat.as_object_mut().expect("material object");
            let extras = obj.entry("extras").or_insert(json!({}));
            if !extras.is_object() {
                *extras = json!({});
            }
            extras[key.as_str()] = value.clone();
            Ok(())
        }
    }
}

pub(super) fn primitive_json<'a>(
    asset: &Asset,
    json: &'a mut Value,
    primitive: usize,
) -> Result<&'a mut Value, ExportError> {
    let bad = ExportError::BadEdit {
        what: "primitive",
        index: primitive,
    };
    let p = asset.primitives.get(primitive).ok_or(bad)?;
    json.pointer_mut(&format!("/meshes/{}/primitives/{}", p.mesh, p.primitive))
        .ok_or(ExportError::BadEdit {
            what: "primitive",
            index: primitive,
        })
}

fn material_json(json: &mut Value, material: usize) -> Result<&mut Value, ExportError> {
    json.pointer_mut(&format!("/materials/{material}"))
        .filter(|m| m.is_object())
        .ok_or(ExportError::BadEdit {
            what: "material",
            index: material,
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

/// Appends image, sampler and texture; returns the texture index.
fn push_texture(b: &mut Builder, image: &EncodedImage, wrap: TextureWrap) -> usize {
    let view = b.push_view(&image.bytes, None);
    let index = {
        let images = b.array("images");
        images.push(json!({"bufferView": view, "mimeType": image.mime_type, "name": image.name}));
        images.len() - 1
    };
    let sampler = {
        let mut s = json!({"magFilter": 9729, "minFilter": 9987});
        if wrap == TextureWrap::ClampToEdge {
            s["wrapS"] = json!(33071);
            s["wrapT"] = json!(33071);
        }
        let samplers = b.array("samplers");
        samplers.push(s);
        samplers.len() - 1
    };
    let textures = b.array("textures");
    textures.push(json!({"source": index, "sampler": sampler, "name": image.name}));
    textures.len() - 1
}

#[allow(clippy::too_many_arguments)]
fn set_texture(
    asset: &Asset,
    b: &mut Builder,
    material: Option<usize>,
    slot: TextureSlot,
    image: &EncodedImage,
    tex_coord: u32,
    wrap: TextureWrap,
    primitives: &[usize],
) -> Result<(), ExportError> {
    if image.bytes.is_empty() {
        return Err(ExportError::MismatchedEdit {
            what: format!("image {:?}", image.name),
            message: "the image has no bytes (encoding failed)".into(),
        });
    }
    let texture = push_texture(b, image, wrap);
    let mut info = json!({"index": texture});
    if tex_coord != 0 {
        info["texCoord"] = json!(tex_coord);
    }
    let material = match material {
        Some(m) => {
            material_json(&mut b.json, m)?;
            m
        }
        None => {
            let mut new = json!({});
            if let Some(&p) = primitives.first() {
                let old = primitive_json(asset, &mut b.json, p)?["material"].as_u64();
                if let Some(old) = old {
                    new = b.json["materials"][old as usize].clone();
                    strip_textures(&mut new);
                }
            }
            new["name"] = json!(image.name);
            let materials = b.array("materials");
            materials.push(new);
            let m = materials.len() - 1;
            for &p in primitives {
                primitive_json(asset, &mut b.json, p)?["material"] = json!(m);
            }
            m
        }
    };
    let mat = &mut b.json["materials"][material];
    match slot {
        TextureSlot::BaseColor => {
            drop_spec_gloss(mat);
            let obj = mat.as_object_mut().expect("material object");
            let pbr = obj.entry("pbrMetallicRoughness").or_insert(json!({}));
            pbr["baseColorTexture"] = info;
            pbr["baseColorFactor"] = json!([1.0, 1.0, 1.0, 1.0]);
            for &p in primitives {
                if let Some(attrs) = primitive_json(asset, &mut b.json, p)?
                    .get_mut("attributes")
                    .and_then(Value::as_object_mut)
                {
                    attrs.remove("COLOR_0");
                }
            }
        }
        TextureSlot::Normal { scale } => {
            if scale != 1.0 {
                info["scale"] = json!(scale);
            }
            mat["normalTexture"] = info;
        }
        TextureSlot::Occlusion { strength } => {
            if strength != 1.0 {
                info["strength"] = json!(strength);
            }
            mat["occlusionTexture"] = info;
        }
        TextureSlot::Emissive { factor } => {
            mat["emissiveTexture"] = info;
            mat["emissiveFactor"] = json!(factor);
        }
        TextureSlot::Extras(key) => {
            let obj = mat.as_object_mut().expect("material object");
            let extras = obj.entry("extras").or_insert(json!({}));
            if !extras.is_object() {
                *extras = json!({});
            }
            let entry = &mut extras[key];
            if !entry.is_object() {
                *entry = json!({});
            }
            entry["index"] = json!(texture);
            entry["texCoord"] = json!(tex_coord);
        }
    }
    Ok(())
}

fn clear_texture(b: &mut Builder, material: usize, slot: TextureSlot) -> Result<(), ExportError> {
    let mat = material_json(&mut b.json, material)?;
    match slot {
        TextureSlot::BaseColor => {
            if let Some(pbr) = mat
                .get_mut("pbrMetallicRoughness")
                .and_then(Value::as_object_mut)
            {
                pbr.remove("baseColorTexture");
                pbr.insert("baseColorFactor".into(), json!([1.0, 1.0, 1.0, 1.0]));
            }
            drop_spec_gloss(mat);
        }
        TextureSlot::Extras(key) => {
            if let Some(extras) = mat.get_mut("extras").and_then(Value::as_object_mut) {
                extras.remove(key);
            }
        }
        other => {
            mat.as_object_mut()
                .expect("material object")
                .remove(other.key());
            if matches!(other, TextureSlot::Emissive { .. }) {
                mat.as_object_mut()
                    .expect("material object")
                    .remove("emissiveFactor");
            }
        }
    }
    Ok(())
}

/// Pushes an attribute accessor (POSITION gets min/max).
fn push_attribute(b: &mut Builder, name: &str, data: &AttributeData) -> usize {
    let bounds = name == "POSITION";
    match data {
        AttributeData::Vec2(v) => b.push_f32(v, "VEC2", bounds),
        AttributeData::Vec3(v) => b.push_f32(v, "VEC3", bounds),
        AttributeData::Vec4(v) => b.push_f32(v, "VEC4", bounds),
    }
}

/// Checks that `data` is a valid type for attribute `name`.
fn check_attribute_type(name: &str, data: &AttributeData) -> Result<(), String> {
    let ok = match name {
        "POSITION" | "NORMAL" => matches!(data, AttributeData::Vec3(_)),
        "TANGENT" => matches!(data, AttributeData::Vec4(_)),
        n if n.starts_with("TEXCOORD_") => matches!(data, AttributeData::Vec2(_)),
        n if n.starts_with("COLOR_") => {
            matches!(data, AttributeData::Vec3(_) | AttributeData::Vec4(_))
        }
        n if n.starts_with('_') => true,
        _ => return Err(format!("attribute {name} cannot be written by an edit")),
    };
    if ok {
        Ok(())
    } else {
        Err(format!(
            "{} is not a valid type for {name}",
            data.gltf_type()
        ))
    }
}

fn set_attribute(
    asset: &Asset,
    b: &mut Builder,
    primitive: usize,
    name: &str,
    data: &AttributeData,
) -> Result<(), ExportError> {
    let vertices = asset
        .primitives
        .get(primitive)
        .ok_or(ExportError::BadEdit {
            what: "primitive",
            index: primitive,
        })?
        .positions
        .len();
    let what = || format!("primitive {primitive} attribute {name}");
    check_attribute_type(name, data).map_err(|message| ExportError::MismatchedEdit {
        what: what(),
        message,
    })?;
    if data.len() != vertices {
        return Err(ExportError::MismatchedEdit {
            what: what(),
            message: format!("{} values for {vertices} vertices", data.len()),
        });
    }
    let acc = push_attribute(b, name, data);
    let prim = primitive_json(asset, &mut b.json, primitive)?;
    prim["attributes"][name] = json!(acc);
    Ok(())
}

fn add_morph_target(
    asset: &Asset,
    b: &mut Builder,
    mesh: usize,
    name: &str,
    weight: f32,
    deltas: &[MorphDeltas],
) -> Result<(), ExportError> {
    let prims: Vec<usize> = asset.primitives_of_mesh(mesh).collect();
    if prims.is_empty() || b.json.pointer(&format!("/meshes/{mesh}")).is_none() {
        return Err(ExportError::BadEdit {
            what: "mesh",
            index: mesh,
        });
    }
    for d in deltas {
        let what = || format!("morph target {name:?} primitive {}", d.primitive);
        if !prims.contains(&d.primitive) {
            return Err(ExportError::MismatchedEdit {
                what: what(),
                message: format!("the primitive is not part of mesh {mesh}"),
            });
        }
        let n = asset.primitives[d.primitive].positions.len();
        let bad_normals = d.normals.as_ref().is_some_and(|v| v.len() != n);
        if d.positions.len() != n || bad_normals {
            return Err(ExportError::MismatchedEdit {
                what: what(),
                message: format!("deltas do not have one value per vertex ({n})"),
            });
        }
    }
    let with_normals = deltas.iter().any(|d| d.normals.is_some());
    let mut previous_targets = 0usize;
    for &p in &prims {
        let n = asset.primitives[p].positions.len();
        let d = deltas.iter().find(|d| d.primitive == p);
        let zeros = vec![[0.0f32; 3]; n];
        let pos = b.push_f32(d.map_or(&zeros, |d| &d.positions), "VEC3", true);
        let nrm = with_normals.then(|| {
            let v = d.and_then(|d| d.normals.as_ref()).unwrap_or(&zeros);
            b.push_f32(v, "VEC3", false)
        });
        let prim = primitive_json(asset, &mut b.json, p)?;
        let obj = prim.as_object_mut().expect("primitive object");
        let targets = obj.entry("targets").or_insert(json!([]));
        if !targets.is_array() {
            *targets = json!([]);
        }
        let list = targets.as_array_mut().expect("just made an array");
        previous_targets = list.len();
        let mut t = json!({"POSITION": pos});
        if let Some(nrm) = nrm {
            t["NORMAL"] = json!(nrm);
        }
        list.push(t);
    }
    let mesh_json = &mut b.json["meshes"][mesh];
    let obj = mesh_json.as_object_mut().expect("mesh object");
    let weights = obj.entry("weights").or_insert(json!([]));
    if !weights.is_array() {
        *weights = json!([]);
    }
    let w = weights.as_array_mut().expect("just made an array");
    w.resize(previous_targets, json!(0.0));
    w.push(json!(weight));
    let extras = obj.entry("extras").or_insert(json!({}));
    if extras.is_object() {
        let names = extras
            .as_object_mut()
            .expect("extras object")
            .entry("targetNames")
            .or_insert(json!([]));
        if let Some(list) = names.as_array_mut() {
            while list.len() < previous_targets {
                list.push(json!(format!("target_{}", list.len())));
            }
            list.push(json!(name));
        }
    }
    Ok(())
}

fn replace_primitive(
    asset: &Asset,
    b: &mut Builder,
    primitive: usize,
    g: &PrimitiveGeometry,
) -> Result<(), ExportError> {
    let n = g.positions.len();
    let what = || format!("primitive {primitive} geometry");
    let counts_ok = g.normals.as_ref().is_none_or(|v| v.len() == n)
        && g.tangents.as_ref().is_none_or(|v| v.len() == n)
        && g.colors.as_ref().is_none_or(|v| v.len() == n)
        && g.tex_coords.iter().all(|v| v.len() == n);
    if !counts_ok {
        return Err(ExportError::MismatchedEdit {
            what: what(),
            message: format!("every attribute needs {n} values"),
        });
    }
    if let Some(bad) = g.triangles.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(ExportError::MismatchedEdit {
            what: what(),
            message: format!("index {bad} is out of range for {n} vertices"),
        });
    }
    primitive_json(asset, &mut b.json, primitive)?;
    let pos = b.push_f32(&g.positions, "VEC3", true);
    let nrm = g.normals.as_ref().map(|v| b.push_f32(v, "VEC3", false));
    let tan = g.tangents.as_ref().map(|v| b.push_f32(v, "VEC4", false));
    let uvs: Vec<usize> = g
        .tex_coords
        .iter()
        .map(|v| b.push_f32(v, "VEC2", false))
        .collect();
    let col = g.colors.as_ref().map(|v| b.push_f32(v, "VEC4", false));
    let idx = b.push_indices(&g.triangles);
    let prim = primitive_json(asset, &mut b.json, primitive)?;
    let mut attrs = json!({"POSITION": pos});
    if let Some(c) = col {
        attrs["COLOR_0"] = json!(c);
    }
    if let Some(n) = nrm {
        attrs["NORMAL"] = json!(n);
    }
    if let Some(t) = tan {
        attrs["TANGENT"] = json!(t);
    }
    for (k, a) in uvs.iter().enumerate() {
        attrs[format!("TEXCOORD_{k}")] = json!(a);
    }
    prim["attributes"] = attrs;
    prim["indices"] = json!(idx);
    if let Some(o) = prim.as_object_mut() {
        o.remove("mode");
        o.remove("targets");
    }
    Ok(())
}
