//! The `detail` pipeline from surfaces to a displacement on the target (Berkiten et al. 2017,
//! §3, Fig. 3): base → hierarchy → source displacement per level → geometric features → metric
//! → synthesis. Pure and synchronous; the method ([`super::method`]) reads the assets and writes
//! the outputs.
//!
//! 1. **Base** (§3, Fig. 4): the given smooth base, or the detailed source smoothed
//!    ([`super::displacement::smooth_base`]).
//! 2. **Hierarchy** (§3.1): the base and the target remeshed at shared absolute edge lengths,
//!    halving per level ([`super::hierarchy::build_pair`]).
//! 3. **Source displacement** per level: the signed distance along each level vertex's base
//!    normal to the detailed surface ([`super::displacement::displacement`]), or, for a source
//!    whose detail is a texture, the texture at the closest source point
//!    ([`transfer_detail_with`], [`super::source_texture`]).
//! 4. **Geometric features** (§3.2.2), z-scored per shape; a column constant on either shape
//!    (std below [`super::metric::RELATIVE_STD_FLOOR`] of its mean) is set to 0 on both, since
//!    it would draw every vertex of the one shape to the other's mean. *Computed once* on the *feature level*
//!    (the finest level whose source and target both have at most `feature_vertices` vertices,
//!    default 20,000; the coarsest when none does) and carried to every other level by
//!    closest-point barycentric interpolation. The paper computes them per mesh and does not say
//!    per level; the spectral, SDF and geodesic features vary at the scale of the shape, far
//!    coarser than a level's edge, and computing them on a 50k-vertex level costs 20-30 s per
//!    shape (README "detail", timing), which would break the benchmark's aim on its own.
//! 5. **Metric** (§3.2.3): learned on up to `metric_samples` (default 4,000) farthest-point
//!    samples of the finest source level: their 17-D detail features (§3.2.1) from the finest
//!    displacement and their geometric features; vertices closer to a mesh border than a detail
//!    patch's reach are left out when that keeps at least half of them (past a border the patch
//!    fill makes detail features that follow the border distance; README, features → metric).
//!    `M = AᵀA`; `identity` is the equal-weights baseline.
//! 6. **Synthesis** (§3.3.1) over all levels with the transformed features `A g`.

use std::time::Instant;

use faer::Mat;
use serde::Serialize;

use super::displacement::{displacement, smooth_base, BaseParams, DisplacementParams};
use super::geometric_features::{geometric_features_pair, GeometricParams, DIM, GROUPS};
use super::hierarchy::{build_pair, mean_edge_length, HierarchyParams};
use super::metric::{
    factor_above, metric_of_kind, residue_floor, top_eigenvector, transform, MetricKind,
    MetricParams, MetricProblem, ZScore,
};
use super::patches::{detail_features_at, PatchParams};
use super::steerable::FEATURES;
use super::sweep::farthest_point_samples;
use super::synthesis::{
    interpolate_rows, synthesize, LevelStats, SourceLevel, SynthesisParams, TargetLevel,
};
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::{topology, Surface};

/// Settings of [`transfer_detail`].
#[derive(Clone, Debug)]
pub struct PipelineParams {
    /// The derived base, when none is given.
    pub base: BaseParams,
    /// The hierarchy.
    pub hierarchy: HierarchyParams,
    /// The displacement search.
    pub displacement: DisplacementParams,
    /// The geometric features.
    pub geometric: GeometricParams,
    /// The detail-feature patches.
    pub patches: PatchParams,
    /// Learned or identity.
    pub metric_kind: MetricKind,
    /// The metric solver.
    pub metric: MetricParams,
    /// Samples of the finest source level the metric is learned on.
    pub metric_samples: usize,
    /// Vertex limit of the level the geometric features are computed on.
    pub feature_vertices: usize,
    /// λ relative to the largest diagonal entry of `B̂` ([`MetricProblem::relative`]).
    pub lambda_relative: bool,
    /// The synthesis.
    pub synthesis: SynthesisParams,
}

impl Default for PipelineParams {
    fn default() -> Self {
        Self {
            base: BaseParams::default(),
            hierarchy: HierarchyParams::default(),
            displacement: DisplacementParams::default(),
            geometric: GeometricParams::default(),
            patches: PatchParams::default(),
            metric_kind: MetricKind::Learned,
            metric: MetricParams::default(),
            metric_samples: 4000,
            feature_vertices: 20_000,
            lambda_relative: true,
            synthesis: SynthesisParams::default(),
        }
    }
}

/// Errors of [`transfer_detail`]: the failing step and what it said.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A step failed (`base`, `hierarchy`, `displacement`, `features`, `metric`, `synthesis`).
    #[error("{step}: {message}")]
    Step {
        /// The step.
        step: &'static str,
        /// Its error.
        message: String,
    },
    /// Cancelled through the control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for PipelineError {
    fn from(_: Cancelled) -> Self {
        PipelineError::Cancelled
    }
}

fn step<'a, E: std::fmt::Display>(
    step: &'static str,
    control: &'a Control,
) -> impl Fn(E) -> PipelineError + 'a {
    move |e| {
        if control.is_cancelled() {
            PipelineError::Cancelled
        } else {
            PipelineError::Step {
                step,
                message: e.to_string(),
            }
        }
    }
}

/// One level pair of the hierarchy.
#[derive(Clone, Debug, Serialize)]
pub struct LevelReport {
    /// Target edge length (world units).
    pub edge_length: f64,
    /// Source (base) vertices and faces.
    pub source_vertices: usize,
    /// Source faces.
    pub source_faces: usize,
    /// Target vertices.
    pub target_vertices: usize,
    /// Target faces.
    pub target_faces: usize,
    /// Source vertices whose ray found no detailed surface within the search distance (0 there).
    pub displacement_missing: usize,
}

/// The metric as learned (or the identity).
#[derive(Clone, Debug, Serialize)]
pub struct MetricReport {
    /// `learned` or `identity`.
    pub kind: MetricKind,
    /// `M`, 60 × 60, row by row (feature order of [`GROUPS`]).
    pub m: Vec<Vec<f64>>,
    /// Rank of the factor `A`: eigenvalues of `M` above `residue_floor`.
    pub rank: usize,
    /// Eigenvalues at or below this are the solver's residue and left out of `A` (0 for the
    /// identity; `metric::residue_floor`).
    pub residue_floor: f64,
    /// Largest eigenvalue of `M`.
    pub top_eigenvalue: f64,
    /// Squared entries of the top eigenvector summed per feature group (they sum to 1).
    pub top_eigenvector_by_group: Vec<(String, f64)>,
    /// Diagonal of `M` summed per group, divided by the trace.
    pub diagonal_by_group: Vec<(String, f64)>,
    /// ADMM iterations.
    pub iterations: usize,
    /// Whether the stopping rule was met.
    pub converged: bool,
    /// Final primal residual.
    pub primal_residual: f64,
    /// Final dual residual.
    pub dual_residual: f64,
    /// Objective value.
    pub objective: f64,
    /// Samples the metric was learned on.
    pub samples: usize,
    /// The learned `M` is zero up to the solver's residue (λ too large for how strongly the
    /// geometry predicts the detail, see `lambda_relative`).
    pub zero_metric: bool,
}

/// Seconds per step.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PipelineTimings {
    /// Base derivation.
    pub base: f64,
    /// Both hierarchies.
    pub hierarchy: f64,
    /// Source displacement on every level.
    pub displacement: f64,
    /// Geometric features and their interpolation.
    pub geometric_features: f64,
    /// Detail features of the samples and the metric.
    pub metric: f64,
    /// Synthesis.
    pub synthesis: f64,
}

/// What the pipeline reports.
#[derive(Clone, Debug, Serialize)]
pub struct PipelineReport {
    /// Whether the base was given (`source_base`, or a source with a displacement texture) or
    /// derived.
    pub base_given: bool,
    /// Per level, coarsest first.
    pub levels: Vec<LevelReport>,
    /// Level the geometric features were computed on (0 coarsest).
    pub feature_level: usize,
    /// The metric.
    pub metric: MetricReport,
    /// Per-level synthesis statistics.
    pub synthesis: Vec<LevelStats>,
    /// Source displacement range over all levels (world units).
    pub source_range: [f64; 2],
    /// Synthesised displacement range on the finest target level.
    pub target_range: [f64; 2],
    /// Seconds per step.
    pub seconds: PipelineTimings,
}

/// The result: the finest target level and its displacement.
#[derive(Clone, Debug)]
pub struct DetailTransfer {
    /// The finest target level (world space).
    pub surface: Surface,
    /// Displacement per vertex of `surface` along its area-weighted normal (world units).
    pub displacement: Vec<f64>,
    /// The finest source level.
    pub source_surface: Surface,
    /// The source displacement per vertex of `source_surface`.
    pub source_displacement: Vec<f64>,
    /// Per vertex of `surface`, the point of `source_surface` its value came from
    /// ([`super::synthesis::Synthesis::finest_source_points`]).
    pub source_points: Vec<Option<[f64; 3]>>,
    /// What happened.
    pub report: PipelineReport,
}

fn group_mass(v: impl Fn(usize) -> f64) -> Vec<(String, f64)> {
    let total: f64 = (0..DIM).map(&v).sum();
    GROUPS
        .iter()
        .map(|(name, r)| {
            let m: f64 = r.clone().map(&v).sum();
            (name.to_string(), if total > 0.0 { m / total } else { 0.0 })
        })
        .collect()
}

/// Vertices of `surface` farther (along edges) than `reach` from every border vertex; all of them
/// on a closed surface.
fn interior_vertices(surface: &Surface, reach: f64) -> Vec<bool> {
    let seeds: Vec<usize> = topology::topology(surface)
        .boundary_loops
        .iter()
        .flatten()
        .map(|&v| v as usize)
        .collect();
    if seeds.is_empty() {
        return vec![true; surface.vertex_count()];
    }
    let dist = super::sweep::edge_distances(surface, &seeds);
    dist.iter().map(|&d| d > reach).collect()
}

/// A learned `M` whose largest entry is at most this fraction of `B̂`'s largest is zero up to
/// the solver's residue (`M` scales as `B̂` over `Ĉ²`, and `Ĉ` is O(1) for z-scored features).
/// The report says so (`zero_metric`), and also whenever λ ≥ 2 max|B̂|: the objective's gradient
/// at `M = 0` is `−2B̂`, so `M = 0` then satisfies the optimality condition whatever the solver
/// returned (the residue it returns can exceed this fraction: 6.6e-14 on bumps of 0.02). The
/// synthesis then follows the residue's factor. Ours.
const ZERO_METRIC: f64 = 1e-9;

/// Learns (or sets) the metric on samples of the finest source level. With
/// `params.lambda_relative` the problem is normalised so that λ is relative to the strongest
/// feature-detail covariance ([`MetricProblem::relative`]).
fn learn(
    finest: &Surface,
    disp: &[f64],
    features: &[f64],
    params: &PipelineParams,
    control: &Control,
) -> Result<(Mat<f64>, MetricReport), PipelineError> {
    let mut samples = farthest_point_samples(finest, params.metric_samples.max(2));
    let h = params.patches.half_width as f64 * mean_edge_length(finest);
    let inside = interior_vertices(finest, h * std::f64::consts::SQRT_2);
    let kept: Vec<usize> = samples.iter().copied().filter(|&v| inside[v]).collect();
    if 2 * kept.len() >= samples.len() {
        samples = kept;
    }
    let detail = detail_features_at(finest, disp, &samples, &params.patches, control)
        .map_err(step("metric", control))?;
    let geo: Vec<f64> = samples
        .iter()
        .flat_map(|&v| features[v * DIM..(v + 1) * DIM].iter().copied())
        .collect();
    let problem = MetricProblem::from_features(&geo, DIM, &detail, FEATURES)
        .map_err(step("metric", control))?;
    let problem = match params.lambda_relative {
        true => problem.relative(),
        false => problem,
    };
    control.check()?;
    let learned = metric_of_kind(params.metric_kind, &problem, &params.metric)
        .map_err(step("metric", control))?;
    let b_max = problem.b.norm_max();
    let zero = params.metric_kind == MetricKind::Learned
        && (params.metric.lambda >= 2.0 * b_max || learned.m.norm_max() <= ZERO_METRIC * b_max);
    let floor = match params.metric_kind {
        MetricKind::Learned => residue_floor(&learned, &params.metric),
        MetricKind::Identity => 0.0,
    };
    let a = factor_above(&learned.m, floor).map_err(step("metric", control))?;
    let (top_value, top) = top_eigenvector(&learned.m).map_err(step("metric", control))?;
    let report = MetricReport {
        kind: params.metric_kind,
        m: (0..DIM)
            .map(|i| (0..DIM).map(|j| learned.m[(i, j)]).collect())
            .collect(),
        rank: a.nrows(),
        residue_floor: floor,
        top_eigenvalue: top_value,
        top_eigenvector_by_group: group_mass(|j| top[j] * top[j]),
        diagonal_by_group: group_mass(|j| learned.m[(j, j)]),
        iterations: learned.iterations,
        converged: learned.converged,
        primal_residual: learned.primal_residual,
        dual_residual: learned.dual_residual,
        objective: learned.objective,
        samples: samples.len(),
        zero_metric: zero,
    };
    Ok((a, report))
}

fn range(values: impl Iterator<Item = f64>) -> [f64; 2] {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    });
    if lo <= hi {
        [lo, hi]
    } else {
        [0.0, 0.0]
    }
}

/// Runs the pipeline (see the module doc). `base` is the given smooth base of `detailed`, if any.
///
/// # Errors
/// [`PipelineError::Step`] naming the failing step, or [`PipelineError::Cancelled`].
pub fn transfer_detail(
    detailed: &Surface,
    base: Option<&Surface>,
    target: &Surface,
    params: &PipelineParams,
    control: &Control,
) -> Result<DetailTransfer, PipelineError> {
    let clock = Instant::now();
    let span = control.span(0.0, 0.05);
    let derived;
    let base_given = base.is_some();
    let base = match base {
        Some(b) => b,
        None => {
            control.stage("detail: base", 0)?;
            derived = smooth_base(detailed, &params.base).map_err(step("base", control))?;
            &derived
        }
    };
    let base_seconds = clock.elapsed().as_secs_f64();
    drop(span);
    let rays = |level: &Surface| -> Result<(Vec<f64>, usize), PipelineError> {
        let d = displacement(level, detailed, &params.displacement)
            .map_err(step("displacement", control))?;
        Ok((d.values, d.missing))
    };
    let mut out = transfer_detail_with(base, &rays, target, params, control)?;
    out.report.base_given = base_given;
    out.report.seconds.base = base_seconds;
    Ok(out)
}

/// The source displacement at a level's vertices: (values, vertices without one).
pub type LevelDisplacement<'a> =
    dyn Fn(&Surface) -> Result<(Vec<f64>, usize), PipelineError> + Sync + 'a;

/// The pipeline from a base whose displacement at a level's vertices `displacement` gives
/// (values, vertices without one): a source whose detail is a texture
/// ([`super::source_texture`]).
///
/// # Errors
/// As [`transfer_detail`].
pub fn transfer_detail_with(
    base: &Surface,
    displacement: &LevelDisplacement<'_>,
    target: &Surface,
    params: &PipelineParams,
    control: &Control,
) -> Result<DetailTransfer, PipelineError> {
    let base_given = true;
    let mut seconds = PipelineTimings::default();
    let mut clock = Instant::now();
    let mut lap = || {
        let now = Instant::now();
        let dt = (now - clock).as_secs_f64();
        clock = now;
        dt
    };
    let span = control.span(0.05, 0.3);
    let (src, tgt) =
        build_pair(base, target, &params.hierarchy, control).map_err(step("hierarchy", control))?;
    seconds.hierarchy = lap();
    drop(span);
    let span = control.span(0.3, 0.35);
    control.stage("detail: displacement", 0)?;
    let mut disp = Vec::new();
    let mut levels = Vec::new();
    for (s, t) in src.iter().zip(&tgt) {
        let (values, missing) = displacement(&s.surface)?;
        levels.push(LevelReport {
            edge_length: s.edge_length,
            source_vertices: s.surface.vertex_count(),
            source_faces: s.surface.face_count(),
            target_vertices: t.surface.vertex_count(),
            target_faces: t.surface.face_count(),
            displacement_missing: missing,
        });
        disp.push(values);
    }
    seconds.displacement = lap();
    drop(span);
    let span = control.span(0.35, 0.55);
    let count = src.len();
    let feature_level = (0..count)
        .rev()
        .find(|&l| {
            src[l]
                .surface
                .vertex_count()
                .max(tgt[l].surface.vertex_count())
                <= params.feature_vertices
        })
        .unwrap_or(0);
    let (gs, gt) = geometric_features_pair(
        &src[feature_level].surface,
        &tgt[feature_level].surface,
        &params.geometric,
        control,
    )
    .map_err(step("features", control))?;
    let (mut fit_s, mut fit_t) = (ZScore::fit(&gs.values, DIM), ZScore::fit(&gt.values, DIM));
    // A feature constant on one shape (z-scored to 0 there) would pull every vertex of that
    // shape to the other shape's mean of it: dropped on both.
    for j in 0..DIM {
        if fit_s.inv_std[j] == 0.0 || fit_t.inv_std[j] == 0.0 {
            fit_s.inv_std[j] = 0.0;
            fit_t.inv_std[j] = 0.0;
        }
    }
    let (zs, zt) = (fit_s.apply(&gs.values), fit_t.apply(&gt.values));
    let carry = |levels: &[super::hierarchy::Level], z: &[f64]| -> Vec<Vec<f64>> {
        (0..count)
            .map(|l| match l == feature_level {
                true => z.to_vec(),
                false => {
                    interpolate_rows(&levels[feature_level].surface, z, DIM, &levels[l].surface)
                }
            })
            .collect()
    };
    let (fs, ft) = (carry(&src, &zs), carry(&tgt, &zt));
    control.check()?;
    seconds.geometric_features = lap();
    drop(span);
    let span = control.span(0.55, 0.6);
    let finest = count - 1;
    let (a, metric) = learn(
        &src[finest].surface,
        &disp[finest],
        &fs[finest],
        params,
        control,
    )?;
    seconds.metric = lap();
    drop(span);
    let _span = control.span(0.6, 1.0);
    let r = a.nrows();
    let tf: Vec<(Vec<f64>, Vec<f64>)> = (0..count)
        .map(|l| (transform(&a, &fs[l]), transform(&a, &ft[l])))
        .collect();
    let sl: Vec<SourceLevel> = (0..count)
        .map(|l| SourceLevel {
            surface: &src[l].surface,
            displacement: &disp[l],
            features: &tf[l].0,
        })
        .collect();
    let tl: Vec<TargetLevel> = (0..count)
        .map(|l| TargetLevel {
            surface: &tgt[l].surface,
            features: &tf[l].1,
        })
        .collect();
    let mut out =
        synthesize(&sl, &tl, r, &params.synthesis, control).map_err(step("synthesis", control))?;
    seconds.synthesis = lap();
    let displacement = out.displacement.pop().unwrap_or_default();
    let report = PipelineReport {
        base_given,
        levels,
        feature_level,
        metric,
        synthesis: out.levels,
        source_range: range(disp.iter().flatten().copied()),
        target_range: range(displacement.iter().copied()),
        seconds,
    };
    let no_levels = || PipelineError::Step {
        step: "hierarchy",
        message: "no levels".into(),
    };
    let surface = tgt.into_iter().next_back().ok_or_else(no_levels)?.surface;
    let source_surface = src.into_iter().next_back().ok_or_else(no_levels)?.surface;
    Ok(DetailTransfer {
        surface,
        displacement,
        source_surface,
        source_displacement: disp.pop().unwrap_or_default(),
        source_points: out.finest_source_points,
        report,
    })
}
