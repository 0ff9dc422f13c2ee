//! [`CoarseToFine`]: the coarse-to-fine loop of MeshMatch (Chen et al. 2012, §4, Figure 2) that
//! [`super::em::synthesize`] runs once the hierarchies, shape features and normalizations are
//! ready. Per level, coarsest first: prepare the level's fans, fan sampler, vote stencil, scaled
//! shape features and by-example / update masks ([`CoarseToFine::prepare`]); initialize the
//! nearest-neighbour field at random on the coarsest level or upsample it from the coarser one
//! (Figure 6, [`super::upsample`]); vote the target colours; iterate EM — E-step propagation and
//! random search ([`super::matcher`]), M-step voting with the level's σ and histogram strength
//! ([`super::vote`], [`super::vote_schedule`]) — until the field stabilizes or `iterations`
//! passes ran. On the coarse levels (at most `region_flip_vertices` target vertices) the
//! field's coherent regions are then re-grown from their neighbours and kept when the energy
//! drops (region flips, ours: [`super::region_flip`], `flips`). The coarsest level's EM runs
//! from `coarsest_restarts` random fields and keeps the lowest-energy one, or from 4 when its
//! first start's finest-colour statistics deviate beyond `coarsest_restart_deviation` (ours,
//! `restarts`).
//! Every E-step adds the finest-colour histogram cost of the current field (ours,
//! [`super::fine_histogram`]); the region flips compare fields without it.
//! On the finest level the colours are finally copied from the matches (nearest-neighbour
//! reconstruction, §4.3) unless disabled, and fidelity is measured on request.
//!
//! The shape weight goes geometrically from `shape_weight` on the coarsest level to
//! `finest_shape_weight` on the finest (§5.2: "lower shape weighting at finer scales").

use crate::engine::geometry::expmap::{ExpMap, RadiusUnit};
use crate::engine::geometry::fans::{FanParams, FanSampler, Fans, FieldRef};
use crate::engine::rng::{mix, SplitMix64};

mod flips;
mod restarts;

use super::em::{
    fan_inside, ExampleMasks, IterationReport, LevelReport, Normalization, Shapes,
    MAX_CHART_VERTICES,
};
use super::fidelity::{measure, Fidelity, FidelityInput};
use super::histogram::HistogramBias;
use super::levels::MeshLevels;
use super::matcher::{bfs_order, components, usage_penalty, EStep, Nnf, PatchSpace};
use super::upsample::{upsample, Allowed, Side};
use super::vote::{nearest_neighbour_colors, vote, SourcePatches, VoteStencil};
use super::vote_schedule::{geometric_at, VoteSchedule};
use super::{MeshMatchError, MeshMatchParams};
use crate::engine::control::Control;
use restarts::Start;

/// What every level of the coarse-to-fine loop reads.
pub(super) struct CoarseToFine<'a> {
    pub(super) params: &'a MeshMatchParams,
    /// The vote's σ per level and histogram strength.
    pub(super) schedule: VoteSchedule,
    pub(super) seed: u64,
    pub(super) control: &'a Control,
    pub(super) src: &'a MeshLevels,
    pub(super) tgt: &'a MeshLevels,
    pub(super) shapes: &'a Shapes,
    pub(super) normalization: &'a Normalization,
    pub(super) masks: &'a ExampleMasks,
    /// Levels used (the shorter hierarchy's).
    pub(super) levels: usize,
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
pub(super) struct AllLevels {
    /// Normalized colours of the finest target vertices.
    pub(super) colors: Vec<[f32; 3]>,
    /// The finest field.
    pub(super) nnf: Nnf,
    /// One report per level, coarsest first.
    pub(super) reports: Vec<LevelReport>,
    /// Fidelity figures (with `measure_fidelity`).
    pub(super) fidelity: Option<Fidelity>,
    /// Warnings of the levels.
    pub(super) warnings: Vec<String>,
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
    pub(super) fn all_levels(&self) -> Result<AllLevels, MeshMatchError> {
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
        let patches = SourcePatches {
            rings: params.rings,
            spokes: params.spokes,
            radius: lv.radius,
            fans: &lv.src_fans.data,
            centers: &lv.centers,
        };
        let keep = lv.keep();
        let sigma = self.schedule.sigma_at(level, self.levels - 1) * lv.radius;
        let Start {
            mut nnf,
            mut colors,
            iterations,
            converged,
            restart_energies,
            first_start_deviation,
        } = self.start(&lv, &coarser, &patches, sigma)?;
        let region_flips = self.flip_regions(&lv, &patches, sigma, &mut nnf, &mut colors)?;
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
            region_flips,
            restart_energies,
            first_start_deviation,
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

    /// The field to start `lv` from: random on the coarsest level (`restart` 0 is the single
    /// start of the paper; each other value draws another field), else upsampled from the
    /// `coarser` level's field.
    fn initial_field(
        &self,
        lv: &Level<'_>,
        coarser: &Nnf,
        restart: u64,
    ) -> Result<Nnf, MeshMatchError> {
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
            let first = mix(self.seed, 0xC0A5, level as u64);
            let mut rng = SplitMix64::new(match restart {
                0 => first,
                r => mix(first, 0x5EED, r),
            });
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
        let tgt_levels = self.tgt;
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
            let inputs = self.step_inputs(lv, nnf, colors, true)?;
            let step = self.e_step(lv, &inputs, mix(seed, level as u64, it as u64));
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

    /// What the E-step compares against: the target fans of `colors` with their ring
    /// statistics, the ring weights and the per-source penalties (completeness and histogram
    /// costs) of `nnf`; the finest-colour histogram cost only with `fine_cost`.
    fn step_inputs(
        &self,
        lv: &Level<'_>,
        nnf: &Nnf,
        colors: &[[f32; 3]],
        fine_cost: bool,
    ) -> Result<StepInputs, MeshMatchError> {
        let params = self.params;
        let flat: Vec<f32> = colors.iter().flatten().copied().collect();
        let tgt_fans = lv.tgt_sampler.sample(
            FieldRef {
                dim: 3,
                values: &flat,
            },
            self.control,
        )?;
        self.control.stage("E-step", 0)?;
        let ring_stats = tgt_fans.shape().ring_stats(&tgt_fans.data);
        let ring_weights = if params.fan_area_weights {
            tgt_fans.shape().area_ring_weights()
        } else {
            Vec::new()
        };
        let fan_len = lv.src_fans.shape().len() as f32;
        let mut penalty = usage_penalty(
            nnf,
            lv.ns,
            lv.allowed.as_deref(),
            lv.fixed,
            params.completeness_weight,
            fan_len,
        );
        // Histogram cost: matches of source vertices whose colour the target's current
        // (voted) colours over-represent cost more, so the matches themselves move to other
        // source patches where the vote's histogram matching could only re-weight.
        if let Some(cost) = HistogramBias::new(&lv.centers, colors, params.histogram_cost) {
            penalty.resize(lv.ns, 0.0);
            for (p, c) in penalty.iter_mut().zip(&lv.centers) {
                *p += fan_len * cost.excess(*c);
            }
        }
        // The finest-colour histogram cost (module `fine_histogram`), left out when fields are
        // compared (region flips).
        if let Some(fine) = self
            .normalization
            .fine_histograms
            .as_ref()
            .filter(|f| fine_cost && f.strength > 0.0)
        {
            let cost = fine.cost(lv.index, &nnf.source, fan_len);
            penalty.resize(lv.ns, 0.0);
            for (p, c) in penalty.iter_mut().zip(cost) {
                *p += c;
            }
        }
        Ok(StepInputs {
            fans: tgt_fans.data,
            ring_stats,
            ring_weights,
            penalty,
        })
    }

    /// The E-step of `lv` over `inputs`, seeded with `seed`.
    fn e_step<'b>(&'b self, lv: &'b Level<'_>, inputs: &'b StepInputs, seed: u64) -> EStep<'b> {
        let level = lv.index;
        EStep {
            space: PatchSpace {
                fan: lv.src_fans.shape(),
                target_fans: &inputs.fans,
                source_fans: &lv.src_fans.data,
                target_shape: &lv.tgt_shape,
                source_shape: &lv.src_shape,
                shape_dim: self.shapes.dim,
                source_allowed: lv.allowed.as_deref(),
                exclude: None,
                source_penalty: &inputs.penalty,
                ring_weights: &inputs.ring_weights,
                target_ring_stats: &inputs.ring_stats,
                source_ring_stats: &lv.src_ring_stats,
            },
            target_adjacency: self.tgt.rings(level),
            source_adjacency: self.src.rings(level),
            source_hierarchy: &self.src.hierarchy,
            level,
            whole_source_draws: level + 1 == self.levels,
            randomized_rotations: self.params.randomized_rotations,
            fixed: lv.fixed.filter(|_| lv.fixed_matches),
            seed,
        }
    }
}

/// The target side of one E-step (see [`CoarseToFine::step_inputs`]).
struct StepInputs {
    fans: Vec<f32>,
    ring_stats: Vec<f32>,
    ring_weights: Vec<f32>,
    penalty: Vec<f32>,
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
