//! [`synthesize`]: the MeshMatch optimization, a coarse-to-fine EM on two synthesis meshes (Chen
//! et al. 2012, §4, Figure 2): build both hierarchies ([`build_levels`]), compute the shape
//! features (§4.1: HKS + up, or geodesic affinities to the correspondences, or both;
//! [`shape_features`]), normalize them and the colours ([`Normalization`]), resolve the vote
//! schedule ([`super::vote_schedule`]), then run the levels coarsest first
//! ([`super::coarse_to_fine`]: random or upsampled field, EM iterations of E-step and vote, the
//! final nearest-neighbour reconstruction).
//!
//! Colours are matched in units of their standard deviation over the source; each shape dimension
//! is divided by its standard deviation over the source and the shape block is weighted so that,
//! with `shape_weight = 1`, shape and colour count equally after normalizing for dimension and
//! variance (§5.2). The shape weight can be lowered towards the finest level (§5.2: "lower shape
//! weighting at finer scales").
//!
//! **Why dark features eroded (issue 14 item 1).** Measured per level on Spot → cat (16K samples,
//! HKS features; k-means k = 5 shares of the synthesised colours against the source's): with the
//! vote Gaussian at σ = 0.5 × the fan radius on every level, no coarse level's *voted* colours
//! contained any of the black patches (0% from the coarsest level to level 3, where the source's
//! own level has 6%): every black vertex is averaged with the white votes around it into grey,
//! the next E-step finds white patches closest to that grey, and the black share of the matches
//! fell 5% → 0.3% from level 4 to level 3 and ended at 0.6% (source 8.6%). Averaging in the vote
//! is the cause; not the cause: a smaller shape weight (0.5: black 0%), a coarser start
//! (`min_vertices` 2048: black 0.3%), the final NN step, the features. A completeness term
//! (`completeness_weight`, a cost per use of a source vertex relative to an even cover, after the
//! occurrence penalty of self-tuning texture optimisation, Kaspar et al. 2015, standing in for
//! bidirectional similarity's completeness) raises rare colours but cannot undo a grey vote, so
//! it is off by default. The remedy in use is the vote schedule (narrow coarse votes with
//! histogram matching when HKS features leave the layout free; [`super::vote_schedule`]): black
//! 6.5% of the output against 9.0% in Spot.
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
use crate::engine::geometry::expmap::ExpMap;
use crate::engine::geometry::heat::Source;
use crate::engine::mesh::Surface;

use super::coarse_to_fine::{AllLevels, CoarseToFine};
use super::features::{
    automatic_features, clamp_hks_to_source, geodesic_affinities, AffinityPair, AffinityReport,
    HksUnits,
};
use super::fidelity::Fidelity;
use super::fine_histogram::FineHistograms;
use super::levels::MeshLevels;
use super::matcher::Nnf;
use super::vote_schedule::VoteSchedule;
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
    /// Coherent regions of the field re-grown from a neighbour (module `region_flip`).
    pub region_flips: usize,
    /// The coarsest level with several starts (`coarsest_restarts` > 1, or a first start beyond
    /// `coarsest_restart_deviation`): the final EM energy of every random
    /// start, in order (the lowest was kept); empty otherwise.
    pub restart_energies: Vec<f64>,
    /// The coarsest level of a plain transfer with `coarsest_restart_deviation` > 0: the first
    /// start's largest finest-colour log ratio (module `fine_histogram`), which decided whether
    /// the level was restarted; absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_start_deviation: Option<f32>,
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
pub(super) struct Shapes {
    pub(super) dim: usize,
    pub(super) source: Vec<Vec<f32>>,
    pub(super) target: Vec<Vec<f32>>,
    pub(super) affinity: Option<AffinityReport>,
    pub(super) kind: &'static str,
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
        let a = automatic_features(src.surface(fs), &params.hks, None, control)?;
        let mut b = if input.mode.painted().is_some() {
            a.clone()
        } else {
            // The target in the (scaled) source's area unit: see `HksUnits`.
            let unit = match params.hks.units {
                HksUnits::Common => Some(src.surface(fs).area()),
                HksUnits::PerShape => None,
            };
            automatic_features(tgt.surface(ft), &params.hks, unit, control)?
        };
        if params.hks.clamp_to_source {
            clamp_hks_to_source(&mut b, &a, params.hks.hks_times);
        }
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

    let normalization = Normalization::new(input, &src_levels, &shapes, params);
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
pub(super) struct Normalization {
    /// The colour scale: std over the source, all channels pooled.
    pub(super) color_std: f32,
    /// Normalized source colours per level, `[vertex][rgb]` flattened.
    pub(super) src_colors: Vec<Vec<f32>>,
    /// Std of each shape dimension over the source (1 where it vanishes); empty without shape.
    pub(super) shape_std: Vec<f32>,
    /// The source's finest-colour histograms per level, with `fine_histogram_cost` or
    /// `coarsest_restart_deviation` > 0.
    pub(super) fine_histograms: Option<FineHistograms>,
}

impl Normalization {
    fn new(
        input: &MatchInput<'_>,
        src_levels: &MeshLevels,
        shapes: &Shapes,
        params: &MeshMatchParams,
    ) -> Self {
        let flat: Vec<f32> = input.source_colors.iter().flatten().copied().collect();
        let color_std = {
            let s = std_per_dim(&flat, 3);
            ((s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / 3.0)
                .sqrt()
                .max(1e-3)
        };
        let normalized: Vec<f32> = flat.iter().map(|x| x / color_std).collect();
        let strength = params.fine_histogram_strength();
        // The restarts on a deviation read them too, in a plain transfer (the by-example and
        // update modes start the coarsest level once).
        let plain = params.example.is_none() && params.update.is_none();
        let fine_histograms = (strength > 0.0
            || (plain && params.coarsest_restart_deviation > 0.0))
            .then(|| FineHistograms::build(src_levels, &normalized, strength));
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
            fine_histograms,
        }
    }
}

/// The target vertices of every level that keep their colour: painted ones in by-example mode
/// (§5.3; the source vertices matches may use are found per level from the fan charts,
/// [`fan_inside`]), copied ones in texture-update mode (with their normalized colours, averaged
/// over each coarse vertex's children, all of which are copied).
pub(super) enum ExampleMasks {
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
    pub(super) fn fixed(&self, level: usize) -> Option<&[bool]> {
        match self {
            ExampleMasks::Transfer => None,
            ExampleMasks::ByExample { painted } => Some(&painted[level]),
            ExampleMasks::Update { copied, .. } => Some(&copied[level]),
        }
    }

    /// Texture update: the copied colours of `level`.
    pub(super) fn fixed_colors(&self, level: usize) -> Option<&[[f32; 3]]> {
        match self {
            ExampleMasks::Update { colors, .. } => Some(&colors[level]),
            _ => None,
        }
    }

    /// By-example mode: the painted vertices of `level`.
    pub(super) fn painted(&self, level: usize) -> Option<&[bool]> {
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
