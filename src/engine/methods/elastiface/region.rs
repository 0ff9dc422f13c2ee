//! The region of a part-based morph (§5 of Zell & Botsch 2013, "blend only parts of the input
//! models", Fig. 1 d): a weight r(v) in [0, 1] per welded vertex of the template, from
//! `params.blend.region`.
//!
//! - `{"channel": c}`: the source's COLOR_0 channel `c` (as stored, linear, clamped to [0, 1]).
//!   A welded vertex takes the mean over the primitive vertices welded into it (split UV-seam
//!   copies normally carry the same value). Vertices of primitives without COLOR_0 get 0. A
//!   source without any COLOR_0 is refused naming `params.blend.region`.
//! - A list of face indices: the source's triangles numbered across its primitives in order
//!   (primitive 0's triangles, then primitive 1's, ...; as `Asset::primitives` lists them). The
//!   welded vertices of the listed faces get weight 1, all others 0; then the border is
//!   **feathered** inward: a region vertex at ring distance d from the region's border (d = 0
//!   for region vertices that also lie on an unlisted face, found by breadth-first search over
//!   the edges of the region's faces) gets min(1, (d + 1)/(n + 1)) with n =
//!   `params.blend.feather_rings` (default 2; 0 keeps the unfeathered 0/1 weights). The
//!   paper publishes no feathering; a 0/1 weight creases the blended shape along the border
//!   (the Poisson solve is only C0 there). An index past the source's triangle count is refused
//!   naming `params.blend.region`.
//!
//! Vertices with r = 0 are the fixed rest of the template ([`super::poisson`]); in the texture
//! the weight is interpolated barycentrically over each triangle ([`super::region_texture`]).

use std::collections::VecDeque;

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::Asset;

use super::params::Region;
use super::MethodError;

fn region_error(message: String) -> MethodError {
    MethodError::Constraints(ConstraintsError::new("params.blend.region", message))
}

/// The weight of every welded vertex (`welded`: per primitive, per vertex, the welded vertex or
/// `u32::MAX`; `faces`: the welded faces, for the feathering).
///
/// # Errors
/// [`MethodError::Constraints`] naming `params.blend.region` for a channel the source lacks or a
/// face index out of range.
pub fn vertex_weights(
    source: &Asset,
    welded: &[Vec<u32>],
    n_welded: usize,
    region: &Region,
    feather_rings: usize,
) -> Result<Vec<f64>, MethodError> {
    match region {
        Region::Channel { channel } => channel_weights(source, welded, n_welded, channel.index()),
        Region::Faces(list) => {
            let (r, in_region) = face_weights(source, welded, n_welded, list)?;
            Ok(feather(r, &in_region, source, welded, feather_rings))
        }
    }
}

fn channel_weights(
    source: &Asset,
    welded: &[Vec<u32>],
    n: usize,
    channel: usize,
) -> Result<Vec<f64>, MethodError> {
    if source.primitives.iter().all(|p| p.colors.is_none()) {
        return Err(region_error(format!(
            "channel '{}' of COLOR_0 was asked for, but no source primitive has COLOR_0",
            ["r", "g", "b", "a"][channel]
        )));
    }
    let mut sum = vec![0.0f64; n];
    let mut count = vec![0u32; n];
    for (p, prim) in source.primitives.iter().enumerate() {
        for (v, &w) in welded[p].iter().enumerate() {
            if w == u32::MAX {
                continue;
            }
            let value = prim
                .colors
                .as_ref()
                .and_then(|c| c.get(v))
                .map_or(0.0, |c| f64::from(c[channel]));
            sum[w as usize] += if value.is_finite() {
                value.clamp(0.0, 1.0)
            } else {
                0.0
            };
            count[w as usize] += 1;
        }
    }
    Ok(sum
        .iter()
        .zip(&count)
        .map(|(s, &c)| if c > 0 { s / f64::from(c) } else { 0.0 })
        .collect())
}

/// 0/1 weights of the listed faces, and per face of the source (in numbering order) whether it
/// is listed.
fn face_weights(
    source: &Asset,
    welded: &[Vec<u32>],
    n: usize,
    list: &[u32],
) -> Result<(Vec<f64>, Vec<bool>), MethodError> {
    let total: usize = source.primitives.iter().map(|p| p.triangles.len()).sum();
    let mut listed = vec![false; total];
    for &f in list {
        let slot = listed.get_mut(f as usize).ok_or_else(|| {
            region_error(format!(
                "face index {f} is out of range: the source has {total} triangles (numbered \
                 across its primitives in order, from 0)"
            ))
        })?;
        *slot = true;
    }
    let mut r = vec![0.0f64; n];
    let mut k = 0;
    for (p, prim) in source.primitives.iter().enumerate() {
        for t in &prim.triangles {
            if listed[k] {
                for &v in t {
                    if let Some(&w) = welded[p].get(v as usize) {
                        if w != u32::MAX {
                            r[w as usize] = 1.0;
                        }
                    }
                }
            }
            k += 1;
        }
    }
    Ok((r, listed))
}

/// Ramps the weight of a face region up over `rings` vertex rings inside its border.
fn feather(
    mut r: Vec<f64>,
    listed: &[bool],
    source: &Asset,
    welded: &[Vec<u32>],
    rings: usize,
) -> Vec<f64> {
    if rings == 0 {
        return r;
    }
    let n = r.len();
    let mut adjacency: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut dist = vec![usize::MAX; n];
    let mut k = 0;
    for (p, prim) in source.primitives.iter().enumerate() {
        for t in &prim.triangles {
            let w = t.map(|v| welded[p].get(v as usize).copied().unwrap_or(u32::MAX));
            if w.contains(&u32::MAX) {
                k += 1;
                continue;
            }
            if listed[k] {
                for a in 0..3 {
                    adjacency[w[a] as usize].push(w[(a + 1) % 3]);
                    adjacency[w[(a + 1) % 3] as usize].push(w[a]);
                }
            } else {
                // A region vertex on an unlisted face is on the border.
                for &v in &w {
                    if r[v as usize] > 0.0 {
                        dist[v as usize] = 0;
                    }
                }
            }
            k += 1;
        }
    }
    let mut queue: VecDeque<u32> = (0..n as u32).filter(|&v| dist[v as usize] == 0).collect();
    while let Some(v) = queue.pop_front() {
        let d = dist[v as usize];
        if d >= rings {
            continue;
        }
        for &u in &adjacency[v as usize] {
            if dist[u as usize] == usize::MAX {
                dist[u as usize] = d + 1;
                queue.push_back(u);
            }
        }
    }
    for (x, &d) in r.iter_mut().zip(&dist) {
        if *x > 0.0 && d != usize::MAX {
            *x = ((d + 1) as f64 / (rings + 1) as f64).min(1.0);
        }
    }
    r
}
