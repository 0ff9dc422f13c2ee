//! The E-step's histogram cost on the source's *finest* colours (`fine_histogram_cost`; ours,
//! after Kopf et al. 2007 §3.3's histogram matching, the remedy issue 14 names).
//!
//! Why: on the coarse levels a vertex's colour is the mean of its descendants', so a source's
//! black patches and its grey regions average into one cluster there, and a coarse field that
//! covers the grey and skips the black has the right coarse statistics but loses the black
//! patches once the finest level tells the two apart (README "meshmatch", "Where the two
//! failure modes are decided"). The cost here therefore sees every source vertex of every level
//! through the colours of the finest vertices it stands for:
//! - `D_s`: per channel, the 16-bin histogram of the finest colours under source vertex `s`
//!   (one-hot on the finest level, averaged over the children level by level, as the colours
//!   themselves are: [`MeshLevels::restrict`]);
//! - `H_t = mean_t D_{m(t)}`: the finest-colour histogram that the current field `m` implies
//!   for the target (the matches, not the vote, so no blur enters), against `H_s = mean_s D_s`,
//!   the level's own uniform cover;
//! - per bin the log ratio `r = ln((H_t + f) / (H_s + f))` (`f` = [`SHARE_FLOOR`]), shrunk by the
//!   dead band [`DEAD_BAND`] = ln 2 towards 0: a colour costs nothing while its share stays
//!   within 0.5-2× of the source's (issue 14's own target), over-represented colours cost,
//!   under-represented ones cost less than the rest (each channel is shifted so that its lowest
//!   bin costs 0, the same constant for every source vertex);
//! - a match of `s` costs `μ · (fan dimension) · Σ_ch Σ_b D_s(ch, b) · shrunk r(ch, b)`.
//!
//! A regular pattern's cover implies the source's histogram within the band (measured on the
//! three stripe files: the largest |r| over every level and iteration is 0.34-0.94, mostly on
//! the coarsest levels' small bins, against 1.3-1.6 on Spot → cat's lost patches), so its field
//! is barely touched. Region flips compare fields without this cost (`flips`): a flip is kept
//! for a better map, not a better histogram; with the cost in the comparison the `--round`
//! capsule's seed 1 keeps its mirror seam (×1.20).
//!
//! The same log ratio, unshrunk and at its largest ([`FineHistograms::deviation`]), decides
//! whether the coarsest level is restarted (`coarsest_restart_deviation`, module
//! `coarse_to_fine::restarts`).
//!
//! Constants (ours, none published): [`DEAD_BAND`] is the band, [`SHARE_FLOOR`] keeps
//! nearly empty bins from dominating, and `μ` (default 0.3 in plain transfers) is chosen from
//! the README's sweep.
//!
//! Written by hand: no crate does this.

use rayon::prelude::*;

use super::histogram::{ChannelBins, BINS};
use super::levels::MeshLevels;

/// Histogram entries per vertex: [`BINS`] per channel.
const DIM: usize = 3 * BINS;

/// The log-ratio band where a bin costs nothing: the issue's own target, every colour within
/// 0.5-2× of the source's share.
const DEAD_BAND: f32 = std::f32::consts::LN_2;

/// Added to both shares before their ratio, so that nearly empty bins do not dominate: 1 %.
const SHARE_FLOOR: f32 = 0.01;

/// The finest-colour histograms of every source vertex on every level, and the cost's strength.
pub(super) struct FineHistograms {
    /// `μ` (`fine_histogram_cost`).
    pub(super) strength: f32,
    /// Per level, `DIM` shares per vertex (each channel's `BINS` sum to 1).
    per_level: Vec<Vec<f32>>,
    /// Per level, the mean over its vertices (`H_s`).
    level_mean: Vec<[f32; DIM]>,
}

impl FineHistograms {
    /// From the finest level's colours (`[vertex][rgb]` flattened), binned over their range,
    /// for the strength `strength`.
    pub(super) fn build(levels: &MeshLevels, finest: &[f32], strength: f32) -> Self {
        let bins = ChannelBins::over(finest.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        let mut level0 = vec![0.0f32; finest.len() / 3 * DIM];
        level0
            .par_chunks_mut(DIM)
            .zip(finest.par_chunks_exact(3))
            .for_each(|(h, c)| {
                for (k, b) in bins.bins([c[0], c[1], c[2]]).into_iter().enumerate() {
                    h[k * BINS + b] = 1.0;
                }
            });
        let mut per_level = vec![level0];
        for l in 1..levels.len() {
            let coarse = levels.restrict(l, DIM, &per_level[l - 1]);
            per_level.push(coarse);
        }
        Self::from_levels(per_level, strength)
    }

    /// From the histograms of every level (`DIM` shares per vertex).
    fn from_levels(per_level: Vec<Vec<f32>>, strength: f32) -> Self {
        let level_mean = per_level.iter().map(|h| mean_histogram(h, None)).collect();
        FineHistograms {
            strength,
            per_level,
            level_mean,
        }
    }

    /// The cost per source vertex of `level` for the field `matches` (target → source), in
    /// units of the patch distance (times `fan_len`, module docs).
    pub(super) fn cost(&self, level: usize, matches: &[u32], fan_len: f32) -> Vec<f32> {
        let hist = &self.per_level[level];
        if matches.is_empty() {
            return vec![0.0; hist.len() / DIM];
        }
        let implied = mean_histogram(hist, Some(matches));
        let mean = &self.level_mean[level];
        // Per bin, the log ratio of the implied share to the source's beyond the dead band.
        let mut excess: [f32; DIM] = std::array::from_fn(|k| {
            let r = ((implied[k] + SHARE_FLOOR) / (mean[k] + SHARE_FLOOR)).ln();
            r.signum() * (r.abs() - DEAD_BAND).max(0.0)
        });
        // Shift each channel to non-negative costs (the same constant for every source vertex).
        for ch in excess.chunks_exact_mut(BINS) {
            let lo = ch.iter().copied().fold(0.0f32, f32::min);
            ch.iter_mut()
                .for_each(|e| *e = self.strength * fan_len * (*e - lo));
        }
        hist.par_chunks_exact(DIM)
            .map(|h| h.iter().zip(&excess).map(|(d, e)| d * e).sum())
            .collect()
    }

    /// The field's largest deviation on `level`: over every channel and bin, the largest
    /// `|ln((H_t + f) / (H_s + f))|` of the share the matches imply for the target against the
    /// level's own (the unshrunk log ratio of [`Self::cost`]). 0 for an empty field.
    pub(super) fn deviation(&self, level: usize, matches: &[u32]) -> f32 {
        if matches.is_empty() {
            return 0.0;
        }
        let implied = mean_histogram(&self.per_level[level], Some(matches));
        implied
            .iter()
            .zip(&self.level_mean[level])
            .map(|(t, s)| ((t + SHARE_FLOOR) / (s + SHARE_FLOOR)).ln().abs())
            .fold(0.0, f32::max)
    }
}

/// The mean of the histograms `hist` (`DIM` per vertex) over all vertices, or over the vertices
/// `picks` lists (with repeats).
fn mean_histogram(hist: &[f32], picks: Option<&[u32]>) -> [f32; DIM] {
    let mut sum = [0.0f64; DIM];
    let mut add = |h: &[f32]| {
        for (s, x) in sum.iter_mut().zip(h) {
            *s += f64::from(*x);
        }
    };
    let n = match picks {
        Some(p) => {
            for &s in p {
                add(&hist[s as usize * DIM..(s as usize + 1) * DIM]);
            }
            p.len()
        }
        None => {
            hist.chunks_exact(DIM).for_each(&mut add);
            hist.len() / DIM
        }
    };
    let inv = 1.0 / n.max(1) as f64;
    std::array::from_fn(|k| (sum[k] * inv) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One level of four source vertices: two pure black, one pure white, one half and half
    /// (a coarse vertex over both), channel 0 only (black in bin 0, white in bin 15).
    fn four_vertices() -> FineHistograms {
        let mut h = vec![0.0f32; 4 * DIM];
        h[0] = 1.0;
        h[DIM] = 1.0;
        h[2 * DIM + BINS - 1] = 1.0;
        h[3 * DIM] = 0.5;
        h[3 * DIM + BINS - 1] = 0.5;
        FineHistograms::from_levels(vec![h], 1.0)
    }

    /// A cover within 0.5-2× of the source's shares costs nothing; one that skips the black
    /// makes the white vertices cost and the black ones not, the mixed one half as much.
    #[test]
    fn only_covers_outside_the_band_cost_and_the_missing_colour_is_cheapest() {
        let fine = four_vertices();
        // Source: black 5/8, white 3/8. Every vertex once: the source's own histogram.
        assert!(fine.cost(0, &[0, 1, 2, 3], 1.0).iter().all(|&c| c == 0.0));
        // Black 4/8, white 4/8: within the band.
        assert!(fine.cost(0, &[0, 2, 3, 3], 1.0).iter().all(|&c| c == 0.0));
        // White only: black far under its share, white over twice its.
        let cost = fine.cost(0, &[2, 2, 2, 2], 1.0);
        assert_eq!((cost[0], cost[1]), (0.0, 0.0), "{cost:?}");
        assert!(cost[2] > 1.0, "{cost:?}");
        assert!((cost[3] - 0.5 * cost[2]).abs() < 1e-5, "{cost:?}");
        // The strength and the fan dimension scale it.
        let half = FineHistograms {
            strength: 0.5,
            ..four_vertices()
        };
        let scaled = half.cost(0, &[2, 2, 2, 2], 4.0);
        assert!((scaled[2] - 2.0 * cost[2]).abs() < 1e-4, "{scaled:?}");
    }

    /// The level mean is each vertex's histogram averaged, and an empty field costs nothing.
    #[test]
    fn the_level_mean_is_the_uniform_cover() {
        let fine = four_vertices();
        assert!((fine.level_mean[0][0] - 0.625).abs() < 1e-6);
        assert!((fine.level_mean[0][BINS - 1] - 0.375).abs() < 1e-6);
        assert!(fine.cost(0, &[], 1.0).iter().all(|&c| c == 0.0));
    }

    /// The deviation is the largest unshrunk log ratio: 0 for the source's own cover; a white
    /// cover's is the black bin's (0 against 5/8), not the white one's (1 against 3/8).
    #[test]
    fn the_deviation_is_the_largest_log_ratio() {
        let fine = four_vertices();
        assert!(fine.deviation(0, &[0, 1, 2, 3]) < 1e-6);
        let white = fine.deviation(0, &[2, 2, 2, 2]);
        let expected = ((0.625f32 + 0.01) / 0.01).ln().max((1.01f32 / 0.385).ln());
        assert!((white - expected).abs() < 1e-4, "{white} {expected}");
        assert_eq!(fine.deviation(0, &[]), 0.0);
    }
}
