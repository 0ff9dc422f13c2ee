//! Writing a colour field into the target: base-colour textures for primitives with UVs,
//! COLOR_0 for those without ([`super::output::write_field`] with the base-colour output).
//!
//! [`ColorField`] is the colour-only face of [`SurfaceField`]: linear RGBA at a world point with
//! its unit normal, which is all that `project` and `meshmatch` need.

use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::{Edit, TextureSlot};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};

use super::output::{write_field, FieldOutput, TexelEncoding};
pub use super::output::{
    OutputReport as ColorOutputReport, SurfaceField, SurfaceSample, TextureReport,
    VertexColorReport,
};

/// A colour field over the target's world-space surface.
pub trait ColorField: Sync {
    /// Linear RGBA at world point `p` of the target, whose (unit) face normal is `normal`;
    /// `hint` is the value returned by the previous call for a nearby point (same texel row), or None.
    /// Returns the color and a new hint, or None where the field has no value (counted unmatched, filled by padding).
    fn color_at(&self, p: [f32; 3], normal: [f32; 3], hint: Option<u32>)
        -> Option<([f32; 4], u32)>;
}

/// A [`ColorField`] seen as a 4-channel [`SurfaceField`].
struct AsSurfaceField<'a>(&'a dyn ColorField);

impl SurfaceField for AsSurfaceField<'_> {
    fn sample(&self, at: &SurfaceSample, hint: Option<u32>, out: &mut [f32; 4]) -> Option<u32> {
        let (color, next) = self.0.color_at(at.position, at.normal, hint)?;
        *out = color;
        Some(next)
    }
}

/// The base-colour output: sRGB textures named `retex_basecolor_*`, COLOR_0 without UVs.
pub fn base_color_output(vertex_color_samples: usize) -> FieldOutput {
    FieldOutput {
        slot: TextureSlot::BaseColor,
        encoding: TexelEncoding::Srgb8,
        name: "retex_basecolor",
        vertex_attribute: Some("COLOR_0"),
        vertex_samples: vertex_color_samples,
    }
}

/// Writes `field` into `target`: baked base-colour textures for primitives with UVs, COLOR_0 (on
/// a refined copy, about `vertex_color_samples` vertices in all) for those without. Control
/// stages `bake`, `pad` and `vertex_colors`.
///
/// # Errors
/// [`Cancelled`].
pub fn write_color_field(
    target: &Asset,
    constraints: &Constraints,
    vertex_color_samples: usize,
    field: &dyn ColorField,
    control: &Control,
) -> Result<(Vec<Edit>, ColorOutputReport), Cancelled> {
    write_field(
        target,
        constraints,
        &base_color_output(vertex_color_samples),
        &AsSurfaceField(field),
        control,
    )
}
