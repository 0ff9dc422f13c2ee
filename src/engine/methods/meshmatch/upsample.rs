//! Upsampling the nearest-neighbour field to the next finer level (Chen et al. 2012, §4.2
//! "Upsampling", Figure 6).
//!
//! For a target vertex `v` of the finer level: its closest point on the coarser target level is
//! known from the hierarchy; the coarse vertex `c` nearest to it (largest barycentric weight) is
//! the anchor. The offset `v − c` is expressed in `c`'s tangent frame (the local geodesic offset
//! for the short distances involved), rotated by the match's rotation `k` into the frame of the
//! matched source vertex `s = NNF(c)`, and added to `s`'s position in its tangent plane. That
//! point is projected onto the finer source level, whose nearest vertex becomes `NNF(v)`. The
//! rotation is carried as well: `k_v = k + (α_T − α_S) / (2π/A)`, where `α_T` is the angle of
//! `v`'s tangent in `c`'s frame and `α_S` that of the new source vertex's tangent in `s`'s frame.
//!
//! By-example mode (§5.3): a match that lands on a source vertex matches may not use, and has no
//! usable descendant of the coarse match, is replaced by a usable vertex drawn at random (seeded
//! per target vertex and level), like the coarsest level's initialization; the EM iterations then
//! restore coherence. The paper does not say how it keeps upsampled matches inside the example;
//! without this they survived into the finest level. Moving them to the nearest usable vertex
//! instead collapsed whole synthesized regions onto the one stripe at the usable border (a striped
//! capsule's synthesized half came out 100% dark).

use rayon::prelude::*;

use crate::engine::geometry::expmap::LocalFrames;
use crate::engine::math::dot;
use crate::engine::multires::Hierarchy;
use crate::engine::rng::mix;
use crate::engine::spatial::Bvh;

use super::matcher::Nnf;

/// Angle of `v` (projected) in the frame `(t, b)`.
fn angle_in(v: [f32; 3], t: [f32; 3], b: [f32; 3]) -> f32 {
    dot(v, b).atan2(dot(v, t))
}

/// One side of the upsampling: hierarchy and frames of every level.
pub struct Side<'a> {
    /// The hierarchy.
    pub hierarchy: &'a Hierarchy,
    /// Frames per level.
    pub frames: &'a [LocalFrames],
}

/// The source vertices matches may use on the finer level (by-example mode) and the seed of the
/// random replacements.
#[derive(Clone, Copy)]
pub struct Allowed<'a> {
    /// Usable source vertices of the finer level.
    pub mask: &'a [bool],
    /// Seed of the replacement draws.
    pub seed: u64,
}

/// Upsamples `coarse` (the field of level `level + 1`) to level `level`. `source_bvh` is the BVH
/// of the finer source level. With `allowed` (by-example mode), every match lands on a usable
/// source vertex: a usable descendant of the coarse match if there is one, else a random usable
/// vertex (see the module docs).
pub fn upsample(
    coarse: &Nnf,
    level: usize,
    target: &Side<'_>,
    source: &Side<'_>,
    source_bvh: &Bvh,
    spokes: usize,
    allowed: Option<Allowed<'_>>,
) -> Nnf {
    let pool: Vec<u32> = allowed.as_ref().map_or_else(Vec::new, |a| {
        (0..a.mask.len() as u32)
            .filter(|&s| a.mask[s as usize])
            .collect()
    });
    let th = target.hierarchy;
    let sh = source.hierarchy;
    let fine_t = &th.level(level).surface;
    let coarse_t = &th.level(level + 1).surface;
    let coarse_s = &sh.level(level + 1).surface;
    let fine_s = &sh.level(level).surface;
    let (tf_fine, tf_coarse) = (&target.frames[level], &target.frames[level + 1]);
    let (sf_fine, sf_coarse) = (&source.frames[level], &source.frames[level + 1]);
    let step = std::f32::consts::TAU / spokes as f32;
    let n = fine_t.vertex_count();
    let results: Vec<(u32, u16)> = (0..n)
        .into_par_iter()
        .map(|v| {
            let fp = th.project_to_coarser(level, v as u32);
            let face = coarse_t.faces[fp.face as usize];
            let corner = (0..3)
                .max_by(|&a, &b| fp.bary[a].total_cmp(&fp.bary[b]).then(b.cmp(&a)))
                .unwrap_or(0);
            let c = face[corner] as usize;
            let (s, k) = (coarse.source[c] as usize, coarse.rotation[c]);
            let pv = fine_t.positions[v];
            let pc = coarse_t.positions[c];
            let d = [pv[0] - pc[0], pv[1] - pc[1], pv[2] - pc[2]];
            let (dx, dy) = (dot(d, tf_coarse.tangent[c]), dot(d, tf_coarse.bitangent[c]));
            let phi = k as f32 * step;
            let (sin, cos) = phi.sin_cos();
            let (sx, sy) = (cos * dx - sin * dy, sin * dx + cos * dy);
            let ps = coarse_s.positions[s];
            let (ts, bs) = (sf_coarse.tangent[s], sf_coarse.bitangent[s]);
            let q: [f32; 3] = std::array::from_fn(|i| ps[i] + sx * ts[i] + sy * bs[i]);
            let hit = source_bvh.closest_point(q, f32::INFINITY);
            let mut fine = match hit {
                Some(h) => {
                    let f = fine_s.faces[h.face as usize];
                    let best = (0..3)
                        .max_by(|&a, &b| h.bary[a].total_cmp(&h.bary[b]).then(b.cmp(&a)))
                        .unwrap_or(0);
                    f[best]
                }
                None => 0,
            };
            if let Some(ok) = &allowed {
                if !ok.mask[fine as usize] && !pool.is_empty() {
                    // A descendant of the coarse match that may be used, else a random usable
                    // vertex.
                    let draw = mix(ok.seed, level as u64, v as u64) % pool.len() as u64;
                    fine = sh
                        .children(level + 1, s as u32)
                        .iter()
                        .copied()
                        .find(|&d| ok.mask[d as usize])
                        .unwrap_or(pool[draw as usize]);
                }
            }
            let alpha_t = angle_in(
                tf_fine.tangent[v],
                tf_coarse.tangent[c],
                tf_coarse.bitangent[c],
            );
            let alpha_s = angle_in(sf_fine.tangent[fine as usize], ts, bs);
            let shift = ((alpha_t - alpha_s) / step).round() as i64;
            let kv = (k as i64 + shift).rem_euclid(spokes as i64) as u16;
            (fine, kv)
        })
        .collect();
    Nnf {
        source: results.iter().map(|r| r.0).collect(),
        rotation: results.iter().map(|r| r.1).collect(),
        distance: vec![f32::INFINITY; n],
    }
}
