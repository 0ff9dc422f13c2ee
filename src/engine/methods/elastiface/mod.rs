//! The `elastiface` method (Zell & Botsch 2013, "ElastiFace: Matching and Blending Textured
//! Faces", NPAR): the source (a template whose connectivity and UVs are kept) is deformed onto the
//! target, and the target's colour is re-laid into the source's UV layout. The output is the
//! source asset.
//!
//! Pipeline, one module per step:
//! 1. [`refs`], [`boundary`]: correspondences as reference points in triangles (§3.1, eq. 1),
//!    plus pairs derived along corresponding boundary loops (Fig. 5);
//! 2. [`frame`]: the best similarity of the source reference points onto the target's
//!    (Horn / Umeyama), and the scale normalisation to a reference diagonal;
//! 3. [`fairing`]: joint fairing of both meshes into base meshes (§3.2, eqs. 2-5);
//! 4. [`register`]: non-rigid registration of the base meshes (§3.3, eqs. 6-8), then
//!    [`originals`]: of the originals starting from the base meshes' closest points, followed by
//!    closest-point rounds with backward pairs (a deviation, see there); with
//!    `free_visibility` > 0 the template's hidden cavities are left unfitted there ([`free`],
//!    ours);
//! 5. [`texture`]: texture matching (§4) through the shared texel loop;
//! 6. [`writeback`]: POSITION / NORMAL through the source's node transforms, or a morph target;
//!    [`crate::engine::methods::tangents`]: TANGENT recomputed with MikkTSpace;
//! 7. [`metrics`]: Hausdorff distance, flipped triangles and residuals for the report;
//! 8. [`blend`]: the linear morph of §5 (`params.blend.weight`) between the template and the
//!    fitted result, positions and texture; with `params.blend.region` the part-based morph of
//!    §5: [`region`] (the per-vertex weights), [`poisson`] (Laplacian blend of the positions,
//!    Alexa 2003 with cotan weights), [`region_texture`] (gradient-domain texture blend, Pérez
//!    et al. 2003) and [`region_colors`] (the same on COLOR_0 of primitives without UVs).
//!
//! [`run`] strings the stages together, each its own function: [`prepare::prepare`] (steps 1-2,
//! §3.1), [`fit::fit`] (steps 3-4, §3.2-3.3), the metrics (step 7), then
//! [`assemble::geometry`] and [`assemble::colors`] (steps 5-6 and 8, §4-5), and the report.
//!
//! Speed (issue 10's aim, README "elastiface" → "Benchmark"): the two surfaces, their BVHs and
//! Laplacians are built in parallel, and the registration's pattern, analysis and the target's
//! solve-frame BVH are built while the fairing runs ([`fit`]'s `fair_and_prepare`); the metrics
//! reuse that BVH. The solves' own shortcuts are described in [`system`], [`register`] and
//! [`originals`]; none changes the algorithm or its results beyond rounding.
//!
//! Known shortfalls (measured by the tests, 2026-12-02; README "elastiface" has the tables): on
//! an open disc with boundary-loop pairs one boundary vertex folds inward; real scans keep some
//! flipped area (a deformed copy of the Lee Perry-Smith scan fitted back onto it: Hausdorff
//! 1.1 % of the diagonal, 0.04 % of the area flipped; the issue asks for 1 % and 0.01 %). The
//! paper's originals stage alone left that case at 6.8 %: the joint fairing collapses the scan's
//! nostril tunnels, so the carried closest points land at their openings; the backward rounds
//! of [`originals`] pull the template into them. Most of what remains lies in cavities behind
//! slits (mouth bag, eye sockets), which [`free`] can leave unfitted (README "elastiface").

pub mod assemble;
pub mod blend;
pub mod boundary;
pub mod boundary_fit;
pub mod fairing;
pub mod fit;
pub mod frame;
pub mod free;
pub mod metrics;
pub mod originals;
pub mod params;
pub mod poisson;
pub mod prepare;
pub mod refs;
pub mod region;
pub mod region_colors;
pub mod region_texture;
pub mod register;
pub mod system;
pub mod texture;
pub mod writeback;

use serde::Serialize;

use super::align::Similarity;
use super::output::{TextureReport, VertexColorReport};
use super::{InputSpec, Method, MethodError, MethodInput, MethodOutput};
use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::asset::edits::{Edit, EditedAsset};
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::spatial::Bvh;

pub use params::{ElastifaceParams, OutputMode};
use prepare::Prepared;

/// Counts of a welded surface.
#[derive(Clone, Debug, Serialize)]
pub struct SurfaceCounts {
    /// Welded vertices.
    pub vertices: usize,
    /// Faces.
    pub faces: usize,
}

/// The joint fairing's figures.
#[derive(Clone, Debug, Serialize)]
pub struct FairingReport {
    /// Solves kept.
    pub iterations: usize,
    /// Total area of the base meshes over that of the inputs.
    pub area_ratio: f64,
    /// Whether the collapse guard stopped the area updates.
    pub collapse_guard: bool,
    /// Whether the fold guard stopped the iterations (the base meshes began to fold).
    pub fold_guard: bool,
    /// Components without reference points, anchored weakly: (source, target).
    pub unanchored_components: (usize, usize),
}

/// The region of a part-based morph (welded template vertices).
#[derive(Clone, Debug, Serialize)]
pub struct RegionReport {
    /// Vertices with a weight above 0.
    pub weighted_vertices: usize,
    /// Vertices with weight 1.
    pub full_vertices: usize,
    /// Vertices with weight 0 (kept as the template's).
    pub fixed_vertices: usize,
}

/// What the method reports.
#[derive(Clone, Debug, Serialize)]
pub struct ElastifaceReport {
    /// The welded source surface.
    pub source_surface: SurfaceCounts,
    /// The welded target surface.
    pub target_surface: SurfaceCounts,
    /// Hand-placed correspondences.
    pub correspondences: usize,
    /// Boundary-loop pairs.
    pub boundary: boundary::BoundaryReport,
    /// The initial similarity (source world → target world).
    pub initial_similarity: Similarity,
    /// Solve units per target world unit.
    pub normalisation_scale: f64,
    /// Correspondence residuals after the similarity alone (relative to the target diagonal).
    pub residuals_initial: metrics::Residuals,
    /// Joint fairing.
    pub fairing: FairingReport,
    /// Registration of the base meshes (`rms_fit` relative to the target diagonal).
    pub registration: register::StageReport,
    /// Registration of the originals (`rms_fit` relative to the target diagonal).
    pub registration_originals: register::StageReport,
    /// Hausdorff distance fitted source ↔ target (relative to the target diagonal).
    pub hausdorff: metrics::Hausdorff,
    /// Flipped triangles of the fitted source.
    pub flipped: metrics::Flipped,
    /// Triangles of the fitted source turned over against the template (after the initial
    /// similarity): folds that `flipped` cannot see.
    pub turned_over: metrics::Flipped,
    /// Correspondence residuals of the fitted source (relative to the target diagonal).
    pub residuals: metrics::Residuals,
    /// With `free_visibility` > 0: the free vertices and the figures of the fitted faces alone
    /// (the figures above cover every face, the free ones included).
    pub fitted_faces: Option<metrics::FittedFaces>,
    /// Output mode.
    pub output: OutputMode,
    /// The morph weight of §5 (`params.blend.weight`), when given. The metrics above are those of
    /// the fitted result (w = 1).
    pub blend_weight: Option<f64>,
    /// The part-based morph's region (`params.blend.region`), when given.
    pub region: Option<RegionReport>,
    /// Baked textures.
    pub textures: Vec<TextureReport>,
    /// Primitives that received COLOR_0 through the shared vertex path.
    pub vertex_colors: Vec<VertexColorReport>,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

/// The `elastiface` method (registry entry).
pub struct Elastiface;

impl Method for Elastiface {
    fn id(&self) -> MethodId {
        MethodId::Elastiface
    }

    fn inputs(&self) -> InputSpec {
        InputSpec::SOURCE_AND_TARGET
    }

    fn params_schema(&self) -> serde_json::Value {
        super::params::schema_of::<ElastifaceParams>()
    }

    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError> {
        ElastifaceParams::from_constraints(constraints)?;
        refs::check_correspondences(constraints)
    }

    /// The solves (growing as `T log T` in the input triangles) plus one baked texture.
    fn working_set(
        &self,
        constraints: &Constraints,
        input_triangles: u64,
    ) -> Option<super::WorkingSet> {
        let texture = super::texture_working_set(constraints);
        let solver = system::solver_working_set_bytes(input_triangles);
        let field = if solver > texture.bytes {
            "inputs"
        } else {
            texture.field
        };
        Some(super::WorkingSet {
            bytes: solver.saturating_add(texture.bytes),
            field,
        })
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let params = ElastifaceParams::from_constraints(input.constraints)?;
        let (edits, report) = run(
            input.source()?,
            input.target,
            input.constraints,
            &params,
            control,
        )?;
        let mut out = MethodOutput::target(edits, &report);
        out.asset = EditedAsset::Source;
        out.warnings = report.warnings;
        Ok(out)
    }
}

/// One call of the method: the inputs and the control every stage reads.
pub struct Call<'a> {
    /// The source asset (the template whose connectivity and UVs are kept).
    pub source: &'a Asset,
    /// The target asset.
    pub target: &'a Asset,
    /// The constraints (correspondences, output options).
    pub constraints: &'a Constraints,
    /// The method's parameters.
    pub params: &'a ElastifaceParams,
    /// Cancel flag and progress.
    pub control: &'a Control,
}

/// Runs `elastiface`: the edits of the source asset and the report.
///
/// Progress: preparation 0-5 % ([`prepare`]), fairing and registration 5-50 % ([`fit`]),
/// metrics 50-55 %, output 55-100 % ([`assemble`]).
///
/// # Errors
/// [`MethodError::Constraints`] for unusable correspondences, [`MethodError::Mesh`],
/// [`MethodError::UnusableInput`] for an instanced source mesh, [`MethodError::Cancelled`].
pub fn run(
    source: &Asset,
    target: &Asset,
    constraints: &Constraints,
    params: &ElastifaceParams,
    control: &Control,
) -> Result<(Vec<Edit>, ElastifaceReport), MethodError> {
    refs::check_correspondences(constraints)?;
    writeback::check_single_instances(source)?;
    let call = Call {
        source,
        target,
        constraints,
        params,
        control,
    };
    let span = control.span(0.0, 0.05);
    let p = prepare::prepare(&call)?;
    drop(span);

    let span = control.span(0.05, 0.5);
    let (lap_s, lap_t) = rayon::join(
        || system::LapRows::of(&p.src),
        || system::LapRows::of(&p.tgt),
    );
    let (lap_s, lap_t) = (lap_s?, lap_t?);
    let fitted = fit::fit(&call, &p, &lap_s, &lap_t)?;
    drop(span);

    let span = control.span(0.5, 0.55);
    let quality = measure(&call, &p, &fitted)?;
    drop(span);

    let _span = control.span(0.55, 1.0);
    let mut warnings: Vec<String> = fit::collapse_warning(&fitted.fairing).into_iter().collect();
    warnings.extend(free::share_warning(&fitted.free, params.free_visibility));
    let (geometry, mut edits) = assemble::geometry(&call, &p, &lap_s, &fitted.fitted)?;
    let colors = assemble::colors(&call, &p, &geometry, &mut edits, &mut warnings)?;
    let report = report(params, &p, fitted, quality, colors, warnings);
    Ok((edits, report))
}

/// The fitted source's quality, in the target's solve frame (relative to the target diagonal).
struct Quality {
    hausdorff: metrics::Hausdorff,
    flipped: metrics::Flipped,
    turned_over: metrics::Flipped,
    residuals: metrics::Residuals,
    fitted_faces: Option<metrics::FittedFaces>,
}

/// The metrics stage: Hausdorff distance, flipped triangles and residuals of the fit.
fn measure(call: &Call<'_>, p: &Prepared, fit: &fit::Fit) -> Result<Quality, MethodError> {
    call.control.stage("metrics", 0)?;
    let ref_diag = call.params.reference_diagonal;
    let fitted32: Vec<[f32; 3]> = fit.fitted.iter().map(|q| q.map(|c| c as f32)).collect();
    let fitted_bvh = Bvh::build(&fitted32, &p.src.faces);
    let fitted_mesh = metrics::MeshRef {
        x: &fit.fitted,
        faces: &p.src.faces,
        bvh: &fitted_bvh,
    };
    let target_mesh = metrics::MeshRef {
        x: &p.xt,
        faces: &p.tgt.faces,
        bvh: &fit.target_bvh,
    };
    Ok(Quality {
        hausdorff: metrics::hausdorff(&fitted_mesh, &target_mesh, ref_diag),
        flipped: metrics::flipped(&fitted_mesh, &target_mesh),
        turned_over: metrics::turned_over(&fitted_mesh, &p.xs),
        residuals: metrics::residuals(&p.hand, &fit.fitted, &p.xt, ref_diag),
        fitted_faces: (!fit.free.is_empty())
            .then(|| metrics::fitted_faces(&fitted_mesh, &target_mesh, &fit.free, ref_diag)),
    })
}

/// The report of a finished run.
fn report(
    params: &ElastifaceParams,
    p: &Prepared,
    fit: fit::Fit,
    quality: Quality,
    colors: assemble::Colors,
    warnings: Vec<String>,
) -> ElastifaceReport {
    ElastifaceReport {
        source_surface: SurfaceCounts {
            vertices: p.src.vertex_count(),
            faces: p.src.face_count(),
        },
        target_surface: SurfaceCounts {
            vertices: p.tgt.vertex_count(),
            faces: p.tgt.face_count(),
        },
        correspondences: p.hand.len(),
        boundary: p.boundary.clone(),
        initial_similarity: p.frame.similarity,
        normalisation_scale: p.frame.scale,
        residuals_initial: p.residuals_initial,
        fairing: fit.fairing,
        registration: fit.registration,
        registration_originals: fit.registration_originals,
        hausdorff: quality.hausdorff,
        flipped: quality.flipped,
        turned_over: quality.turned_over,
        residuals: quality.residuals,
        fitted_faces: quality.fitted_faces,
        output: params.output,
        blend_weight: params.blend.as_ref().map(|b| b.weight),
        region: p.region_weights.as_ref().map(|r| RegionReport {
            weighted_vertices: r.iter().filter(|&&x| x > 0.0).count(),
            full_vertices: r.iter().filter(|&&x| x >= 1.0).count(),
            fixed_vertices: r.iter().filter(|&&x| x <= 0.0).count(),
        }),
        textures: colors.textures,
        vertex_colors: colors.vertex_colors,
        warnings,
    }
}
