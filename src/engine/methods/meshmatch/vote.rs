//! The M-step of MeshMatch (Chen et al. 2012, §4.2 "Texture Reconstruction", Figure 5): every
//! target vertex `q` takes the Gaussian-weighted average of the colours that the matches of the
//! target vertices `p` around it vote for it.
//!
//! `q` lies at chart position `U_p(q) = (r, θ)` in `p`'s exponential map ([`exponential_map`],
//! radius = the fan radius). `p`'s match `(s, k)` maps that position to angle `θ + k·2π/A` at
//! radius `r` around `s`; the source colour there is read from `s`'s geodesic fan (bilinear in
//! ring and spoke, with `s`'s own colour as ring 0 at the centre). The vote's weight falls off as
//! `exp(−r² / 2σ_v²)` with the distance from `p` (the paper's Gaussian). Votes are gathered per
//! `q` from a transposed chart table built once per level, so voting is parallel over `q` and
//! deterministic.
//!
//! [`nearest_neighbour_colors`] is the paper's optional last step: at the finest level copy the
//! colour of the matched source vertex instead of voting, for crisp output.

use rayon::prelude::*;

use crate::engine::geometry::expmap::ExpMap;
use crate::engine::mesh::csr::group_by_key;

use super::histogram::HistogramBias;
use super::matcher::Nnf;

/// For every target vertex `q`: the vertices `p` whose chart contains it and `q`'s polar
/// position `(r, θ)` in that chart. CSR by `q`.
#[derive(Clone, Debug, Default)]
pub struct VoteStencil {
    offsets: Vec<u32>,
    voter: Vec<u32>,
    polar: Vec<[f32; 2]>,
}

impl VoteStencil {
    /// Builds the stencil from charts (`maps`, at least `radius` in size) of the target level:
    /// every chart entry within `radius` of its centre.
    pub fn build(maps: &ExpMap, radius: f32) -> Self {
        let n = maps.offsets.len() - 1;
        let r2 = radius * radius;
        let inside = |xy: &[f32; 2]| xy[0] * xy[0] + xy[1] * xy[1] <= r2;
        let entries = (0..n).flat_map(|p| {
            let (verts, coords) = maps.chart(p);
            verts
                .iter()
                .zip(coords)
                .filter(|(_, xy)| inside(xy))
                .map(move |(&q, xy)| (q, (p as u32, *xy)))
        });
        let (offsets, entries) = group_by_key(n, entries);
        Self {
            offsets,
            voter: entries.iter().map(|e| e.0).collect(),
            polar: entries
                .iter()
                .map(|e| {
                    let (r, t) = ExpMap::polar(e.1);
                    [r, t]
                })
                .collect(),
        }
    }

    /// Number of (voter, voted) entries.
    pub fn len(&self) -> usize {
        self.voter.len()
    }

    /// Whether the stencil is empty.
    pub fn is_empty(&self) -> bool {
        self.voter.is_empty()
    }
}

/// The source colours a vote reads: fans in colour units and the centre colours.
#[derive(Clone, Copy)]
pub struct SourcePatches<'a> {
    /// Rings `R`.
    pub rings: usize,
    /// Spokes `A`.
    pub spokes: usize,
    /// Outer fan radius, world units.
    pub radius: f32,
    /// `[vertex][ring][spoke][rgb]`, linear colour units.
    pub fans: &'a [f32],
    /// Colour of each source vertex (ring 0).
    pub centers: &'a [[f32; 3]],
}

impl SourcePatches<'_> {
    /// Colour at polar `(r, θ)` (source frame) around source vertex `s`.
    fn color(&self, s: usize, r: f32, theta: f32) -> [f32; 3] {
        let (rings, spokes) = (self.rings, self.spokes);
        let fan = &self.fans[s * rings * spokes * 3..(s + 1) * rings * spokes * 3];
        let u = (r / (self.radius / rings as f32)).clamp(0.0, rings as f32);
        let i0 = (u.floor() as usize).min(rings);
        let i1 = (i0 + 1).min(rings);
        let fu = u - i0 as f32;
        let w = (theta / std::f32::consts::TAU * spokes as f32).rem_euclid(spokes as f32);
        let j0 = (w.floor() as usize) % spokes;
        let j1 = (j0 + 1) % spokes;
        let fw = w - w.floor();
        let at = |i: usize, j: usize| -> [f32; 3] {
            if i == 0 {
                self.centers[s]
            } else {
                let o = ((i - 1) * spokes + j) * 3;
                [fan[o], fan[o + 1], fan[o + 2]]
            }
        };
        let ring_value = |i: usize| -> [f32; 3] {
            let (a, b) = (at(i, j0), at(i, j1));
            std::array::from_fn(|c| a[c] * (1.0 - fw) + b[c] * fw)
        };
        let (a, b) = (ring_value(i0), ring_value(i1));
        std::array::from_fn(|c| a[c] * (1.0 - fu) + b[c] * fu)
    }
}

/// Votes target colours from the field (see the module docs). `sigma` is the Gaussian's
/// standard deviation in world units. Vertices in `keep` (by-example mode) keep `previous`.
/// With `bias`, every vote's weight is also multiplied by its colour's histogram factor
/// ([`HistogramBias::factor`]).
pub fn vote(
    stencil: &VoteStencil,
    nnf: &Nnf,
    source: &SourcePatches<'_>,
    sigma: f32,
    keep: Option<(&[bool], &[[f32; 3]])>,
    bias: Option<&HistogramBias>,
) -> Vec<[f32; 3]> {
    let n = stencil.offsets.len() - 1;
    let inv = 1.0 / (2.0 * sigma * sigma);
    let step = std::f32::consts::TAU / source.spokes as f32;
    (0..n)
        .into_par_iter()
        .map(|q| {
            if let Some((mask, previous)) = keep {
                if mask[q] {
                    return previous[q];
                }
            }
            let (a, b) = (stencil.offsets[q] as usize, stencil.offsets[q + 1] as usize);
            let mut sum = [0.0f32; 3];
            let mut weight = 0.0f32;
            for e in a..b {
                let p = stencil.voter[e] as usize;
                let s = nnf.source[p] as usize;
                let [r, theta] = stencil.polar[e];
                let c = source.color(s, r, theta + nnf.rotation[p] as f32 * step);
                let w = (-r * r * inv).exp() * bias.map_or(1.0, |b| b.factor(c));
                for k in 0..3 {
                    sum[k] += w * c[k];
                }
                weight += w;
            }
            if weight > 0.0 {
                sum.map(|x| x / weight)
            } else {
                source.centers[nnf.source[q] as usize]
            }
        })
        .collect()
}

/// The paper's final nearest-neighbour reconstruction: the colour of each match.
pub fn nearest_neighbour_colors(
    nnf: &Nnf,
    source_colors: &[[f32; 3]],
    keep: Option<(&[bool], &[[f32; 3]])>,
) -> Vec<[f32; 3]> {
    nnf.source
        .iter()
        .enumerate()
        .map(|(q, &s)| match keep {
            Some((mask, previous)) if mask[q] => previous[q],
            _ => source_colors[s as usize],
        })
        .collect()
}
