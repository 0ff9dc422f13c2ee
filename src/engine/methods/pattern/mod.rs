//! The `pattern` method (Soler, Cani, Angelidis, *Hierarchical Pattern Mapping*, SIGGRAPH 2002):
//! a mesh covered with one pattern image, seamlessly as far as the pattern allows, by texture
//! coordinates only: the output is the target with TEXCOORD_0 per corner into the unmodified
//! input image.
//!
//! Pipeline, one module per step:
//! 1. [`hierarchy`] (§2.1, §3.1): the face-cluster hierarchy, each component a root, about
//!    `children` sub-clusters per split, down to single faces.
//! 2. [`flatten`] (§3.2): a flattening per disc cluster and its flatness error.
//! 3. [`driver`] (§2.2): coarsest flat-enough cluster first at the user's scale and orientation,
//!    then level by level by number of textured neighbours; split or accept.
//! 4. [`bands`] (§4.1): the textured neighbours' band triangles placed in the cluster's frame;
//!    [`mask`] rasterises them (the mask I and its support J).
//! 5. [`fit`] (§4.2, eq. 2): best placement over all orientations and offsets by FFT, on the
//!    colour space and rotated copies of [`texture`], with the 2-D FFTs of [`fft2`].
//! 6. [`relax`] (§4.4): local relaxation of the cluster's shared border vertices.
//! 7. [`uv_output`] (§4.3): TEXCOORD_0 per corner, vertices split only where patches meet, the
//!    image passed through.
//!
//! Deviations are stated in each module; the main one is the flattening (free-boundary LSCM per
//! cluster instead of the control-polygon recursion, see [`flatten`]).

pub mod bands;
pub mod driver;
pub mod fft2;
pub mod fit;
pub mod fit_window;
pub mod flatten;
pub mod hierarchy;
pub mod mask;
pub mod orient;
pub mod params;
pub mod relax;
pub mod report;
pub mod texture;
pub mod uv_output;

use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::mesh::{build_surface, topology, Surface, WeldParams};
use crate::engine::methods::{
    InputSpec, InputUse, Method, MethodError, MethodInput, MethodOutput, PatternImage, WorkingSet,
};

use params::{FaceRef, PatternParams};
use report::PatternReport;
use texture::PatternTexture;

/// Working-set bytes per input triangle: the hierarchy (each face listed once per level, about
/// ten levels), the flattenings and the output copy.
pub const TRIANGLE_BYTES: u64 = 512;

/// The `pattern` method (registry entry).
pub struct Pattern;

impl Method for Pattern {
    fn id(&self) -> MethodId {
        MethodId::Pattern
    }

    fn inputs(&self) -> InputSpec {
        InputSpec {
            source: InputUse::Unused,
            source_base: InputUse::Unused,
            pattern: InputUse::Required,
        }
    }

    fn params_schema(&self) -> serde_json::Value {
        crate::engine::methods::params::schema_of::<PatternParams>()
    }

    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError> {
        PatternParams::from_constraints(constraints).map(drop)
    }

    /// [`TRIANGLE_BYTES`] per input triangle (the pattern's FFTs are counted with the decoded
    /// image's budget by its size limits).
    fn working_set(&self, constraints: &Constraints, input_triangles: u64) -> Option<WorkingSet> {
        PatternParams::from_constraints(constraints).ok()?;
        Some(WorkingSet {
            bytes: input_triangles.saturating_mul(TRIANGLE_BYTES),
            field: "inputs",
        })
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let params = PatternParams::from_constraints(input.constraints)?;
        let pattern = input.pattern.ok_or_else(|| {
            MethodError::Internal("the pattern method ran without a pattern image".into())
        })?;
        let (edits, report) = run(
            input.target,
            pattern,
            &params,
            input.constraints.seed,
            control,
        )?;
        let mut out = MethodOutput::target(edits, &report);
        out.warnings = report.warnings;
        Ok(out)
    }
}

/// The surface face of a `first_face` reference (its first instance).
fn resolve_face(surface: &Surface, r: FaceRef) -> Result<u32, MethodError> {
    surface
        .origins
        .iter()
        .enumerate()
        .filter(|(_, o)| o.primitive as usize == r.primitive && o.triangle as usize == r.triangle)
        .min_by_key(|(_, o)| o.instance)
        .map(|(f, _)| f as u32)
        .ok_or_else(|| {
            MethodError::Constraints(ConstraintsError::new(
                "params.first_face",
                format!(
                    "primitive {} triangle {} is not a (non-degenerate, instanced) triangle of the target",
                    r.primitive, r.triangle
                ),
            ))
        })
}

/// Runs `pattern`: the edits of the target and the report.
///
/// # Errors
/// [`MethodError`]: an unusable surface or pattern, a bad `first_face`, cancellation.
pub fn run(
    target: &Asset,
    pattern: &PatternImage,
    params: &PatternParams,
    seed: u64,
    control: &Control,
) -> Result<(Vec<crate::engine::asset::edits::Edit>, PatternReport), MethodError> {
    let span = control.span(0.0, 0.2);
    control.stage("surface", 0)?;
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    let surface = build_surface(target, &weld).map_err(|source| MethodError::Mesh {
        side: "target",
        source,
    })?;
    if surface.face_count() == 0 {
        return Err(MethodError::UnusableInput {
            field: Some("target".into()),
            kind: "unusable-mesh",
            message: "the target has no non-degenerate triangle".into(),
        });
    }
    let topo = topology(&surface);
    let first_face = params
        .first_face
        .map(|r| resolve_face(&surface, r))
        .transpose()?;
    let hierarchy = hierarchy::build(&surface, &topo, params.children, seed, control)?;
    drop(span);

    let span = control.span(0.2, 0.3);
    control.stage("texture", 0)?;
    let texture = PatternTexture::new(&pattern.image, params.toroidal, params.orientations)?;
    drop(span);

    let span = control.span(0.3, 0.9);
    let scale = params.scale_for(surface.diagonal());
    let out = driver::run(
        &driver::DriverInput {
            surface: &surface,
            topo: &topo,
            hierarchy: &hierarchy,
            texture: &texture,
            params,
            scale,
            first_face,
            seed,
        },
        control,
    )?;
    drop(span);

    let _span = control.span(0.9, 1.0);
    control.stage("output", 0)?;
    let seam = uv_output::seam_error(&surface, &topo, &out.face_patch, &out.patches, &texture);
    let written = uv_output::write_uvs(
        target,
        &surface,
        &out.face_patch,
        &out.patches,
        pattern,
        params.toroidal,
    );
    let report = PatternReport {
        pattern_size: [texture.width(), texture.height()],
        scale,
        toroidal: params.toroidal,
        faces: surface.face_count(),
        components: hierarchy.roots.len(),
        hierarchy_levels: hierarchy.per_level.clone(),
        seed_redraws: hierarchy.seed_redraws,
        mean_seam_error: seam.map_or(0.0, |s| s / out.stats.random_pair_error),
        driver: out.stats,
        output_vertices: written.vertices,
        warnings: written.warnings,
    };
    Ok((written.edits, report))
}
