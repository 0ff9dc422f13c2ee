//! Texture matching (§4): the target's colour re-laid into the source's UV layout.
//!
//! For every covered texel of the source's UV layout the shared texel loop
//! ([`crate::engine::methods::output::write_field`], the one `project` uses) hands over its
//! (primitive, triangle, barycentric) point of the source; this field moves it onto the *fitted*
//! source (same barycentric combination of the fitted welded vertices), finds the closest point
//! on the target (exact point-triangle distance through the BVH, warm-started by the previous
//! texel's face), and samples the target's base colour there (factor × texture × COLOR_0, bilinear,
//! in linear colour). No distance or normal gating. The texel loop then pads with its dilation and
//! pull-push (more robust than the paper's one-pixel dilation).
//!
//! With `params.blend` the template's own colour is mixed in per texel ([`super::blend`]).
//!
//! Source primitives without UVs receive COLOR_0 on their *own* vertices (the shared vertex path
//! would refine them, which would change the vertex count ElastiFace must keep), unless
//! `output.vertex_colors` is set, in which case the shared path already writes own vertices.

use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::{AttributeData, Edit};
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::mesh::Surface;
use crate::engine::methods::color_output::base_color_output;
use crate::engine::methods::output::{write_field, OutputReport, SurfaceField, SurfaceSample};
use crate::engine::spatial::Bvh;
use crate::engine::texture::sample::MaterialSampler;

use super::blend::TemplateColor;
use super::MethodError;

/// The target's colour at the fitted source.
pub struct RelaidColor<'a> {
    /// The source asset (its primitives' triangles).
    pub source: &'a Asset,
    /// Per source primitive, per vertex: its welded vertex (`u32::MAX` if none).
    pub welded: &'a [Vec<u32>],
    /// Fitted welded source positions, in the target's world frame.
    pub fitted: &'a [[f32; 3]],
    /// The target asset.
    pub target: &'a Asset,
    /// Its welded world surface.
    pub target_surface: &'a Surface,
    /// BVH of that surface.
    pub target_bvh: &'a Bvh,
    /// The target's material sampler.
    pub sampler: MaterialSampler<'a>,
    /// The morph of §5: the template's own colour blended in ([`super::blend`]), or `None`.
    pub blend: Option<TemplateColor<'a>>,
}

impl RelaidColor<'_> {
    pub(super) fn fitted_point(
        &self,
        primitive: usize,
        vertices: [u32; 3],
        bary: [f32; 3],
    ) -> Option<[f32; 3]> {
        let map = self.welded.get(primitive)?;
        let mut p = [0.0f32; 3];
        for k in 0..3 {
            let w = *map.get(vertices[k] as usize)?;
            let q = self.fitted.get(w as usize)?;
            for d in 0..3 {
                p[d] += bary[k] * q[d];
            }
        }
        Some(p)
    }

    /// Colour of the target at its closest point to `p`, and that target face.
    pub(super) fn color_near(&self, p: [f32; 3], hint: Option<u32>) -> Option<([f32; 4], u32)> {
        let bound = hint.map_or(f32::INFINITY, |h| {
            self.target_surface.hint_bound(h as usize, p)
        });
        let hit = self.target_bvh.closest_point(p, bound)?;
        let (primitive, triangle, bary) =
            self.target_surface
                .primitive_point(self.target, hit.face as usize, hit.bary)?;
        let color = self.sampler.base_color(primitive, triangle, bary);
        Some((color, hit.face))
    }
}

impl SurfaceField for RelaidColor<'_> {
    fn sample(&self, at: &SurfaceSample, hint: Option<u32>, out: &mut [f32; 4]) -> Option<u32> {
        let tri = *self
            .source
            .primitives
            .get(at.primitive)?
            .triangles
            .get(at.triangle)?;
        let p = self.fitted_point(at.primitive, tri, at.barycentric)?;
        let (color, face) = self.color_near(p, hint)?;
        *out = match &self.blend {
            Some(b) => b.at_point(color, at.primitive, at.triangle, at.barycentric),
            None => color,
        };
        Some(face)
    }
}

/// Whether the target has any colour to re-lay: a base-colour texture or COLOR_0.
pub fn target_has_color(target: &Asset) -> bool {
    target.primitives.iter().any(|p| {
        p.colors.is_some()
            || p.material
                .and_then(|m| target.materials.get(m))
                .is_some_and(|m| m.base_color_texture.is_some())
    })
}

/// Whether a source primitive has the UV set its base colour would be baked through.
pub(super) fn has_uvs(asset: &Asset, p: usize) -> bool {
    let set = asset.primitives[p]
        .material
        .and_then(|m| asset.materials.get(m))
        .and_then(|m| m.base_color_texture)
        .map_or(0, |t| t.tex_coord) as usize;
    asset.primitives[p].tex_coords.len() > set
}

/// Writes the re-laid colour into the source (textures; COLOR_0 on own vertices without UVs).
///
/// # Errors
/// [`MethodError::Cancelled`].
pub fn relay_texture(
    field: &RelaidColor<'_>,
    constraints: &Constraints,
    control: &Control,
) -> Result<(Vec<Edit>, OutputReport), MethodError> {
    let mut output = base_color_output(1);
    let own_vertices = !constraints.output.all_vertex_colors();
    if own_vertices {
        output.vertex_attribute = None;
    }
    let (mut edits, mut report) = write_field(field.source, constraints, &output, field, control)?;
    if own_vertices {
        report.warnings.retain(|w| !w.contains("have no UVs"));
        let stage = control.stage("vertex_colors", 0)?;
        for (p, prim) in field.source.primitives.iter().enumerate() {
            if has_uvs(field.source, p) || field.welded[p].is_empty() {
                continue;
            }
            let colors: Vec<[f32; 4]> = (0..prim.positions.len() as u32)
                .map(|v| {
                    let c = field
                        .fitted_point(p, [v; 3], [1.0, 0.0, 0.0])
                        .and_then(|q| field.color_near(q, None))
                        .map_or([1.0; 4], |c| c.0);
                    match &field.blend {
                        Some(b) => b.at_vertex(c, p, v as usize),
                        None => c,
                    }
                })
                .collect();
            edits.push(Edit::SetAttribute {
                primitive: p,
                name: "COLOR_0".into(),
                data: AttributeData::Vec4(colors),
            });
            stage.tick(1)?;
        }
    }
    Ok((edits, report))
}
