//! Non-parametric synthesis: image analogies on the surface samples (Mertens et al. 2006, §5.1,
//! after Hertzmann et al. 2001 "Image Analogies" with Ashikhmin's coherence, on a surface as
//! Turk 2001 does). The guidance is the unfiltered channel (A on the source, B on the target),
//! the colour the filtered one (A′ on the source, B′ synthesised on the target).
//!
//! **Neighbourhoods.** Per sample a geodesic fan ([`crate::engine::geometry::fans`], MeshMatch's)
//! of `(neighbourhood − 1) / 2` rings × [`SPOKES`] spokes, outer radius `(neighbourhood − 1)/2`
//! mean edge lengths of the level's own sample mesh (so, like the paper's per-sample 5×5 windows,
//! a neighbourhood spans the same number of samples on source and target whatever their sizes),
//! plus the centre sample. Every fan sample carries the colour and the guidance. Fans are
//! oriented by the tangent frames from the `up` axis, on source and target alike, and compared
//! at rotation 0: the up axis plays the part of Turk's orientation field (weathering runs with
//! gravity), so the search needs no rotation. Where a normal is parallel to `up` the frame falls
//! back to an edge reference and the orientation is arbitrary there.
//!
//! **Distance.** `D(t, s) = (1 − w)·‖colour(t) − colour(s)‖²/(3σ²) + w·‖guidance(t) − guidance(s)‖²/d`
//! summed over the fan samples and the centre, with `w = feature_weight`, σ² the source colour's
//! mean channel variance and d the guidance dimension (the guidance has unit variance per axis on
//! the source): each block is normalised for dimension and variance, so `w = 0.5` is the paper's
//! "equal weights" (§5.1 text) and `w = 0.8` its Fig. 11. retex's default is 0.8, the figure's
//! value, kept after the README's sweep (0.3 / 0.5 / 0.8 / 1.0 over two procedural cases and
//! three seeds): it follows the geometry better than 0.5 in every run at a moderate loss of
//! coherent patch size, and 1.0 gains little more placement for a larger loss.
//!
//! **Search** (replaces the paper's exhaustive ANN, so that it runs in minutes). Per level, from
//! the coarsest: the target's colour starts as the coarser level's result prolongated
//! (barycentric) onto this level, and each target sample's match as the child of its parent's
//! match whose guidance value is closest; on the coarsest level the match is the source sample of
//! nearest guidance *value* ([`super::guidance_index`]: "initialised by the guidance alone").
//! Then `passes` passes of: (1) every target sample's candidates are evaluated: the *coherent*
//! set (Ashikhmin): for every target neighbour r, r's match and its source 1-ring (on an
//! irregular sampling there is no exact "shift by q − r", so the samples next to where r copies
//! from stand for it); the *approximate* set: the current match, the guidance-nearest source
//! sample, and MeshMatch's random search (a random descendant of the current match's ancestor j
//! levels up, for every coarser level, and ⌈log₂ n⌉ uniform draws on the coarsest); (2) the
//! coherent best wins unless the approximate best is better by the factor of image analogies,
//! `D_coh ≤ D_app·(1 + 2^(l−L)·κ)` with `L` the finest level (so `2^(−level)` with retex's level
//! 0 the finest); (3) every target sample copies its match's colour. The samples are visited
//! in MeshMatch's order (breadth-first from a start that moves every pass, cut into blocks of
//! [`BLOCK`] samples searched in parallel, sequential inside a block): inside a block a sample's
//! coherent candidates follow its neighbours' *new* matches, as in Turk's sequential order; the
//! colours (hence the fans) are those of the pass's start, so the whole neighbourhood (not only
//! its causal half) is known, as in Wei & Levoy's multi-pass variant. Measured on the weathering
//! case, reading only the pass's start (Jacobi) gave 0.52-0.59 coherent edges, too few for κ to
//! matter: neighbours moving at once break each other's coherence. The coarser level enters through the start, not through
//! a second (coarser-level) neighbourhood in the distance as in Hertzmann's paper: fewer floats
//! per comparison; the prolongated colour carries the coarse structure into the fans.
//!
//! Masked source samples (weight 0; on coarser levels where the Gaussian-smoothed weight is
//! below ½) are never matched. Deterministic for a seed, with any thread count.

use rayon::prelude::*;
use serde::Serialize;

use super::guidance_index::GuidanceIndex;
use super::parametric::SynthesisInput;
use super::pyramid::SurfacePyramid;
use crate::engine::control::Control;
use crate::engine::geometry::expmap::{local_frames, FrameParams, RadiusUnit};
use crate::engine::geometry::fans::{
    geodesic_fans, FanError, FanParams, FanSampler, FanShape, FieldRef,
};
use crate::engine::mesh::csr::vertex_neighbours;
use crate::engine::methods::meshmatch::matcher::{bfs_order, components, BLOCK};
use crate::engine::methods::MethodError;
use crate::engine::rng::{mix, SplitMix64};

/// Spokes per fan ring (a 5×5 window's outer ring has 16 pixels, its inner 8; 8 spokes on both
/// rings keeps the comparison at 16 samples + centre, close to the window's 25).
pub const SPOKES: usize = 8;
/// Most vertices per exponential-map chart (MeshMatch's bound).
const MAX_CHART_VERTICES: usize = 256;

/// Settings of [`synthesize_nonparametric`].
#[derive(Clone, Debug, PartialEq)]
pub struct NonparametricSettings {
    /// Neighbourhood size in samples across (odd, 3..=15; paper 5).
    pub neighbourhood: usize,
    /// Ashikhmin coherence κ (paper 1).
    pub coherence: f32,
    /// Weight `w` of the guidance against the colour (see the module docs).
    pub feature_weight: f32,
    /// Search passes per level.
    pub passes: usize,
    /// Up axis (unit) orienting the fans.
    pub up: [f32; 3],
    /// Seed of the random search.
    pub seed: u64,
}

/// One level of [`NonparametricReport`].
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct LevelReport {
    /// Pyramid level (0 = finest).
    pub level: usize,
    /// Target samples.
    pub target_samples: usize,
    /// Source samples that may be matched.
    pub source_candidates: usize,
    /// Share of target samples whose last pass chose the coherent candidate.
    pub coherent_choice: f32,
    /// Mean neighbourhood distance of the final matches.
    pub mean_distance: f32,
}

/// What [`synthesize_nonparametric`] reports.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct NonparametricReport {
    /// Fan rings.
    pub rings: usize,
    /// Fan spokes.
    pub spokes: usize,
    /// Guidance weight used.
    pub feature_weight: f32,
    /// Coherence κ used.
    pub coherence: f32,
    /// Search passes per level.
    pub passes: usize,
    /// Per level, coarsest first.
    pub levels: Vec<LevelReport>,
    /// Share of level-0 target edges whose ends copy the same or neighbouring source samples.
    pub coherent_edges: f32,
    /// Mean size (samples) of the coherent patch a level-0 target sample lies in (patches:
    /// components of the coherent edges).
    pub mean_patch_samples: f32,
}

/// The target's linear RGB per level-0 sample, its matched source sample, the report.
pub type NonparametricOutput = (Vec<[f32; 3]>, Vec<u32>, NonparametricReport);

fn fan_error(e: FanError) -> MethodError {
    match e {
        FanError::Cancelled => MethodError::Cancelled,
        e => MethodError::UnusableInput {
            field: None,
            kind: "unusable-mesh",
            message: format!("non-parametric synthesis fans: {e}"),
        },
    }
}

type Adjacency = (Vec<u32>, Vec<u32>);
/// One level's source colour, source guidance and target guidance.
type LevelFields<'a> = (&'a [[f32; 3]], &'a [[f32; 3]], &'a [[f32; 3]]);

fn ring(adj: &Adjacency, v: usize) -> &[u32] {
    &adj.1[adj.0[v] as usize..adj.0[v + 1] as usize]
}

/// Weighted per-sample features `[colour·a_c, guidance·a_g]` (see the module docs).
struct Scaling {
    colour: f32,
    guidance: f32,
    dims: usize,
}

impl Scaling {
    fn dim(&self) -> usize {
        3 + self.dims
    }

    fn field(&self, colour: &[[f32; 3]], guidance: &[[f32; 3]]) -> Vec<f32> {
        let mut out = Vec::with_capacity(colour.len() * self.dim());
        for (c, g) in colour.iter().zip(guidance) {
            out.extend(c.iter().map(|x| x * self.colour));
            out.extend(g[..self.dims].iter().map(|x| x * self.guidance));
        }
        out
    }
}

/// Everything the passes of one level read.
struct Level<'a> {
    index: usize,
    shape: FanShape,
    dim: usize,
    src_fans: Vec<f32>,
    src_centre: Vec<f32>,
    allowed: Vec<bool>,
    src_adj: Adjacency,
    tgt_adj: Adjacency,
    nearest: Vec<u32>,
    pyramid: &'a SurfacePyramid,
    top: usize,
    factor: f32,
}

impl Level<'_> {
    /// `D(t, s)`, or a partial sum ≥ `bound` once it passes `bound`.
    fn distance(&self, tf: &[f32], tc: &[f32], s: usize, bound: f32) -> f32 {
        let sc = &self.src_centre[s * self.dim..(s + 1) * self.dim];
        let c: f32 = tc.iter().zip(sc).map(|(a, b)| (a - b) * (a - b)).sum();
        if c >= bound {
            return c;
        }
        let n = self.shape.len();
        c + self
            .shape
            .distance_below(tf, &self.src_fans[s * n..(s + 1) * n], 0, bound - c)
    }

    /// One pass for target sample `t`: (match, distance, chose the coherent candidate).
    fn search(
        &self,
        t: usize,
        (tf, tc): (&[f32], &[f32]),
        m: &impl Fn(u32) -> u32,
        seed: u64,
    ) -> (u32, f32, bool) {
        let mut rng = SplitMix64::new(mix(seed, 0x5EA2, t as u64));
        let mut seen: Vec<u32> = Vec::with_capacity(64);
        let mut coh = (u32::MAX, f32::INFINITY);
        for &r in ring(&self.tgt_adj, t) {
            let sr = m(r);
            for c in std::iter::once(sr).chain(ring(&self.src_adj, sr as usize).iter().copied()) {
                if seen.contains(&c) || !self.allowed[c as usize] {
                    continue;
                }
                seen.push(c);
                let d = self.distance(tf, tc, c as usize, coh.1);
                if d < coh.1 {
                    coh = (c, d);
                }
            }
        }
        let mut app = (u32::MAX, f32::INFINITY);
        let mut consider = |c: u32, app: &mut (u32, f32)| {
            if seen.contains(&c) || !self.allowed[c as usize] {
                return;
            }
            seen.push(c);
            let d = self.distance(tf, tc, c as usize, app.1.min(coh.1));
            if d < app.1 && d < coh.1 {
                *app = (c, d);
            }
        };
        let cur = m(t as u32);
        consider(cur, &mut app);
        consider(self.nearest[t], &mut app);
        let h = self.pyramid.hierarchy();
        let level = self.index;
        for j in 1..=(self.top - level) {
            let a = h.ancestor(level, cur, j);
            let c = h.random_descendant(level + j, a, j, &mut rng);
            consider(c, &mut app);
        }
        if level == self.top {
            let n = self.allowed.len() as u64;
            for _ in 0..(64 - n.leading_zeros()).max(1) {
                consider(rng.below(n) as u32, &mut app);
            }
        }
        if coh.0 != u32::MAX && (app.0 == u32::MAX || coh.1 <= app.1 * self.factor) {
            (coh.0, coh.1, true)
        } else if app.0 != u32::MAX {
            (app.0, app.1, false)
        } else {
            (cur, f32::INFINITY, false)
        }
    }
}

/// Synthesises the target's colour by image analogies (see the module docs).
///
/// # Errors
/// [`MethodError::UnusableInput`] when the mask leaves no source sample on a level or the fans
/// cannot be built; [`MethodError::Cancelled`].
pub fn synthesize_nonparametric(
    input: &SynthesisInput<'_>,
    settings: &NonparametricSettings,
    control: &Control,
) -> Result<NonparametricOutput, MethodError> {
    let (src, tgt) = (input.source, input.target);
    let levels = src.level_count().min(tgt.level_count());
    let dims = input.guidance_dims.clamp(1, 3);
    let w = settings.feature_weight.clamp(0.0, 1.0);
    let variance = colour_variance(input.source_color, input.source_weight, src.area(0));
    let scaling = Scaling {
        colour: ((1.0 - w) / (3.0 * variance.max(1e-8))).sqrt(),
        guidance: (w / dims as f32).sqrt(),
        dims,
    };
    let src_col = src.gaussian_levels(input.source_color, levels);
    let src_gui = src.gaussian_levels(input.source_guidance, levels);
    let tgt_gui = tgt.gaussian_levels(input.target_guidance, levels);
    let weight: Vec<[f32; 1]> = input.source_weight.iter().map(|w| [*w]).collect();
    let src_w = src.gaussian_levels(&weight, levels);
    let rings = (settings.neighbourhood.max(3) - 1) / 2;
    let mut report = NonparametricReport {
        rings,
        spokes: SPOKES,
        feature_weight: w,
        coherence: settings.coherence,
        passes: settings.passes,
        ..Default::default()
    };
    let mut colour: Vec<[f32; 3]> = Vec::new();
    let mut m: Vec<u32> = Vec::new();
    for level in (0..levels).rev() {
        let allowed: Vec<bool> = src_w[level]
            .iter()
            .map(|x| if level == 0 { x[0] > 0.0 } else { x[0] >= 0.5 })
            .collect();
        let lv = prepare(
            src,
            tgt,
            level,
            allowed,
            (&src_col[level], &src_gui[level], &tgt_gui[level]),
            &scaling,
            settings,
            control,
        )?;
        // Start: guidance alone on the coarsest level, else from the coarser level.
        if level == levels - 1 {
            m = lv.nearest.clone();
        } else {
            colour = tgt.hierarchy().prolongate(level + 1, &colour);
            m = refine_matches(&lv, &m, tgt.parent(level), &src_gui[level], &tgt_gui[level]);
        }
        if level == levels - 1 {
            colour = m.iter().map(|&s| src_col[level][s as usize]).collect();
        }
        let sampler = {
            let frames = frames_of(tgt.mesh(level), settings.up);
            FanSampler::new(tgt.mesh(level), &frames, &fan_params(rings), control)
                .map_err(fan_error)?
        };
        let mut last = vec![(0u32, 0.0f32, false); m.len()];
        let (component, mut starts) =
            components((lv.tgt_adj.0.as_slice(), lv.tgt_adj.1.as_slice()), m.len());
        for pass in 0..settings.passes {
            let field = scaling.field(&colour, &tgt_gui[level]);
            let fans = sampler
                .sample(
                    FieldRef {
                        dim: lv.dim,
                        values: &field,
                    },
                    control,
                )
                .map_err(fan_error)?;
            let stage = control.stage("nonparametric_search", m.len() as u64)?;
            let seed = mix(settings.seed, level as u64, pass as u64);
            let order = bfs_order(
                (lv.tgt_adj.0.as_slice(), lv.tgt_adj.1.as_slice()),
                &component,
                &mut starts,
            );
            last = gauss_seidel(&lv, &order, &fans.data, &field, &m, seed);
            m = last.iter().map(|x| x.0).collect();
            colour = m.iter().map(|&s| src_col[level][s as usize]).collect();
            stage.tick(m.len() as u64)?;
        }
        let finite: Vec<f64> = last
            .iter()
            .filter(|x| x.1.is_finite())
            .map(|x| f64::from(x.1))
            .collect();
        report.levels.push(LevelReport {
            level,
            target_samples: m.len(),
            source_candidates: lv.allowed.iter().filter(|a| **a).count(),
            coherent_choice: last.iter().filter(|x| x.2).count() as f32 / last.len().max(1) as f32,
            mean_distance: (finite.iter().sum::<f64>() / finite.len().max(1) as f64) as f32,
        });
        if level == 0 {
            let (edges, patch) = coherence_stats(&lv.tgt_adj, &lv.src_adj, &m);
            report.coherent_edges = edges;
            report.mean_patch_samples = patch;
        }
    }
    Ok((colour, m, report))
}

/// One pass in `order` (MeshMatch's propagation order): blocks of [`BLOCK`] samples in
/// parallel, in a block sequentially, a sample seeing the block's earlier updates (so a
/// coherent candidate follows its neighbour's *new* match, as in a sequential scan) and the
/// pass's start outside the block. Returns (match, distance, coherent) per target sample.
fn gauss_seidel(
    lv: &Level<'_>,
    order: &[u32],
    fans: &[f32],
    field: &[f32],
    m: &[u32],
    seed: u64,
) -> Vec<(u32, f32, bool)> {
    let n = order.len();
    let mut pos = vec![0u32; n];
    for (i, &v) in order.iter().enumerate() {
        pos[v as usize] = i as u32;
    }
    let mut perm: Vec<(u32, f32, bool)> = order
        .iter()
        .map(|&v| (m[v as usize], f32::INFINITY, false))
        .collect();
    let (fl, dim) = (lv.shape.len(), lv.dim);
    perm.par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(b, block)| {
            let base = b * BLOCK;
            for i in 0..block.len() {
                let t = order[base + i] as usize;
                let get = |r: u32| {
                    let p = pos[r as usize] as usize;
                    if p >= base && p < base + block.len() {
                        block[p - base].0
                    } else {
                        m[r as usize]
                    }
                };
                let x = (&fans[t * fl..(t + 1) * fl], &field[t * dim..(t + 1) * dim]);
                let found = lv.search(t, x, &get, seed);
                block[i] = found;
            }
        });
    let mut out = vec![(0u32, 0.0f32, false); n];
    for (i, &v) in order.iter().enumerate() {
        out[v as usize] = perm[i];
    }
    out
}

fn fan_params(rings: usize) -> FanParams {
    FanParams {
        rings,
        spokes: SPOKES,
        radius: rings as f32,
        radius_unit: RadiusUnit::MeanEdge,
        max_chart_vertices: MAX_CHART_VERTICES,
        ..Default::default()
    }
}

fn frames_of(
    mesh: &crate::engine::mesh::Surface,
    up: [f32; 3],
) -> crate::engine::geometry::expmap::LocalFrames {
    local_frames(
        mesh,
        &FrameParams {
            up: Some(up),
            ..Default::default()
        },
    )
}

/// Source fans and centres, adjacency, the guidance-nearest candidates of one level.
#[allow(clippy::too_many_arguments)]
fn prepare<'a>(
    src: &'a SurfacePyramid,
    tgt: &SurfacePyramid,
    level: usize,
    allowed: Vec<bool>,
    (src_col, src_gui, tgt_gui): LevelFields<'_>,
    scaling: &Scaling,
    settings: &NonparametricSettings,
    control: &Control,
) -> Result<Level<'a>, MethodError> {
    control.stage("nonparametric_fans", 0)?;
    let index = GuidanceIndex::build(src_gui, |i| allowed[i]).ok_or_else(|| {
        MethodError::UnusableInput {
            field: Some("params.mask".into()),
            kind: "mask-removes-everything",
            message: format!("the mask leaves no source sample on pyramid level {level}"),
        }
    })?;
    let nearest: Vec<u32> = tgt_gui.par_iter().map(|g| index.nearest(*g)).collect();
    drop(index);
    let rings = (settings.neighbourhood.max(3) - 1) / 2;
    let mesh = src.mesh(level);
    let src_centre = scaling.field(src_col, src_gui);
    let src_fans = geodesic_fans(
        mesh,
        &frames_of(mesh, settings.up),
        FieldRef {
            dim: scaling.dim(),
            values: &src_centre,
        },
        &fan_params(rings),
        control,
    )
    .map_err(fan_error)?;
    let top = src.hierarchy().level_count() - 1;
    Ok(Level {
        index: level,
        shape: src_fans.shape(),
        dim: scaling.dim(),
        src_fans: src_fans.data,
        src_centre,
        allowed,
        src_adj: vertex_neighbours(mesh),
        tgt_adj: vertex_neighbours(tgt.mesh(level)),
        nearest,
        pyramid: src,
        top,
        factor: 1.0 + settings.coherence * 0.5f32.powi(level as i32),
    })
}

/// Each target sample's start on a finer level: among the children of its parent's match, the
/// allowed one of closest guidance value (the guidance-nearest sample when none is allowed).
fn refine_matches(
    lv: &Level<'_>,
    coarse: &[u32],
    tgt_parent: &[u32],
    src_gui: &[[f32; 3]],
    tgt_gui: &[[f32; 3]],
) -> Vec<u32> {
    let h = lv.pyramid.hierarchy();
    (0..tgt_gui.len())
        .into_par_iter()
        .map(|t| {
            let s = coarse[tgt_parent[t] as usize];
            let d = |c: u32| {
                (0..3)
                    .map(|k| (src_gui[c as usize][k] - tgt_gui[t][k]).powi(2))
                    .sum::<f32>()
            };
            h.descendants(lv.index + 1, s, 1)
                .iter()
                .copied()
                .filter(|&c| lv.allowed[c as usize])
                .min_by(|&a, &b| d(a).total_cmp(&d(b)).then(a.cmp(&b)))
                .unwrap_or(lv.nearest[t])
        })
        .collect()
}

/// The source's mean per-channel colour variance over the training samples (area × weight).
fn colour_variance(colour: &[[f32; 3]], weight: &[f32], area: &[f32]) -> f32 {
    let mut sum = [0.0f64; 3];
    let mut sq = [0.0f64; 3];
    let mut total = 0.0f64;
    for ((c, w), a) in colour.iter().zip(weight).zip(area) {
        let x = f64::from(w * a);
        total += x;
        for k in 0..3 {
            sum[k] += x * f64::from(c[k]);
            sq[k] += x * f64::from(c[k]) * f64::from(c[k]);
        }
    }
    if total <= 0.0 {
        return 0.0;
    }
    let v: f64 = (0..3)
        .map(|k| (sq[k] / total - (sum[k] / total).powi(2)).max(0.0))
        .sum();
    (v / 3.0) as f32
}

/// Share of coherent target edges (both ends copy the same or adjacent source samples) and the
/// mean size of the coherent patch a sample lies in (components of those edges).
pub fn coherence_stats(tgt: &Adjacency, src: &Adjacency, m: &[u32]) -> (f32, f32) {
    let n = m.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    let (mut edges, mut coherent) = (0usize, 0usize);
    for t in 0..n {
        for &r in ring(tgt, t) {
            if (r as usize) <= t {
                continue;
            }
            edges += 1;
            let (a, b) = (m[t], m[r as usize]);
            if a == b || ring(src, a as usize).contains(&b) {
                coherent += 1;
                let (x, y) = (find(&mut parent, t as u32), find(&mut parent, r));
                if x != y {
                    parent[x.max(y) as usize] = x.min(y);
                }
            }
        }
    }
    let mut size = vec![0u64; n];
    for t in 0..n {
        let r = find(&mut parent, t as u32);
        size[r as usize] += 1;
    }
    let weighted: f64 = size.iter().map(|s| (*s as f64) * (*s as f64)).sum();
    (
        coherent as f32 / edges.max(1) as f32,
        (weighted / n.max(1) as f64) as f32,
    )
}
