//! Histogram matching in MeshMatch's vote (Kopf, Fu, Cohen-Or, Deussen, Lischinski & Wong,
//! *Solid Texture Synthesis from 2D Exemplars*, SIGGRAPH 2007, §3.3), the remedy issue 14 names
//! for dark features eroding in the vote (Chen et al. 2012 §4.2's M-step averages every vote).
//!
//! Per colour channel the source's colours and the target's current colours are binned into
//! [`BINS`] bins over the source's range. A vote for colour `c` is down-weighted by how much its
//! bins are over-represented in the target: `w' = w / (1 + λ Σ_ch max(0, H_t(ch, b) − H_s(ch, b))
//! · BINS)`, `H` the bin shares (so the excess is in units of a bin's mean share) and `λ` the
//! strength (`histogram_weight`). Colours the target lacks keep their full weight and win more
//! votes. Kopf et al. use 16 bins and `λ = 1` in counts; the share scaling is ours, so that `λ`
//! does not depend on the mesh size.
//!
//! The same excess, times the fan dimension, is the E-step's optional histogram cost per source
//! vertex (`histogram_cost`, default off; README "Histogram cost in the E-step").
//!
//! Written by hand: no crate does this.

/// Bins per channel (Kopf et al. 2007: 16).
pub const BINS: usize = 16;

/// [`BINS`] equal bins per colour channel over a set of colours' range.
#[derive(Clone, Copy, Debug)]
pub(super) struct ChannelBins {
    /// Per channel, the lowest colour value.
    lo: [f32; 3],
    /// Per channel, bins per unit of colour (0 for a constant channel: everything in bin 0).
    scale: [f32; 3],
}

impl ChannelBins {
    /// The bins over the range of `colors`.
    pub(super) fn over(colors: impl IntoIterator<Item = [f32; 3]>) -> Self {
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for c in colors {
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        let scale = std::array::from_fn(|k| {
            if hi[k] > lo[k] {
                BINS as f32 / (hi[k] - lo[k])
            } else {
                0.0
            }
        });
        ChannelBins { lo, scale }
    }

    /// The bin of each channel of `c` (clamped to the range).
    pub(super) fn bins(&self, c: [f32; 3]) -> [usize; 3] {
        std::array::from_fn(|k| {
            (((c[k] - self.lo[k]) * self.scale[k]).max(0.0) as usize).min(BINS - 1)
        })
    }
}

/// The vote weight factor of every colour, from the source's and the target's histograms.
#[derive(Clone, Debug)]
pub struct HistogramBias {
    bins: ChannelBins,
    /// `λ · BINS · max(0, H_t − H_s)` per channel and bin.
    excess: [[f32; BINS]; 3],
}

impl HistogramBias {
    /// The bias for target colours `target` against source colours `source` at strength
    /// `strength`; `None` when `strength` is 0 or either set is empty.
    pub fn new(source: &[[f32; 3]], target: &[[f32; 3]], strength: f32) -> Option<Self> {
        if strength <= 0.0 || source.is_empty() || target.is_empty() {
            return None;
        }
        let mut bias = HistogramBias {
            bins: ChannelBins::over(source.iter().copied()),
            excess: [[0.0; BINS]; 3],
        };
        let shares = |colors: &[[f32; 3]]| {
            let mut h = [[0.0f32; BINS]; 3];
            for c in colors {
                for (k, b) in bias.bins(*c).into_iter().enumerate() {
                    h[k][b] += 1.0;
                }
            }
            let n = colors.len() as f32;
            h.map(|row| row.map(|x| x / n))
        };
        let (hs, ht) = (shares(source), shares(target));
        for k in 0..3 {
            for b in 0..BINS {
                bias.excess[k][b] = strength * BINS as f32 * (ht[k][b] - hs[k][b]).max(0.0);
            }
        }
        Some(bias)
    }

    /// The bin of each channel of `c` (clamped to the source's range).
    fn bins(&self, c: [f32; 3]) -> [usize; 3] {
        self.bins.bins(c)
    }

    /// `λ · BINS · Σ_ch max(0, H_t − H_s)` at colour `c`: how over-represented `c` is in the
    /// target (0 where no channel's bin is). The E-step's histogram cost (`histogram_cost`) is
    /// this times the fan dimension.
    pub fn excess(&self, c: [f32; 3]) -> f32 {
        let b = self.bins(c);
        self.excess[0][b[0]] + self.excess[1][b[1]] + self.excess[2][b[2]]
    }

    /// The factor a vote for colour `c` is multiplied by, in (0, 1].
    pub fn factor(&self, c: [f32; 3]) -> f32 {
        1.0 / (1.0 + self.excess(c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Black is under-represented in the target (10% against the source's 40%), white over:
    /// a white vote is down-weighted, a black one is not, and equal histograms change nothing.
    #[test]
    fn over_represented_colours_lose_weight() {
        let (black, white) = ([0.0f32; 3], [1.0f32; 3]);
        let source: Vec<[f32; 3]> = (0..100)
            .map(|i| if i < 40 { black } else { white })
            .collect();
        let target: Vec<[f32; 3]> = (0..100)
            .map(|i| if i < 10 { black } else { white })
            .collect();
        let bias = HistogramBias::new(&source, &target, 1.0).unwrap();
        assert_eq!(bias.factor(black), 1.0);
        // White: excess 0.3 of the share in each channel, × 16 bins, × 3 channels.
        let expected = 1.0 / (1.0 + 3.0 * 16.0 * 0.3);
        assert!(
            (bias.factor(white) - expected).abs() < 1e-5,
            "{}",
            bias.factor(white)
        );
        // The E-step cost's excess: white's, black none.
        assert!((bias.excess(white) - 3.0 * 16.0 * 0.3).abs() < 1e-4);
        assert_eq!(bias.excess(black), 0.0);
        let same = HistogramBias::new(&source, &source, 1.0).unwrap();
        assert_eq!((same.factor(black), same.factor(white)), (1.0, 1.0));
        assert!(HistogramBias::new(&source, &target, 0.0).is_none());
    }
}
