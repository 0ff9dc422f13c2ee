//! Region flips of the nearest-neighbour field on the coarse levels (ours; not in Chen et al.
//! 2012, whose E-step is PatchMatch's propagation and random search, §4.2).
//!
//! **Why.** Propagation and random search only move a match when one vertex's dissimilarity
//! drops. Two coherent regions of the field that are equally good inside, such as a direct and a
//! mirrored copy of a symmetric source, meet in a seam that no single vertex can remove: on
//! either side of it, the other side's extension is no better. With a texture that the mirror
//! does not keep, such as stripes whose phase it inverts, the seam shows as one ring half a period
//! too wide (README "meshmatch", mirror-end seam).
//!
//! **What.** The field is cut into *coherent regions*: target vertices joined by an edge whose two
//! matches lie within [`COHERENT_EDGES`] mean source edge lengths of each other. Each region of
//! [`MIN_REGION`] vertices up to half the level, smallest first, is re-grown from its largest
//! neighbouring region: an affine map from target to source positions is fitted by least
//! squares to the matches of that neighbour's band next to the region ([`BAND_RINGS`] rings
//! deep), and each vertex of the region is matched to the source vertex nearest to the closest
//! point of its mapped position. This continues the neighbour's map across the seam, mirrored
//! or not. (Developing the map vertex by vertex from the border, with each neighbour's rotation
//! or its local linear map, was tried first: on the coarse levels the field is too noisy
//! locally, and the development stalled or turned.) The caller runs the level's EM iterations
//! from the re-grown field and keeps the result only when its energy (re-voted colours,
//! refreshed dissimilarities) is lower than the current field's. Written by hand: it is
//! specific to this field.

use crate::engine::spatial::Bvh;

use super::matcher::{components_where, ring, Nnf};

/// Two target neighbours are in one region when their matches are closer than this many mean
/// source edge lengths (a match moves by about one edge per target edge inside a coherent region;
/// matches from two unrelated places are many edges apart).
pub const COHERENT_EDGES: f32 = 3.0;

/// Smallest region that is re-grown: smaller ones are the field's ordinary noise, which the
/// E-step itself moves (and each try costs the level's EM iterations).
pub const MIN_REGION: usize = 16;

/// Both meshes of one level: what the regions and the development read.
pub struct FlipGeometry<'a> {
    pub target_positions: &'a [[f32; 3]],
    pub source_positions: &'a [[f32; 3]],
    /// Target 1-rings (CSR offsets, neighbours).
    pub target_adjacency: (&'a [u32], &'a [u32]),
    /// The source level's faces and their BVH.
    pub source_faces: &'a [[u32; 3]],
    pub source_bvh: &'a Bvh,
    /// Mean source edge length of the level.
    pub source_edge: f32,
}

/// The coherent regions of `nnf`: a label per target vertex and the size of every region.
pub fn coherent_regions(g: &FlipGeometry<'_>, nnf: &Nnf) -> (Vec<u32>, Vec<usize>) {
    let limit2 = (COHERENT_EDGES * g.source_edge).powi(2);
    let coherent = |a: usize, b: usize| {
        let (p, q) = (
            g.source_positions[nnf.source[a] as usize],
            g.source_positions[nnf.source[b] as usize],
        );
        (0..3).map(|i| (p[i] - q[i]).powi(2)).sum::<f32>() <= limit2
    };
    let (labels, firsts) = components_where(g.target_adjacency, nnf.source.len(), coherent);
    let mut sizes = vec![0; firsts.len()];
    for &l in &labels {
        sizes[l as usize] += 1;
    }
    (labels, sizes)
}

/// The region bordering `region` along the most target edges, if any.
pub fn largest_neighbour(g: &FlipGeometry<'_>, labels: &[u32], region: u32) -> Option<u32> {
    let mut counts: Vec<(u32, usize)> = Vec::new();
    for (v, &l) in labels.iter().enumerate() {
        if l != region {
            continue;
        }
        for &nb in ring(g.target_adjacency, v) {
            let m = labels[nb as usize];
            if m == region {
                continue;
            }
            match counts.iter_mut().find(|c| c.0 == m) {
                Some(c) => c.1 += 1,
                None => counts.push((m, 1)),
            }
        }
    }
    counts
        .into_iter()
        .max_by_key(|c| (c.1, u32::MAX - c.0))
        .map(|c| c.0)
}

/// Rings of `from` next to `region` whose matches the extension is fitted to: deep enough that
/// the band spans the surface in both directions (one ring of a cylinder lies in a plane), short
/// enough that the fit stays local to the seam. Ours; not swept.
const BAND_RINGS: usize = 4;

/// `nnf` with the vertices of `region` re-grown from the region `from` (module docs).
pub fn regrow(g: &FlipGeometry<'_>, nnf: &Nnf, labels: &[u32], region: u32, from: u32) -> Nnf {
    let mut out = nnf.clone();
    let n = labels.len();
    // The band of `from` next to `region`, breadth first into `from`.
    let mut depth = vec![usize::MAX; n];
    let mut band: Vec<usize> = Vec::new();
    for (v, &l) in labels.iter().enumerate() {
        if l == from
            && ring(g.target_adjacency, v)
                .iter()
                .any(|&nb| labels[nb as usize] == region)
        {
            depth[v] = 0;
            band.push(v);
        }
    }
    let mut head = 0;
    while head < band.len() {
        let v = band[head];
        head += 1;
        if depth[v] + 1 >= BAND_RINGS {
            continue;
        }
        for &nb in ring(g.target_adjacency, v) {
            let nb = nb as usize;
            if labels[nb] == from && depth[nb] == usize::MAX {
                depth[nb] = depth[v] + 1;
                band.push(nb);
            }
        }
    }
    let Some(map) = fit_affine(band.iter().map(|&v| {
        (
            g.target_positions[v],
            g.source_positions[nnf.source[v] as usize],
        )
    })) else {
        return out;
    };
    let rotation = band.first().map_or(0, |&v| nnf.rotation[v]);
    for (t, &l) in labels.iter().enumerate() {
        if l != region {
            continue;
        }
        let q = map.apply(g.target_positions[t]);
        let Some(hit) = g.source_bvh.closest_point(q, f32::INFINITY) else {
            continue;
        };
        let face = g.source_faces[hit.face as usize];
        let corner = (0..3)
            .max_by(|&a, &b| hit.bary[a].total_cmp(&hit.bary[b]))
            .unwrap_or(0);
        out.source[t] = face[corner];
        out.rotation[t] = rotation;
        out.distance[t] = f32::INFINITY;
    }
    out
}

/// A least-squares affine map `q ≈ μ_q + M (p − μ_p)` over the pairs, with a ridge of 1e-3 of
/// the spread on the linear part so that a flat or thin band keeps its other directions;
/// `None` for fewer than four pairs.
fn fit_affine(pairs: impl Iterator<Item = ([f32; 3], [f32; 3])>) -> Option<AffineFit> {
    let pairs: Vec<([f64; 3], [f64; 3])> = pairs
        .map(|(p, q)| (p.map(f64::from), q.map(f64::from)))
        .collect();
    if pairs.len() < 4 {
        return None;
    }
    let n = pairs.len() as f64;
    let mp: [f64; 3] = std::array::from_fn(|i| pairs.iter().map(|x| x.0[i]).sum::<f64>() / n);
    let mq: [f64; 3] = std::array::from_fn(|i| pairs.iter().map(|x| x.1[i]).sum::<f64>() / n);
    let mut c = [[0.0f64; 3]; 3];
    let mut b = [[0.0f64; 3]; 3];
    for (p, q) in &pairs {
        let (dp, dq): ([f64; 3], [f64; 3]) = (
            std::array::from_fn(|i| p[i] - mp[i]),
            std::array::from_fn(|i| q[i] - mq[i]),
        );
        for r in 0..3 {
            for k in 0..3 {
                c[r][k] += dp[r] * dp[k];
                b[r][k] += dq[r] * dp[k];
            }
        }
    }
    let ridge = 1e-3 * (c[0][0] + c[1][1] + c[2][2]);
    for (r, row) in c.iter_mut().enumerate() {
        row[r] += ridge;
    }
    let inv = invert3(c)?;
    let m = std::array::from_fn(|r| {
        std::array::from_fn(|k| (0..3).map(|j| b[r][j] * inv[j][k]).sum::<f64>())
    });
    Some(AffineFit { m, mp, mq })
}

fn invert3(a: [[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if !det.is_normal() {
        return None;
    }
    let c = |r: usize, k: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
        a[r1][k1] * a[r2][k2] - a[r1][k2] * a[r2][k1]
    };
    Some(std::array::from_fn(|r| {
        std::array::from_fn(|k| c(k, r) / det)
    }))
}

struct AffineFit {
    m: [[f64; 3]; 3],
    mp: [f64; 3],
    mq: [f64; 3],
}

impl AffineFit {
    fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        let d: [f64; 3] = std::array::from_fn(|i| f64::from(p[i]) - self.mp[i]);
        std::array::from_fn(|r| {
            (self.mq[r] + (0..3).map(|k| self.m[r][k] * d[k]).sum::<f64>()) as f32
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::mesh::primitives::grid;

    /// 1-rings of a face list, CSR.
    fn rings(n: usize, faces: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); n];
        for f in faces {
            for k in 0..3 {
                for m in 1..3 {
                    let (a, b) = (f[k] as usize, f[(k + m) % 3]);
                    if !lists[a].contains(&b) {
                        lists[a].push(b);
                    }
                }
            }
        }
        let mut offsets = vec![0u32];
        let mut flat = Vec::new();
        for l in lists {
            flat.extend(l);
            offsets.push(flat.len() as u32);
        }
        (offsets, flat)
    }

    /// A 20 × 10 grid matched onto itself: columns 0-9 directly, columns 10-20 mirrored onto
    /// columns 20-10 (a seam between columns 9 and 10, whose matches are 11 columns apart).
    #[test]
    fn a_mirrored_region_regrows_as_the_continuation_of_its_neighbour() {
        let surface = grid(20, 10, 1.0);
        let n = surface.vertex_count();
        let adjacency = rings(n, &surface.faces);
        let bvh = Bvh::build(&surface.positions, &surface.faces);
        let g = FlipGeometry {
            target_positions: &surface.positions,
            source_positions: &surface.positions,
            target_adjacency: (&adjacency.0, &adjacency.1),
            source_faces: &surface.faces,
            source_bvh: &bvh,
            source_edge: 1.0,
        };
        let column = |v: usize| v % 21;
        let source: Vec<u32> = (0..n)
            .map(|v| {
                let (i, j) = (column(v), v / 21);
                let i = if i < 10 { i } else { 30 - i };
                (j * 21 + i) as u32
            })
            .collect();
        let nnf = Nnf {
            source,
            rotation: vec![0; n],
            distance: vec![0.0; n],
        };
        let (labels, sizes) = coherent_regions(&g, &nnf);
        assert_eq!(sizes.len(), 2, "direct and mirrored halves: {sizes:?}");
        let (direct, mirrored) = (labels[0], labels[20]);
        assert_eq!(sizes[direct as usize], 110);
        assert_eq!(sizes[mirrored as usize], 121);
        assert_eq!(largest_neighbour(&g, &labels, mirrored), Some(direct));
        let regrown = regrow(&g, &nnf, &labels, mirrored, direct);
        for v in 0..n {
            assert_eq!(
                regrown.source[v] as usize,
                v,
                "vertex {v} (column {})",
                column(v)
            );
        }
        // A field without a seam is one region.
        let identity = Nnf {
            source: (0..n as u32).collect(),
            ..nnf
        };
        assert_eq!(coherent_regions(&g, &identity).1, vec![n]);
    }
}
