//! Morphing (§5 of Zell & Botsch 2013, "Morphing"): once template and target share the
//! template's connectivity and UV layout, a morph is a per-vertex and per-texel linear blend.
//!
//! `params.blend = {"weight": w}` (w in [0, 1]):
//! - **Geometry**: the written world position of every welded vertex is
//!   `(1 − w)·template + w·fitted`, where `template` is the source's own world position and
//!   `fitted` the registered position in the target's world placement. The blend is in world
//!   coordinates, as the paper's morph between the two aligned meshes; when the initial
//!   similarity is far from the identity (template and target placed or scaled differently), the
//!   in-between shapes also move and scale linearly between the two placements (a rotation is
//!   interpolated linearly, not slerped: a half-way morph of a head turned by 90° is slightly
//!   shrunk). Normals and tangents are recomputed from the blended shape by the write-back.
//! - **Texture**: the base colour written at every texel is `(1 − w)·template + w·re-laid`, in
//!   linear colour, where `template` is the source's own base colour at that texel's surface point
//!   (factor × texture × COLOR_0, sampled in its own UV layout; its factor or COLOR_0 alone when it
//!   has no texture) and `re-laid` the target's colour of §4 ([`super::texture`]). Sources without
//!   UVs blend their own COLOR_0 the same way, per vertex.
//! - With `output = "morph_target"` the morph target keeps the full displacement and `w` becomes
//!   its default weight in `mesh.weights` (glTF blends the geometry itself); the texture is blended
//!   with the same `w`, so the default look of the asset is the blend at `w`.
//! - w = 1 (or no `blend`) is the unblended output, byte for byte; w = 0 gives the template's
//!   positions back (up to the float round trip through the node transform).
//!
//! Deviation: the region blend of §5 (Laplacian coordinates interpolated inside a region and the
//! Poisson system solved, Alexa 2003; gradient-domain texture blend, Pérez et al. 2003) is not
//! implemented; `blend.region` is refused by [`super::params`].

use crate::engine::asset::Asset;
use crate::engine::texture::sample::MaterialSampler;

/// `(1 − w)·template + w·fitted` per vertex (both in world coordinates).
pub fn blend_positions(template: &[[f64; 3]], fitted: &[[f64; 3]], w: f64) -> Vec<[f64; 3]> {
    template
        .iter()
        .zip(fitted)
        .map(|(t, f)| std::array::from_fn(|k| (1.0 - w) * t[k] + w * f[k]))
        .collect()
}

/// `(1 − w)·a + w·b` per channel.
pub fn mix(a: [f32; 4], b: [f32; 4], w: f32) -> [f32; 4] {
    std::array::from_fn(|k| (1.0 - w) * a[k] + w * b[k])
}

/// The template's own colour, blended into the re-laid colour with weight `w` on the latter.
pub struct TemplateColor<'a> {
    /// The source's material sampler.
    pub sampler: MaterialSampler<'a>,
    /// Weight of the re-laid (target) colour.
    pub weight: f32,
}

impl<'a> TemplateColor<'a> {
    /// The blend of `source`'s own colour with weight `1 − w`.
    pub fn new(source: &'a Asset, w: f64) -> Self {
        Self {
            sampler: MaterialSampler::new(source),
            weight: w as f32,
        }
    }

    /// The blend at a surface point of the source (its primitive, triangle, barycentric).
    pub fn at_point(
        &self,
        relaid: [f32; 4],
        primitive: usize,
        triangle: usize,
        bary: [f32; 3],
    ) -> [f32; 4] {
        let own = self.sampler.base_color(primitive, triangle, bary);
        mix(own, relaid, self.weight)
    }

    /// The blend at vertex `v` of a primitive without UVs: its own colour is the material factor
    /// times its COLOR_0 (white without).
    pub fn at_vertex(&self, relaid: [f32; 4], primitive: usize, v: usize) -> [f32; 4] {
        mix(
            vertex_base_color(self.sampler.asset(), primitive, v),
            relaid,
            self.weight,
        )
    }
}

/// The base colour of vertex `v` of a primitive without UVs: the material factor times its
/// COLOR_0 (white without).
pub(super) fn vertex_base_color(asset: &Asset, primitive: usize, v: usize) -> [f32; 4] {
    let prim = &asset.primitives[primitive];
    let factor = prim
        .material
        .and_then(|m| asset.materials.get(m))
        .map_or([1.0; 4], |m| m.base_color_factor);
    let c = prim
        .colors
        .as_ref()
        .and_then(|c| c.get(v).copied())
        .unwrap_or([1.0; 4]);
    std::array::from_fn(|k| factor[k] * c[k])
}
