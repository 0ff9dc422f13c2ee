//! The `project` method: closest-point transfer of the source's base color onto the target.
//!
//! This is the texture-matching step of ElastiFace (Zell & Botsch 2013, section 4: after the
//! source is fitted to the target, every target texel takes the color of the closest source
//! point) and what every baker does. For every covered texel of the target's UV layout (and for
//! every vertex of primitives without UVs) the target surface point is found, the closest point on
//! the source is computed exactly (point–triangle distance through a BVH, not nearest vertex), and
//! the source's base color is sampled there (factor × texture × COLOR_0, in linear space).
//!
//! Options: `max_distance` and `max_normal_angle` gate the search (texels with no valid source
//! point are counted as `unmatched` and filled by padding); with two or more correspondences the
//! source is first moved onto the target by the best similarity transform (Horn/Umeyama, see
//! [`super::align`]). Parallel over texel rows with rayon; every texel is independent, so the
//! output does not depend on the thread count.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::align::{best_similarity, Similarity};
use super::color_output::{write_color_field, ColorField};
use super::correspondence::resolve_on_surfaces;
use super::shared_params::SharedParams;
use super::{InputSpec, Method, MethodError, MethodInput, MethodOutput};
use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::asset::edits::Edit;
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::math::{dot, to_f32};
use crate::engine::mesh::{build_surface, Surface, WeldParams};
use crate::engine::spatial::Bvh;
use crate::engine::texture::sample::MaterialSampler;

pub use super::color_output::{TextureReport, VertexColorReport};

/// Parameters of the `project` method (the `params` object of the constraints).
// Ranges are on the fields and checked through the derived schema (`super::params`); the shared
// options' doc, default and range come from `SharedParams`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
#[schemars(transform = super::shared_params::shared_fields)]
pub struct ProjectParams {
    /// Largest source–target distance accepted, as a fraction of the target's bounding-box
    /// diagonal. Default: none (unbounded).
    #[schemars(range(max = 10), extend("exclusiveMinimum" = 0))]
    pub max_distance: Option<f32>,
    /// Largest angle between the target face normal and the source face normal, in degrees.
    /// Default: none (no gating).
    #[schemars(range(max = 180), extend("exclusiveMinimum" = 0))]
    pub max_normal_angle: Option<f32>,
    /// Align the source to the target from the correspondences (needs at least 2). Default true.
    pub align: bool,
    /// Shared: [`SharedParams::vertex_color_samples`].
    pub vertex_color_samples: usize,
    /// Shared: [`SharedParams::snap_tolerance`].
    pub snap_tolerance: f32,
    /// Shared: [`SharedParams::weld_tolerance`] (see [`WeldParams`]).
    pub weld_tolerance: f32,
}

impl Default for ProjectParams {
    fn default() -> Self {
        let shared = SharedParams::default();
        Self {
            max_distance: None,
            max_normal_angle: None,
            align: true,
            vertex_color_samples: shared.vertex_color_samples,
            snap_tolerance: shared.snap_tolerance,
            weld_tolerance: shared.weld_tolerance,
        }
    }
}

impl ProjectParams {
    /// Reads and range-checks the parameters from the constraints' `params`.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        super::params::parse(c)
    }
}

/// The alignment that was applied.
#[derive(Clone, Debug, Serialize)]
pub struct AlignmentReport {
    /// The transform applied to the source.
    pub transform: Similarity,
    /// Correspondence pairs used.
    pub pairs: usize,
    /// Residual after alignment, world units of the target.
    pub rms_error: f64,
}

/// Counts of a welded surface.
#[derive(Clone, Debug, Serialize)]
pub struct SurfaceReport {
    /// Welded vertices.
    pub vertices: usize,
    /// Faces.
    pub faces: usize,
    /// Degenerate triangles removed.
    pub degenerate_removed: usize,
}

impl SurfaceReport {
    fn of(s: &Surface) -> Self {
        Self {
            vertices: s.vertex_count(),
            faces: s.face_count(),
            degenerate_removed: s.degenerate_removed,
        }
    }
}

/// What the method reports.
#[derive(Clone, Debug, Serialize)]
pub struct ProjectReport {
    /// The welded source surface.
    pub source_surface: SurfaceReport,
    /// The welded target surface.
    pub target_surface: SurfaceReport,
    /// The alignment, when one was applied.
    pub alignment: Option<AlignmentReport>,
    /// One entry per baked texture.
    pub textures: Vec<TextureReport>,
    /// One entry per primitive that received COLOR_0.
    pub vertex_colors: Vec<VertexColorReport>,
    /// The generated UV atlas of the primitives that had no UVs (`output.uv = "auto"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub atlas: Option<crate::engine::uv::AtlasReport>,
    /// Things the user should know (lowercase sentences).
    pub warnings: Vec<String>,
}

/// The source, placed in the target's frame, ready to answer "what color is closest to p".
struct SourceField<'a> {
    asset: &'a Asset,
    surface: Surface,
    bvh: Bvh,
    sampler: MaterialSampler<'a>,
    normals: Vec<[f32; 3]>,
    max_distance: f32,
    min_cos: Option<f32>,
}

impl ColorField for SourceField<'_> {
    /// Base color of the closest valid source point to `p` (target face normal `normal` for gating), and
    /// the source face it lies on. `hint` is a face that was closest for a nearby point: its
    /// distance bounds the search (a warm start that prunes most of the BVH); the result does not
    /// depend on it, because the bound includes the true closest point and ties still go to the
    /// lowest face index.
    fn color_at(
        &self,
        p: [f32; 3],
        normal: [f32; 3],
        hint: Option<u32>,
    ) -> Option<([f32; 4], u32)> {
        let accept = |f: u32| {
            self.min_cos
                .is_none_or(|c| dot(self.normals[f as usize], normal) >= c)
        };
        let mut bound = self.max_distance;
        if let Some(h) = hint.filter(|h| accept(*h)) {
            bound = bound.min(self.surface.hint_bound(h as usize, p));
        }
        let hit = match self.min_cos {
            None => self.bvh.closest_point(p, bound),
            Some(_) => self.bvh.closest_point_filtered(p, bound, accept),
        }?;
        let (primitive, triangle, bary) =
            self.surface
                .primitive_point(self.asset, hit.face as usize, hit.bary)?;
        let color = self.sampler.base_color(primitive, triangle, bary);
        Some((color, hit.face))
    }
}

/// The `project` method (registry entry).
pub struct Project;

impl Method for Project {
    fn id(&self) -> MethodId {
        MethodId::Project
    }

    fn inputs(&self) -> InputSpec {
        InputSpec::SOURCE_AND_TARGET
    }

    fn params_schema(&self) -> serde_json::Value {
        super::params::schema_of::<ProjectParams>()
    }

    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError> {
        ProjectParams::from_constraints(constraints).map(drop)
    }

    fn working_set(
        &self,
        constraints: &Constraints,
        input_triangles: u64,
    ) -> Option<super::WorkingSet> {
        let texture = super::texture_working_set(constraints);
        // A UV-less target gets an atlas (output.uv = auto).
        let atlas = super::atlas_working_set(constraints, input_triangles);
        Some(super::WorkingSet {
            bytes: texture.bytes.saturating_add(atlas),
            field: if atlas > texture.bytes {
                "output.uv"
            } else {
                texture.field
            },
        })
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let params = ProjectParams::from_constraints(input.constraints)?;
        let (edits, report) = run(
            input.source()?,
            input.target,
            input.constraints,
            &params,
            control,
        )?;
        let mut out = MethodOutput::target(edits, &report);
        out.warnings = report.warnings;
        Ok(out)
    }
}

/// Runs `project`: returns the edits to write into the target and the report.
///
/// # Errors
/// [`MethodError::Mesh`] when a surface cannot be built, [`MethodError::Constraints`] for a
/// correspondence that does not resolve, [`MethodError::Cancelled`].
pub fn run(
    source: &Asset,
    target: &Asset,
    constraints: &Constraints,
    params: &ProjectParams,
    control: &Control,
) -> Result<(Vec<Edit>, ProjectReport), MethodError> {
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    let surfaces = control.span(0.0, 0.1);
    control.stage("surface", 2)?;
    let (src_surface, tgt_surface) = rayon::join(
        || build_surface(source, &weld),
        || build_surface(target, &weld),
    );
    let mut src_surface = src_surface.map_err(|source| MethodError::Mesh {
        side: "source",
        source,
    })?;
    let tgt_surface = tgt_surface.map_err(|source| MethodError::Mesh {
        side: "target",
        source,
    })?;
    // The target's hierarchy only serves to resolve correspondences.
    let (mut src_bvh, tgt_bvh) = rayon::join(
        || Bvh::build(&src_surface.positions, &src_surface.faces),
        || match constraints.correspondences.is_empty() {
            true => Bvh::build(&[], &[]),
            false => Bvh::build(&tgt_surface.positions, &tgt_surface.faces),
        },
    );
    let mut warnings = Vec::new();

    drop(surfaces);
    let align = control.span(0.1, 0.15);
    control.stage("align", 1)?;
    let resolved = resolve_on_surfaces(
        &constraints.correspondences,
        (source, &src_bvh, &src_surface),
        (target, &tgt_bvh, &tgt_surface),
        params.snap_tolerance,
    )?;
    let mut from = Vec::new();
    let mut to = Vec::new();
    for r in &resolved {
        for t in &r.targets {
            from.push(r.source.position.map(f64::from));
            to.push(t.position.map(f64::from));
        }
    }
    let alignment = if params.align && from.len() >= 2 {
        let transform = best_similarity(&from, &to);
        for p in src_surface.positions.iter_mut() {
            *p = to_f32(transform.apply(p.map(f64::from)));
        }
        src_bvh = Bvh::build(&src_surface.positions, &src_surface.faces);
        Some(AlignmentReport {
            rms_error: transform.rms_error(&from, &to),
            pairs: from.len(),
            transform,
        })
    } else {
        if from.len() == 1 && params.align {
            warnings.push(
                "one correspondence pair cannot define an alignment; the source was not moved"
                    .into(),
            );
        }
        None
    };

    let diag = tgt_surface.diagonal();
    let normals = (0..src_surface.face_count())
        .map(|f| src_surface.face_normal(f))
        .collect();
    let field = SourceField {
        asset: source,
        bvh: src_bvh,
        sampler: MaterialSampler::new(source),
        normals,
        max_distance: params.max_distance.map_or(f32::INFINITY, |d| d * diag),
        min_cos: params.max_normal_angle.map(|a| a.to_radians().cos()),
        surface: src_surface,
    };
    let src_report = SurfaceReport::of(&field.surface);

    drop(align);
    let _output = control.span(0.15, 1.0);
    let (edits, out) = write_color_field(
        target,
        constraints,
        params.vertex_color_samples,
        &field,
        control,
    )?;
    warnings.extend(out.warnings);
    let report = ProjectReport {
        source_surface: src_report,
        target_surface: SurfaceReport::of(&tgt_surface),
        alignment,
        textures: out.textures,
        vertex_colors: out.vertex_colors,
        atlas: out.atlas,
        warnings,
    };
    Ok((edits, report))
}
