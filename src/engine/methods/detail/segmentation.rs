//! The SDF segmentation behind the "distance to segmentation boundary" feature of Berkiten et
//! al. 2017, §3.2.2 (the paper cites Shapira et al. 2008, which fits a GMM to the SDF and cuts
//! with a graph cut; this is a simpler stand-in, stated): 1-D k-means on `log SDF` (centres
//! started at the quantiles `(j + ½)/k`, Lloyd to convergence), centres closer than a gap merged
//! (so a part of constant thickness is not cut by the SDF's noise), labels smoothed by 3 rounds
//! of one-ring majority vote (the graph cut's role), segments = connected components of equal
//! label. Boundary vertices have a neighbour in another segment; their geodesic distance comes
//! from one multi-source heat-method query, divided by the maximum within each segment (Chen et
//! al. 2012). Defaults and reasons: [`super::geometric_features`].

use super::geometric_features::GeometricError;
use crate::engine::geometry::heat::{HeatGeodesics, Source};
use crate::engine::mesh::Surface;

/// One-ring neighbours (CSR).
fn one_rings(surface: &Surface) -> (Vec<usize>, Vec<u32>) {
    let nv = surface.vertex_count();
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(surface.faces.len() * 6);
    for f in &surface.faces {
        for i in 0..3 {
            let (a, b) = (f[i], f[(i + 1) % 3]);
            pairs.push((a, b));
            pairs.push((b, a));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    let mut offsets = vec![0usize; nv + 1];
    for &(a, _) in &pairs {
        offsets[a as usize + 1] += 1;
    }
    for v in 0..nv {
        offsets[v + 1] += offsets[v];
    }
    (offsets, pairs.into_iter().map(|p| p.1).collect())
}

/// Segment id per vertex (see the module doc): `segments` k-means clusters on log SDF, centres
/// closer than `merge_log_gap` merged.
pub fn segment_by_sdf(
    surface: &Surface,
    sdf: &[f64],
    segments: usize,
    merge_log_gap: f64,
) -> Vec<u32> {
    let nv = sdf.len();
    let logs: Vec<f64> = sdf.iter().map(|&x| x.max(1e-30).ln()).collect();
    let mut sorted = logs.clone();
    sorted.sort_by(f64::total_cmp);
    let k = segments.clamp(1, nv.max(1));
    let mut centres: Vec<f64> = (0..k)
        .map(|j| sorted[((j as f64 + 0.5) / k as f64 * nv as f64) as usize])
        .collect();
    let nearest = |x: f64, centres: &[f64]| {
        (0..centres.len())
            .min_by(|&a, &b| (x - centres[a]).abs().total_cmp(&(x - centres[b]).abs()))
            .unwrap_or(0)
    };
    for _ in 0..100 {
        let mut sum = vec![(0.0, 0usize); centres.len()];
        for &x in &logs {
            let c = nearest(x, &centres);
            sum[c].0 += x;
            sum[c].1 += 1;
        }
        let next: Vec<f64> = (sum.iter().zip(&centres))
            .map(|(&(s, n), &c)| if n > 0 { s / n as f64 } else { c })
            .collect();
        let moved = next
            .iter()
            .zip(&centres)
            .any(|(a, b)| (a - b).abs() > 1e-12);
        centres = next;
        if !moved {
            break;
        }
    }
    centres.sort_by(f64::total_cmp);
    let mut merged: Vec<f64> = Vec::new();
    for c in centres {
        match merged.last_mut() {
            Some(last) if c - *last < merge_log_gap => *last = 0.5 * (*last + c),
            _ => merged.push(c),
        }
    }
    let mut label: Vec<u32> = logs.iter().map(|&x| nearest(x, &merged) as u32).collect();
    let (offsets, ring) = one_rings(surface);
    for _ in 0..3 {
        label = (0..nv)
            .map(|v| {
                let mut votes = vec![0usize; merged.len()];
                votes[label[v] as usize] += 1;
                for &q in &ring[offsets[v]..offsets[v + 1]] {
                    votes[label[q as usize] as usize] += 1;
                }
                // Most votes; ties keep the lowest label (deterministic).
                (0..votes.len())
                    .max_by_key(|&i| (votes[i], usize::MAX - i))
                    .unwrap_or(0) as u32
            })
            .collect();
    }
    // Connected components of equal label.
    let mut segment = vec![u32::MAX; nv];
    let mut next = 0u32;
    for s in 0..nv {
        if segment[s] != u32::MAX {
            continue;
        }
        segment[s] = next;
        let mut stack = vec![s];
        while let Some(v) = stack.pop() {
            for &q in &ring[offsets[v]..offsets[v + 1]] {
                let q = q as usize;
                if segment[q] == u32::MAX && label[q] == label[s] {
                    segment[q] = next;
                    stack.push(q);
                }
            }
        }
        next += 1;
    }
    segment
}

/// Geodesic distance to the nearest segment boundary, ÷ the maximum within each segment.
pub fn boundary_distance(
    surface: &Surface,
    heat: &HeatGeodesics,
    segments: &[u32],
) -> Result<Vec<f64>, GeometricError> {
    let nv = segments.len();
    let mut boundary = vec![false; nv];
    for f in &surface.faces {
        for i in 0..3 {
            let (a, b) = (f[i] as usize, f[(i + 1) % 3] as usize);
            if segments[a] != segments[b] {
                boundary[a] = true;
                boundary[b] = true;
            }
        }
    }
    let sources: Vec<Source> = (0..nv)
        .filter(|&v| boundary[v])
        .map(|v| Source::Vertex(v as u32))
        .collect();
    if sources.is_empty() {
        return Ok(vec![0.0; nv]);
    }
    let d = heat.distance(&sources)?;
    let count = segments.iter().copied().max().unwrap_or(0) as usize + 1;
    let mut max = vec![0.0f64; count];
    for (v, &s) in segments.iter().enumerate() {
        if d[v].is_finite() {
            max[s as usize] = max[s as usize].max(d[v]);
        }
    }
    Ok((0..nv)
        .map(|v| {
            let m = max[segments[v] as usize];
            if d[v].is_finite() && m > 0.0 {
                d[v] / m
            } else {
                0.0
            }
        })
        .collect())
}
