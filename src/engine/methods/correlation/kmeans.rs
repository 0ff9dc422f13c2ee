//! Weighted k-means (Lloyd 1982) for the segmentation of the guidance field (Mertens et al. 2006,
//! §5.2.1: "k-means clustering on the values in the guidance map"), with k-means++ seeding
//! (Arthur & Vassilvitskii 2007).
//!
//! Points are guidance values (up to 3 axes; unused axes are 0 and do not change distances), each
//! weighted by its sample's area (and, on the source, its mask weight): a weight of 0 takes no part
//! in seeding or in the centres, but the point still gets a label.
//!
//! Constants the paper does not publish (retex's choice): at most [`MAX_ITERATIONS`] Lloyd
//! iterations; stop early when no label changes or the weighted inertia decreased by less than
//! [`TOLERANCE`] (relative) in the last iteration. Clusters left empty are dropped and the rest
//! renumbered in order, so there may be fewer than `k` clusters (also when there are fewer
//! distinct points than `k`).
//!
//! Deterministic for a seed: seeding draws from a [`SplitMix64`]; the assignment is parallel per
//! point and the centre sums are accumulated sequentially in f64.

use rayon::prelude::*;

use crate::engine::control::{Cancelled, Control};
use crate::engine::rng::SplitMix64;

/// Most Lloyd iterations.
pub const MAX_ITERATIONS: usize = 100;
/// Relative decrease of the weighted inertia below which the iterations stop.
pub const TOLERANCE: f64 = 1e-5;

/// A clustering.
#[derive(Clone, Debug, PartialEq)]
pub struct Clustering {
    /// Cluster centres (weighted means of their points).
    pub centres: Vec<[f32; 3]>,
    /// Cluster of every point.
    pub labels: Vec<u32>,
    /// Points per cluster (counting points of any weight).
    pub sizes: Vec<usize>,
    /// Lloyd iterations run.
    pub iterations: usize,
    /// Weighted mean squared distance of the points to their centres.
    pub inertia: f64,
}

fn d2(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

/// Index of the nearest centre and its squared distance (ties to the lower index).
pub fn nearest(centres: &[[f32; 3]], p: [f32; 3]) -> (u32, f32) {
    let mut best = (0u32, f32::INFINITY);
    for (c, &q) in centres.iter().enumerate() {
        let d = d2(p, q);
        if d < best.1 {
            best = (c as u32, d);
        }
    }
    best
}

/// Draws an index with probability proportional to `mass` (all non-negative, total > 0).
fn draw(mass: &[f64], total: f64, rng: &mut SplitMix64) -> usize {
    let r = rng.unit_f64() * total;
    let mut acc = 0.0;
    for (i, &m) in mass.iter().enumerate() {
        acc += m;
        if acc > r && m > 0.0 {
            return i;
        }
    }
    mass.iter().rposition(|&m| m > 0.0).unwrap_or(0)
}

/// k-means++ seeding: up to `k` centres, fewer when every remaining point coincides with one.
fn seed_centres(
    points: &[[f32; 3]],
    weights: &[f32],
    k: usize,
    rng: &mut SplitMix64,
) -> Vec<[f32; 3]> {
    let w: Vec<f64> = weights.iter().map(|&w| w.max(0.0) as f64).collect();
    let total: f64 = w.iter().sum();
    let first = draw(&w, total, rng);
    let mut centres = vec![points[first]];
    let mut dist: Vec<f32> = points.par_iter().map(|&p| d2(p, points[first])).collect();
    while centres.len() < k {
        let mass: Vec<f64> = dist.iter().zip(&w).map(|(&d, &w)| d as f64 * w).collect();
        let total: f64 = mass.iter().sum();
        if total <= 0.0 {
            break;
        }
        let c = points[draw(&mass, total, rng)];
        centres.push(c);
        dist.par_iter_mut()
            .zip(points.par_iter())
            .for_each(|(d, &p)| *d = d.min(d2(p, c)));
    }
    centres
}

/// Weighted k-means of `points` into at most `k` clusters; see the module docs. Returns `None`
/// when no point has a positive weight.
///
/// # Errors
/// [`Cancelled`] when `control` is cancelled (checked once per iteration).
///
/// # Panics
/// If `weights` has a different length than `points`.
pub fn kmeans(
    points: &[[f32; 3]],
    weights: &[f32],
    k: usize,
    seed: u64,
    control: &Control,
) -> Result<Option<Clustering>, Cancelled> {
    assert_eq!(points.len(), weights.len(), "one weight per point");
    let usable = |w: f32| w.is_finite() && w > 0.0;
    if k == 0 || !weights.iter().any(|&w| usable(w)) {
        return Ok(None);
    }
    let weights: Vec<f32> = weights
        .iter()
        .map(|&w| if usable(w) { w } else { 0.0 })
        .collect();
    let mut rng = SplitMix64::new(seed);
    let mut centres = seed_centres(points, &weights, k, &mut rng);
    let total_w: f64 = weights.iter().map(|&w| w as f64).sum();
    let mut labels = vec![u32::MAX; points.len()];
    let mut inertia = f64::INFINITY;
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS {
        control.check()?;
        iterations += 1;
        let assigned: Vec<(u32, f32)> = points.par_iter().map(|&p| nearest(&centres, p)).collect();
        let changed = assigned
            .iter()
            .zip(&labels)
            .filter(|((a, _), &l)| *a != l)
            .count();
        let new_inertia = assigned
            .iter()
            .zip(&weights)
            .map(|((_, d), &w)| *d as f64 * w as f64)
            .sum::<f64>()
            / total_w;
        for (l, (a, _)) in labels.iter_mut().zip(&assigned) {
            *l = *a;
        }
        // Centres: weighted means (a cluster without weight keeps its centre).
        let mut sum = vec![[0.0f64; 3]; centres.len()];
        let mut wsum = vec![0.0f64; centres.len()];
        for ((p, &l), &w) in points.iter().zip(&labels).zip(&weights) {
            for a in 0..3 {
                sum[l as usize][a] += w as f64 * p[a] as f64;
            }
            wsum[l as usize] += w as f64;
        }
        for (c, (s, &w)) in centres.iter_mut().zip(sum.iter().zip(&wsum)) {
            if w > 0.0 {
                *c = s.map(|x| (x / w) as f32);
            }
        }
        let converged =
            changed == 0 || (inertia.is_finite() && inertia - new_inertia <= TOLERANCE * inertia);
        inertia = new_inertia;
        if converged {
            break;
        }
    }
    // Final assignment to the final centres, then drop clusters without weighted points.
    let assigned: Vec<(u32, f32)> = points.par_iter().map(|&p| nearest(&centres, p)).collect();
    let mut wsum = vec![0.0f64; centres.len()];
    for ((l, _), &w) in assigned.iter().zip(&weights) {
        wsum[*l as usize] += w as f64;
    }
    let keep: Vec<usize> = (0..centres.len()).filter(|&c| wsum[c] > 0.0).collect();
    let centres: Vec<[f32; 3]> = keep.iter().map(|&c| centres[c]).collect();
    let assigned: Vec<(u32, f32)> = points.par_iter().map(|&p| nearest(&centres, p)).collect();
    let labels: Vec<u32> = assigned.iter().map(|a| a.0).collect();
    let mut sizes = vec![0usize; centres.len()];
    for &l in &labels {
        sizes[l as usize] += 1;
    }
    let inertia = assigned
        .iter()
        .zip(&weights)
        .map(|((_, d), &w)| *d as f64 * w as f64)
        .sum::<f64>()
        / total_w;
    Ok(Some(Clustering {
        centres,
        labels,
        sizes,
        iterations,
        inertia,
    }))
}
