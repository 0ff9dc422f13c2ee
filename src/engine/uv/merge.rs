//! Chart merging (issue 15): after the growth and the splits, neighbouring charts are merged
//! while the union is still a disc that the atlas's parameterisation (LSCM, optionally refined
//! by ARAP) flattens within the stretch bound.
//!
//! Lévy et al. 2002 §4 grow charts from seeds and then merge charts whose boundary between them
//! is long relative to their size; Sander et al. 2001 merge greedily while the merged chart's
//! stretch stays bounded. Here the growth by normal deviation (`charts.rs`) leaves many small
//! charts on scans, where normals are noisy, and each costs a seam and packing room. The merge
//! keeps the atlas's guarantee, since a union is accepted only when [`super::atlas`]'s own
//! flattening accepts it: a disc, no flipped triangle, L2 stretch within `max_stretch`.
//!
//! **Order.** The merge runs in rounds. In a round, each pair of neighbouring charts whose union
//! has at most [`MERGE_MAX_FACES`] faces is a candidate. Candidates are ranked by the smaller
//! chart's face count, smallest first; then by the length of the shared boundary, longest first;
//! then by the charts' first faces. Pairs are picked greedily so that no chart is in two pairs.
//! The picked unions are flattened in parallel and the accepted ones replace their two charts.
//! A failed pair is not tried again while both charts are unchanged. Rounds stop when none
//! succeeds, or after [`MERGE_ROUNDS`] rounds. This is deterministic and independent of the
//! thread count.
//!
//! **Constants** (the papers give none):
//! - [`MERGE_MAX_FACES`] = 2,000 bounds the cost. Each attempt is one LSCM solve of at most that
//!   many faces. Large charts (a sphere's few big charts) are never re-solved.
//! - [`MERGE_ROUNDS`] = 8 caps the rounds. Chart counts at the start of each round on the
//!   README's scans: cat 242, 136, 78, 46, 32, 25, 23 (settled in 7 rounds); skull 1,137 … 61
//!   (7); koala 656 … 61 (settled in the 8th). Demosthenes (25 → 21) and Nefertiti (52 → 50)
//!   are still merging a few charts in the 8th round.
//!
//! Both are `AtlasParams` fields (`merge_max_faces`, `merge_rounds`) with these defaults,
//! chosen from a sweep over the six scans of the README's xatlas comparison
//! (`tests/engine/uv_merge_sweep.rs`, table in the README): 16 rounds instead of 8 change one
//! scan by 1-4 charts; 4,000 faces instead of 2,000 cut the charts 234 → 155 and the seams by
//! 14 %, for 0.01-0.03 more L2 stretch on four scans, 0.02-0.05 less packing on three and 18 %
//! more atlas time; 1,000 faces leave 398 charts and 22 % longer seams. Without the merge
//! (0 faces): 3,770 charts and twice the seams.
//!
//! Written here: no crate merges charts under a distortion bound.

use std::collections::HashSet;

use rayon::prelude::*;

use super::atlas::{flatten, AtlasParams, Flat};
use super::charts::Adjacency;
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::Surface;

/// The default largest union tried, in faces (`AtlasParams::merge_max_faces`; module doc).
pub const MERGE_MAX_FACES: usize = 2000;

/// The default most merge rounds (`AtlasParams::merge_rounds`; module doc).
pub const MERGE_ROUNDS: usize = 8;

/// A chart's identity while it is unchanged: its first face and its face count.
type ChartKey = (u32, usize);

fn key(flat: &Flat) -> ChartKey {
    (flat.faces[0], flat.faces.len())
}

/// Pairs of neighbouring charts `(a, b)`, `a < b`, with the length of the boundary they share.
fn shared_boundaries(surface: &Surface, adj: &Adjacency, flats: &[Flat]) -> Vec<(u32, u32, f64)> {
    let mut face_chart = vec![u32::MAX; surface.faces.len()];
    for (c, flat) in flats.iter().enumerate() {
        for f in &flat.faces {
            face_chart[*f as usize] = c as u32;
        }
    }
    let mut edges: Vec<(u32, u32, f64)> = Vec::new();
    for (f, neighbours) in adj.neighbors.iter().enumerate() {
        let a = face_chart[f];
        for (k, other) in neighbours.iter().enumerate() {
            let Some(o) = other else { continue };
            let b = face_chart[*o as usize];
            if a < b && b != u32::MAX {
                let v = surface.faces[f];
                let (p, q) = (
                    surface.positions[v[k] as usize],
                    surface.positions[v[(k + 1) % 3] as usize],
                );
                let length = (0..3)
                    .map(|i| f64::from(p[i] - q[i]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                edges.push((a, b, length));
            }
        }
    }
    edges.sort_by_key(|e| (e.0, e.1));
    let mut pairs: Vec<(u32, u32, f64)> = Vec::new();
    for (a, b, l) in edges {
        match pairs.last_mut() {
            Some(last) if last.0 == a && last.1 == b => last.2 += l,
            _ => pairs.push((a, b, l)),
        }
    }
    pairs
}

/// Merges neighbouring charts (module doc). `flats` are sorted by their first face; so is the
/// result.
///
/// # Errors
/// [`Cancelled`].
pub(super) fn merge_charts(
    surface: &Surface,
    adj: &Adjacency,
    mut flats: Vec<Flat>,
    params: &AtlasParams,
    control: &Control,
) -> Result<Vec<Flat>, Cancelled> {
    let mut failed: HashSet<(ChartKey, ChartKey)> = HashSet::new();
    for _ in 0..params.merge_rounds {
        control.check()?;
        let mut candidates: Vec<(usize, f64, u32, u32)> = shared_boundaries(surface, adj, &flats)
            .into_iter()
            .filter(|&(a, b, _)| {
                let (fa, fb) = (&flats[a as usize], &flats[b as usize]);
                fa.faces.len() + fb.faces.len() <= params.merge_max_faces
                    && !failed.contains(&(key(fa), key(fb)))
            })
            .map(|(a, b, l)| {
                let smaller = flats[a as usize]
                    .faces
                    .len()
                    .min(flats[b as usize].faces.len());
                (smaller, l, a, b)
            })
            .collect();
        candidates.sort_by(|x, y| {
            x.0.cmp(&y.0)
                .then(y.1.total_cmp(&x.1))
                .then((x.2, x.3).cmp(&(y.2, y.3)))
        });
        let mut used = vec![false; flats.len()];
        let mut picks: Vec<(usize, usize)> = Vec::new();
        for (_, _, a, b) in candidates {
            let (a, b) = (a as usize, b as usize);
            if !used[a] && !used[b] {
                used[a] = true;
                used[b] = true;
                picks.push((a, b));
            }
        }
        let merged: Vec<Option<Flat>> = picks
            .par_iter()
            .map(|&(a, b)| {
                let mut faces = flats[a].faces.clone();
                faces.extend_from_slice(&flats[b].faces);
                faces.sort_unstable();
                flatten(surface, &faces, params)
            })
            .collect();
        let mut removed = vec![false; flats.len()];
        let mut unions: Vec<Flat> = Vec::new();
        for (&(a, b), union) in picks.iter().zip(merged) {
            match union {
                Some(u) => {
                    removed[a] = true;
                    removed[b] = true;
                    unions.push(u);
                }
                None => {
                    failed.insert((key(&flats[a]), key(&flats[b])));
                }
            }
        }
        if unions.is_empty() {
            break;
        }
        let mut next: Vec<Flat> = flats
            .into_iter()
            .zip(removed)
            .filter_map(|(f, r)| (!r).then_some(f))
            .collect();
        next.extend(unions);
        next.sort_by_key(|f| f.faces[0]);
        flats = next;
    }
    Ok(flats)
}
