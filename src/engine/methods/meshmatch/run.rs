//! `meshmatch` from glTF to glTF (Chen et al. 2012, Figure 2 end to end): weld both assets into
//! surfaces, build the synthesis meshes and the source colours, resolve the correspondences,
//! scale the source ([`ScaleMode`]), run [`synthesize`], and write the synthesized colours into
//! the target through the shared output path ([`write_color_field`]: baked base-colour textures
//! for primitives with UVs, COLOR_0 on a refined copy otherwise). The target texel at a surface
//! point takes the barycentric interpolation of the synthesis vertex colours there.
//!
//! By-example mode (§5.3, `params.example`): the *target* asset is both the example and the
//! canvas; the source upload is not read (send the same file twice).
//!
//! Texture-update mode (§5.3, Figure 10, `params.update`): the target is an edited copy of the
//! source, in the same units (no area scaling); its copied region ([`copied_region`]) keeps the
//! source's colour, read at full resolution at the closest source point, and the rest is
//! synthesized around it.

use std::cell::OnceCell;

use serde::Serialize;

use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::Edit;
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::mesh::{build_surface, Surface, WeldParams};
use crate::engine::methods::color_output::{write_color_field, ColorField, ColorOutputReport};
use crate::engine::methods::correspondence::resolve_on_surfaces;
use crate::engine::spatial::Bvh;

use super::em::{synthesize, Copied, MatchInput, MatchReport, Mode, PointPair};
use super::example::painted_vertices;
use super::nnf_file::NnfFile;
use super::sampling::{input_color, synthesis_colors, synthesis_mesh};
use super::scale::extent_ratio;
use super::update::{copied_region, CopiedRegion, CopySource};
use super::{MeshMatchError, MeshMatchParams, ScaleMode};
use crate::engine::texture::sample::MaterialSampler;

/// The job report of `meshmatch`.
#[derive(Clone, Debug, Serialize)]
pub struct MeshMatchReport {
    /// Target synthesis vertices.
    pub target_samples: usize,
    /// Source synthesis vertices.
    pub source_samples: usize,
    /// Scale applied to the source.
    pub source_scale: f32,
    /// Correspondences used.
    pub correspondences: usize,
    /// Painted synthesis vertices (by-example mode).
    pub painted_samples: Option<usize>,
    /// Target synthesis vertices copied from the source (texture-update mode).
    pub copied_samples: Option<usize>,
    /// The optimization.
    pub synthesis: MatchReport,
    /// What was written into the target.
    pub output: ColorOutputReport,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

/// The synthesized colours on the target synthesis mesh, as a field over the target surface.
/// In by-example mode, points inside the painted region read the original base colour instead
/// (the painted texture is kept at full resolution, not re-baked from the samples); in
/// texture-update mode, points inside the copied region read the source's.
struct SynthesizedField<'a> {
    surface: Surface,
    bvh: Bvh,
    colors: Vec<[f32; 3]>,
    original: Option<Original<'a>>,
}

/// What a synthesis keeps fixed, owned ([`Mode`] borrows it).
enum Kept {
    /// A plain transfer.
    Transfer,
    /// By-example: the painted synthesis vertices.
    ByExample(Vec<bool>),
    /// Texture update: the copied synthesis vertices and their colours.
    Update(CopiedRegion),
}

impl Kept {
    fn mode(&self) -> Mode<'_> {
        match self {
            Kept::Transfer => Mode::Transfer,
            Kept::ByExample(painted) => Mode::ByExample(painted),
            Kept::Update(region) => Mode::Update(Copied {
                mask: &region.mask,
                colors: &region.colors,
            }),
        }
    }
}

/// The painted original of by-example mode (the target), or the source of texture-update mode.
struct Original<'a> {
    asset: &'a Asset,
    input: &'a Surface,
    /// The input surface's BVH (the original colour is read at the closest input point: the
    /// synthesis mesh may be a decimation of the input).
    input_bvh: &'a Bvh,
    /// Painted (copied) synthesis vertices: a triangle whose corners all are reads the original.
    painted: Vec<bool>,
    sampler: MaterialSampler<'a>,
}

impl ColorField for SynthesizedField<'_> {
    fn color_at(
        &self,
        p: [f32; 3],
        _normal: [f32; 3],
        hint: Option<u32>,
    ) -> Option<([f32; 4], u32)> {
        let bound = hint.map_or(f32::INFINITY, |h| self.surface.hint_bound(h as usize, p));
        let hit = self.bvh.closest_point(p, bound)?;
        let f = self.surface.faces[hit.face as usize];
        if let Some(o) = &self.original {
            if f.iter().all(|&v| o.painted[v as usize]) {
                if let Some(h) = o.input_bvh.closest_point(p, f32::INFINITY) {
                    let c = input_color(o.asset, o.input, &o.sampler, h.face as usize, h.bary);
                    return Some((c.map(|x| x.clamp(0.0, 1.0)), hit.face));
                }
            }
        }
        let mut c = [0.0f32, 0.0, 0.0, 1.0];
        for k in 0..3 {
            for ch in 0..3 {
                c[ch] += hit.bary[k] * self.colors[f[k] as usize][ch];
            }
        }
        // Interpolation may overshoot by an ulp; glTF wants COLOR_0 in [0, 1].
        Some((c.map(|x| x.clamp(0.0, 1.0)), hit.face))
    }
}

/// The edits for the target, the report and the NNF artifact bytes.
pub type RunOutput = (Vec<Edit>, MeshMatchReport, Option<Vec<u8>>);

/// Runs `meshmatch`: returns the edits for the target, the report and the NNF artifact bytes.
///
/// # Errors
/// [`MeshMatchError`].
pub fn run(
    source: &Asset,
    target: &Asset,
    constraints: &Constraints,
    params: &MeshMatchParams,
    control: &Control,
) -> Result<RunOutput, MeshMatchError> {
    params.validate()?;
    let mut warnings = Vec::new();
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    let span = control.span(0.0, 0.02);
    control.stage("surface", 0)?;
    let by_example = params.example.is_some();
    let tgt_surface = build_surface(target, &weld).map_err(|source| MeshMatchError::Mesh {
        side: "target",
        source,
    })?;
    let (src_asset, src_surface) = if by_example {
        warnings.push(
            "by-example mode: the target is the example; the source upload was not read".into(),
        );
        (target, tgt_surface.clone())
    } else {
        let s = build_surface(source, &weld).map_err(|source| MeshMatchError::Mesh {
            side: "source",
            source,
        })?;
        (source, s)
    };
    let (area_s, area_t) = (src_surface.area(), tgt_surface.area());
    if !(area_s > 0.0 && area_t > 0.0) {
        return Err(MeshMatchError::Param {
            name: "samples",
            message: "a surface has zero area".into(),
        });
    }
    // By-example and texture update work in one model's units: no scaling.
    let same_units = by_example || params.update.is_some();
    let scale = match (params.scale, same_units) {
        (_, true) | (ScaleMode::World, _) => 1.0f32,
        (mode, false) => {
            let area = (area_t / area_s).sqrt();
            let extents = || extent_ratio(&src_surface, &tgt_surface).unwrap_or(area);
            (match mode {
                ScaleMode::MatchArea => area,
                ScaleMode::MatchExtents => extents(),
                _ => area.min(extents()),
            }) as f32
        }
    };
    let source_samples = if by_example {
        params.samples
    } else {
        params.source_samples.unwrap_or_else(|| {
            let scaled_area = area_s * (scale as f64).powi(2);
            ((params.samples as f64 * scaled_area / area_t).round() as usize)
                .clamp(256, (4 * params.samples).min(super::MAX_SAMPLES))
        })
    };
    // BVHs of the input surfaces, each built once when first needed (correspondences, the
    // by-example or texture-update original).
    let (src_input_bvh, tgt_input_bvh) = (OnceCell::new(), OnceCell::new());
    let src_bvh =
        || src_input_bvh.get_or_init(|| Bvh::build(&src_surface.positions, &src_surface.faces));
    let tgt_bvh =
        || tgt_input_bvh.get_or_init(|| Bvh::build(&tgt_surface.positions, &tgt_surface.faces));
    // Correspondences onto the input surfaces.
    let mut pairs = Vec::new();
    if !constraints.correspondences.is_empty() {
        let resolved = resolve_on_surfaces(
            &constraints.correspondences,
            (src_asset, src_bvh(), &src_surface),
            (target, tgt_bvh(), &tgt_surface),
            params.snap_tolerance,
        )?;
        for r in resolved {
            pairs.push(PointPair {
                source: vec![r.source.position.map(|x| x * scale)],
                target: r.targets.iter().map(|t| t.position).collect(),
            });
        }
    }
    drop(span);

    let span = control.span(0.02, 0.06);
    control.stage("synthesis meshes", 0)?;
    let tgt_mesh = synthesis_mesh(&tgt_surface, params.samples, control)?;
    let src_mesh = if by_example {
        tgt_mesh.clone()
    } else {
        synthesis_mesh(&src_surface, source_samples, control)?
    };
    let source_colors = synthesis_colors(src_asset, &src_surface, &src_mesh);
    // What the synthesis keeps: the painted vertices (by-example, read back from the target's
    // full-resolution surface) or the copied ones (texture update, read from the source's).
    let kept = match (&params.example, &params.update) {
        (Some(mask), _) => {
            Kept::ByExample(painted_vertices(mask, target, &tgt_surface, &tgt_mesh)?)
        }
        (None, Some(update)) => {
            let region = copied_region(
                update,
                &CopySource {
                    asset: src_asset,
                    surface: &src_surface,
                    bvh: src_bvh(),
                },
                (target, &tgt_surface),
                &tgt_mesh,
            )?;
            warnings.extend(region.warnings.iter().cloned());
            Kept::Update(region)
        }
        (None, None) => Kept::Transfer,
    };
    let mut scaled_source = src_mesh.surface.clone();
    for p in scaled_source.positions.iter_mut() {
        *p = p.map(|x| x * scale);
    }
    drop(span);

    let span = control.span(0.06, 0.9);
    let out = synthesize(
        &MatchInput {
            source: &scaled_source,
            source_colors: &source_colors,
            target: &tgt_mesh.surface,
            correspondences: &pairs,
            mode: kept.mode(),
        },
        params,
        constraints.seed,
        control,
    )?;
    drop(span);
    warnings.extend(out.report.warnings.iter().cloned());

    let nnf_bytes = params.write_nnf.then(|| {
        NnfFile {
            spokes: params.spokes as u32,
            source_scale: scale,
            target_positions: tgt_mesh.surface.positions.clone(),
            source_positions: src_mesh.surface.positions.clone(),
            nnf: out.nnf.clone(),
        }
        .encode()
    });
    let count = |mask: &[bool]| mask.iter().filter(|x| **x).count();
    let (painted_count, copied_count) = match &kept {
        Kept::Transfer => (None, None),
        Kept::ByExample(painted) => (Some(count(painted)), None),
        Kept::Update(region) => (None, Some(count(&region.mask))),
    };
    let original = match kept {
        Kept::Transfer => None,
        Kept::ByExample(painted) => Some(Original {
            asset: target,
            input: &tgt_surface,
            input_bvh: tgt_bvh(),
            painted,
            sampler: MaterialSampler::new(target),
        }),
        Kept::Update(region) => Some(Original {
            asset: src_asset,
            input: &src_surface,
            input_bvh: src_bvh(),
            painted: region.mask,
            sampler: MaterialSampler::new(src_asset),
        }),
    };
    let field = SynthesizedField {
        bvh: Bvh::build(&tgt_mesh.surface.positions, &tgt_mesh.surface.faces),
        surface: tgt_mesh.surface,
        colors: out.colors,
        original,
    };
    let _span = control.span(0.9, 1.0);
    let (edits, output) = write_color_field(
        target,
        constraints,
        params.vertex_color_samples,
        &field,
        control,
    )?;
    let report = MeshMatchReport {
        target_samples: field.surface.vertex_count(),
        source_samples: src_mesh.surface.vertex_count(),
        source_scale: scale,
        correspondences: pairs.len(),
        painted_samples: painted_count,
        copied_samples: copied_count,
        synthesis: out.report,
        output,
        warnings,
    };
    Ok((edits, report, nnf_bytes))
}
