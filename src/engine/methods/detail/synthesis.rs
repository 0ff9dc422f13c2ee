//! Detail transfer over surfaces (Berkiten et al. 2017, §3.3.1, Algorithms 1-2, eqs. 5-7):
//! given the source hierarchy with a displacement per vertex and transformed geometric
//! features `A g` on every level, and the target hierarchy with its transformed features,
//! synthesise a displacement on every target level, coarsest to finest.
//!
//! **Algorithm 1** ([`synthesize`]), per level, coarsest first:
//! 1. up-sample: each vertex of the level takes the barycentric interpolation of the coarser
//!    level's result at its closest point on the coarser surface (BVH); the coarsest level
//!    starts from the source's mean displacement, with no matching confidence;
//! 2. sweep order ([`super::sweep`]): good-correspondence counts, seeds with the fewest, Dijkstra
//!    order from them (computed per level: each level has its own vertices);
//! 3. SYNTHESIZE-LEVEL ([`super::patch_match`]) in that order, then again in reverse order; the
//!    source patches are sampled once per level and shared by both passes (they do not change);
//!    each pass starts with `w_disp = 0` (else the second pass would skip every vertex) and
//!    shows the previous result until a vertex receives a contribution;
//! 4. `n ← 2n + 1`.
//!
//! Displacements are normalised to `[0, 1]` by the source's range over all levels (eq. 7's
//! `d_max = 1`) and mapped back at the end. The grid step of a level is the mean of the source's
//! and the target's mean edge lengths (the hierarchy shares them), so `n` counts edges and
//! `n ← 2n + 1` keeps a patch's world size about constant while edges halve.
//!
//! **Values the paper leaves open** ([`SynthesisParams`] defaults, and why):
//! - initial `n = 3`: with four levels the sides are 3, 7, 15, 31 edges, about 24-31 finest
//!   edges, the extent of a detail-feature patch ([`super::patches`]: 16 edges at half-edge
//!   resolution) plus its neighbourhood; smaller coarse patches just copy single vertices;
//! - candidates `K = 16`: step 1's learned metric decides the region, step 2 the alignment.
//!   Too few, and step 2 has nothing to align with: where the metric learns that position
//!   predicts the detail (the stretch case's rings, whose wavelength grows along x), the 8
//!   nearest samples lie around one ring, all in one phase, and the chain of patches drifts into
//!   a stretched copy (stretched part's wavelength 0.667 at K = 8, 0.600 at 12, 0.500 at 16,
//!   0.429 at 32; source at most 0.5). Too many, and step 2 picks detail that continues the
//!   context from the wrong place: the self-transfer of `detail_synthesis` (features that
//!   locate a point) keeps Pearson r 0.83-0.97 up to K = 20 and falls to 0.28 / 0.18 at 24 / 32.
//!   16 is the smallest `K` both pass (README "detail", the sweep of λ and `K`);
//! - good-correspondence threshold: the 5 % quantile of target-to-sample feature distances
//!   (a scale-free notion of "good"; see [`super::sweep`]);
//! - seeds: 3;
//! - source samples per level: 1024 by farthest-point sampling (all vertices on smaller levels):
//!   on the finest level of a 10-20k-vertex source they lie 3-4 edges apart, which the shift
//!   range closes;
//! - shift range `s = 1` grid step (`(2s+1)² = 9` shifts per candidate): the samples' spacing
//!   over the shift range, so together they reach about every alignment;
//! - the candidates' wider refinement (not in the paper; off by default, `max_reach`): on a
//!   level whose samples lie farther apart than the shift range closes (1024 samples on a
//!   38k-vertex level lie about 6 edges apart), step 1's `K` candidates are re-aligned by
//!   feature distance over every shift up to the samples' covering radius (rounded up to grid
//!   steps, at most `max_reach`), and step 2 searches its shift range around that alignment
//!   ([`super::patch_match`]). It reproduces a known answer far better (README "detail",
//!   "The candidates' reach") but drifts the stretch case's rings (stretched part's wavelength
//!   0.500 → 0.600, the test's bound), so it is an option;
//! - feature sub-grid `m = 7`; matching confidence 0.5 for an up-sampled value, 1 for the
//!   forward pass's result in the reverse pass.
//!
//! Parallel (rayon) where it is safe: source patches, counts, step 1 over samples, step 2 over
//! candidates; the sweep itself is sequential. One Control stage per level.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use super::blend::Blend;
use super::patch_match::{recorded_point, source_patches, Charts, Level, Record};
use super::sweep::{farthest_point_cover, good_counts, good_threshold, sweep_order};
use crate::engine::control::{Cancelled, Control};
use crate::engine::geometry::expmap::mean_edge_length;
use crate::engine::mesh::Surface;
use crate::engine::spatial::Bvh;

pub use super::patch_match::{Choice, PassStats};

/// Parameters of [`synthesize`] (defaults and reasons in the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct SynthesisParams {
    /// Patch side on the coarsest level, in grid steps (≈ edges). Default 3. Range 1..=63.
    pub initial_patch_size: usize,
    /// Candidates of step 1 (`K`). Default 16. Range ≥ 1.
    pub candidates: usize,
    /// Quantile of feature distances below which a correspondence is good. Default 0.05.
    pub good_quantile: f64,
    /// Seed vertices of the sweep order. Default 3. Range ≥ 1.
    pub seeds: usize,
    /// Source samples per level. Default 1024. Range ≥ 1.
    pub source_samples: usize,
    /// Translational refinement range, grid steps. Default 1. Range 0..=4.
    pub shift: usize,
    /// Largest reach of the candidates' wider refinement, grid steps (the reach itself is the
    /// source samples' covering radius, see the module doc); 0 turns it off. Default 0 (off).
    /// Range 0..=16.
    pub max_reach: usize,
    /// Side of the feature sub-grid of step 1. Default 7. Range ≥ 1.
    pub feature_grid: usize,
    /// Matching confidence of an up-sampled value. Default 0.5.
    pub upsampled_confidence: f64,
    /// Matching confidence of the forward pass's result in the reverse pass. Default 1.
    pub previous_pass_confidence: f64,
    /// How patches are chosen (the two-step matching, or a random baseline).
    pub choice: Choice,
}

impl Default for SynthesisParams {
    fn default() -> Self {
        Self {
            initial_patch_size: 3,
            candidates: 16,
            good_quantile: 0.05,
            seeds: 3,
            source_samples: 1024,
            shift: 1,
            max_reach: 0,
            feature_grid: 7,
            upsampled_confidence: 0.5,
            previous_pass_confidence: 1.0,
            choice: Choice::Matched,
        }
    }
}

/// Errors of [`synthesize`].
#[derive(Debug, thiserror::Error)]
pub enum SynthesisError {
    /// A parameter or the level structure is invalid.
    #[error("invalid synthesis input: {0}")]
    Param(String),
    /// An array has the wrong length.
    #[error("{what} of level {level} has {got} values, expected {expected}")]
    Shape {
        /// Which array.
        what: &'static str,
        /// Level (0 coarsest).
        level: usize,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// A value is NaN or infinite.
    #[error("{what} of level {level} has a non-finite value")]
    NonFinite {
        /// Which array.
        what: &'static str,
        /// Level.
        level: usize,
    },
    /// A level has no faces, a non-finite position, a face index out of range, or no extent.
    #[error("level {level} of the {shape} has no usable faces")]
    Empty {
        /// `source` or `target`.
        shape: &'static str,
        /// Level.
        level: usize,
    },
    /// Cancelled through the control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for SynthesisError {
    fn from(_: Cancelled) -> Self {
        SynthesisError::Cancelled
    }
}

/// One source level.
#[derive(Clone, Copy, Debug)]
pub struct SourceLevel<'a> {
    /// The level's surface.
    pub surface: &'a Surface,
    /// Displacement per vertex (world units).
    pub displacement: &'a [f64],
    /// Transformed features `A g`, vertex-major `n × r`.
    pub features: &'a [f64],
}

/// One target level.
#[derive(Clone, Copy, Debug)]
pub struct TargetLevel<'a> {
    /// The level's surface.
    pub surface: &'a Surface,
    /// Transformed features `A g`, vertex-major `n × r`.
    pub features: &'a [f64],
}

/// What happened on one level.
#[derive(Clone, Debug, Serialize)]
pub struct LevelStats {
    /// Patch side `n` (grid steps).
    pub patch_size: usize,
    /// Grid step (world units).
    pub grid_step: f64,
    /// Source patches sampled.
    pub source_samples: usize,
    /// Reach of the candidates' wider refinement (grid steps; the shift range when it is not
    /// larger).
    pub reach: usize,
    /// Good-correspondence threshold `τ` (squared feature distance).
    pub threshold: f64,
    /// Seeds of the sweep order.
    pub seeds: Vec<usize>,
    /// Forward and reverse pass.
    pub passes: [PassStats; 2],
    /// Seconds: up-sampling, source patches, sweep order, forward pass, reverse pass.
    pub seconds: [f64; 5],
}

/// The result of [`synthesize`].
#[derive(Clone, Debug)]
pub struct Synthesis {
    /// Displacement per vertex of every target level (world units), coarsest first.
    pub displacement: Vec<Vec<f64>>,
    /// Final `w_disp` (reverse pass) per vertex of every level.
    pub weight: Vec<Vec<f64>>,
    /// Per-level statistics.
    pub levels: Vec<LevelStats>,
    /// Per vertex of the finest target level, the point of the finest source level its value was
    /// read from by its strongest contribution (reverse pass, else forward pass; `None` where no
    /// patch reached it): the correspondence the texture-space refinement
    /// ([`super::refine`]) starts from.
    pub finest_source_points: Vec<Option<[f64; 3]>>,
}

fn validate(
    source: &[SourceLevel<'_>],
    target: &[TargetLevel<'_>],
    r: usize,
    p: &SynthesisParams,
) -> Result<(), SynthesisError> {
    if source.is_empty() || source.len() != target.len() {
        return Err(SynthesisError::Param(format!(
            "{} source and {} target levels (need the same number, ≥ 1)",
            source.len(),
            target.len()
        )));
    }
    let ok = (1..=63).contains(&p.initial_patch_size)
        && p.candidates >= 1
        && (0.0..=1.0).contains(&p.good_quantile)
        && p.seeds >= 1
        && p.source_samples >= 1
        && p.shift <= 4
        && p.max_reach <= 16
        && p.feature_grid >= 1
        && (0.0..=1.0).contains(&p.upsampled_confidence)
        && (0.0..=1.0).contains(&p.previous_pass_confidence);
    if !ok {
        return Err(SynthesisError::Param(format!("{p:?}")));
    }
    let check = |what, level, arr: &[f64], expected| {
        if arr.len() != expected {
            return Err(SynthesisError::Shape {
                what,
                level,
                expected,
                got: arr.len(),
            });
        }
        match arr.iter().all(|x| x.is_finite()) {
            true => Ok(()),
            false => Err(SynthesisError::NonFinite { what, level }),
        }
    };
    for (l, (s, t)) in source.iter().zip(target).enumerate() {
        for (shape, surface) in [("source", s.surface), ("target", t.surface)] {
            let finite = surface.positions.iter().flatten().all(|x| x.is_finite());
            let nv = surface.vertex_count();
            let indexed = surface.faces.iter().flatten().all(|&v| (v as usize) < nv);
            if surface.faces.is_empty() || !finite || !indexed || mean_edge_length(surface) <= 0.0 {
                return Err(SynthesisError::Empty { shape, level: l });
            }
        }
        let (ns, nt) = (s.surface.vertex_count(), t.surface.vertex_count());
        check("source displacement", l, s.displacement, ns)?;
        check("source features", l, s.features, ns * r)?;
        check("target features", l, t.features, nt * r)?;
    }
    Ok(())
}

/// Barycentric interpolation of `values` (on `coarse`) at the closest point of every vertex of
/// `fine`.
pub fn upsample(coarse: &Surface, values: &[f64], fine: &Surface) -> Vec<f64> {
    interpolate_rows(coarse, values, 1, fine)
}

/// Barycentric interpolation of `width` values per vertex of `from` at the closest point of every
/// vertex of `to`.
pub fn interpolate_rows(from: &Surface, values: &[f64], width: usize, to: &Surface) -> Vec<f64> {
    let bvh = Bvh::build(&from.positions, &from.faces);
    let mut out = vec![0.0; to.vertex_count() * width];
    out.par_chunks_mut(width.max(1))
        .zip(&to.positions)
        .for_each(|(row, p)| {
            if let Some(hit) = bvh.closest_point(*p, f32::INFINITY) {
                let f = from.faces[hit.face as usize];
                for k in 0..3 {
                    let (w, v) = (hit.bary[k] as f64, f[k] as usize);
                    for (o, x) in row.iter_mut().zip(&values[v * width..(v + 1) * width]) {
                        *o += w * x;
                    }
                }
            }
        });
    out
}

/// Algorithm 1 (see the module doc). `r` is the transformed feature width (0 is allowed: every
/// feature then matches equally and only the detail decides).
///
/// # Errors
/// [`SynthesisError`] for inconsistent input, bad parameters, or cancellation.
pub fn synthesize(
    source: &[SourceLevel<'_>],
    target: &[TargetLevel<'_>],
    r: usize,
    params: &SynthesisParams,
    control: &Control,
) -> Result<Synthesis, SynthesisError> {
    validate(source, target, r, params)?;
    // Normalisation to [0, 1] by the source's range over all levels.
    let all = source.iter().flat_map(|s| s.displacement.iter().copied());
    let lo = all.clone().fold(f64::INFINITY, f64::min);
    let hi = all.fold(f64::NEG_INFINITY, f64::max);
    let range = if hi > lo { hi - lo } else { 1.0 };
    let mut out = Synthesis {
        displacement: Vec::new(),
        weight: Vec::new(),
        levels: Vec::new(),
        finest_source_points: Vec::new(),
    };
    let mut previous: Option<Vec<f64>> = None;
    let mut n = params.initial_patch_size;
    let mut rng = match params.choice {
        Choice::Random(seed) => seed,
        Choice::Matched => 0,
    };
    let count = source.len();
    for (l, (s, t)) in source.iter().zip(target).enumerate() {
        let _span = control.span(l as f64 / count as f64, (l + 1) as f64 / count as f64);
        let disp: Vec<f64> = s.displacement.iter().map(|d| (d - lo) / range).collect();
        let mut clock = Instant::now();
        let mut lap = || {
            let now = Instant::now();
            let dt = (now - clock).as_secs_f64();
            clock = now;
            dt
        };
        let (base, confidence) = match previous.take() {
            Some(values) => (
                upsample(target[l - 1].surface, &values, t.surface),
                params.upsampled_confidence,
            ),
            None => {
                let mean = disp.iter().sum::<f64>() / disp.len().max(1) as f64;
                (vec![mean; t.surface.vertex_count()], 0.0)
            }
        };
        let t_up = lap();
        let step = 0.5 * (mean_edge_length(s.surface) + mean_edge_length(t.surface)) as f64;
        let (samples, cover) = farthest_point_cover(s.surface, params.source_samples);
        let source_charts = Charts::new(s.surface);
        let target_charts = Charts::new(t.surface);
        let nt = t.surface.vertex_count();
        let stage = control.stage(
            &format!("detail synthesis level {}/{count}", l + 1),
            (samples.len() + 2 * nt) as u64,
        )?;
        let reach = candidate_reach(cover, step, params);
        let side = n + 2 * reach;
        let patches = source_patches(&source_charts, &disp, &samples, side, step, &stage)?;
        let t_patches = lap();
        let threshold = good_threshold(t.features, s.features, &samples, r, params.good_quantile);
        let counts = good_counts(t.features, s.features, &samples, r, threshold);
        let (order, seeds) = sweep_order(t.surface, &counts, params.seeds);
        let t_order = lap();
        let level = Level {
            target: &target_charts,
            target_features: t.features,
            source_features: s.features,
            patches: &patches,
            r,
            n,
            step,
            shift: params.shift,
            reach,
            candidates: params.candidates,
            feature_grid: params.feature_grid,
            choice: params.choice,
        };
        let finest = l + 1 == count;
        let mut records = vec![vec![Record::default(); if finest { nt } else { 0 }]; 2];
        let [rec_forward, rec_reverse] = &mut records[..] else {
            unreachable!("two record arrays")
        };
        let mut blend = Blend::new(base, confidence);
        let forward = level.pass(&order, &mut blend, &mut rng, &stage, record(rec_forward))?;
        let t_forward = lap();
        let reversed: Vec<usize> = order.iter().rev().copied().collect();
        let mut blend = Blend::new(blend.values(), params.previous_pass_confidence);
        let reverse = level.pass(&reversed, &mut blend, &mut rng, &stage, record(rec_reverse))?;
        let t_reverse = lap();
        if finest {
            out.finest_source_points = (rec_reverse.iter().zip(rec_forward.iter()))
                .map(|(r, f)| {
                    let chosen = if r.is_set() { r } else { f };
                    recorded_point(&patches, chosen, side)
                })
                .collect();
        }
        let values = blend.values();
        out.displacement
            .push(values.iter().map(|d| lo + d * range).collect());
        out.weight.push(blend.weights().to_vec());
        out.levels.push(LevelStats {
            patch_size: n,
            grid_step: step,
            source_samples: samples.len(),
            reach,
            threshold,
            seeds,
            passes: [forward, reverse],
            seconds: [t_up, t_patches, t_order, t_forward, t_reverse],
        });
        previous = Some(values);
        n = 2 * n + 1;
    }
    Ok(out)
}

/// The reach of the candidates' wider refinement on a level (see the module doc): the source
/// samples' covering radius `cover` (world units) in grid steps `step`, rounded up, at most
/// `max_reach` and at least the shift range (which is also the reach when `max_reach` is 0).
pub(super) fn candidate_reach(cover: f64, step: f64, params: &SynthesisParams) -> usize {
    let radius = cover / step.max(f64::MIN_POSITIVE);
    let reach = if radius.is_finite() {
        radius.ceil() as usize
    } else {
        0
    };
    reach.min(params.max_reach).max(params.shift)
}

/// The record array of a pass, `None` when it is not recorded (empty).
fn record(r: &mut [Record]) -> Option<&mut [Record]> {
    (!r.is_empty()).then_some(r)
}
