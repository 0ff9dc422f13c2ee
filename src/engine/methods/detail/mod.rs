//! The `detail` method (Berkiten, Halber, Solomon, Ma, Li, Rusinkiewicz, *Learning Detail
//! Transfer based on Geometric Features*, Eurographics 2017; issue 13): the detail of a sculpted
//! source (its displacement over a smooth base) synthesised onto a target where the target's
//! geometry resembles the source's, as a displacement texture, a normal map and `displaced.glb`.
//!
//! The method ([`Detail`]) reads the source (detailed), its optional smooth base (`source_base`)
//! and the target, runs [`pipeline`] and writes [`outputs`]. Its parts, each tested on its own:
//! - [`metric`] (§3.2.3, eqs. 1-2): the learned Mahalanobis metric (two-block ADMM), its factor
//!   `M = AᵀA` and the equal-weights baseline.
//! - [`displacement`] (§3, Fig. 4): the base (given, or the source smoothed) and the signed
//!   displacement along its normal to the detailed surface.
//! - [`hierarchy`] (§3.1): four remeshed levels per shape, edge length halving per level, shared
//!   absolute lengths between source and target (remesher: [`crate::engine::mesh::remesh`]).
//! - [`steerable`] (§3.2.1): the 17 sub-band deviations of a steerable pyramid of a square grid
//!   of displacements.
//! - [`patches`] (§3.2.1): the exponential-map patch of every vertex sampled into that grid, and
//!   the 17-D detail feature per vertex.
//! - [`geometric_features`] (§3.2.2): the 60-D geometric feature vector per vertex, HKS / WKS
//!   at scales shared by a source and a target; [`segmentation`] the SDF segments it measures
//!   boundary distances to.
//! - [`synthesis`] (§3.3.1, Algorithms 1-2, eqs. 5-7): the displacement of every target level,
//!   coarse to fine, from the source levels' displacements and both shapes' transformed
//!   features; [`sweep`] the sweep order and source sampling, [`blend`] eqs. 5-7, and the
//!   private `patch_match` the patches, the two-step matching and SYNTHESIZE-LEVEL.
//! - [`pipeline`]: the steps in order, from surfaces to the finest target level's displacement.
//! - [`outputs`]: the displacement and normal-map textures, TANGENT, the replaced UV-less
//!   primitives and `displaced.glb`, both maps sampled once per texel by the private `maps`;
//!   [`params`] the `params` object.
//!
//! - [`source_texture`]: a source whose detail is a displacement texture
//!   (`materials[i].extras.retex_displacement`, what `detail` writes); the source is then the base.
//!
//! Not done (README "detail"): the texture-space refinement (§3.3.2).

pub mod blend;
pub mod displacement;
pub mod fine_detail;
pub mod geometric_features;
pub mod hierarchy;
mod maps;
pub mod metric;
pub mod outputs;
pub mod params;
mod patch_match;
pub mod patches;
pub mod pipeline;
pub mod refine;
pub mod segmentation;
pub mod source_texture;
pub mod steerable;
pub mod sweep;
pub mod synthesis;

use serde::Serialize;

use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::control::Control;
use crate::engine::mesh::{build_surface, WeldParams};
use crate::engine::methods::{
    texture_working_set, InputSpec, InputUse, Method, MethodError, MethodInput, MethodOutput,
    WorkingSet,
};
use outputs::OutputSummary;
use params::DetailParams;
use pipeline::{transfer_detail, PipelineError, PipelineReport};

/// Working-set bytes per face of `max_faces` (both shapes' finest levels, their remeshing,
/// features, charts and the synthesis buffers). Measured: `retex bench --method detail` peaks at
/// 450 MiB for finest levels of 347k + 393k faces with 2048² maps (about 640 bytes a face with
/// the inputs and textures); doubled for margin.
pub const FACE_BYTES: u64 = 1200;

/// What `detail` reports.
#[derive(Clone, Debug, Serialize)]
pub struct DetailReport {
    /// Levels, metric, synthesis statistics and timings.
    #[serde(flatten)]
    pub pipeline: PipelineReport,
    /// Factor the source was scaled by (`params.match_scale`).
    pub source_scale: f64,
    /// What was written.
    pub outputs: OutputSummary,
    /// Seconds writing the outputs.
    pub output_seconds: f64,
    /// Things the user should know (lowercase sentences).
    pub warnings: Vec<String>,
}

/// Where the source's full-resolution detail is read.
enum Fine<'a> {
    /// Rays to the detailed mesh.
    Rays,
    /// The source's displacement texture.
    Map(source_texture::TextureDetail<'a>),
}

/// The `detail` method (registry entry).
pub struct Detail;

impl Method for Detail {
    fn id(&self) -> MethodId {
        MethodId::Detail
    }

    fn inputs(&self) -> InputSpec {
        InputSpec {
            source: InputUse::Required,
            source_base: InputUse::Optional,
            pattern: InputUse::Unused,
        }
    }

    fn params_schema(&self) -> serde_json::Value {
        crate::engine::methods::params::schema_of::<DetailParams>()
    }

    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError> {
        DetailParams::from_constraints(constraints).map(drop)
    }

    /// [`FACE_BYTES`] per face of `params.max_faces` for each of the two shapes, plus the two
    /// baked textures.
    fn working_set(&self, constraints: &Constraints, _input_triangles: u64) -> Option<WorkingSet> {
        let params = DetailParams::from_constraints(constraints).ok()?;
        let texture = texture_working_set(constraints);
        let levels = 2 * params.max_faces as u64 * FACE_BYTES;
        Some(WorkingSet {
            bytes: levels.saturating_add(2 * texture.bytes),
            field: if levels > 2 * texture.bytes {
                "params.max_faces"
            } else {
                texture.field
            },
        })
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let params = DetailParams::from_constraints(input.constraints)?;
        let weld = WeldParams {
            relative_tolerance: params.weld_tolerance,
        };
        let surface = |side: &'static str, asset| {
            build_surface(asset, &weld).map_err(|source| MethodError::Mesh { side, source })
        };
        let mut detailed = surface("source", input.source()?)?;
        let mut base = input
            .source_base
            .map(|b| surface("source_base", b))
            .transpose()?;
        let target = surface("target", input.target)?;
        let source_scale = match params.match_scale {
            true => target.diagonal() as f64 / (detailed.diagonal() as f64).max(f64::MIN_POSITIVE),
            false => 1.0,
        };
        if source_scale != 1.0 {
            let (lo, hi) = detailed.bounding_box();
            let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] as f64 + hi[k] as f64));
            for s in std::iter::once(&mut detailed).chain(base.as_mut()) {
                for p in s.positions.iter_mut() {
                    *p = std::array::from_fn(|k| {
                        (centre[k] + source_scale * (p[k] as f64 - centre[k])) as f32
                    });
                }
            }
        }
        let settings = params.pipeline(detailed.diagonal() as f64, target.diagonal() as f64);
        let span = control.span(0.0, 0.9);
        let mut warnings = Vec::new();
        let maps = source_texture::read_maps(input.source()?)?;
        if maps.is_some() && base.is_some() {
            warnings.push(
                "the source carries a displacement texture (extras.retex_displacement): it is \
                 the base, and source_base was ignored"
                    .to_string(),
            );
        }
        let source_asset = input.source()?;
        let fine = match maps {
            None => Fine::Rays,
            Some(maps) => Fine::Map(source_texture::TextureDetail::new(
                source_asset,
                &detailed,
                maps,
                source_scale,
            )),
        };
        let result = match &fine {
            Fine::Rays => transfer_detail(&detailed, base.as_ref(), &target, &settings, control),
            Fine::Map(field) => {
                let sample = |level: &crate::engine::mesh::Surface| {
                    use rayon::prelude::*;
                    let v: Vec<Option<f64>> =
                        level.positions.par_iter().map(|p| field.at(*p)).collect();
                    let missing = v.iter().filter(|x| x.is_none()).count();
                    Ok((v.into_iter().map(|x| x.unwrap_or(0.0)).collect(), missing))
                };
                pipeline::transfer_detail_with(&detailed, &sample, &target, &settings, control)
            }
        }
        .map_err(|e| match e {
            PipelineError::Cancelled => MethodError::Cancelled,
            PipelineError::Step { step, message } => MethodError::UnusableInput {
                field: None,
                kind: "unusable-mesh",
                message: format!("detail transfer failed at the {step} step: {message}"),
            },
        })?;
        drop(span);
        let _span = control.span(0.9, 1.0);
        let clock = std::time::Instant::now();
        let refine_params = params.refine_params();
        let refine_input = |fine| refine::RefineInput {
            source: &result.source_surface,
            source_displacement: &result.source_displacement,
            target: &result.surface,
            target_displacement: &result.displacement,
            points: &result.source_points,
            fine,
        };
        let (rays, sampled);
        let fine_source: &dyn refine::FineDetail = match &fine {
            Fine::Rays => {
                let d_max = params.max_displacement as f64 * detailed.diagonal() as f64;
                let edge = hierarchy::mean_edge_length(&result.surface);
                rays = fine_detail::RayDetail::new(&detailed, d_max, edge);
                &rays
            }
            Fine::Map(field) => {
                // Differences one map texel wide (a quarter edge where that is unknown).
                let texel = field.texel_size();
                let step = match texel.is_finite() {
                    true => texel,
                    false => 0.25 * hierarchy::mean_edge_length(&result.surface),
                };
                sampled = fine_detail::SampledDetail {
                    value: |p| field.at(p),
                    step,
                    texel,
                };
                &sampled
            }
        };
        let written = outputs::write_outputs(
            input.target,
            &target,
            &result.surface,
            &result.displacement,
            Some((refine_input(fine_source), &refine_params)),
            input.constraints,
            control,
        )?;
        warnings.extend(written.warnings);
        let report = DetailReport {
            pipeline: result.report,
            source_scale,
            outputs: written.summary,
            output_seconds: clock.elapsed().as_secs_f64(),
            warnings: warnings.clone(),
        };
        let mut out = MethodOutput::target(written.edits, &report);
        out.files = written.files;
        out.warnings = warnings;
        Ok(out)
    }
}
