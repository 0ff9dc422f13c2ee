//! The output vocabulary: what a method changes in an uploaded asset, applied by
//! [`super::export::export`] (DESIGN.md "Data flow": edits → export).
//!
//! A method returns an ordered list of [`Edit`]s for one asset (the target, or the source for
//! methods that deform the source, such as ElastiFace). Each edit names what it touches by index
//! into [`super::Asset`] (`primitive` = index into `Asset::primitives`, `material` = glTF material
//! index, `mesh` = glTF mesh index); export checks every index and count and refuses an edit that
//! does not fit ([`super::export::ExportError::BadEdit`]). Everything no edit touches survives.
//!
//! Images are carried encoded: [`EncodedImage`] has one constructor per texel encoding (sRGB
//! 8-bit, linear 8-bit, 16-bit grayscale, all PNG) and one that passes uploaded bytes through
//! unmodified with their MIME type.

use crate::engine::texture::encode::{encode_png_gray16, encode_png_linear8};

/// An image ready to be stored in the output, with the name of its glTF image and texture.
#[derive(Clone, Debug, PartialEq)]
pub struct EncodedImage {
    /// Name of the new glTF image and texture (also the artifact's file stem).
    pub name: String,
    /// Encoded bytes.
    pub bytes: Vec<u8>,
    /// `image/png` or `image/jpeg`.
    pub mime_type: String,
    /// How the texels were encoded.
    pub encoding: ImageEncoding,
}

/// How an [`EncodedImage`]'s texels are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageEncoding {
    /// 8-bit sRGB RGBA PNG (base colour, emissive).
    Srgb8,
    /// 8-bit linear PNG (normal maps, occlusion, data).
    Linear8,
    /// 16-bit grayscale PNG (displacement).
    Gray16,
    /// Uploaded bytes stored unmodified.
    Passthrough,
}

impl EncodedImage {
    /// An already encoded sRGB 8-bit PNG (what [`crate::engine::texture::encode::encode_png_srgb`]
    /// returns).
    pub fn srgb8_png(name: impl Into<String>, png: Vec<u8>) -> Self {
        Self {
            name: name.into(),
            bytes: png,
            mime_type: "image/png".into(),
            encoding: ImageEncoding::Srgb8,
        }
    }

    /// Linear 8-bit PNG of `channels` (1..=4) values in [0, 1] per texel, row-major, top row
    /// first (values are clamped and rounded).
    pub fn linear8(
        name: impl Into<String>,
        width: u32,
        height: u32,
        channels: u8,
        texels: &[f32],
    ) -> Self {
        Self {
            name: name.into(),
            bytes: encode_png_linear8(width, height, channels, texels),
            mime_type: "image/png".into(),
            encoding: ImageEncoding::Linear8,
        }
    }

    /// 16-bit grayscale PNG of one value in [0, 1] per texel (clamped, rounded to 1/65535).
    pub fn gray16(name: impl Into<String>, width: u32, height: u32, texels: &[f32]) -> Self {
        Self {
            name: name.into(),
            bytes: encode_png_gray16(width, height, texels),
            mime_type: "image/png".into(),
            encoding: ImageEncoding::Gray16,
        }
    }

    /// Bytes stored byte-for-byte (an uploaded PNG or JPEG).
    pub fn passthrough(
        name: impl Into<String>,
        bytes: Vec<u8>,
        mime_type: impl Into<String>,
    ) -> Self {
        Self {
            name: name.into(),
            bytes,
            mime_type: mime_type.into(),
            encoding: ImageEncoding::Passthrough,
        }
    }

    /// File extension of the bytes (`png` or `jpg`).
    pub fn extension(&self) -> &'static str {
        if self.mime_type == "image/jpeg" {
            "jpg"
        } else {
            "png"
        }
    }
}

/// A material's texture slot (glTF 2.0 §3.9).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TextureSlot {
    /// `pbrMetallicRoughness.baseColorTexture`. Setting it also makes `baseColorFactor` white,
    /// removes `KHR_materials_pbrSpecularGlossiness` and COLOR_0 of the edit's primitives (the
    /// texture holds the final colour, §3.7.2 says COLOR_0 would multiply it).
    BaseColor,
    /// `normalTexture` with its `scale`.
    Normal {
        /// Normal scale (1 = as encoded).
        scale: f32,
    },
    /// `occlusionTexture` with its `strength`.
    Occlusion {
        /// Occlusion strength in [0, 1].
        strength: f32,
    },
    /// `emissiveTexture` with the `emissiveFactor` it is multiplied by.
    Emissive {
        /// Linear RGB factor.
        factor: [f32; 3],
    },
    /// A texture referenced from `material.extras[key]` (e.g. `retex_displacement`): export
    /// sets `index` and `texCoord` in that object and keeps its other members (write them first
    /// with [`Edit::SetMaterialExtra`]).
    Extras(&'static str),
}

impl TextureSlot {
    /// The slot's key in the material JSON.
    pub fn key(self) -> &'static str {
        match self {
            TextureSlot::BaseColor => "baseColorTexture",
            TextureSlot::Normal { .. } => "normalTexture",
            TextureSlot::Occlusion { .. } => "occlusionTexture",
            TextureSlot::Emissive { .. } => "emissiveTexture",
            TextureSlot::Extras(key) => key,
        }
    }
}

/// Texture wrap of a new texture's sampler.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TextureWrap {
    /// REPEAT (glTF's default; nothing is written).
    #[default]
    Repeat,
    /// CLAMP_TO_EDGE on both axes.
    ClampToEdge,
}

/// Vertex data of one attribute, one element per vertex.
#[derive(Clone, Debug, PartialEq)]
pub enum AttributeData {
    /// VEC2 float (TEXCOORD_n).
    Vec2(Vec<[f32; 2]>),
    /// VEC3 float (POSITION, NORMAL, COLOR_0 RGB).
    Vec3(Vec<[f32; 3]>),
    /// VEC4 float (TANGENT with handedness in w, COLOR_0 RGBA).
    Vec4(Vec<[f32; 4]>),
}

impl AttributeData {
    /// Elements.
    pub fn len(&self) -> usize {
        match self {
            AttributeData::Vec2(v) => v.len(),
            AttributeData::Vec3(v) => v.len(),
            AttributeData::Vec4(v) => v.len(),
        }
    }

    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The glTF accessor type.
    pub fn gltf_type(&self) -> &'static str {
        match self {
            AttributeData::Vec2(_) => "VEC2",
            AttributeData::Vec3(_) => "VEC3",
            AttributeData::Vec4(_) => "VEC4",
        }
    }
}

/// New geometry for a primitive: unwelded vertices with their attributes and triangles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PrimitiveGeometry {
    /// Local-space positions.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Tangents (xyz unit, w = ±1 handedness).
    pub tangents: Option<Vec<[f32; 4]>>,
    /// TEXCOORD_0, TEXCOORD_1, ... in order.
    pub tex_coords: Vec<Vec<[f32; 2]>>,
    /// Linear RGBA COLOR_0.
    pub colors: Option<Vec<[f32; 4]>>,
    /// Triangles (indices into the vertices above).
    pub triangles: Vec<[u32; 3]>,
}

/// One primitive's displacement in a morph target.
#[derive(Clone, Debug, PartialEq)]
pub struct MorphDeltas {
    /// Index into `Asset::primitives` (a primitive of the edit's mesh).
    pub primitive: usize,
    /// Local-space position deltas, one per vertex.
    pub positions: Vec<[f32; 3]>,
    /// Normal deltas, one per vertex.
    pub normals: Option<Vec<[f32; 3]>>,
}

/// One change to an asset.
#[derive(Clone, Debug, PartialEq)]
pub enum Edit {
    /// A new texture in a material slot.
    SetTexture {
        /// glTF material index; `None` creates a new material (named after the image) and
        /// assigns it to `primitives`: a copy of the first primitive's material when it has one
        /// (its factors, alpha mode, double-sidedness and extensions kept, its texture
        /// references dropped: they read UV sets the new layout replaced), else an empty one.
        material: Option<usize>,
        /// The slot.
        slot: TextureSlot,
        /// The image.
        image: EncodedImage,
        /// The TEXCOORD set the texture is read through.
        tex_coord: u32,
        /// Sampler wrap (filters are linear, trilinear minification).
        wrap: TextureWrap,
        /// Primitives that use the texture (base colour: their stale COLOR_0 is removed).
        primitives: Vec<usize>,
    },
    /// Removes a texture from a material slot (base colour: the factor becomes white and
    /// spec-gloss is removed, as the primitives carry COLOR_0 instead).
    ClearTexture {
        /// glTF material index.
        material: usize,
        /// The slot.
        slot: TextureSlot,
    },
    /// Sets (adds or replaces) a vertex attribute of a primitive: `COLOR_0`, `TEXCOORD_n`,
    /// `POSITION` (min/max written), `NORMAL`, `TANGENT`.
    SetAttribute {
        /// Index into `Asset::primitives`.
        primitive: usize,
        /// Attribute semantic.
        name: String,
        /// One element per existing vertex.
        data: AttributeData,
    },
    /// Removes a vertex attribute (e.g. a TANGENT that no longer fits new positions).
    RemoveAttribute {
        /// Index into `Asset::primitives`.
        primitive: usize,
        /// Attribute semantic.
        name: String,
    },
    /// Appends a morph target to every primitive of a mesh (primitives not listed get zero
    /// deltas, since glTF requires the same target count on all of a mesh's primitives).
    AddMorphTarget {
        /// glTF mesh index.
        mesh: usize,
        /// Target name (written to `mesh.extras.targetNames`).
        name: String,
        /// Default weight of the new target in `mesh.weights`.
        weight: f32,
        /// Deltas per primitive.
        deltas: Vec<MorphDeltas>,
    },
    /// Replaces a primitive's geometry (attributes, indices; mode becomes triangles and its
    /// morph targets are dropped).
    ReplacePrimitive {
        /// Index into `Asset::primitives`.
        primitive: usize,
        /// The new geometry.
        geometry: PrimitiveGeometry,
    },
    /// Sets `materials[material].extras[key] = value`.
    SetMaterialExtra {
        /// glTF material index.
        material: usize,
        /// Key inside `extras`.
        key: String,
        /// Value.
        value: serde_json::Value,
    },
}

/// Which uploaded asset a method's edits apply to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EditedAsset {
    /// The target (most methods).
    #[default]
    Target,
    /// The source (methods that deform the source onto the target).
    Source,
}
