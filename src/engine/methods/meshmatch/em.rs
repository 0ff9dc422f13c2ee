//! [`synthesize`]: the MeshMatch optimization, a coarse-to-fine EM on two synthesis meshes (Chen
//! et al. 2012, §4, Figure 2): build both hierarchies ([`build_levels`]), compute the shape
//! features (§4.1: HKS + up, or geodesic affinities to the correspondences, or both;
//! [`shape_features`]), normalize them and the colours ([`Normalization`]), then coarse to fine
//! ([`CoarseToFine`]): initialize the nearest-neighbour field at random on the coarsest level or
//! upsample it from the coarser one (Figure 6), vote the target colours, and iterate EM — E-step propagation and random search ([`super::matcher`]), M-step voting
//! ([`super::vote`]) — until the field stabilizes or `iterations` passes ran. At the finest level
//! the colours are finally copied from the matches (nearest-neighbour reconstruction) unless
//! disabled.
//!
//! Colours are matched in units of their standard deviation over the source; each shape dimension
//! is divided by its standard deviation over the source and the shape block is weighted so that,
//! with `shape_weight = 1`, shape and colour count equally after normalizing for dimension and
//! variance (§5.2). The shape weight can be lowered towards the finest level (§5.2: "lower shape
//! weighting at finer scales").
//!
//! **Why dark features erode (issue 14, open).** Measured per level on Spot → cat (16K samples,
//! HKS features; k-means k = 5 shares of the synthesised colours against the source's): with the
//! vote Gaussian at σ = 0.5 × the fan radius, no coarse level's *voted* colours contained any of
//! the black patches (0% from the coarsest level to level 3, where the source's own level has
//! 6%): every black vertex is averaged with the white votes around it into grey, the next E-step
//! finds white patches closest to that grey, and the black share of the matches fell 5% → 0.3%
//! from level 4 to level 3 and ended at 0.6% (source 8.6%). Averaging in the vote is the cause:
//! σ = 0.1 (0.3 mean edges: a vote is nearly the colour the match puts at the vertex itself, the
//! per-level analogue of the paper's final nearest-neighbour step) keeps black at 5.9% and the
//! TV distance falls 0.234 → 0.149 (Blub → fish remesh: 0.202 → 0.100). Tried and not the cause:
//! a smaller shape weight (0.5: black 0%), a coarser start (`min_vertices` 2048: black 0.3%),
//! no final NN step (no change), no shape features (everything collapses onto the first colour).
//! A completeness term (`completeness_weight`, a cost per use of a source vertex relative to an
//! even cover, after the occurrence penalty of self-tuning texture optimisation, Kaspar et al.
//! 2015, standing in for bidirectional similarity's completeness) raises rare colours (black
//! 5.9% → 11% at weight 1 with σ = 0.1) but cannot undo a grey vote, so it is off by default.
//! σ stays 0.5 by default: at 0.1 the synthetic tests fail (three-colour bands on a stretched
//! capsule: TV 0.215, was 0.07; the stripe-period and by-example stripe tests fail too), so a
//! default that serves both (per-level σ, or NN voting only on the finer levels) is still to be
//! found; Spot → cat also keeps a second error at σ = 0.1 (cream 13.8% → 3.8%, orange 2% →
//! 13.8%, present from the coarse levels on).
//!
//! By-example mode (§5.3): source and target are the same mesh; painted vertices keep their colour
//! and matches may only use painted vertices whose whole fan lies in the painted region. "Whole
//! fan" is measured, not estimated from a ring count: a source vertex is usable on a level when
//! every vertex of its fan chart (the vertices within the fan radius plus the filter's reach,
//! exactly those whose colours enter its fan samples) is painted ([`fan_inside`]), on the finest
//! level; an empty result there is an error (the painted region is narrower than one fan). Coarser
//! levels, which only seed the finer ones, use the painted vertices unshrunk: restricting them too
//! collapsed the synthesized region onto one colour.
//!
//! Texture update (§5.3, Figure 10; [`super::update`]): source and target are different meshes;
//! the copied target vertices keep their copied colour in every vote (restricted to coarser levels
//! by averaging over each coarse vertex's children, all copied), but, unlike painted vertices,
//! they are matched like every other vertex, so their matches (the source patches they were
//! copied from) propagate into the synthesized region and it continues the copied texture.

use serde::Serialize;

use crate::engine::control::Control;
use crate::engine::geometry::expmap::{ExpMap, RadiusUnit};
use crate::engine::geometry::fans::{FanParams, FanSampler, Fans, FieldRef};
use crate::engine::geometry::heat::Source;
use crate::engine::mesh::Surface;
use crate::engine::rng::{mix, SplitMix64};

use super::features::{automatic_features, geodesic_affinities, AffinityPair, AffinityReport};
use super::fidelity::{measure, Fidelity, FidelityInput};
use super::histogram::HistogramBias;
use super::levels::MeshLevels;
use super::matcher::{bfs_order, components, usage_penalty, EStep, Nnf, PatchSpace};
use super::upsample::{upsample, Allowed, Side};
use super::vote::{nearest_neighbour_colors, vote, SourcePatches, VoteStencil};
use super::vote_schedule::{geometric_at, VoteSchedule};
use super::{MeshMatchError, MeshMatchParams, ShapeFeatures};

/// Most vertices per fan chart: an even mesh has about 75 within the fan radius plus the filter
/// reach; the cap (3.4×) only bites where the tessellation is far denser than the mean edge
/// (CAD-like assets mixing huge panels and tiny details: ToyCar as a target took 110 s without
/// it, 28 s with it), bounding the cost of charts and fans there.
pub const MAX_CHART_VERTICES: usize = 256;

/// One correspondence as world points on the synthesis meshes: source point(s), target point(s).
#[derive(Clone, Debug, PartialEq)]
pub struct PointPair {
    /// Source point(s).
    pub source: Vec<[f32; 3]>,
    /// Target point(s) (several: a one-to-many correspondence).
    pub target: Vec<[f32; 3]>,
}

/// What [`synthesize`] works on.
pub struct MatchInput<'a> {
    /// The source synthesis mesh.
    pub source: &'a Surface,
    /// Linear RGB per source vertex.
    pub source_colors: &'a [[f32; 3]],
    /// The target synthesis mesh (the same as `source` in by-example mode).
    pub target: &'a Surface,
    /// Correspondences.
    pub correspondences: &'a [PointPair],
    /// Which target vertices keep a given colour: none (a plain transfer), the painted ones
    /// (by-example) or the copied ones (texture update).
    pub mode: Mode<'a>,
}

/// What a synthesis keeps fixed (§5.3).
#[derive(Clone, Copy)]
pub enum Mode<'a> {
    /// A plain transfer: every target vertex is synthesized.
    Transfer,
    /// By-example: source and target are one mesh; these vertices are painted and keep their
    /// colour, the rest is synthesized from them.
    ByExample(&'a [bool]),
    /// Texture update: these target vertices were copied from the source and keep that colour.
    Update(Copied<'a>),
}

impl<'a> Mode<'a> {
    /// The painted vertices in by-example mode.
    pub fn painted(&self) -> Option<&'a [bool]> {
        match *self {
            Mode::ByExample(p) => Some(p),
            _ => None,
        }
    }
}

/// Texture-update mode (§5.3, Figure 10): target vertices whose colour was copied from the source
/// (by projection); they keep it, and the synthesis of the rest is constrained by them.
#[derive(Clone, Copy)]
pub struct Copied<'a> {
    /// Copied target vertices.
    pub mask: &'a [bool],
    /// Linear RGB per target vertex (read where `mask` is set).
    pub colors: &'a [[f32; 3]],
}

/// One EM iteration.
#[derive(Clone, Debug, Serialize)]
pub struct IterationReport {
    /// Mean patch dissimilarity after the E-step.
    pub energy: f64,
    /// Matches changed by propagation.
    pub propagated: usize,
    /// Matches changed by random search.
    pub searched: usize,
}

/// One level.
#[derive(Clone, Debug, Serialize)]
pub struct LevelReport {
    /// Level index (0 = finest).
    pub level: usize,
    /// Target vertices.
    pub target_vertices: usize,
    /// Source vertices.
    pub source_vertices: usize,
    /// Fan radius, world units.
    pub fan_radius: f32,
    /// Shape weight used.
    pub shape_weight: f32,
    /// Iterations run.
    pub iterations: Vec<IterationReport>,
    /// Whether the field stabilized before the iteration limit.
    pub converged: bool,
    /// By-example mode: source vertices matches may use on this level (whole fan painted).
    pub usable_sources: Option<usize>,
}

/// Figures of a synthesis.
#[derive(Clone, Debug, Serialize)]
pub struct MatchReport {
    /// Levels used, coarsest first.
    pub levels: Vec<LevelReport>,
    /// Shape dimensions per vertex (HKS + up, affinities).
    pub shape_dims: usize,
    /// Which features were used.
    pub features: &'static str,
    /// The vote's σ on the coarsest and finest levels and the histogram strength, as resolved
    /// from the params and the features.
    pub vote: VoteSchedule,
    /// The correspondence transform, when affinities were used.
    pub affinity: Option<AffinityReport>,
    /// Coherence, source self-match and completeness (with `measure_fidelity`).
    pub fidelity: Option<Fidelity>,
    /// Things the user should know (by-example levels where no fan fits in the painted region).
    pub warnings: Vec<String>,
}

/// The result: colours of the target synthesis vertices and the finest field.
pub struct MatchOutput {
    /// Linear RGB per target synthesis vertex.
    pub colors: Vec<[f32; 3]>,
    /// The finest nearest-neighbour field.
    pub nnf: Nnf,
    /// Figures.
    pub report: MatchReport,
}

fn std_per_dim(values: &[f32], dim: usize) -> Vec<f32> {
    let n = values.len() / dim.max(1);
    (0..dim)
        .map(|k| {
            let mean = (0..n).map(|v| values[v * dim + k] as f64).sum::<f64>() / n.max(1) as f64;
            let var = (0..n)
                .map(|v| (values[v * dim + k] as f64 - mean).powi(2))
                .sum::<f64>()
                / n.max(1) as f64;
            var.sqrt() as f32
        })
        .collect()
}

/// Shape features of both meshes on their feature levels, spread over all levels.
struct Shapes {
    dim: usize,
    source: Vec<Vec<f32>>,
    target: Vec<Vec<f32>>,
    affinity: Option<AffinityReport>,
    kind: &'static str,
}

/// Which shape features a synthesis uses: (HKS + up, geodesic affinities).
fn feature_kinds(params: &MeshMatchParams, correspondences: bool) -> (bool, bool) {
    match params.shape_features {
        ShapeFeatures::Auto => (!correspondences, correspondences),
        ShapeFeatures::Automatic => (true, false),
        ShapeFeatures::Affinity => (false, true),
        ShapeFeatures::Both => (true, true),
        ShapeFeatures::None => (false, false),
    }
}

/// The shape features of both meshes; `(use_auto, use_affinity)` from [`feature_kinds`].
fn shape_features(
    input: &MatchInput<'_>,
    (src, tgt): (&MeshLevels, &MeshLevels),
    params: &MeshMatchParams,
    (use_auto, use_affinity): (bool, bool),
    control: &Control,
) -> Result<Shapes, MeshMatchError> {
    if use_affinity && input.correspondences.is_empty() {
        return Err(MeshMatchError::Param {
            name: "shape_features",
            message: "geodesic affinities need correspondences".into(),
        });
    }
    let fs = src.level_with_at_most(params.feature_vertices);
    let ft = tgt.level_with_at_most(params.feature_vertices);
    let mut src_parts: Vec<(usize, Vec<f32>)> = Vec::new();
    let mut tgt_parts: Vec<(usize, Vec<f32>)> = Vec::new();
    let mut affinity = None;
    if use_auto {
        let a = automatic_features(src.surface(fs), &params.hks, control)?;
        let b = if input.mode.painted().is_some() {
            a.clone()
        } else {
            automatic_features(tgt.surface(ft), &params.hks, control)?
        };
        src_parts.push((a.dim, a.values));
        tgt_parts.push((b.dim, b.values));
    }
    if use_affinity {
        let locate = |levels: &MeshLevels, level: usize, p: [f32; 3]| -> Source {
            match levels.bvh[level].closest_point(p, f32::INFINITY) {
                Some(h) => Source::Point {
                    face: h.face,
                    bary: h.bary.map(f64::from),
                },
                None => Source::Vertex(0),
            }
        };
        let pairs: Vec<AffinityPair> = input
            .correspondences
            .iter()
            .map(|c| AffinityPair {
                source: c.source.iter().map(|&p| locate(src, fs, p)).collect(),
                target: c.target.iter().map(|&p| locate(tgt, ft, p)).collect(),
            })
            .collect();
        let (a, b, report) = geodesic_affinities(
            src.surface(fs),
            tgt.surface(ft),
            &pairs,
            &params.affinity,
            control,
        )?;
        src_parts.push((a.dim, a.values));
        tgt_parts.push((b.dim, b.values));
        affinity = Some(report);
    }
    let dim: usize = src_parts.iter().map(|p| p.0).sum();
    let interleave = |parts: &[(usize, Vec<f32>)], n: usize| -> Vec<f32> {
        let mut out = Vec::with_capacity(n * dim);
        for v in 0..n {
            for (d, values) in parts {
                out.extend_from_slice(&values[v * d..(v + 1) * d]);
            }
        }
        out
    };
    let ns = src.surface(fs).vertex_count();
    let nt = tgt.surface(ft).vertex_count();
    let kind = match (use_auto, use_affinity) {
        (true, true) => "hks+up, geodesic affinities",
        (true, false) => "hks+up",
        (false, true) => "geodesic affinities",
        (false, false) => "none",
    };
    if dim == 0 {
        return Ok(Shapes {
            dim: 0,
            source: vec![Vec::new(); src.len()],
            target: vec![Vec::new(); tgt.len()],
            affinity,
            kind,
        });
    }
    Ok(Shapes {
        dim,
        source: src.spread(fs, dim, interleave(&src_parts, ns)),
        target: tgt.spread(ft, dim, interleave(&tgt_parts, nt)),
        affinity,
        kind,
    })
}

/// Runs MeshMatch (see the module docs).
///
/// # Errors
/// [`MeshMatchError`] for bad parameters or meshes, failed features, or cancellation.
pub fn synthesize(
    input: &MatchInput<'_>,
    params: &MeshMatchParams,
    seed: u64,
    control: &Control,
) -> Result<MatchOutput, MeshMatchError> {
    params.validate()?;
    if input.source_colors.len() != input.source.vertex_count() {
        return Err(MeshMatchError::Param {
            name: "source_colors",
            message: format!(
                "{} colours for {} vertices",
                input.source_colors.len(),
                input.source.vertex_count()
            ),
        });
    }
    let span = control.span(0.0, 0.08);
    control.stage("meshmatch: hierarchy", 0)?;
    let (src_levels, tgt_owned) = build_levels(input, params, control)?;
    let tgt_levels = tgt_owned.as_ref().unwrap_or(&src_levels);
    drop(span);

    let span = control.span(0.08, 0.15);
    control.stage("meshmatch: features", 0)?;
    let (hks, affinity) = feature_kinds(params, !input.correspondences.is_empty());
    let shapes = shape_features(
        input,
        (&src_levels, tgt_levels),
        params,
        (hks, affinity),
        control,
    )?;
    drop(span);

    let normalization = Normalization::new(input, &src_levels, &shapes);
    let masks = ExampleMasks::new(input, tgt_levels, normalization.color_std)?;
    let schedule = VoteSchedule::resolve(params, hks, affinity);
    let run = CoarseToFine {
        params,
        schedule,
        seed,
        control,
        src: &src_levels,
        tgt: tgt_levels,
        shapes: &shapes,
        normalization: &normalization,
        masks: &masks,
        levels: src_levels.len().min(tgt_levels.len()),
    };
    let AllLevels {
        colors,
        nnf,
        reports,
        fidelity,
        warnings,
    } = run.all_levels()?;
    control.set_prefix("");
    let colors = colors
        .into_iter()
        .map(|c| c.map(|x| (x * normalization.color_std).max(0.0)))
        .collect();
    Ok(MatchOutput {
        colors,
        nnf,
        report: MatchReport {
            levels: reports,
            shape_dims: shapes.dim,
            features: shapes.kind,
            vote: schedule,
            affinity: shapes.affinity,
            fidelity,
            warnings,
        },
    })
}

/// The hierarchies of the source and, unless in by-example mode (where the target is the
/// source), of the target.
fn build_levels(
    input: &MatchInput<'_>,
    params: &MeshMatchParams,
    control: &Control,
) -> Result<(MeshLevels, Option<MeshLevels>), MeshMatchError> {
    let up = params.hks.up;
    let src_levels = MeshLevels::build(input.source, params.min_vertices, up, control)?;
    let tgt_owned = if input.mode.painted().is_some() {
        None
    } else {
        Some(MeshLevels::build(
            input.target,
            params.min_vertices,
            up,
            control,
        )?)
    };
    Ok((src_levels, tgt_owned))
}

/// Colours and shape features in units of their standard deviation over the source.
struct Normalization {
    /// The colour scale: std over the source, all channels pooled.
    color_std: f32,
    /// Normalized source colours per level, `[vertex][rgb]` flattened.
    src_colors: Vec<Vec<f32>>,
    /// Std of each shape dimension over the source (1 where it vanishes); empty without shape.
    shape_std: Vec<f32>,
}

impl Normalization {
    fn new(input: &MatchInput<'_>, src_levels: &MeshLevels, shapes: &Shapes) -> Self {
        let flat: Vec<f32> = input.source_colors.iter().flatten().copied().collect();
        let color_std = {
            let s = std_per_dim(&flat, 3);
            ((s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / 3.0)
                .sqrt()
                .max(1e-3)
        };
        let normalized: Vec<f32> = flat.iter().map(|x| x / color_std).collect();
        let src_colors = src_levels.spread(0, 3, normalized);
        let shape_std: Vec<f32> = if shapes.dim > 0 {
            std_per_dim(&shapes.source[0], shapes.dim)
                .into_iter()
                .map(|s| if s > 1e-12 { s } else { 1.0 })
                .collect()
        } else {
            Vec::new()
        };
        Normalization {
            color_std,
            src_colors,
            shape_std,
        }
    }
}

/// The target vertices of every level that keep their colour: painted ones in by-example mode
/// (§5.3; the source vertices matches may use are found per level from the fan charts,
/// [`fan_inside`]), copied ones in texture-update mode (with their normalized colours, averaged
/// over each coarse vertex's children, all of which are copied).
enum ExampleMasks {
    /// A plain transfer: nothing is kept.
    Transfer,
    /// By-example: the painted vertices per level.
    ByExample { painted: Vec<Vec<bool>> },
    /// Texture update: the copied vertices per level and their colours, normalized like the
    /// source's.
    Update {
        copied: Vec<Vec<bool>>,
        colors: Vec<Vec<[f32; 3]>>,
    },
}

impl ExampleMasks {
    fn new(
        input: &MatchInput<'_>,
        tgt_levels: &MeshLevels,
        color_std: f32,
    ) -> Result<Self, MeshMatchError> {
        let restrict = |mask: &[bool], name: &'static str| {
            let levels = tgt_levels.restrict_mask_all(mask);
            if levels[0].iter().any(|&x| x) {
                Ok(levels)
            } else {
                Err(MeshMatchError::Param {
                    name,
                    message: format!("the {name} mask selects no vertex"),
                })
            }
        };
        Ok(match input.mode {
            Mode::Transfer => ExampleMasks::Transfer,
            Mode::ByExample(p) => ExampleMasks::ByExample {
                painted: restrict(p, "example")?,
            },
            Mode::Update(c) => {
                let copied = restrict(c.mask, "update")?;
                let flat: Vec<f32> = c.colors.iter().flatten().map(|x| x / color_std).collect();
                let colors = tgt_levels
                    .spread(0, 3, flat)
                    .into_iter()
                    .map(|l| l.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
                    .collect();
                ExampleMasks::Update { copied, colors }
            }
        })
    }

    /// The target vertices of `level` that keep their colour (painted or copied).
    fn fixed(&self, level: usize) -> Option<&[bool]> {
        match self {
            ExampleMasks::Transfer => None,
            ExampleMasks::ByExample { painted } => Some(&painted[level]),
            ExampleMasks::Update { copied, .. } => Some(&copied[level]),
        }
    }

    /// Texture update: the copied colours of `level`.
    fn fixed_colors(&self, level: usize) -> Option<&[[f32; 3]]> {
        match self {
            ExampleMasks::Update { colors, .. } => Some(&colors[level]),
            _ => None,
        }
    }

    /// By-example mode: the painted vertices of `level`.
    fn painted(&self, level: usize) -> Option<&[bool]> {
        match self {
            ExampleMasks::ByExample { painted } => Some(&painted[level]),
            _ => None,
        }
    }
}

/// The vertices of `mask` whose whole fan chart lies in `mask`: every vertex within the fan radius
/// plus the filter's reach (the chart of [`FanSampler`]), i.e. every vertex whose colour enters
/// one of the vertex's fan samples, is set.
pub fn fan_inside(mask: &[bool], charts: &ExpMap) -> Vec<bool> {
    (0..mask.len())
        .map(|v| mask[v] && charts.chart(v).0.iter().all(|&q| mask[q as usize]))
        .collect()
}

/// What every level of the coarse-to-fine loop reads.
struct CoarseToFine<'a> {
    params: &'a MeshMatchParams,
    /// The vote's σ per level and histogram strength.
    schedule: VoteSchedule,
    seed: u64,
    control: &'a Control,
    src: &'a MeshLevels,
    tgt: &'a MeshLevels,
    shapes: &'a Shapes,
    normalization: &'a Normalization,
    masks: &'a ExampleMasks,
    /// Levels used (the shorter hierarchy's).
    levels: usize,
}

/// The data of one level that stays fixed through its EM iterations.
struct Level<'a> {
    index: usize,
    /// Source and target vertices.
    ns: usize,
    nt: usize,
    /// Fan radius, world units.
    radius: f32,
    /// Shape weight of this level.
    weight: f32,
    src_fans: Fans,
    /// [`FanShape::ring_stats`] of `src_fans` (the E-step's candidate pruning).
    src_ring_stats: Vec<f32>,
    tgt_sampler: FanSampler,
    stencil: VoteStencil,
    /// Normalized source colour per vertex.
    centers: Vec<[f32; 3]>,
    /// Scaled shape features.
    src_shape: Vec<f32>,
    tgt_shape: Vec<f32>,
    /// By-example masks of this level: source vertices matches may use, painted targets.
    allowed: Option<Vec<bool>>,
    fixed: Option<&'a [bool]>,
    /// Texture update: the copied colours of this level (normalized), else the fixed vertices
    /// keep their source colour (`centers`, by-example mode: the same mesh).
    fixed_colors: Option<&'a [[f32; 3]]>,
    /// Whether the E-step leaves the fixed vertices' matches alone (by-example mode, where a
    /// painted vertex matches itself). In texture-update mode copied vertices are matched like
    /// the others, so their matches propagate into the synthesized region.
    fixed_matches: bool,
    /// Why `allowed` is the unshrunk painted mask on this level, if it is.
    warning: Option<String>,
}

/// What the coarse-to-fine loop ends with.
struct AllLevels {
    /// Normalized colours of the finest target vertices.
    colors: Vec<[f32; 3]>,
    /// The finest field.
    nnf: Nnf,
    /// One report per level, coarsest first.
    reports: Vec<LevelReport>,
    /// Fidelity figures (with `measure_fidelity`).
    fidelity: Option<Fidelity>,
    /// Warnings of the levels.
    warnings: Vec<String>,
}

/// What one level hands on: the field, the colours, and its figures.
struct LevelOutput {
    nnf: Nnf,
    colors: Vec<[f32; 3]>,
    fidelity: Option<Fidelity>,
    report: LevelReport,
    warning: Option<String>,
}

impl Level<'_> {
    /// The vertices the vote leaves alone, and the colours they keep.
    fn keep(&self) -> Option<(&[bool], &[[f32; 3]])> {
        self.fixed
            .map(|f| (f, self.fixed_colors.unwrap_or(self.centers.as_slice())))
    }
}

impl<'a> CoarseToFine<'a> {
    /// All levels, coarsest first.
    fn all_levels(&self) -> Result<AllLevels, MeshMatchError> {
        // Progress: the levels share the rest of the span in proportion to their vertex counts
        // (charts, fans, E-steps and votes are all linear in them).
        let level_cost: Vec<f64> = (0..self.levels)
            .map(|l| {
                (self.src.surface(l).vertex_count() + self.tgt.surface(l).vertex_count()) as f64
            })
            .collect();
        let total_cost: f64 = level_cost.iter().sum::<f64>().max(1.0);
        let mut cost_done = 0.0;
        let mut reports = Vec::new();
        let mut fidelity = None;
        let mut warnings = Vec::new();
        let mut nnf = Nnf::default();
        let mut colors: Vec<[f32; 3]> = Vec::new();
        for level in (0..self.levels).rev() {
            let level_start = 0.15 + 0.85 * cost_done / total_cost;
            cost_done += level_cost[level];
            let _level_span = self
                .control
                .span(level_start, 0.15 + 0.85 * cost_done / total_cost);
            let out = self.level(level, nnf)?;
            nnf = out.nnf;
            colors = out.colors;
            if out.fidelity.is_some() {
                fidelity = out.fidelity;
            }
            warnings.extend(out.warning);
            reports.push(out.report);
        }
        Ok(AllLevels {
            colors,
            nnf,
            reports,
            fidelity,
            warnings,
        })
    }

    /// One level: prepare, initialize or upsample the field from `coarser`, vote, iterate EM,
    /// and on the finest level reconstruct and measure.
    fn level(&self, level: usize, coarser: Nnf) -> Result<LevelOutput, MeshMatchError> {
        let (params, levels) = (self.params, self.levels);
        self.control
            .set_prefix(&format!("meshmatch level {}/{levels}", levels - level));
        self.control.stage("prepare", 0)?;
        let lv = self.prepare(level)?;
        self.control.stage("initial field and vote", 0)?;
        let mut nnf = self.initial_field(&lv, &coarser)?;
        if let Some(f) = lv.fixed.filter(|_| lv.fixed_matches) {
            for (t, &is_fixed) in f.iter().enumerate() {
                if is_fixed {
                    nnf.source[t] = t as u32;
                    nnf.rotation[t] = 0;
                }
            }
        }
        let patches = SourcePatches {
            rings: params.rings,
            spokes: params.spokes,
            radius: lv.radius,
            fans: &lv.src_fans.data,
            centers: &lv.centers,
        };
        let keep = lv.keep();
        let sigma = self.schedule.sigma_at(level, self.levels - 1) * lv.radius;
        let mut colors = vote(&lv.stencil, &nnf, &patches, sigma, keep, None);
        let (iterations, converged) = self.iterate(&lv, &patches, sigma, &mut nnf, &mut colors)?;
        if level == 0 && params.nearest_neighbor_final {
            self.control.stage("nearest-neighbour colours", 0)?;
            colors = nearest_neighbour_colors(&nnf, &lv.centers, keep);
        }
        let mut fidelity = None;
        if level == 0 && params.measure_fidelity {
            self.control.stage("fidelity", 0)?;
            fidelity = Some(measure(
                &FidelityInput {
                    source: self.src,
                    target: self.tgt,
                    source_fans: &lv.src_fans.data,
                    target_sampler: &lv.tgt_sampler,
                    colors: &colors,
                    nnf: &nnf,
                    allowed: lv.allowed.as_deref(),
                    fixed: lv.fixed,
                    rings: params.rings,
                    seed: self.seed,
                },
                self.control,
            )?);
        }
        let report = LevelReport {
            level,
            target_vertices: lv.nt,
            source_vertices: lv.ns,
            fan_radius: lv.radius,
            shape_weight: lv.weight,
            iterations,
            converged,
            usable_sources: lv
                .allowed
                .as_ref()
                .map(|a| a.iter().filter(|&&x| x).count()),
        };
        Ok(LevelOutput {
            nnf,
            colors,
            fidelity,
            report,
            warning: lv.warning,
        })
    }

    /// Fans of the source colours, the target's fan sampler and vote stencil, and the shape
    /// features scaled for `level`.
    fn prepare(&self, level: usize) -> Result<Level<'a>, MeshMatchError> {
        let (params, control) = (self.params, self.control);
        let (src_levels, tgt_levels, shapes) = (self.src, self.tgt, self.shapes);
        let src_colors = &self.normalization.src_colors;
        let src_surface = src_levels.surface(level);
        let tgt_surface = tgt_levels.surface(level);
        let (ns, nt) = (src_surface.vertex_count(), tgt_surface.vertex_count());
        let radius = params.fan_radius * tgt_levels.mean_edge[level];
        let fan_params = FanParams {
            rings: params.rings,
            spokes: params.spokes,
            radius,
            radius_unit: RadiusUnit::World,
            max_chart_vertices: MAX_CHART_VERTICES,
            ..Default::default()
        };
        let src_sampler =
            FanSampler::new(src_surface, &src_levels.frames[level], &fan_params, control)?;
        let src_fans = src_sampler.sample(
            FieldRef {
                dim: 3,
                values: &src_colors[level],
            },
            control,
        )?;
        let (allowed, warning) = self.usable_sources(level, src_sampler.charts())?;
        drop(src_sampler);
        let mut tgt_sampler =
            FanSampler::new(tgt_surface, &tgt_levels.frames[level], &fan_params, control)?;
        // The target's colours are sampled at every EM iteration: keep the filter weights.
        tgt_sampler.cache_weights(control)?;
        let stencil = VoteStencil::build(tgt_sampler.charts(), radius);
        let centers: Vec<[f32; 3]> = src_colors[level]
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let weight = shape_weight_at(params, level, self.levels - 1);
        let fan_dims = (params.rings * params.spokes * 3) as f32;
        let scale: Vec<f32> = self
            .normalization
            .shape_std
            .iter()
            .map(|s| (weight * fan_dims / shapes.dim.max(1) as f32).sqrt() / s)
            .collect();
        let scaled = |values: &[f32]| -> Vec<f32> {
            values
                .iter()
                .enumerate()
                .map(|(i, x)| x * scale[i % shapes.dim.max(1)])
                .collect()
        };
        let (src_shape, tgt_shape) = if shapes.dim > 0 {
            (scaled(&shapes.source[level]), scaled(&shapes.target[level]))
        } else {
            (Vec::new(), Vec::new())
        };
        let src_ring_stats = src_fans.shape().ring_stats(&src_fans.data);
        Ok(Level {
            index: level,
            ns,
            nt,
            radius,
            weight,
            src_fans,
            src_ring_stats,
            tgt_sampler,
            stencil,
            centers,
            src_shape,
            tgt_shape,
            allowed,
            fixed: self.masks.fixed(level),
            fixed_colors: self.masks.fixed_colors(level),
            fixed_matches: self.masks.painted(level).is_some(),
            warning,
        })
    }

    /// By-example mode: the source vertices of `level` whose whole fan lies in the painted region
    /// ([`fan_inside`]), and a warning when there is none on a coarser level (the painted mask is
    /// used unshrunk there). None on the finest level is an error.
    #[allow(clippy::type_complexity)]
    fn usable_sources(
        &self,
        level: usize,
        charts: &ExpMap,
    ) -> Result<(Option<Vec<bool>>, Option<String>), MeshMatchError> {
        let Some(painted) = self.masks.painted(level) else {
            return Ok((None, None));
        };
        if level > 0 {
            // Coarser levels only seed the finer ones: restricting them to whole-fan vertices
            // left so few usable sources that the synthesized region collapsed onto one colour
            // (a striped capsule's unpainted half came out 100% dark).
            return Ok((Some(painted.to_vec()), None));
        }
        let inside = fan_inside(painted, charts);
        if inside.iter().any(|&x| x) {
            return Ok((Some(inside), None));
        }
        if level == 0 {
            return Err(MeshMatchError::Param {
                name: "example",
                message: format!(
                    "no fan fits inside the painted region (fan radius {:.4} world units plus the filter reach): paint a wider region or lower fan_radius",
                    charts.radius
                ),
            });
        }
        let warning = format!(
            "by-example: on level {level} ({} vertices) no fan fits inside the painted region; matches there may use any painted vertex",
            painted.len()
        );
        Ok((Some(painted.to_vec()), Some(warning)))
    }

    /// The field to start `lv` from: random on the coarsest level, else upsampled from the
    /// `coarser` level's field.
    fn initial_field(&self, lv: &Level<'_>, coarser: &Nnf) -> Result<Nnf, MeshMatchError> {
        let (level, ns, nt) = (lv.index, lv.ns, lv.nt);
        if level == self.levels - 1 {
            let pool: Vec<u32> = (0..ns as u32)
                .filter(|&s| lv.allowed.as_ref().is_none_or(|a| a[s as usize]))
                .collect();
            if pool.is_empty() {
                return Err(MeshMatchError::Param {
                    name: "example",
                    message: format!(
                        "the painted region vanishes on the coarsest level ({ns} vertices): paint a larger part or raise min_vertices"
                    ),
                });
            }
            let mut rng = SplitMix64::new(mix(self.seed, 0xC0A5, level as u64));
            Ok(Nnf {
                source: (0..nt)
                    .map(|_| pool[rng.below(pool.len() as u64) as usize])
                    .collect(),
                rotation: (0..nt)
                    .map(|_| rng.below(self.params.spokes as u64) as u16)
                    .collect(),
                distance: vec![f32::INFINITY; nt],
            })
        } else {
            Ok(upsample(
                coarser,
                level,
                &Side {
                    hierarchy: &self.tgt.hierarchy,
                    frames: &self.tgt.frames,
                },
                &Side {
                    hierarchy: &self.src.hierarchy,
                    frames: &self.src.frames,
                },
                &self.src.bvh[level],
                self.params.spokes,
                lv.allowed.as_deref().map(|mask| Allowed {
                    mask,
                    seed: mix(self.seed, 0x5a11, level as u64),
                }),
            ))
        }
    }

    /// The EM iterations of one level (E-step: refresh, propagation, random search; M-step:
    /// vote) until the field stabilizes or `iterations` passes ran. Returns the iteration
    /// reports and whether it converged.
    fn iterate(
        &self,
        lv: &Level<'_>,
        patches: &SourcePatches<'_>,
        sigma: f32,
        nnf: &mut Nnf,
        colors: &mut Vec<[f32; 3]>,
    ) -> Result<(Vec<IterationReport>, bool), MeshMatchError> {
        let (params, control, seed) = (self.params, self.control, self.seed);
        let (level, nt, levels) = (lv.index, lv.nt, self.levels);
        let (src_levels, tgt_levels) = (self.src, self.tgt);
        let keep = lv.keep();
        let (labels, firsts) = components(tgt_levels.rings(level), nt);
        let mut rng = SplitMix64::new(mix(seed, 0x0bf5, level as u64));
        // A random start inside each component.
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); firsts.len()];
        for (v, &c) in labels.iter().enumerate() {
            members[c as usize].push(v as u32);
        }
        let mut starts: Vec<u32> = members
            .iter()
            .map(|m| m[rng.below(m.len() as u64) as usize])
            .collect();
        let mut iterations = Vec::new();
        let mut converged = false;
        for it in 0..params.iterations {
            control.set_prefix(&format!(
                "meshmatch level {}/{levels} iteration {}",
                levels - level,
                it + 1
            ));
            control.check()?;
            let flat: Vec<f32> = colors.iter().flatten().copied().collect();
            let tgt_fans = lv.tgt_sampler.sample(
                FieldRef {
                    dim: 3,
                    values: &flat,
                },
                control,
            )?;
            control.stage("E-step", 0)?;
            let tgt_ring_stats = tgt_fans.shape().ring_stats(&tgt_fans.data);
            let ring_weights = if params.fan_area_weights {
                tgt_fans.shape().area_ring_weights()
            } else {
                Vec::new()
            };
            let penalty = usage_penalty(
                nnf,
                lv.ns,
                lv.allowed.as_deref(),
                lv.fixed,
                params.completeness_weight,
                lv.src_fans.shape().len() as f32,
            );
            let step = EStep {
                space: PatchSpace {
                    fan: lv.src_fans.shape(),
                    target_fans: &tgt_fans.data,
                    source_fans: &lv.src_fans.data,
                    target_shape: &lv.tgt_shape,
                    source_shape: &lv.src_shape,
                    shape_dim: self.shapes.dim,
                    source_allowed: lv.allowed.as_deref(),
                    exclude: None,
                    source_penalty: &penalty,
                    ring_weights: &ring_weights,
                    target_ring_stats: &tgt_ring_stats,
                    source_ring_stats: &lv.src_ring_stats,
                },
                target_adjacency: tgt_levels.rings(level),
                source_adjacency: src_levels.rings(level),
                source_hierarchy: &src_levels.hierarchy,
                level,
                whole_source_draws: level + 1 == levels,
                randomized_rotations: params.randomized_rotations,
                fixed: lv.fixed.filter(|_| lv.fixed_matches),
                seed: mix(seed, level as u64, it as u64),
            };
            step.refresh(nnf);
            control.check()?;
            let order = bfs_order(tgt_levels.rings(level), &labels, &mut starts);
            let propagated = step.propagate(nnf, &order);
            control.check()?;
            let searched = step.random_search(nnf);
            let energy = nnf.energy();
            control.stage("vote", 0)?;
            let bias = HistogramBias::new(&lv.centers, colors, self.schedule.histogram_weight);
            *colors = vote(&lv.stencil, nnf, patches, sigma, keep, bias.as_ref());
            iterations.push(IterationReport {
                energy,
                propagated,
                searched,
            });
            let changed = (propagated + searched) as f32 / nt.max(1) as f32;
            if it > 0 && changed < params.convergence {
                converged = true;
                break;
            }
        }
        Ok((iterations, converged))
    }
}

/// Shape weight of `level`: `shape_weight` on the coarsest level, `finest_shape_weight` on level 0,
/// geometric in between.
fn shape_weight_at(params: &MeshMatchParams, level: usize, top: usize) -> f32 {
    let coarse = params.shape_weight;
    geometric_at(
        coarse,
        params.finest_shape_weight.unwrap_or(coarse),
        level,
        top,
    )
}
