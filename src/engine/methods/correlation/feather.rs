//! Feathering of the k-means segmentation (Mertens et al. 2006, §5.2.2): "we feather the result
//! to avoid seams using a Gaussian with a standard deviation equal to that of the corresponding
//! cluster's distribution", the weights "forced to sum to one on a per-texel basis".
//!
//! Reading of the paper (it does not say in which space the Gaussian lives): the cluster's
//! distribution is that of its guidance values, so the Gaussian is in guidance space: sample `i`
//! with guidance `g` gets `exp(−|g − μ_c|² / (2σ_c²))` for cluster `c` with centre `μ_c` and
//! spread `σ_c` (the RMS per-axis distance of the cluster's points to its centre). The guidance
//! field is continuous over the surface, so the weights are too: no seams where the hard labels
//! change.
//!
//! Constants the paper does not publish (retex's choice, to keep the work linear in the samples):
//! every sample keeps its [`MAX_MEMBERS`] largest weights and drops those below
//! [`MIN_SHARE`] of the kept sum, then renormalises to 1. A sample far from every centre (every
//! Gaussian underflows) belongs to its nearest cluster alone. σ is at least [`MIN_SPREAD`] times
//! the RMS spread of all points (a cluster of identical points would otherwise be a spike).

use rayon::prelude::*;

use super::kmeans::nearest;
use crate::engine::mesh::csr::group_by_key;

/// Most clusters a sample belongs to.
pub const MAX_MEMBERS: usize = 6;
/// Smallest kept share of a sample's weight.
pub const MIN_SHARE: f32 = 0.01;
/// Smallest cluster spread, relative to the spread of all points.
pub const MIN_SPREAD: f32 = 0.05;

/// Soft memberships of the samples of one level, grouped by cluster (CSR).
#[derive(Clone, Debug, Default)]
pub struct Membership {
    /// `samples[offsets[c]..offsets[c + 1]]` are the samples of cluster `c`.
    pub offsets: Vec<u32>,
    /// Member samples, ascending per cluster.
    pub samples: Vec<u32>,
    /// Weight of each member (a sample's weights over its clusters sum to 1).
    pub weights: Vec<f32>,
}

impl Membership {
    /// Number of clusters.
    pub fn clusters(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Members of cluster `c`: (samples, weights).
    pub fn members(&self, c: usize) -> (&[u32], &[f32]) {
        let r = self.offsets[c] as usize..self.offsets[c + 1] as usize;
        (&self.samples[r.clone()], &self.weights[r])
    }
}

/// Per-axis RMS distance of each cluster's points to its centre (weighted by `weights`), floored
/// at [`MIN_SPREAD`] times the spread of all points (and at a tiny absolute value).
pub fn cluster_spreads(
    points: &[[f32; 3]],
    weights: &[f32],
    labels: &[u32],
    centres: &[[f32; 3]],
    dims: usize,
) -> Vec<f32> {
    let k = centres.len();
    let mut s = vec![0.0f64; k];
    let mut w = vec![0.0f64; k];
    let (mut all_w, mut all_mean) = (0.0f64, [0.0f64; 3]);
    for ((p, &l), &wi) in points.iter().zip(labels).zip(weights) {
        let wi = wi.max(0.0) as f64;
        let d: f64 = (0..3)
            .map(|a| (p[a] - centres[l as usize][a]) as f64)
            .map(|x| x * x)
            .sum();
        s[l as usize] += wi * d;
        w[l as usize] += wi;
        all_w += wi;
        for a in 0..3 {
            all_mean[a] += wi * p[a] as f64;
        }
    }
    let all_mean = all_mean.map(|x| x / all_w.max(1e-300));
    let all_var: f64 = points
        .iter()
        .zip(weights)
        .map(|(p, &wi)| {
            wi.max(0.0) as f64
                * (0..3)
                    .map(|a| (p[a] as f64 - all_mean[a]).powi(2))
                    .sum::<f64>()
        })
        .sum::<f64>()
        / all_w.max(1e-300);
    let dims = dims.max(1) as f64;
    let floor = ((MIN_SPREAD as f64) * (all_var / dims).sqrt()).max(1e-6);
    (0..k)
        .map(|c| ((s[c] / w[c].max(1e-300) / dims).sqrt().max(floor)) as f32)
        .collect()
}

/// The feathered memberships of `points` in the clusters (`centres`, `spreads`).
pub fn feather(points: &[[f32; 3]], centres: &[[f32; 3]], spreads: &[f32]) -> Membership {
    let per_sample: Vec<Vec<(u32, f32)>> = points
        .par_iter()
        .map(|&p| {
            let mut best: Vec<(u32, f32)> = Vec::with_capacity(MAX_MEMBERS + 1);
            for (c, (&q, &s)) in centres.iter().zip(spreads).enumerate() {
                let d: f32 = (0..3).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum();
                let e = (-d / (2.0 * s * s)).exp();
                if e > 0.0 && (best.len() < MAX_MEMBERS || e > best[MAX_MEMBERS - 1].1) {
                    let at = best.partition_point(|b| b.1 >= e);
                    best.insert(at, (c as u32, e));
                    best.truncate(MAX_MEMBERS);
                }
            }
            if best.is_empty() {
                return vec![(nearest(centres, p).0, 1.0)];
            }
            let sum: f32 = best.iter().map(|b| b.1).sum();
            best.retain(|b| b.1 >= MIN_SHARE * sum);
            let sum: f32 = best.iter().map(|b| b.1).sum();
            best.iter().map(|&(c, e)| (c, e / sum)).collect()
        })
        .collect();
    let items = per_sample
        .iter()
        .enumerate()
        .flat_map(|(i, m)| m.iter().map(move |&(c, w)| (c, (i as u32, w))));
    let (offsets, pairs) = group_by_key(centres.len(), items);
    Membership {
        offsets,
        samples: pairs.iter().map(|p| p.0).collect(),
        weights: pairs.iter().map(|p| p.1).collect(),
    }
}
