//! Safe ingest of a glTF 2.0 asset from named blobs into the [`Asset`] model.
//!
//! Order of work, each step checked before the next allocates anything sized by the file:
//! upload size; another format than glTF ([`super::sniff`]: OBJ, PNG, text...); container
//! ([`super::glb`], §4.4); JSON size and syntax, kept verbatim; the typed
//! document (§3, via `gltf::json`), `asset.version` 2.x (§3.2) and `extensionsRequired` (§3.12);
//! buffers (§3.6.1: URI or GLB BIN chunk, exact `byteLength`) through [`super::uri`] (§2.8);
//! every buffer view and accessor ([`super::accessor`], §3.6.2); images, textures and materials
//! ([`super::images`], §3.8, §3.9, plus `KHR_texture_transform` and the archived
//! `KHR_materials_pbrSpecularGlossiness`); mesh primitives (§3.7.2: modes, attribute types incl.
//! `KHR_mesh_quantization`, index range, finite positions, vertex/triangle budgets); the node
//! hierarchy and scene (§3.5: strict forest, no cycles, finite TRS or matrix, f64 products);
//! and the model's budget ([`super::budget`]: instanced geometry, decoded image bytes) before
//! the images its primitives sample are decoded.
//!
//! [`load`] never touches the filesystem or network, and runs under `catch_unwind`, so a bug
//! surfaces as [`IngestError::Internal`] instead of taking the process down.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;

use gltf::json::Root;
use serde::de::DeserializeOwned;
use serde_json::Value;

use super::accessor;
use super::budget::{self, Demand};
use super::meshes::read_meshes;
use super::model::*;
use super::scene::scene_instances;
use super::{glb, images, sniff, uri, BlobSet, IngestError};

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
    /// Vertices summed over all primitives (points and lines excluded), and again over every
    /// mesh instance of every model a job reads ([`super::budget`]). Default: 20,000,000.
    pub max_vertices: u64,
    /// Triangles summed over all primitives, and again over every mesh instance of every model
    /// a job reads. Default: 20,000,000.
    pub max_triangles: u64,
    /// Bytes of decoded pixels per job: width × height × max(4, bytes per pixel) summed over
    /// every image the job decodes (the base-colour images a drawn primitive samples, and the
    /// pattern), from the headers before anything is decoded ([`super::budget`]).
    /// Default: 512 MiB (e.g. eight 4096² images; a 16384² image alone is 1 GiB).
    pub max_decoded_image_bytes: u64,
    /// Bytes of a method's own working memory per job, as the method estimates it from the
    /// constraints before the job runs (MeshMatch: its synthesis meshes and fans; every method
    /// that bakes a texture: `output.texture_size`² × 32 bytes). Default: 4 GiB.
    pub max_method_bytes: u64,
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
            max_decoded_image_bytes: 512 << 20,
            max_method_bytes: 4 << 30,
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
    load_with(main, blobs, limits, Decode::BaseColor)
}

/// Which images [`load_with`] decodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decode {
    /// Decode the base-color images that a drawn primitive samples
    /// ([`super::budget::sampled_images`], what the methods read), after checking their decoded
    /// size against `max_decoded_image_bytes`. Other images are never decoded.
    BaseColor,
    /// Decode nothing: every image's format and header dimensions are still checked against the
    /// limits, and the model's budget ([`super::budget`]) too, but no pixels are read. For
    /// validating an upload quickly, or for a caller that checks a whole job's budget before
    /// decoding ([`super::budget::decode_images`]).
    HeadersOnly,
}

/// [`load`], choosing which images are decoded.
///
/// # Errors
/// As [`load`].
pub fn load_with(
    main: &str,
    blobs: &BlobSet,
    limits: &IngestLimits,
    decode: Decode,
) -> Result<Asset, IngestError> {
    catch_unwind(AssertUnwindSafe(|| {
        load_unguarded(main, blobs, limits, decode)
    }))
    .unwrap_or_else(|panic| {
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
    decode: Decode,
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
    if let Some(f) = sniff::foreign_format(bytes) {
        return Err(IngestError::NotGltf {
            name: main.to_string(),
            format: f.what,
            advice: if f.advice.is_empty() {
                String::new()
            } else {
                format!("; {}", f.advice)
            },
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
                decoded_bytes: 0,
                decoded: None,
            });
            continue;
        }
        let header = images::read_header(i, &data, limits)?;
        image_list.push(ImageSource {
            bytes: Arc::new(data),
            mime_type: images::mime_of(header.format).to_string(),
            width: header.width,
            height: header.height,
            decoded_bytes: header.decoded_bytes(),
            decoded: None,
        });
    }

    let textures = images::read_textures(&json, &root)?;
    let materials = images::read_materials(&root, textures.len())?;

    let primitives = read_meshes(&root, &layouts, &buffers, &materials, limits, &mut warnings)?;
    let instances = scene_instances(&root, limits)?;
    let mut asset = Asset {
        json,
        buffers,
        images: image_list,
        textures,
        materials,
        primitives,
        instances,
        warnings,
    };
    // This model alone against the job's budget (the pipeline and the service also check the
    // sum over a job's inputs); the sampled images are decoded only within it.
    let demand = Demand::of_asset(&asset, &[]);
    budget::check_job(&[("model", &demand)], limits).map_err(|(_, e)| e)?;
    if decode == Decode::BaseColor {
        budget::decode_images(&mut asset, &demand, limits)?;
    }
    Ok(asset)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_deserialize_with_defaults_and_reject_unknown() {
        let l: IngestLimits = serde_json::from_str(r#"{"max_vertices": 5}"#).unwrap();
        assert_eq!(l.max_vertices, 5);
        assert_eq!(l.max_image_side, 16384);
        assert!(serde_json::from_str::<IngestLimits>(r#"{"max_vertex": 5}"#).is_err());
    }
}
