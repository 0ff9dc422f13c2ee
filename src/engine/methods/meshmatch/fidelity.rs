//! Patch fidelity of a MeshMatch result: the two terms that MeshMatch's nearest-neighbour field
//! stands for (Chen et al. 2012, §4.2 build on PatchMatch; the terms are the bidirectional
//! similarity of Simakov et al. 2008).
//!
//! - **Coherence**: the mean best-match colour-fan distance of the *output* target patches
//!   against the source (every target patch should look like some source patch), per fan number,
//!   in units of the source colour variance.
//! - **Source self-match**: the same mean for the source's own patches matched against the rest
//!   of the source (matches closer than one fan radius refused). A coherent result has coherence
//!   close to this: its patches are as close to the source as the source's patches are to each
//!   other.
//! - **Completeness**: the fraction of (usable) source vertices lying within `R` rings of a
//!   vertex that some target vertex matched (the source's patches get used).
//!
//! All three are found with the E-step machinery of [`super::matcher`] (colour only, three
//! passes of propagation and random search), so they are approximate nearest neighbours like the
//! field itself.

use serde::Serialize;

use crate::engine::control::Control;
use crate::engine::geometry::fans::{FanSampler, FieldRef};
use crate::engine::rng::{mix, SplitMix64};

use super::levels::MeshLevels;
use super::matcher::{bfs_order, components, EStep, Exclusion, Nnf, PatchSpace};
use super::MeshMatchError;

/// Passes of propagation and random search per measure.
const PASSES: usize = 3;

/// The figures (see the module docs).
#[derive(Clone, Debug, Serialize)]
pub struct Fidelity {
    /// Mean best-match distance of the output's patches, per fan number (σ² units).
    pub coherence: f64,
    /// Mean best-match distance of the source's patches within the source, per fan number.
    pub source_self_match: f64,
    /// `coherence / source_self_match`.
    pub ratio: f64,
    /// Fraction of usable source vertices near a used match.
    pub completeness: f64,
}

/// What [`measure`] reads.
pub struct FidelityInput<'a> {
    /// Source levels (level 0 is used).
    pub source: &'a MeshLevels,
    /// Target levels.
    pub target: &'a MeshLevels,
    /// Source colour fans of level 0 (normalized colours).
    pub source_fans: &'a [f32],
    /// Fan layout of the target's level 0.
    pub target_sampler: &'a FanSampler,
    /// Final target colours (normalized), level 0.
    pub colors: &'a [[f32; 3]],
    /// The final field.
    pub nnf: &'a Nnf,
    /// Usable source vertices (by-example); `None`: all.
    pub allowed: Option<&'a [bool]>,
    /// Target vertices that were not synthesized (by-example); `None`: none.
    pub fixed: Option<&'a [bool]>,
    /// Rings `R` of the fans.
    pub rings: usize,
    /// Seed.
    pub seed: u64,
}

fn passes(step: &EStep<'_>, nnf: &mut Nnf, control: &Control) -> Result<(), MeshMatchError> {
    let n = nnf.source.len();
    let (labels, firsts) = components(step.target_adjacency, n);
    let mut starts = firsts;
    step.refresh(nnf);
    for _ in 0..PASSES {
        control.check()?;
        let order = bfs_order(step.target_adjacency, &labels, &mut starts);
        step.propagate(nnf, &order);
        step.random_search(nnf);
    }
    Ok(())
}

fn mean_over(nnf: &Nnf, keep: impl Fn(usize) -> bool, per: f64) -> f64 {
    let (sum, count) = nnf
        .distance
        .iter()
        .enumerate()
        .filter(|(t, d)| keep(*t) && d.is_finite())
        .fold((0.0f64, 0usize), |(s, c), (_, d)| (s + *d as f64, c + 1));
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64 / per
    }
}

/// Measures coherence, the source self-match and completeness.
///
/// # Errors
/// [`MeshMatchError`] for failed fans or cancellation.
pub fn measure(input: &FidelityInput<'_>, control: &Control) -> Result<Fidelity, MeshMatchError> {
    let flat: Vec<f32> = input.colors.iter().flatten().copied().collect();
    let target_fans = input.target_sampler.sample(
        FieldRef {
            dim: 3,
            values: &flat,
        },
        control,
    )?;
    let fan = target_fans.shape();
    let per = fan.len() as f64;
    let fixed = |t: usize| input.fixed.is_some_and(|f| f[t]);

    // Coherence: the output's patches against the source.
    let mut nnf = input.nnf.clone();
    let step = EStep {
        space: PatchSpace {
            fan,
            target_fans: &target_fans.data,
            source_fans: input.source_fans,
            target_shape: &[],
            source_shape: &[],
            shape_dim: 0,
            source_allowed: input.allowed,
            exclude: None,
            source_penalty: &[],
            ring_weights: &[],
            target_ring_stats: &[],
            source_ring_stats: &[],
        },
        target_adjacency: input.target.rings(0),
        source_adjacency: input.source.rings(0),
        source_hierarchy: &input.source.hierarchy,
        level: 0,
        // Level 0 is searched through the hierarchy (whole-source draws only for a one-level source).
        whole_source_draws: input.source.hierarchy.level_count() == 1,
        randomized_rotations: false,
        fixed: input.fixed,
        seed: mix(input.seed, 0xF1DE, 1),
    };
    passes(&step, &mut nnf, control)?;
    let coherence = mean_over(&nnf, |t| !fixed(t), per);

    // The source against itself, nearby matches refused.
    let src = input.source.surface(0);
    let ns = src.vertex_count();
    let radius = input.target_sampler.radius();
    let pool: Vec<u32> = (0..ns as u32)
        .filter(|&s| input.allowed.is_none_or(|a| a[s as usize]))
        .collect();
    let mut rng = SplitMix64::new(mix(input.seed, 0xF1DE, 2));
    let mut self_nnf = Nnf {
        source: (0..ns)
            .map(|_| pool[rng.below(pool.len() as u64) as usize])
            .collect(),
        rotation: vec![0; ns],
        distance: vec![f32::INFINITY; ns],
    };
    let self_step = EStep {
        space: PatchSpace {
            fan,
            target_fans: input.source_fans,
            source_fans: input.source_fans,
            target_shape: &[],
            source_shape: &[],
            shape_dim: 0,
            source_allowed: input.allowed,
            exclude: Some(Exclusion {
                target: &src.positions,
                source: &src.positions,
                radius2: radius * radius,
            }),
            source_penalty: &[],
            ring_weights: &[],
            target_ring_stats: &[],
            source_ring_stats: &[],
        },
        target_adjacency: input.source.rings(0),
        source_adjacency: input.source.rings(0),
        source_hierarchy: &input.source.hierarchy,
        level: 0,
        // Level 0 is searched through the hierarchy (whole-source draws only for a one-level source).
        whole_source_draws: input.source.hierarchy.level_count() == 1,
        randomized_rotations: false,
        fixed: None,
        seed: mix(input.seed, 0xF1DE, 3),
    };
    passes(&self_step, &mut self_nnf, control)?;
    let source_self_match = mean_over(&self_nnf, |s| input.allowed.is_none_or(|a| a[s]), per);

    // Completeness: used source vertices, grown by R rings.
    let mut used = vec![false; ns];
    for (t, &s) in input.nnf.source.iter().enumerate() {
        if !fixed(t) {
            used[s as usize] = true;
        }
    }
    let (offsets, neighbours) = input.source.rings(0);
    for _ in 0..input.rings {
        let prev = used.clone();
        for v in 0..ns {
            if !prev[v] {
                let ring = &neighbours[offsets[v] as usize..offsets[v + 1] as usize];
                if ring.iter().any(|&n| prev[n as usize]) {
                    used[v] = true;
                }
            }
        }
    }
    let usable = pool.len().max(1);
    let covered = pool.iter().filter(|&&s| used[s as usize]).count();
    Ok(Fidelity {
        coherence,
        source_self_match,
        ratio: coherence / source_self_match,
        completeness: covered as f64 / usable as f64,
    })
}
