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
//!    closest-point rounds with backward pairs (a deviation, see there);
//! 5. [`texture`]: texture matching (§4) through the shared texel loop;
//! 6. [`writeback`]: POSITION / NORMAL through the source's node transforms, or a morph target;
//!    [`tangents`]: TANGENT recomputed with MikkTSpace;
//! 7. [`metrics`]: Hausdorff distance, flipped triangles and residuals for the report;
//! 8. [`blend`]: the linear morph of §5 (`params.blend.weight`) between the template and the
//!    fitted result, positions and texture; with `params.blend.region` the part-based morph of
//!    §5: [`region`] (the per-vertex weights), [`poisson`] (Laplacian blend of the positions,
//!    Alexa 2003 with cotan weights), [`region_texture`] (gradient-domain texture blend, Pérez
//!    et al. 2003) and [`region_colors`] (the same on COLOR_0 of primitives without UVs).
//!
//! Speed (issue 10's aim, README "elastiface" → "Benchmark"): the two surfaces, their BVHs and
//! Laplacians are built in parallel, and the registration's pattern, analysis and the target's
//! solve-frame BVH are built while the fairing runs (`fair_and_prepare`); the metrics reuse
//! that BVH. The solves' own shortcuts are described in [`system`], [`register`] and
//! [`originals`]; none changes the algorithm or its results beyond rounding.
//!
//! Known shortfalls (measured by the tests, 2026-12-02; README "elastiface" has the tables): on
//! an open disc with boundary-loop pairs one boundary vertex folds inward; real scans keep some
//! flipped area (a deformed copy of the Lee Perry-Smith scan fitted back onto it: Hausdorff
//! 1.1 % of the diagonal, 0.04 % of the area flipped; the issue asks for 1 % and 0.01 %). The
//! paper's originals stage alone left that case at 6.8 %: the joint fairing collapses the scan's
//! nostril tunnels, so the carried closest points land at their openings; the backward rounds
//! of [`originals`] pull the template into them.

pub mod blend;
pub mod boundary;
pub mod fairing;
pub mod frame;
pub mod metrics;
pub mod originals;
pub mod params;
pub mod poisson;
pub mod refs;
pub mod region;
pub mod region_colors;
pub mod region_texture;
pub mod register;
pub mod system;
pub mod tangents;
pub mod texture;
pub mod writeback;

use serde::Serialize;

use super::align::{best_similarity, Similarity};
use super::correspondence::resolve_on_surfaces;
use super::output::{TextureReport, VertexColorReport};
use super::{InputSpec, Method, MethodError, MethodInput, MethodOutput};
use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::asset::edits::{Edit, EditedAsset};
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::mesh::{build_surface, Surface, WeldParams};
use crate::engine::spatial::Bvh;
use crate::engine::texture::sample::MaterialSampler;

pub use params::{ElastifaceParams, OutputMode};

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
    /// Correspondence residuals of the fitted source (relative to the target diagonal).
    pub residuals: metrics::Residuals,
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

fn surface_of(
    asset: &Asset,
    weld: &WeldParams,
    side: &'static str,
) -> Result<Surface, MethodError> {
    build_surface(asset, weld).map_err(|source| MethodError::Mesh { side, source })
}

fn f64s(p: &[[f32; 3]]) -> Vec<[f64; 3]> {
    p.iter().map(|q| q.map(f64::from)).collect()
}

/// Runs `elastiface`: the edits of the source asset and the report.
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
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    let span = control.span(0.0, 0.05);
    control.stage("surface", 0)?;
    let surface_and_bvh = |asset, side| {
        surface_of(asset, &weld, side).map(|s| {
            let bvh = Bvh::build(&s.positions, &s.faces);
            (s, bvh)
        })
    };
    let (src, tgt) = rayon::join(
        || surface_and_bvh(source, "source"),
        || surface_and_bvh(target, "target"),
    );
    let ((src, src_bvh), (tgt, tgt_bvh)) = (src?, tgt?);

    let welded = writeback::welded_map(source, &src);
    let region_weights = match params.region_blend() {
        Some((b, r)) => Some(region::vertex_weights(
            source,
            &welded,
            src.vertex_count(),
            r,
            b.feather_rings,
        )?),
        None => None,
    };

    control.stage("correspondences", 0)?;
    let resolved = resolve_on_surfaces(
        &constraints.correspondences,
        (source, &src_bvh, &src),
        (target, &tgt_bvh, &tgt),
        params.snap_tolerance,
    )?;
    let src_world = f64s(&src.positions);
    let tgt_world = f64s(&tgt.positions);
    let hand = refs::hand_pairs(&resolved, &src.faces, &tgt.faces);
    let from: Vec<[f64; 3]> = hand.iter().map(|p| p.source.eval(&src_world)).collect();
    let to: Vec<[f64; 3]> = hand.iter().map(|p| p.target.eval(&tgt_world)).collect();
    refs::check_not_collinear(&from, "source")?;
    refs::check_not_collinear(&to, "target")?;
    let similarity = best_similarity(&from, &to);
    let (lo, hi) = tgt.bounding_box();
    let frame = frame::Frame::new(
        similarity,
        lo.map(f64::from),
        hi.map(f64::from),
        params.reference_diagonal,
    );
    let xs: Vec<[f64; 3]> = src_world
        .iter()
        .map(|p| frame.source_to_solve(*p))
        .collect();
    let xt: Vec<[f64; 3]> = tgt_world
        .iter()
        .map(|p| frame.target_to_solve(*p))
        .collect();
    let ref_diag = params.reference_diagonal;
    let src_diag = bbox_diagonal(&xs);
    let (derived, boundary_report) = boundary::derive_boundary_pairs(
        &boundary::LoopSide {
            x: &xs,
            faces: &src.faces,
            diagonal: src_diag,
        },
        &boundary::LoopSide {
            x: &xt,
            faces: &tgt.faces,
            diagonal: ref_diag,
        },
        &hand,
    )?;
    let mut pairs = hand.clone();
    pairs.extend(derived);
    let residuals_initial = metrics::residuals(&hand, &xs, &xt, ref_diag);
    drop(span);

    let span = control.span(0.05, 0.5);
    let (lap_s, lap_t) = rayon::join(|| system::LapRows::of(&src), || system::LapRows::of(&tgt));
    let (lap_s, lap_t) = (lap_s?, lap_t?);
    let (faired, reg, xt_bvh, paper_start) = fair_and_prepare(
        (&xs, &src, &lap_s),
        (&xt, &tgt, &lap_t),
        &pairs,
        params,
        control,
    )?;
    let mut warnings = Vec::new();
    if faired.collapse_guard {
        warnings.push(format!(
            "the joint fairing shrank the meshes to {:.0}% of their area; the area updates were stopped",
            100.0 * faired.area_ratio
        ));
    }

    let bt32: Vec<[f32; 3]> = faired.target.iter().map(|p| p.map(|c| c as f32)).collect();
    let bt_bvh = Bvh::build(&bt32, &tgt.faces);
    let base_target = register::FitTarget {
        x: &faired.target,
        faces: &tgt.faces,
        bvh: &bt_bvh,
    };
    let (_, carried, mut base_report) = reg.base(
        &faired.source,
        &base_target,
        params.registration_iterations,
        control,
    )?;
    let orig_target = register::FitTarget {
        x: &xt,
        faces: &tgt.faces,
        bvh: &xt_bvh,
    };
    let (fitted, mut orig_report) = reg.originals_from(
        paper_start,
        &xs,
        &orig_target,
        &carried,
        originals::Rounds {
            levels: params.original_stiffness_levels,
            per_level: params.original_iterations,
            backward_weight: params.backward_weight,
            max_distance: params.backward_max_distance * ref_diag,
            min_cos: params.backward_min_cos,
        },
        control,
    )?;
    base_report.rms_fit /= ref_diag;
    orig_report.rms_fit /= ref_diag;
    drop(span);

    let span = control.span(0.5, 0.55);
    control.stage("metrics", 0)?;
    let fitted32: Vec<[f32; 3]> = fitted.iter().map(|p| p.map(|c| c as f32)).collect();
    let fitted_bvh = Bvh::build(&fitted32, &src.faces);
    let fitted_mesh = metrics::MeshRef {
        x: &fitted,
        faces: &src.faces,
        bvh: &fitted_bvh,
    };
    let target_mesh = metrics::MeshRef {
        x: &xt,
        faces: &tgt.faces,
        bvh: &xt_bvh,
    };
    let hausdorff = metrics::hausdorff(&fitted_mesh, &target_mesh, ref_diag);
    let flipped = metrics::flipped(&fitted_mesh, &target_mesh);
    let residuals = metrics::residuals(&hand, &fitted, &xt, ref_diag);
    drop(span);

    let _span = control.span(0.55, 1.0);
    let world: Vec<[f64; 3]> = fitted.iter().map(|p| frame.solve_to_target(*p)).collect();
    let morph = params.output == OutputMode::MorphTarget;
    let blend_weight = params.blend_weight();
    let region_solve = match &region_weights {
        Some(r) => {
            control.stage("region_geometry", 0)?;
            let areas = system::voronoi_areas(&src_world, &src.faces)?;
            let w = params.blend.as_ref().map_or(1.0, |b| b.weight);
            let omega: Vec<f64> = r.iter().map(|x| w * x).collect();
            Some((
                poisson::MeshPoisson::new(&lap_s, &src.faces, r, areas)?,
                omega,
            ))
        }
        None => None,
    };
    let placed = match (&region_solve, &region_weights) {
        (Some((solver, omega)), Some(r)) => {
            // In the template's placement; a morph target holds the w = 1 blend (the solution
            // is affine in w) and glTF applies w.
            let back: Vec<[f64; 3]> = world.iter().map(|q| frame.target_to_source(*q)).collect();
            let full: Vec<f64>;
            let om = if morph {
                full = r.clone();
                &full
            } else {
                omega
            };
            let x = solver.blend(&coords(&src_world), &coords(&back), om)?;
            (0..src_world.len())
                .map(|v| [x[0][v], x[1][v], x[2][v]])
                .collect()
        }
        _ => match blend_weight {
            Some(w) if !morph => blend::blend_positions(&src_world, &world, w),
            _ => world.clone(),
        },
    };
    let same = |q: [f64; 3]| q;
    let back = |q: [f64; 3]| frame.target_to_source(q);
    let to_source: &dyn Fn([f64; 3]) -> [f64; 3] =
        if region_solve.is_some() { &same } else { &back };
    let follow = |p: [f64; 3]| match src_bvh.closest_point(p.map(|c| c as f32), f32::INFINITY) {
        Some(h) => refs::RefRow::face(src.faces[h.face as usize], h.bary).eval(&placed),
        None => frame.similarity.apply(p),
    };
    let mut edits = writeback::geometry_edits(
        source,
        &writeback::Placement {
            fitted: &placed,
            faces: &src.faces,
            welded: &welded,
            to_source_frame: to_source,
            follow_surface: &follow,
            morph,
            morph_weight: params.blend.as_ref().map_or(0.0, |b| b.weight as f32),
        },
    )?;
    let mut textures = Vec::new();
    let mut vertex_colors = Vec::new();
    if texture::target_has_color(target) {
        let world32: Vec<[f32; 3]> = world.iter().map(|p| p.map(|c| c as f32)).collect();
        let field = texture::RelaidColor {
            source,
            welded: &welded,
            fitted: &world32,
            target,
            target_surface: &tgt,
            target_bvh: &tgt_bvh,
            sampler: MaterialSampler::new(target),
            blend: blend_weight.map(|w| blend::TemplateColor::new(source, w)),
        };
        if let (Some((solver, omega)), Some(r)) = (&region_solve, &region_weights) {
            let all = constraints.output.all_vertex_colors();
            if !all {
                let rt = region_texture::RegionTexture {
                    relaid: &field,
                    template: MaterialSampler::new(source),
                    weights: r,
                    w: params.blend.as_ref().map_or(1.0, |b| b.weight),
                    max_texels: params.blend.as_ref().map_or(1, |b| b.max_region_texels),
                };
                let (tex_edits, reports) =
                    region_texture::region_textures(&rt, constraints, control)?;
                edits.extend(tex_edits);
                textures = reports;
            }
            edits.extend(region_colors::region_vertex_colors(
                &field, solver, omega, all, control,
            )?);
        } else {
            let (tex_edits, out) = texture::relay_texture(&field, constraints, control)?;
            edits.extend(tex_edits);
            textures = out.textures;
            vertex_colors = out.vertex_colors;
            warnings.extend(out.warnings);
        }
    } else {
        warnings.push(
            "the target has no base color texture and no COLOR_0: the source keeps its own texture"
                .into(),
        );
    }

    let report = ElastifaceReport {
        source_surface: SurfaceCounts {
            vertices: src.vertex_count(),
            faces: src.face_count(),
        },
        target_surface: SurfaceCounts {
            vertices: tgt.vertex_count(),
            faces: tgt.face_count(),
        },
        correspondences: hand.len(),
        boundary: boundary_report,
        initial_similarity: similarity,
        normalisation_scale: frame.scale,
        residuals_initial,
        fairing: FairingReport {
            iterations: faired.iterations,
            area_ratio: faired.area_ratio,
            collapse_guard: faired.collapse_guard,
            unanchored_components: faired.unanchored_components,
        },
        registration: base_report,
        registration_originals: orig_report,
        hausdorff,
        flipped,
        residuals,
        output: params.output,
        blend_weight: params.blend.as_ref().map(|b| b.weight),
        region: region_weights.as_ref().map(|r| RegionReport {
            weighted_vertices: r.iter().filter(|&&x| x > 0.0).count(),
            full_vertices: r.iter().filter(|&&x| x >= 1.0).count(),
            fixed_vertices: r.iter().filter(|&&x| x <= 0.0).count(),
        }),
        textures,
        vertex_colors,
        warnings: warnings.clone(),
    };
    Ok((edits, report))
}

/// What the stages after the fairing start from.
type Prepared<'a> = (
    fairing::Faired,
    register::Registration<'a>,
    Bvh,
    originals::PaperStart,
);

/// The joint fairing (§3.2) of the aligned source and target (positions, surface, Laplacian),
/// overlapped with what does not depend on it: the registration's pattern and analysis, the
/// original target's hierarchy and the paper's solve of the originals (factor and fixed
/// right-hand side) are prepared on the other core meanwhile.
fn fair_and_prepare<'a>(
    src: (&[[f64; 3]], &'a Surface, &'a system::LapRows),
    tgt: (&[[f64; 3]], &Surface, &system::LapRows),
    pairs: &'a [refs::RefPair],
    params: &ElastifaceParams,
    control: &Control,
) -> Result<Prepared<'a>, MethodError> {
    let (faired, prepared) = rayon::join(
        || {
            fairing::joint_fairing(
                &fairing::FairMesh {
                    x: src.0,
                    faces: &src.1.faces,
                    lap: src.2,
                },
                &fairing::FairMesh {
                    x: tgt.0,
                    faces: &tgt.1.faces,
                    lap: tgt.2,
                },
                pairs,
                fairing::FairingWeights {
                    lambda: [
                        params.lambda_smooth,
                        params.lambda_coincide,
                        params.lambda_position,
                    ],
                    iterations: params.fairing_iterations,
                },
                control,
            )
        },
        || {
            let x32: Vec<[f32; 3]> = tgt.0.iter().map(|p| p.map(|c| c as f32)).collect();
            let bvh = Bvh::build(&x32, &tgt.1.faces);
            let reg = register::Registration::new(src.2, &src.1.faces, pairs)?;
            let start = reg.paper_start(src.0, tgt.0)?;
            Ok::<_, MethodError>((reg, bvh, start))
        },
    );
    let faired = faired?;
    let (reg, bvh, start) = prepared?;
    Ok((faired, reg, bvh, start))
}

/// Positions as three coordinate vectors.
fn coords(x: &[[f64; 3]]) -> Vec<Vec<f64>> {
    (0..3).map(|k| x.iter().map(|p| p[k]).collect()).collect()
}

fn bbox_diagonal(x: &[[f64; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}
