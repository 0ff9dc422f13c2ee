//! Sweep order and source sampling of the synthesis (Berkiten et al. 2017, §3.3.1, "Sweep
//! order" and "Sampling").
//!
//! - **Source samples**: Euclidean farthest-point sampling on the level's vertices, starting at
//!   vertex 0 (deterministic; on a remeshed, isotropic level Euclidean and geodesic spreads
//!   agree at the sample spacing, and no factorization is needed).
//! - **Good correspondences**: a target vertex's count is the number of source *samples* whose
//!   transformed feature is within the threshold `τ` of its own (`‖A g_t − A g_s‖² < τ`); counting
//!   against the samples rather than all source vertices keeps it `O(N_t · S · r)`. `τ` is the
//!   `good_quantile` quantile of the squared distances of (up to 256 strided target vertices) ×
//!   (all samples), so the notion of "good" adapts to the metric's scale.
//! - **Seeds**: the `seeds` vertices with the fewest good correspondences (ties by index), plus,
//!   for every connected component none of them is on, that component's vertex with the fewest.
//! - **Order**: multi-source Dijkstra on the edge graph (edge lengths) from the seeds, vertices in
//!   the order they are settled. Dijkstra, not the toolkit's heat geodesics: it needs no
//!   factorization per level, and only the *order* matters, for which the graph metric's
//!   √2-type overestimates are harmless.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use crate::engine::math::dist2;
use crate::engine::mesh::csr::vertex_neighbours;
use crate::engine::mesh::Surface;

/// `count` vertices of `surface` by Euclidean farthest-point sampling from vertex 0 (all
/// vertices when `count ≥` their number), in selection order.
pub fn farthest_point_samples(surface: &Surface, count: usize) -> Vec<usize> {
    farthest_point_cover(surface, count).0
}

/// [`farthest_point_samples`] and their covering radius: the largest Euclidean distance from a
/// vertex of `surface` to its nearest sample (0 when every vertex is a sample).
pub fn farthest_point_cover(surface: &Surface, count: usize) -> (Vec<usize>, f64) {
    let nv = surface.vertex_count();
    if count >= nv {
        return ((0..nv).collect(), 0.0);
    }
    let p = |v: usize| surface.positions[v].map(|x| x as f64);
    let mut nearest = vec![f64::INFINITY; nv];
    let mut out = Vec::with_capacity(count);
    let mut next = 0usize;
    while out.len() < count {
        out.push(next);
        let c = p(next);
        nearest
            .par_iter_mut()
            .enumerate()
            .for_each(|(v, d)| *d = d.min(dist2(p(v), c)));
        // Farthest vertex, ties to the lowest index.
        next = (0..nv).fold(0, |b, v| if nearest[v] > nearest[b] { v } else { b });
        if nearest[next] == 0.0 {
            break;
        }
    }
    (out, nearest.get(next).map_or(0.0, |d| d.sqrt()))
}

/// Squared Euclidean distance of two `r`-vectors.
pub fn feature_dist2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// The `quantile` of the squared feature distances between up to 256 strided target vertices
/// and the source samples (see the module doc); 0 without pairs.
pub fn good_threshold(
    target: &[f64],
    source: &[f64],
    samples: &[usize],
    r: usize,
    quantile: f64,
) -> f64 {
    let nt = target.len().checked_div(r).unwrap_or(0);
    if nt == 0 || samples.is_empty() || r == 0 {
        return 0.0;
    }
    let stride = nt.div_ceil(256).max(1);
    let mut d: Vec<f64> = (0..nt)
        .step_by(stride)
        .flat_map(|t| {
            samples.iter().map(move |&s| {
                feature_dist2(&target[t * r..(t + 1) * r], &source[s * r..(s + 1) * r])
            })
        })
        .collect();
    let k = ((quantile.clamp(0.0, 1.0) * (d.len() - 1) as f64).round() as usize).min(d.len() - 1);
    let (_, v, _) = d.select_nth_unstable_by(k, f64::total_cmp);
    *v
}

/// Per target vertex: the samples within `threshold` (squared feature distance, strict).
pub fn good_counts(
    target: &[f64],
    source: &[f64],
    samples: &[usize],
    r: usize,
    threshold: f64,
) -> Vec<u32> {
    if r == 0 {
        // Every feature is equal: every sample is as good as any other.
        return vec![samples.len() as u32; target.len()];
    }
    target
        .par_chunks(r)
        .map(|t| {
            samples
                .iter()
                .filter(|&&s| feature_dist2(t, &source[s * r..(s + 1) * r]) < threshold)
                .count() as u32
        })
        .collect()
}

/// The sweep order of a level and the seeds used (see the module doc).
pub fn sweep_order(surface: &Surface, counts: &[u32], seeds: usize) -> (Vec<usize>, Vec<usize>) {
    let nv = surface.vertex_count();
    let mut by_count: Vec<usize> = (0..nv).collect();
    by_count.sort_by_key(|&v| (counts.get(v).copied().unwrap_or(0), v));
    let (offsets, neighbours) = vertex_neighbours(surface);
    let p = |v: usize| surface.positions[v].map(|x| x as f64);
    let mut dist = vec![f64::INFINITY; nv];
    let mut done = vec![false; nv];
    let mut order = Vec::with_capacity(nv);
    let mut used: Vec<usize> = Vec::new();
    let mut heap: BinaryHeap<Reverse<(u64, usize)>> = BinaryHeap::new();
    let mut initial = by_count.iter().copied().take(seeds.max(1));
    let mut rest = by_count.iter().copied();
    loop {
        // Seed: the requested ones first, then one per component not reached yet.
        let seed = match initial.next() {
            Some(v) => Some(v),
            None if heap.is_empty() => rest.by_ref().find(|&v| !done[v]),
            None => None,
        };
        if let Some(s) = seed {
            if dist[s] > 0.0 {
                dist[s] = 0.0;
                used.push(s);
                heap.push(Reverse((0.0f64.to_bits(), s)));
            }
            if used.len() < seeds.max(1) && used.len() < nv {
                continue;
            }
        }
        let Some(Reverse((bits, v))) = heap.pop() else {
            if order.len() == nv {
                break;
            }
            continue;
        };
        if done[v] || f64::from_bits(bits) > dist[v] {
            continue;
        }
        done[v] = true;
        order.push(v);
        for &q in &neighbours[offsets[v] as usize..offsets[v + 1] as usize] {
            let q = q as usize;
            let d = dist[v] + dist2(p(v), p(q)).sqrt();
            if !done[q] && d < dist[q] {
                dist[q] = d;
                // Non-negative f64 bit patterns order like the values.
                heap.push(Reverse((d.to_bits(), q)));
            }
        }
    }
    (order, used)
}

/// Shortest edge-path lengths from the nearest of `sources` to every vertex (multi-source
/// Dijkstra on edge lengths; infinite where unreachable).
pub fn edge_distances(surface: &Surface, sources: &[usize]) -> Vec<f64> {
    let nv = surface.vertex_count();
    let (offsets, neighbours) = vertex_neighbours(surface);
    let p = |v: usize| surface.positions[v].map(|x| x as f64);
    let mut dist = vec![f64::INFINITY; nv];
    let mut heap: BinaryHeap<Reverse<(u64, usize)>> = BinaryHeap::new();
    for &s in sources.iter().filter(|&&s| s < nv) {
        dist[s] = 0.0;
        heap.push(Reverse((0.0f64.to_bits(), s)));
    }
    while let Some(Reverse((bits, v))) = heap.pop() {
        if f64::from_bits(bits) > dist[v] {
            continue;
        }
        for &q in &neighbours[offsets[v] as usize..offsets[v + 1] as usize] {
            let q = q as usize;
            let d = dist[v] + dist2(p(v), p(q)).sqrt();
            if d < dist[q] {
                dist[q] = d;
                heap.push(Reverse((d.to_bits(), q)));
            }
        }
    }
    dist
}
