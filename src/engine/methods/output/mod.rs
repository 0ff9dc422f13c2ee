//! Writing a field into an asset: the output half shared by every method that computes a value
//! per surface point (a colour, a normal, a displacement) of the asset it edits.
//!
//! A method supplies a [`SurfaceField`] of 1 to 4 channels, evaluated at a [`SurfaceSample`]:
//! the full surface point (primitive, triangle, barycentric coordinates, world position, face or
//! vertex normal). Because the sample names the primitive and triangle, a method can bake into
//! another asset's layout through a mapping (ElastiFace bakes the target's colour into the
//! source's UVs through the fitted source). [`write_field`] does the rest, as [`FieldOutput`]
//! says:
//!
//! * primitives whose material's base-colour UV set exists are grouped by material; each group's
//!   UV layout is rasterized ([`crate::engine::texture::bake::rasterize_uv_layout`]), the field
//!   is evaluated at every covered texel (parallel over chunks of 16 texel rows, each chunk
//!   carrying the field's hint from texel to texel), uncovered and unmatched texels are filled
//!   ([`crate::engine::texture::pad::pad`]) and the texture is encoded ([`TexelEncoding`]) into
//!   the output's material slot ([`texels`]);
//! * primitives without such UVs (or all of them, when `output.vertex_colors` is set) receive
//!   the field as a vertex attribute when the output names one (COLOR_0 for colour): on a refined
//!   copy with at most about `vertex_samples` vertices in all (on their own vertices when vertex
//!   colours were requested or the primitive is skinned or morphed); vertices where the field has
//!   no value take their neighbours' mean ([`vertices`]);
//! * except that, with `output.uv = "auto"` (the default) and the base-colour output, primitives
//!   without UVs (not skinned or morphed) get a generated atlas instead ([`atlas`]): they are
//!   replaced by copies carrying TEXCOORD_0 and baked into one texture of a new material. Other
//!   outputs (normal maps, ...) and outputs without a vertex attribute (ElastiFace writes COLOR_0
//!   on the source's own vertices itself) are left as they were by [`write_field`].
//!
//! A method writing several textures implements [`SurfaceFields`] (one evaluation per point
//! gives every output's values) and bakes all of them in one texel loop with [`write_fields`],
//! through an atlas it built once ([`atlas::build`]) when it wants one, so its textures keep one
//! layout and share their per-point work (`detail`'s normal map and displacement texture share
//! the closest point and the texture-space refinement; [`fields`] says why). [`write_field`]
//! runs through the same loop with one output.
//!
//! The output depends only on the field's values, never on the thread count: texels and
//! vertices are independent and results are collected in order.

pub mod atlas;
pub mod fields;
pub mod texels;
pub mod vertices;

pub use fields::SurfaceFields;

use serde::Serialize;

use crate::engine::asset::constraints::{Constraints, UvMode};
use crate::engine::asset::edits::{Edit, TextureSlot};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};

/// A point of the edited asset's surface at which a field is evaluated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceSample {
    /// Index into `Asset::primitives`.
    pub primitive: usize,
    /// Triangle of that primitive (index into `Primitive::triangles`).
    pub triangle: usize,
    /// Weights of the triangle's corners, in `Primitive::triangles[triangle]` order.
    pub barycentric: [f32; 3],
    /// World-space position (the first instance of the primitive's mesh).
    pub position: [f32; 3],
    /// Unit world-space normal: the face normal at texels, the area-weighted vertex normal at
    /// vertices (flipped for mirroring instances).
    pub normal: [f32; 3],
}

/// A field of 1 to 4 values per point over the edited asset's surface (how many are stored is
/// the [`FieldOutput`]'s encoding: 3 for a linear RGB normal map, 1 for 16-bit gray, ...).
pub trait SurfaceField: Sync {
    /// Writes the values at `at` into `out` and returns a hint for the next nearby
    /// sample (same texel row), or `None` where the field has no value there (the texel is
    /// counted unmatched and filled by padding; a vertex takes its neighbours' mean). `hint` is
    /// what the previous call returned for a nearby sample, or `None`.
    fn sample(&self, at: &SurfaceSample, hint: Option<u32>, out: &mut [f32; 4]) -> Option<u32>;
}

/// How a baked texture's texels are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TexelEncoding {
    /// Linear RGBA → 8-bit sRGB PNG (RGB when every alpha is 1).
    Srgb8,
    /// The first `channels` values, linear 8-bit PNG.
    Linear8 {
        /// 1..=4.
        channels: u8,
    },
    /// The first value, 16-bit grayscale PNG.
    Gray16,
}

/// Where and how a field is written.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldOutput {
    /// The material slot that receives the textures.
    pub slot: TextureSlot,
    /// Texel encoding.
    pub encoding: TexelEncoding,
    /// Image names: `<name>_material<m>`, or `<name>_default` for primitives without a material.
    pub name: &'static str,
    /// The vertex attribute written on primitives without UVs (`COLOR_0`), or `None` to skip
    /// them with a warning.
    pub vertex_attribute: Option<&'static str>,
    /// Vertex budget of the refined copies of primitives without UVs.
    pub vertex_samples: usize,
}

/// Figures of one baked texture.
#[derive(Clone, Debug, Serialize)]
pub struct TextureReport {
    /// Target material (`None`: a new material for primitives without one).
    pub material: Option<usize>,
    /// Texture width = height.
    pub size: u32,
    /// UV set baked into.
    pub tex_coord: u32,
    /// Triangles rasterized.
    pub triangles: usize,
    /// Texels inside some triangle.
    pub covered: u64,
    /// Covered texels claimed by more than one triangle (resolved to the lowest index).
    pub overlapped: u64,
    /// Covered texels with no valid source point (distance or normal gating); padded instead.
    pub unmatched: u64,
    /// Texels filled by dilation padding.
    pub padded: u64,
    /// Remaining texels filled by pull-push.
    pub filled: u64,
}

/// Figures of one primitive that received the vertex attribute.
#[derive(Clone, Debug, Serialize)]
pub struct VertexColorReport {
    /// glTF mesh index.
    pub mesh: usize,
    /// Primitive index within the mesh.
    pub primitive: usize,
    /// Whether a refined copy replaced the primitive.
    pub refined: bool,
    /// Vertices written.
    pub vertices: usize,
    /// Vertices with no valid source point (filled from neighbours).
    pub unmatched: usize,
}

/// What was written.
#[derive(Clone, Debug, Default, Serialize)]
pub struct OutputReport {
    /// One entry per baked texture.
    pub textures: Vec<TextureReport>,
    /// One entry per primitive that received the vertex attribute.
    pub vertex_colors: Vec<VertexColorReport>,
    /// Things the user should know (lowercase sentences).
    pub warnings: Vec<String>,
    /// The generated UV atlas, when primitives without UVs got one (`output.uv = "auto"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub atlas: Option<crate::engine::uv::AtlasReport>,
}

/// Writes `field` into `asset` as `output` says (see the module docs). Control stages `bake`,
/// `pad` and `vertex_colors`.
///
/// # Errors
/// [`Cancelled`].
pub fn write_field(
    asset: &Asset,
    constraints: &Constraints,
    output: &FieldOutput,
    field: &dyn SurfaceField,
    control: &Control,
) -> Result<(Vec<Edit>, OutputReport), Cancelled> {
    let mut report = OutputReport::default();
    let mut layout = texels::layout(asset, constraints, &mut report.warnings);
    let size = constraints.output.texture_size;
    let mut atlas_edits = Vec::new();
    if constraints.output.uv == UvMode::Auto
        && !constraints.output.all_vertex_colors()
        && output.slot == TextureSlot::BaseColor
        && output.vertex_attribute.is_some()
    {
        let (take, keep): (Vec<_>, Vec<_>) = layout
            .vertex_path
            .iter()
            .partition(|(p, _)| atlas::replaceable(asset, *p));
        if !take.is_empty() {
            let span = control.span(0.0, 0.1);
            let built = atlas::build(
                asset,
                &take,
                size,
                constraints.output.padding,
                constraints.output.atlas_parameterization,
                control,
                &mut report.warnings,
            )?;
            drop(span);
            if let Some(a) = built {
                layout.vertex_path = keep;
                layout.atlas = a.tris;
                atlas_edits = a.edits;
                report.atlas = Some(a.report);
            }
        }
    }
    finish(
        asset,
        constraints,
        std::slice::from_ref(output),
        &fields::Single(field),
        layout,
        atlas_edits,
        report,
        control,
    )
    .map(only)
}

/// The only output's edits and report.
fn only(mut per_output: Vec<(Vec<Edit>, OutputReport)>) -> (Vec<Edit>, OutputReport) {
    per_output.pop().unwrap_or_default()
}

/// The bake, padding, encoding and vertex path shared by [`write_field`] and [`write_fields`]:
/// one texel loop for all `outputs` (output `k` is `fields`' value `k`); per output its edits and report (`report` plus its own textures and
/// vertex figures). `atlas_edits` go first in the first output's edits (its texture edit
/// assigns the new material to the replaced primitives).
#[allow(clippy::too_many_arguments)]
fn finish(
    asset: &Asset,
    constraints: &Constraints,
    outputs: &[FieldOutput],
    fields: &dyn SurfaceFields,
    layout: texels::Layout,
    atlas_edits: Vec<Edit>,
    report: OutputReport,
    control: &Control,
) -> Result<Vec<(Vec<Edit>, OutputReport)>, Cancelled> {
    let size = constraints.output.texture_size;
    let span = control.span(0.0, 0.75);
    let baked = texels::bake_groups(asset, &layout, size, fields, outputs.len(), control)?;
    drop(span);

    let span = control.span(0.75, 0.9);
    let finished =
        texels::finish_textures(baked, size, constraints.output.padding, outputs, control)?;
    drop(span);

    let mut atlas_edits = Some(atlas_edits);
    let n = outputs.len() as f64;
    let mut per_output = Vec::with_capacity(outputs.len());
    for (k, (output, textures)) in outputs.iter().zip(finished).enumerate() {
        let mut report = report.clone();
        let mut edits = atlas_edits.take().unwrap_or_default();
        for (texture, tr) in textures {
            edits.push(texture);
            report.textures.push(tr);
        }
        let _span = control.span(0.9 + 0.1 * k as f64 / n, 0.9 + 0.1 * (k + 1) as f64 / n);
        let vertex_edits = vertices::write_vertex_values(
            asset,
            constraints,
            &layout,
            output,
            fields::OutputOf {
                fields,
                index: k,
                count: outputs.len(),
            },
            control,
            &mut report,
        )?;
        edits.extend(vertex_edits.into_edits());
        per_output.push((edits, report));
    }
    Ok(per_output)
}

pub(crate) use crate::engine::math::{cross, dot, normal_of, sub, to_f32};
pub(crate) use atlas::{build as build_atlas, replaceable as atlas_replaceable, AtlasLayout};
pub(crate) use fields::write_fields;
pub(crate) use texels::uv_set_of;
