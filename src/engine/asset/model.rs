//! The in-memory asset model: what ingest produces from a glTF 2.0 file and what the Surface,
//! texture sampling and export read.
//!
//! Conventions: positions are in the primitive's local space (node transforms live in
//! [`MeshInstance::world`]); vertex colors and factors are linear; images keep their encoded
//! bytes for export and, for the base-color images a drawn primitive samples, a decoded sRGB RGBA8 copy for sampling.
//! glTF UV convention: (0,0) is the top-left of the image, v grows downwards.

use std::sync::Arc;

/// A loaded glTF asset.
#[derive(Clone, Debug)]
pub struct Asset {
    /// The glTF JSON as uploaded (the GLB JSON chunk or the .gltf file), parsed. Export edits a
    /// copy of it, so everything retex does not understand survives untouched.
    pub json: serde_json::Value,
    /// The resolved bytes of every buffer, in glTF buffer order (GLB BIN chunk, data: URI or a
    /// named blob of the upload). Each holds exactly `byteLength` bytes.
    pub buffers: Vec<Vec<u8>>,
    /// Every image of the asset, in glTF image order.
    pub images: Vec<ImageSource>,
    /// Every texture, in glTF texture order.
    pub textures: Vec<Texture>,
    /// Every material, in glTF material order.
    pub materials: Vec<Material>,
    /// Every triangle primitive (triangles, strips and fans, converted to triangle lists) of
    /// every mesh, ordered by (mesh, primitive). Points and lines are skipped with a warning.
    pub primitives: Vec<Primitive>,
    /// Every node of the default scene (or scene 0, or every root node when there is no scene)
    /// that instantiates a mesh, in depth-first order, with its world transform.
    pub instances: Vec<MeshInstance>,
    /// Things that were skipped or fixed while loading (lowercase sentences).
    pub warnings: Vec<String>,
}

/// One image: its encoded bytes (for export) and, when used as a base-color texture, decoded
/// pixels (for sampling).
#[derive(Clone, Debug)]
pub struct ImageSource {
    /// Encoded bytes (PNG or JPEG), resolved from a bufferView, a data: URI or a named blob.
    pub bytes: Arc<Vec<u8>>,
    /// MIME type (`image/png` or `image/jpeg`), from the JSON or sniffed from the bytes.
    pub mime_type: String,
    /// Width and height read from the image header.
    pub width: u32,
    /// See `width`.
    pub height: u32,
    /// Bytes its decoded pixels take ([`super::images::ImageHeader::decoded_bytes`]); 0 for an
    /// image retex does not read (kept for export only).
    pub decoded_bytes: u64,
    /// The decoded pixels, present for images that a drawn primitive samples as base color
    /// ([`super::budget::sampled_images`]).
    pub decoded: Option<Arc<DecodedImage>>,
}

/// Decoded pixels, RGBA8, row-major from the top-left. The color channels are sRGB-encoded
/// (as stored in glTF base-color images); alpha is linear.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedImage {
    /// Width in pixels (> 0).
    pub width: u32,
    /// Height in pixels (> 0).
    pub height: u32,
    /// `width * height` pixels.
    pub pixels: Vec<[u8; 4]>,
}

/// A texture: an image and a sampler.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Index into [`Asset::images`]; `None` when the texture has no source.
    pub image: Option<usize>,
    /// Wrap and filter modes.
    pub sampler: Sampler,
}

/// Texture wrap mode (glTF sampler `wrapS` / `wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Wrap {
    /// 10497, the glTF default.
    #[default]
    Repeat,
    /// 33648.
    MirroredRepeat,
    /// 33071.
    ClampToEdge,
}

/// Sampler state relevant to sampling a base color.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Sampler {
    /// Horizontal wrap mode.
    pub wrap_s: Wrap,
    /// Vertical wrap mode.
    pub wrap_t: Wrap,
    /// Magnification filter is NEAREST (9728) rather than LINEAR.
    pub nearest: bool,
}

/// `KHR_texture_transform` applied to a texture reference: uv' = T(offset) R(rotation) S(scale) uv.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    /// Translation in UV units.
    pub offset: [f32; 2],
    /// Counter-clockwise rotation in radians (in UV space, as the extension specifies).
    pub rotation: f32,
    /// Scale factors.
    pub scale: [f32; 2],
}

impl Default for UvTransform {
    fn default() -> Self {
        Self {
            offset: [0.0, 0.0],
            rotation: 0.0,
            scale: [1.0, 1.0],
        }
    }
}

/// A material's reference to a texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`Asset::textures`].
    pub texture: usize,
    /// The TEXCOORD_n set to read (the `KHR_texture_transform` texCoord override already applied).
    pub tex_coord: u32,
    /// The `KHR_texture_transform`, if any.
    pub transform: Option<UvTransform>,
}

/// The part of a material that decides base color.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// The material's name, if any.
    pub name: Option<String>,
    /// Linear RGBA factor (pbrMetallicRoughness.baseColorFactor, or the legacy
    /// KHR_materials_pbrSpecularGlossiness diffuseFactor). Default [1, 1, 1, 1].
    pub base_color_factor: [f32; 4],
    /// pbrMetallicRoughness.baseColorTexture (or the legacy diffuseTexture).
    pub base_color_texture: Option<TextureRef>,
    /// `doubleSided`.
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            name: None,
            base_color_factor: [1.0; 4],
            base_color_texture: None,
            double_sided: false,
        }
    }
}

/// How a primitive's triangles were stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TriangleMode {
    /// mode 4.
    Triangles,
    /// mode 5, converted to a list with alternating winding fixed.
    Strip,
    /// mode 6, converted to a list.
    Fan,
}

/// One triangle primitive, decoded and validated.
#[derive(Clone, Debug)]
pub struct Primitive {
    /// Index of the glTF mesh.
    pub mesh: usize,
    /// Index of the primitive within its mesh.
    pub primitive: usize,
    /// Index into [`Asset::materials`]; `None` means the glTF default material.
    pub material: Option<usize>,
    /// How the triangles were stored.
    pub mode: TriangleMode,
    /// POSITION, local space, all finite.
    pub positions: Vec<[f32; 3]>,
    /// NORMAL, if present.
    pub normals: Option<Vec<[f32; 3]>>,
    /// TEXCOORD_0, TEXCOORD_1, ... in set order (dequantized to float).
    pub tex_coords: Vec<Vec<[f32; 2]>>,
    /// COLOR_0 as linear RGBA (RGB inputs get alpha 1; normalized integers dequantized).
    pub colors: Option<Vec<[f32; 4]>>,
    /// Triangles as vertex indices (all < positions.len()), after strip/fan conversion;
    /// generated 0,1,2,... for non-indexed geometry.
    pub triangles: Vec<[u32; 3]>,
}

/// A node of the scene that instantiates a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshInstance {
    /// Index of the glTF node.
    pub node: usize,
    /// Index of the glTF mesh.
    pub mesh: usize,
    /// Local-to-world transform, column-major 4x4 (as glTF `matrix`), products in f64.
    pub world: [[f64; 4]; 4],
}

impl MeshInstance {
    /// Transforms a local-space point to world space.
    pub fn transform_point(&self, p: [f32; 3]) -> [f64; 3] {
        let m = &self.world;
        let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
        [
            m[0][0] * x + m[1][0] * y + m[2][0] * z + m[3][0],
            m[0][1] * x + m[1][1] * y + m[2][1] * z + m[3][1],
            m[0][2] * x + m[1][2] * y + m[2][2] * z + m[3][2],
        ]
    }

    /// Whether the transform mirrors (negative determinant of the upper 3x3), which flips winding.
    pub fn mirrors(&self) -> bool {
        let m = &self.world;
        let det = m[0][0] * (m[1][1] * m[2][2] - m[2][1] * m[1][2])
            - m[1][0] * (m[0][1] * m[2][2] - m[2][1] * m[0][2])
            + m[2][0] * (m[0][1] * m[1][2] - m[1][1] * m[0][2]);
        det < 0.0
    }
}

impl Asset {
    /// The decoded pixels of image `index`, for a method that samples an image other than the
    /// base colour (a mask): the method names it in `Method::extra_images`, and the pipeline
    /// decodes it under the job's image limits before the method runs.
    ///
    /// # Errors
    /// A message for the constraint field at fault: the image does not exist, or it was not
    /// decoded (the method did not declare it: a retex bug, reported rather than decoded here
    /// without the job's limits).
    pub fn decoded_image(&self, index: usize) -> Result<&Arc<DecodedImage>, String> {
        let image = self.images.get(index).ok_or_else(|| {
            format!(
                "image {index} does not exist (the model has {})",
                self.images.len()
            )
        })?;
        image.decoded.as_ref().ok_or_else(|| {
            format!("image {index} was not decoded: the method did not declare it as read")
        })
    }

    /// Indices into [`Asset::primitives`] of the primitives of glTF mesh `mesh`.
    pub fn primitives_of_mesh(&self, mesh: usize) -> impl Iterator<Item = usize> + '_ {
        self.primitives
            .iter()
            .enumerate()
            .filter(move |(_, p)| p.mesh == mesh)
            .map(|(i, _)| i)
    }

    /// Total triangle count over all instances (what the Surface will hold before welding).
    pub fn instanced_triangle_count(&self) -> usize {
        self.instances
            .iter()
            .map(|inst| {
                self.primitives_of_mesh(inst.mesh)
                    .map(|p| self.primitives[p].triangles.len())
                    .sum::<usize>()
            })
            .sum()
    }
}
