//! Safe ingest of a glTF 2.0 asset from named blobs into the [`Asset`] model.
//!
//! Order of work, each step checked before the next allocates anything sized by the file:
//! upload size; container ([`super::glb`], §4.4); JSON size and syntax, kept verbatim; the typed
//! document (§3, via `gltf::json`), `asset.version` 2.x (§3.2) and `extensionsRequired` (§3.12);
//! buffers (§3.6.1: URI or GLB BIN chunk, exact `byteLength`) through [`super::uri`] (§2.8);
//! every buffer view and accessor ([`super::accessor`], §3.6.2); images, textures and materials
//! ([`super::images`], §3.8, §3.9, plus `KHR_texture_transform` and the archived
//! `KHR_materials_pbrSpecularGlossiness`); mesh primitives (§3.7.2: modes, attribute types incl.
//! `KHR_mesh_quantization`, index range, finite positions, vertex/triangle budgets); and the node
//! hierarchy and scene (§3.5: strict forest, no cycles, finite TRS or matrix, f64 products).
//!
//! [`load`] never touches the filesystem or network, and runs under `catch_unwind`, so a bug
//! surfaces as [`IngestError::Internal`] instead of taking the process down.

use std::collections::BTreeSet;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::Checked;
use gltf::json::Root;
use rayon::prelude::*;
use serde::de::DeserializeOwned;
use serde_json::Value;

use super::accessor::{self, Layout};
use super::model::*;
use super::{glb, images, uri, BlobSet, IngestError};

/// Limits applied while loading. Every size is checked before the allocation it guards.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IngestLimits {
    /// Total bytes of all blobs of the upload. Default: 1 GiB.
    pub max_input_bytes: u64,
    /// Bytes of the glTF JSON (file or GLB chunk). Default: 64 MiB.
    pub max_json_bytes: u64,
    /// Decoded bytes of all data: URIs together. Default: 256 MiB.
    pub max_data_uri_bytes: u64,
    /// Vertices summed over all primitives (points and lines excluded). Default: 20,000,000.
    pub max_vertices: u64,
    /// Triangles summed over all primitives. Default: 20,000,000.
    pub max_triangles: u64,
    /// Width or height of any image, in pixels. Default: 16384.
    pub max_image_side: u32,
    /// Width × height of any image, in pixels. Default: 16384².
    pub max_image_pixels: u64,
    /// Bytes the image decoder may allocate for one image. Default: 1 GiB.
    pub max_image_alloc_bytes: u64,
    /// Depth of the node hierarchy (a root node has depth 1). Default: 1024.
    pub max_node_depth: u64,
}

impl Default for IngestLimits {
    fn default() -> Self {
        Self {
            max_input_bytes: 1 << 30,
            max_json_bytes: 64 << 20,
            max_data_uri_bytes: 256 << 20,
            max_vertices: 20_000_000,
            max_triangles: 20_000_000,
            max_image_side: 16384,
            max_image_pixels: 16384 * 16384,
            max_image_alloc_bytes: 1 << 30,
            max_node_depth: 1024,
        }
    }
}

/// Extensions whose being required does not stop retex from reading the asset correctly.
fn extension_supported(name: &str) -> bool {
    matches!(
        name,
        "KHR_texture_transform" | "KHR_mesh_quantization" | "KHR_lights_punctual"
    ) || name.starts_with("KHR_materials_")
}

/// Loads the glTF (GLB detected by its magic) named `main` in `blobs`, resolving its URIs only
/// inside `blobs`, under `limits`.
///
/// # Errors
/// Any [`IngestError`]; a panic inside the loader becomes [`IngestError::Internal`].
pub fn load(main: &str, blobs: &BlobSet, limits: &IngestLimits) -> Result<Asset, IngestError> {
    catch_unwind(AssertUnwindSafe(|| load_unguarded(main, blobs, limits))).unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".to_string());
        Err(IngestError::Internal(message))
    })
}

fn load_unguarded(
    main: &str,
    blobs: &BlobSet,
    limits: &IngestLimits,
) -> Result<Asset, IngestError> {
    let total = blobs.total_bytes();
    if total > limits.max_input_bytes {
        return Err(IngestError::InputTooLarge {
            bytes: total,
            max: limits.max_input_bytes,
        });
    }
    let bytes = blobs.get(main).ok_or_else(|| IngestError::MissingMain {
        name: main.to_string(),
    })?;
    if bytes.is_empty() {
        return Err(IngestError::EmptyFile {
            name: main.to_string(),
        });
    }
    let looks_like_json = bytes
        .iter()
        .find(|b| !b.is_ascii_whitespace())
        .is_some_and(|&b| b == b'{' || b == 0xEF);
    let (json_bytes, bin) = if glb::is_glb(bytes)
        || (!looks_like_json && main.to_ascii_lowercase().ends_with(".glb"))
    {
        let g = glb::parse(bytes)?;
        (g.json, g.bin)
    } else {
        (bytes, None)
    };
    if json_bytes.len() as u64 > limits.max_json_bytes {
        return Err(IngestError::JsonTooLarge {
            bytes: json_bytes.len() as u64,
            max: limits.max_json_bytes,
        });
    }
    let json: Value = serde_json::from_slice(json_bytes).map_err(|e| IngestError::InvalidJson {
        line: e.line(),
        column: e.column(),
        message: e.to_string(),
    })?;
    let root = typed_root(&json)?;
    check_version(&json)?;
    if let Some(ext) = root
        .extensions_required
        .iter()
        .find(|e| !extension_supported(e))
    {
        return Err(IngestError::UnsupportedExtension(ext.clone()));
    }
    let base = uri::base_dir(main);
    let mut warnings = Vec::new();
    let mut data_budget = limits.max_data_uri_bytes;

    // Structure first (against the declared lengths), then the data (which must match them).
    let declared: Vec<u64> = root.buffers.iter().map(|b| b.byte_length.0).collect();
    let views = accessor::check_views(&root, &declared)?;
    let layouts = (0..root.accessors.len())
        .map(|i| accessor::layout(&root, &views, i))
        .collect::<Result<Vec<_>, _>>()?;
    let buffers = load_buffers(&root, bin, base, blobs, &mut data_budget)?;

    let mut image_list = Vec::with_capacity(root.images.len());
    let mut formats = Vec::with_capacity(root.images.len());
    for (i, img) in root.images.iter().enumerate() {
        let what = format!("images[{i}]");
        let (data, uri_mime): (Vec<u8>, Option<String>) = match (&img.uri, img.buffer_view) {
            (Some(u), _) => {
                let r = uri::resolve(u, base, &what, blobs, data_budget)?;
                if matches!(r.bytes, std::borrow::Cow::Owned(_)) {
                    data_budget -= r.bytes.len() as u64;
                }
                (r.bytes.into_owned(), r.mime)
            }
            (None, Some(v)) => {
                let view = views
                    .get(v.value())
                    .ok_or(IngestError::UnresolvedReference {
                        path: format!("{what}.bufferView"),
                        target: "bufferViews",
                        index: v.value(),
                        count: views.len(),
                    })?;
                (
                    buffers[view.buffer][view.offset..view.offset + view.len].to_vec(),
                    None,
                )
            }
            (None, None) => return Err(IngestError::ImageWithoutData { image: i }),
        };
        let declared = img.mime_type.as_ref().map(|m| m.0.clone()).or(uri_mime);
        let core = |m: &str| m == "image/png" || m == "image/jpeg";
        if images::sniff(&data).is_none()
            && declared
                .as_deref()
                .is_some_and(|m| !core(m) && m.starts_with("image/"))
        {
            let m = declared.unwrap_or_default();
            warnings.push(format!(
                "{what} is {m}, which retex does not read; it is kept for export only"
            ));
            image_list.push(ImageSource {
                bytes: Arc::new(data),
                mime_type: m,
                width: 0,
                height: 0,
                decoded: None,
            });
            formats.push(None);
            continue;
        }
        let (format, width, height) = images::checked_dimensions(i, &data, limits)?;
        let mime_type = images::mime_of(format).to_string();
        image_list.push(ImageSource {
            bytes: Arc::new(data),
            mime_type,
            width,
            height,
            decoded: None,
        });
        formats.push(Some(format));
    }

    let textures = images::read_textures(&json, &root)?;
    let materials = images::read_materials(&root, textures.len())?;

    // Decode the images that some material uses as base color.
    let used: BTreeSet<usize> = materials
        .iter()
        .filter_map(|m| m.base_color_texture)
        .filter_map(|t| textures[t.texture].image)
        .filter(|&i| formats[i].is_some())
        .collect();
    let used: Vec<usize> = used.into_iter().collect();
    let decoded = used
        .par_iter()
        .map(|&i| {
            images::decode_rgba8(
                i,
                &image_list[i].bytes,
                formats[i].expect("filtered"),
                limits,
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    for (i, d) in used.into_iter().zip(decoded) {
        image_list[i].decoded = Some(Arc::new(d));
    }

    let primitives = read_meshes(&root, &layouts, &buffers, &materials, limits, &mut warnings)?;
    let instances = scene_instances(&root, limits)?;
    Ok(Asset {
        json,
        buffers,
        images: image_list,
        textures,
        materials,
        primitives,
        instances,
        warnings,
    })
}

/// Deserializes the typed document. `textures` are read from the raw JSON instead (gltf-json
/// requires `source`, which glTF does not), so they are left out here.
fn typed_root(json: &Value) -> Result<Root, IngestError> {
    let Value::Object(map) = json else {
        return Err(IngestError::InvalidDocument {
            path: "/".into(),
            message: "the top level is not an object".into(),
        });
    };
    let mut map = map.clone();
    map.remove("textures");
    let value = Value::Object(map);
    Root::deserialize_value(&value).map_err(|message| IngestError::InvalidDocument {
        path: locate(&value),
        message,
    })
}

trait FromValue: Sized {
    fn deserialize_value(v: &Value) -> Result<Self, String>;
}

impl<T: DeserializeOwned> FromValue for T {
    fn deserialize_value(v: &Value) -> Result<Self, String> {
        serde::Deserialize::deserialize(v).map_err(|e: serde_json::Error| e.to_string())
    }
}

/// Finds which top-level object fails to deserialize, for the error's path.
fn locate(root: &Value) -> String {
    fn find<T: DeserializeOwned>(root: &Value, key: &str) -> Option<String> {
        let items = root.get(key)?.as_array()?;
        items
            .iter()
            .position(|v| T::deserialize_value(v).is_err())
            .map(|i| format!("{key}[{i}]"))
    }
    use gltf::json as j;
    find::<j::Accessor>(root, "accessors")
        .or_else(|| find::<j::Animation>(root, "animations"))
        .or_else(|| find::<j::Buffer>(root, "buffers"))
        .or_else(|| find::<j::buffer::View>(root, "bufferViews"))
        .or_else(|| find::<j::Camera>(root, "cameras"))
        .or_else(|| find::<j::Image>(root, "images"))
        .or_else(|| find::<j::Material>(root, "materials"))
        .or_else(|| find::<j::Mesh>(root, "meshes"))
        .or_else(|| find::<j::Node>(root, "nodes"))
        .or_else(|| find::<j::texture::Sampler>(root, "samplers"))
        .or_else(|| find::<j::Scene>(root, "scenes"))
        .or_else(|| find::<j::Skin>(root, "skins"))
        .unwrap_or_else(|| "/".to_string())
}

fn check_version(json: &Value) -> Result<(), IngestError> {
    let version = json
        .pointer("/asset/version")
        .and_then(Value::as_str)
        .unwrap_or("");
    let major = version.split('.').next().unwrap_or("");
    if major != "2" {
        return Err(IngestError::UnsupportedVersion {
            version: version.to_string(),
        });
    }
    Ok(())
}

fn load_buffers(
    root: &Root,
    bin: Option<&[u8]>,
    base: &str,
    blobs: &BlobSet,
    data_budget: &mut u64,
) -> Result<Vec<Vec<u8>>, IngestError> {
    let mut out = Vec::with_capacity(root.buffers.len());
    for (i, b) in root.buffers.iter().enumerate() {
        let declared = b.byte_length.0;
        let (data, slack): (std::borrow::Cow<[u8]>, u64) = match (&b.uri, bin) {
            (Some(u), _) => {
                let r = uri::resolve(u, base, &format!("buffers[{i}]"), blobs, *data_budget)?;
                if matches!(r.bytes, std::borrow::Cow::Owned(_)) {
                    *data_budget -= r.bytes.len() as u64;
                }
                (r.bytes, 0)
            }
            // The BIN chunk may carry up to 3 bytes of padding (§4.4.3.3).
            (None, Some(bin)) if i == 0 => (std::borrow::Cow::Borrowed(bin), 3),
            (None, _) => return Err(IngestError::BufferWithoutData { buffer: i }),
        };
        let actual = data.len() as u64;
        if actual < declared || actual > declared + slack {
            return Err(IngestError::BufferLengthMismatch {
                buffer: i,
                declared,
                actual,
            });
        }
        let mut data = data.into_owned();
        data.truncate(declared as usize);
        out.push(data);
    }
    Ok(out)
}

fn semantic_name(s: &Semantic) -> String {
    match s {
        Semantic::Positions => "POSITION".into(),
        Semantic::Normals => "NORMAL".into(),
        Semantic::Tangents => "TANGENT".into(),
        Semantic::Colors(n) => format!("COLOR_{n}"),
        Semantic::TexCoords(n) => format!("TEXCOORD_{n}"),
        Semantic::Joints(n) => format!("JOINTS_{n}"),
        Semantic::Weights(n) => format!("WEIGHTS_{n}"),
        Semantic::Extras(s) => s.clone(),
    }
}

/// Checks an attribute's accessor type against what glTF (with `KHR_mesh_quantization`) allows.
fn check_type(
    l: &Layout,
    path: &str,
    kinds: &[gltf::json::accessor::Type],
    ok: impl Fn(gltf::json::accessor::ComponentType, bool) -> bool,
    expected: &'static str,
) -> Result<(), IngestError> {
    if kinds.contains(&l.kind) && ok(l.component, l.normalized) {
        Ok(())
    } else {
        Err(IngestError::WrongAccessorType {
            path: path.to_string(),
            accessor: l.accessor,
            found: l.describe(),
            expected,
        })
    }
}

fn read_meshes(
    root: &Root,
    layouts: &[Layout],
    buffers: &[Vec<u8>],
    materials: &[Material],
    limits: &IngestLimits,
    warnings: &mut Vec<String>,
) -> Result<Vec<Primitive>, IngestError> {
    use gltf::json::accessor::{ComponentType as C, Type as T};
    let mut out = Vec::new();
    let (mut vertices, mut triangles) = (0u64, 0u64);
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let path = format!("meshes[{mi}].primitives[{pi}]");
            let mode = match prim.mode {
                Checked::Valid(Mode::Triangles) => TriangleMode::Triangles,
                Checked::Valid(Mode::TriangleStrip) => TriangleMode::Strip,
                Checked::Valid(Mode::TriangleFan) => TriangleMode::Fan,
                Checked::Valid(m) => {
                    warnings.push(format!(
                        "{path}: mode {} (points or lines) skipped",
                        m.as_gl_enum()
                    ));
                    continue;
                }
                Checked::Invalid => {
                    warnings.push(format!("{path}: unknown mode skipped"));
                    continue;
                }
            };
            // Resolve every attribute reference and compare counts before reading anything.
            let mut attrs: Vec<(Semantic, &Layout, String)> = Vec::new();
            for (sem, idx) in &prim.attributes {
                let Checked::Valid(sem) = sem else { continue };
                let apath = format!("{path}.attributes.{}", semantic_name(sem));
                let l = layouts
                    .get(idx.value())
                    .ok_or(IngestError::UnresolvedReference {
                        path: apath.clone(),
                        target: "accessors",
                        index: idx.value(),
                        count: layouts.len(),
                    })?;
                attrs.push((sem.clone(), l, apath));
            }
            let find = |s: &Semantic| {
                attrs
                    .iter()
                    .find(|(x, _, _)| x == s)
                    .map(|(_, l, p)| (*l, p.as_str()))
            };
            let (pos, pos_path) =
                find(&Semantic::Positions).ok_or_else(|| IngestError::MissingPosition {
                    path: format!("{path}.attributes.POSITION"),
                })?;
            let count = pos.count;
            for (_, l, p) in &attrs {
                if l.count != count {
                    return Err(IngestError::UnequalCount {
                        path: p.clone(),
                        accessor: l.accessor,
                        count: l.count,
                        expected: count,
                    });
                }
            }
            vertices = vertices.saturating_add(count);
            if vertices > limits.max_vertices {
                return Err(IngestError::TooManyVertices {
                    count: vertices,
                    max: limits.max_vertices,
                });
            }
            let quantized = |c: C, _n: bool| c != C::U32;
            check_type(
                pos,
                pos_path,
                &[T::Vec3],
                quantized,
                "VEC3 of float, or (KHR_mesh_quantization) of [unsigned] byte/short",
            )?;
            let positions = accessor::read_vec::<3>(pos, buffers)?;
            if let Some(e) = positions
                .iter()
                .position(|p| !p.iter().all(|x| x.is_finite()))
            {
                return Err(IngestError::NonFinite {
                    path: pos_path.to_string(),
                    accessor: pos.accessor,
                    element: e as u64,
                });
            }
            let normals = match find(&Semantic::Normals) {
                Some((l, p)) => {
                    let ok = |c: C, n: bool| c == C::F32 || (n && matches!(c, C::I8 | C::I16));
                    check_type(
                        l,
                        p,
                        &[T::Vec3],
                        ok,
                        "VEC3 of float, or normalized byte/short",
                    )?;
                    Some(accessor::read_vec::<3>(l, buffers)?)
                }
                None => None,
            };
            let mut tex_coords = Vec::new();
            while let Some((l, p)) = find(&Semantic::TexCoords(tex_coords.len() as u32)) {
                check_type(
                    l,
                    p,
                    &[T::Vec2],
                    quantized,
                    "VEC2 of float, normalized unsigned byte/short, or quantized",
                )?;
                tex_coords.push(accessor::read_vec::<2>(l, buffers)?);
            }
            if attrs.iter().any(
                |(s, _, _)| matches!(s, Semantic::TexCoords(n) if *n as usize > tex_coords.len()),
            ) {
                warnings.push(format!("{path}: texture coordinate sets after TEXCOORD_{} are not contiguous and were skipped", tex_coords.len()));
            }
            let colors = match find(&Semantic::Colors(0)) {
                Some((l, p)) => {
                    let ok = |c: C, n: bool| c == C::F32 || (n && matches!(c, C::U8 | C::U16));
                    check_type(
                        l,
                        p,
                        &[T::Vec3, T::Vec4],
                        ok,
                        "VEC3/VEC4 of float or normalized unsigned byte/short",
                    )?;
                    Some(if l.kind == T::Vec3 {
                        accessor::read_vec::<3>(l, buffers)?
                            .into_iter()
                            .map(|[r, g, b]| [r, g, b, 1.0])
                            .collect()
                    } else {
                        accessor::read_vec::<4>(l, buffers)?
                    })
                }
                None => None,
            };
            let triangle_list = match prim.indices {
                Some(idx) => {
                    let ipath = format!("{path}.indices");
                    let l = layouts
                        .get(idx.value())
                        .ok_or(IngestError::UnresolvedReference {
                            path: ipath.clone(),
                            target: "accessors",
                            index: idx.value(),
                            count: layouts.len(),
                        })?;
                    let ok = |c: C, n: bool| !n && matches!(c, C::U8 | C::U16 | C::U32);
                    check_type(
                        l,
                        &ipath,
                        &[T::Scalar],
                        ok,
                        "SCALAR of unsigned byte/short/int",
                    )?;
                    let room = (limits.max_triangles - triangles)
                        .saturating_mul(3)
                        .saturating_add(2);
                    if l.count > room {
                        return Err(IngestError::TooManyTriangles {
                            count: triangles + l.count / 3,
                            max: limits.max_triangles,
                        });
                    }
                    let indices = accessor::read_u32(l, buffers)?;
                    if let Some(k) = indices.iter().position(|&v| v as u64 >= count) {
                        return Err(IngestError::IndexOutOfRange {
                            path: ipath,
                            accessor: l.accessor,
                            position: k as u64,
                            value: indices[k] as u64,
                            vertex_count: count,
                        });
                    }
                    // §3.7.2.1: the maximum value of the component type (primitive restart) is not allowed.
                    let restart = match l.component {
                        C::U8 => 0xFF,
                        C::U16 => 0xFFFF,
                        _ => 0xFFFF_FFFF,
                    };
                    if let Some(k) = indices.iter().position(|&v| v == restart) {
                        return Err(IngestError::PrimitiveRestartIndex {
                            path: ipath,
                            accessor: l.accessor,
                            position: k as u64,
                            value: restart as u64,
                        });
                    }
                    assemble(mode, indices.len(), |i| indices[i])
                }
                None => assemble(mode, count as usize, |i| i as u32),
            };
            let leftover = match mode {
                TriangleMode::Triangles => {
                    prim.indices.map_or(count, |i| layouts[i.value()].count) % 3
                }
                _ => 0,
            };
            if leftover != 0 {
                warnings.push(format!(
                    "{path}: {leftover} trailing indices do not form a triangle and were ignored"
                ));
            }
            triangles = triangles.saturating_add(triangle_list.len() as u64);
            if triangles > limits.max_triangles {
                return Err(IngestError::TooManyTriangles {
                    count: triangles,
                    max: limits.max_triangles,
                });
            }
            let material = prim.material.map(|m| m.value());
            if let Some(m) = material {
                let mat = materials.get(m).ok_or(IngestError::UnresolvedReference {
                    path: format!("{path}.material"),
                    target: "materials",
                    index: m,
                    count: materials.len(),
                })?;
                if let Some(t) = mat.base_color_texture {
                    if t.tex_coord as usize >= tex_coords.len() {
                        warnings.push(format!("{path}: material {m} samples base color from TEXCOORD_{}, which is missing", t.tex_coord));
                    }
                }
            }
            out.push(Primitive {
                mesh: mi,
                primitive: pi,
                material,
                mode,
                positions,
                normals,
                tex_coords,
                colors,
                triangles: triangle_list,
            });
        }
    }
    Ok(out)
}

/// Converts `n` vertex references (index `i` → vertex `v(i)`) in `mode` to a triangle list
/// (glTF 2.0 §3.7.2.1 "Topology Types"): strips keep a consistent winding by swapping the last
/// two corners of odd triangles; fans pivot on the first vertex.
fn assemble(mode: TriangleMode, n: usize, v: impl Fn(usize) -> u32) -> Vec<[u32; 3]> {
    match mode {
        TriangleMode::Triangles => (0..n / 3)
            .map(|t| [v(3 * t), v(3 * t + 1), v(3 * t + 2)])
            .collect(),
        TriangleMode::Strip => (0..n.saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [v(i), v(i + 1), v(i + 2)]
                } else {
                    [v(i), v(i + 2), v(i + 1)]
                }
            })
            .collect(),
        TriangleMode::Fan => (0..n.saturating_sub(2))
            .map(|i| [v(i + 1), v(i + 2), v(0)])
            .collect(),
    }
}

type Mat4 = [[f64; 4]; 4];

const IDENTITY: Mat4 = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Column-major product `a * b`.
fn mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut out = [[0.0; 4]; 4];
    for (c, col) in out.iter_mut().enumerate() {
        for (r, x) in col.iter_mut().enumerate() {
            *x = (0..4).map(|k| a[k][r] * b[c][k]).sum();
        }
    }
    out
}

/// A node's local matrix (§3.5.3 "Transformations"): `matrix`, or T·R·S.
fn local_matrix(node: &gltf::json::Node, index: usize) -> Result<Mat4, IngestError> {
    let non_finite = IngestError::NonFiniteTransform { node: index };
    if let Some(m) = node.matrix {
        if !m.iter().all(|x| x.is_finite()) {
            return Err(non_finite);
        }
        return Ok(std::array::from_fn(|c| {
            std::array::from_fn(|r| m[4 * c + r] as f64)
        }));
    }
    let t = node.translation.unwrap_or([0.0; 3]).map(f64::from);
    let q = node
        .rotation
        .as_ref()
        .map_or([0.0, 0.0, 0.0, 1.0], |q| q.0)
        .map(f64::from);
    let s = node.scale.unwrap_or([1.0; 3]).map(f64::from);
    if !(t.iter().chain(&q).chain(&s).all(|x| x.is_finite())) {
        return Err(non_finite);
    }
    let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    let [x, y, z, w] = if norm > 0.0 {
        q.map(|v| v / norm)
    } else {
        [0.0, 0.0, 0.0, 1.0]
    };
    let rot = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let mut m = IDENTITY;
    for c in 0..3 {
        for r in 0..3 {
            m[c][r] = rot[r][c] * s[c];
        }
    }
    m[3] = [t[0], t[1], t[2], 1.0];
    Ok(m)
}

/// Checks that the nodes form a forest (§3.5.2 "Node Hierarchy") and returns the mesh instances
/// of the chosen scene: `scene`, else scene 0, else every root node.
fn scene_instances(root: &Root, limits: &IngestLimits) -> Result<Vec<MeshInstance>, IngestError> {
    let n = root.nodes.len();
    let node_ref = |path: String, i: usize| {
        if i < n {
            Ok(i)
        } else {
            Err(IngestError::UnresolvedReference {
                path,
                target: "nodes",
                index: i,
                count: n,
            })
        }
    };
    let mut parent: Vec<Option<usize>> = vec![None; n];
    for (i, node) in root.nodes.iter().enumerate() {
        if let Some(m) = node.mesh {
            if m.value() >= root.meshes.len() {
                return Err(IngestError::UnresolvedReference {
                    path: format!("nodes[{i}].mesh"),
                    target: "meshes",
                    index: m.value(),
                    count: root.meshes.len(),
                });
            }
        }
        for (j, c) in node.children.iter().flatten().enumerate() {
            let c = node_ref(format!("nodes[{i}].children[{j}]"), c.value())?;
            if c == i {
                return Err(IngestError::InvalidNodeHierarchy {
                    node: c,
                    reason: "is its own child".into(),
                });
            }
            if parent[c].is_some() {
                return Err(IngestError::InvalidNodeHierarchy {
                    node: c,
                    reason: "has more than one parent".into(),
                });
            }
            parent[c] = Some(i);
        }
    }
    // With at most one parent each, nodes unreachable from a parentless node lie on a cycle.
    let mut reached = vec![false; n];
    let mut stack: Vec<usize> = (0..n).filter(|&i| parent[i].is_none()).collect();
    while let Some(i) = stack.pop() {
        reached[i] = true;
        stack.extend(root.nodes[i].children.iter().flatten().map(|c| c.value()));
    }
    if let Some(i) = reached.iter().position(|r| !r) {
        return Err(IngestError::InvalidNodeHierarchy {
            node: i,
            reason: "is part of a cycle of children".into(),
        });
    }
    let roots: Vec<usize> = match (root.scene, root.scenes.first()) {
        (Some(s), _) => {
            let scene = root
                .scenes
                .get(s.value())
                .ok_or(IngestError::UnresolvedReference {
                    path: "scene".into(),
                    target: "scenes",
                    index: s.value(),
                    count: root.scenes.len(),
                })?;
            let si = s.value();
            scene
                .nodes
                .iter()
                .enumerate()
                .map(|(j, x)| node_ref(format!("scenes[{si}].nodes[{j}]"), x.value()))
                .collect::<Result<_, _>>()?
        }
        (None, Some(scene)) => scene
            .nodes
            .iter()
            .enumerate()
            .map(|(j, x)| node_ref(format!("scenes[0].nodes[{j}]"), x.value()))
            .collect::<Result<_, _>>()?,
        (None, None) => (0..n).filter(|&i| parent[i].is_none()).collect(),
    };
    let mut instances = Vec::new();
    let mut stack: Vec<(usize, Mat4, u64)> =
        roots.iter().rev().map(|&r| (r, IDENTITY, 1)).collect();
    while let Some((i, parent_world, depth)) = stack.pop() {
        if depth > limits.max_node_depth {
            return Err(IngestError::NodeTooDeep {
                node: i,
                depth,
                max: limits.max_node_depth,
            });
        }
        let node = &root.nodes[i];
        let world = mul(&parent_world, &local_matrix(node, i)?);
        if !world.iter().flatten().all(|x| x.is_finite()) {
            return Err(IngestError::NonFiniteTransform { node: i });
        }
        if let Some(m) = node.mesh {
            instances.push(MeshInstance {
                node: i,
                mesh: m.value(),
                world,
            });
        }
        for c in node.children.iter().flatten().rev() {
            stack.push((c.value(), world, depth + 1));
        }
    }
    Ok(instances)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_fans_keep_winding() {
        assert_eq!(
            assemble(TriangleMode::Strip, 5, |i| i as u32),
            [[0, 1, 2], [1, 3, 2], [2, 3, 4]]
        );
        assert_eq!(
            assemble(TriangleMode::Fan, 5, |i| i as u32),
            [[1, 2, 0], [2, 3, 0], [3, 4, 0]]
        );
        assert_eq!(
            assemble(TriangleMode::Triangles, 7, |i| i as u32),
            [[0, 1, 2], [3, 4, 5]]
        );
        assert!(assemble(TriangleMode::Strip, 2, |i| i as u32).is_empty());
    }

    #[test]
    fn trs_matches_hand_product() {
        let node: gltf::json::Node = serde_json::from_str(
            r#"{"translation":[1,2,3],"rotation":[0,0,0.7071067811865476,0.7071067811865476],"scale":[2,2,2]}"#,
        )
        .unwrap();
        let m = local_matrix(&node, 0).unwrap();
        let inst = MeshInstance {
            node: 0,
            mesh: 0,
            world: m,
        };
        let p = inst.transform_point([1.0, 0.0, 0.0]);
        // scale 2, rotate 90° about z: (1,0,0) -> (0,2,0), then translate.
        assert!(
            (p[0] - 1.0).abs() < 1e-6 && (p[1] - 4.0).abs() < 1e-6 && (p[2] - 3.0).abs() < 1e-6,
            "{p:?}"
        );
    }

    #[test]
    fn limits_deserialize_with_defaults_and_reject_unknown() {
        let l: IngestLimits = serde_json::from_str(r#"{"max_vertices": 5}"#).unwrap();
        assert_eq!(l.max_vertices, 5);
        assert_eq!(l.max_image_side, 16384);
        assert!(serde_json::from_str::<IngestLimits>(r#"{"max_vertex": 5}"#).is_err());
    }
}
