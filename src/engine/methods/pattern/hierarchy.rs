//! The face-cluster hierarchy (Soler et al. 2002, §2.1 and §3.1 "general meshes").
//!
//! Every connected component (faces joined by shared edges) is a root. A cluster of more than
//! `children` faces is split into `children` sub-clusters grown from random seed faces by
//! Dijkstra on face-centroid distances over face adjacency; a cluster of at most `children`
//! faces is split into its single faces (the leaves). Sizes are kept near uniform by growing the
//! regions together, the smallest region taking its nearest free face next (the paper grows from
//! seeds by distance and keeps sizes near uniform without saying how). Borders are then
//! regularised by exchanging triangles: a face with at most one edge-neighbour in its own
//! region and at least two in another one moves there (a face with one neighbour in its region
//! is a leaf of that region's dual graph, so the move never disconnects it), three passes.
//!
//! Per level (a face belongs, at level L, to its ancestor of level min(L, its leaf's level)),
//! each cluster stores its border vertices, its control vertices (border vertices where at least
//! three regions meet, the outside of an open boundary counting as one) and its same-level
//! neighbours. A cluster is a disc when its Euler characteristic is 1 and every border vertex
//! has exactly two border edges; clusters that are not discs are never flattened, only split.
//!
//! **Seed re-draw** (§3.1: seeds are re-drawn when the control vertices are nearly aligned). After
//! a split, each region's control vertices *within the parent* are found (vertices where at least
//! three of {the sibling regions, everything outside the parent, an open boundary} meet). The
//! split's quality is the smallest over its regions of
//! `min(A / (ALIGN_MIN · d_max²), d_min / (CLOSE_MIN · d_max))`, with `A` the largest triangle
//! spanned by three of the region's control vertices and `d_min`, `d_max` their closest and
//! farthest pair: 0 for fewer than three control vertices, for collinear ones or for two that
//! coincide. Below 1 the seeds are drawn again, at most [`SEED_DRAWS`] times in all, and the best
//! split is kept. Constants the paper does not publish: [`ALIGN_MIN`] = 0.05 (an equilateral
//! triangle scores 0.43, one whose height is a tenth of its base 0.05) and [`CLOSE_MIN`] = 0.05.
//! The flattening here does not use the control polygon ([`super::flatten`]), so the re-draw
//! only keeps the clusters' shapes compact, as in the paper; the number of re-drawn splits is
//! [`Hierarchy::seed_redraws`].

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::{Surface, Topology};
use crate::engine::rng::SplitMix64;

/// No cluster / no face.
pub const NONE: u32 = u32::MAX;

/// Passes of border regularisation per split.
const REGULARISE_PASSES: usize = 3;

/// Seed draws per split at most (module doc: seed re-draw).
pub const SEED_DRAWS: usize = 4;

/// Largest control triangle / farthest control pair² below which control vertices are "nearly
/// aligned".
pub const ALIGN_MIN: f32 = 0.05;

/// Closest / farthest control pair below which two control vertices are "too close".
pub const CLOSE_MIN: f32 = 0.05;

/// One cluster of faces.
#[derive(Clone, Debug, Default)]
pub struct Cluster {
    /// Faces of the surface (sorted).
    pub faces: Vec<u32>,
    /// Depth: 0 for a root.
    pub level: u32,
    /// The parent cluster.
    pub parent: Option<u32>,
    /// Sub-clusters (empty for a leaf, a single face).
    pub children: Vec<u32>,
    /// Connected component (the root's index among the roots).
    pub component: u32,
    /// Whether the faces form a topological disc.
    pub disc: bool,
    /// Vertices on the cluster's contour (sorted).
    pub border: Vec<u32>,
    /// Border vertices shared by at least three regions of its level (sorted).
    pub control: Vec<u32>,
    /// Clusters of the same level sharing an edge with it (sorted).
    pub neighbours: Vec<u32>,
}

/// The hierarchy of one surface.
#[derive(Clone, Debug, Default)]
pub struct Hierarchy {
    /// All clusters; parents before children.
    pub clusters: Vec<Cluster>,
    /// The roots, one per connected component.
    pub roots: Vec<u32>,
    /// The leaf (single-face cluster) of each face.
    pub face_leaf: Vec<u32>,
    /// Clusters per level.
    pub per_level: Vec<usize>,
    /// Splits whose seeds were drawn more than once (module doc: seed re-draw).
    pub seed_redraws: usize,
}

impl Hierarchy {
    /// Deepest level + 1.
    pub fn depth(&self) -> usize {
        self.per_level.len()
    }

    /// Whether a cluster is a leaf.
    pub fn is_leaf(&self, c: u32) -> bool {
        self.clusters[c as usize].children.is_empty()
    }
}

/// Faces grouped into edge-connected components.
pub fn face_components(topo: &Topology, faces: usize) -> Vec<Vec<u32>> {
    let mut seen = vec![false; faces];
    let mut out = Vec::new();
    for start in 0..faces {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut comp = vec![start as u32];
        let mut i = 0;
        while i < comp.len() {
            let f = comp[i] as usize;
            i += 1;
            for n in topo.face_neighbors[f].iter().flatten() {
                if !seen[*n as usize] {
                    seen[*n as usize] = true;
                    comp.push(*n);
                }
            }
        }
        comp.sort_unstable();
        out.push(comp);
    }
    out
}

/// Builds the hierarchy down to single faces.
///
/// # Errors
/// [`Cancelled`].
pub fn build(
    surface: &Surface,
    topo: &Topology,
    children: usize,
    seed: u64,
    control: &Control,
) -> Result<Hierarchy, Cancelled> {
    let nf = surface.face_count();
    let centroids: Vec<[f32; 3]> = (0..nf)
        .map(|f| {
            let p = surface.face_positions(f);
            [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0)
        })
        .collect();
    let mut h = Hierarchy {
        face_leaf: vec![NONE; nf],
        ..Default::default()
    };
    let stage = control.stage("hierarchy", nf as u64)?;
    let mut rng = SplitMix64::new(crate::engine::rng::mix(seed, 0x5041_5454, 1));
    let mut scratch = Scratch::new(nf);
    let mut queue = Vec::new();
    for (ci, comp) in face_components(topo, nf).into_iter().enumerate() {
        let id = h.clusters.len() as u32;
        h.roots.push(id);
        h.clusters.push(Cluster {
            faces: comp,
            component: ci as u32,
            ..Default::default()
        });
        queue.push(id);
    }
    let mut head = 0;
    while head < queue.len() {
        let id = queue[head];
        head += 1;
        let (faces, level, component) = {
            let c = &h.clusters[id as usize];
            (c.faces.clone(), c.level, c.component)
        };
        if faces.len() == 1 {
            h.face_leaf[faces[0] as usize] = id;
            stage.tick(1)?;
            continue;
        }
        let parts = if faces.len() <= children {
            faces.iter().map(|f| vec![*f]).collect()
        } else {
            let (parts, draws, _) = split(
                &faces,
                surface,
                topo,
                &centroids,
                (children, SEED_DRAWS),
                &mut rng,
                &mut scratch,
            );
            h.seed_redraws += usize::from(draws > 1);
            parts
        };
        for mut part in parts {
            part.sort_unstable();
            let child = h.clusters.len() as u32;
            h.clusters.push(Cluster {
                faces: part,
                level: level + 1,
                parent: Some(id),
                component,
                ..Default::default()
            });
            h.clusters[id as usize].children.push(child);
            queue.push(child);
        }
    }
    let depth = h.clusters.iter().map(|c| c.level).max().unwrap_or(0) as usize + 1;
    h.per_level = vec![0; depth];
    for c in &h.clusters {
        h.per_level[c.level as usize] += 1;
    }
    for level in 0..depth {
        control.check()?;
        annotate_level(&mut h, surface, topo, level as u32);
    }
    Ok(h)
}

/// Per-face marks reused across splits.
struct Scratch {
    region: Vec<u32>,
    in_set: Vec<u32>,
    stamp: u32,
}

impl Scratch {
    fn new(n: usize) -> Self {
        Self {
            region: vec![NONE; n],
            in_set: vec![0; n],
            stamp: 0,
        }
    }
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Splits a connected set of faces into about `k` connected regions of near-uniform size,
/// drawing the seeds again while the control vertices are degenerate (module doc); returns the
/// regions, the number of draws and the kept split's quality. `(k, max_draws)`.
fn split(
    faces: &[u32],
    surface: &Surface,
    topo: &Topology,
    centroids: &[[f32; 3]],
    (k, max_draws): (usize, usize),
    rng: &mut SplitMix64,
    s: &mut Scratch,
) -> (Vec<Vec<u32>>, usize, f32) {
    s.stamp += 1;
    let stamp = s.stamp;
    for f in faces {
        s.in_set[*f as usize] = stamp;
    }
    let mut best: Option<(f32, Vec<u32>)> = None;
    let mut draws = 0;
    while draws < max_draws.max(1) {
        draws += 1;
        grow(faces, topo, centroids, k, rng, s);
        let quality = split_quality(faces, surface, topo, k, s);
        if best.as_ref().is_none_or(|b| quality > b.0) {
            best = Some((
                quality,
                faces.iter().map(|f| s.region[*f as usize]).collect(),
            ));
        }
        if quality >= 1.0 {
            break;
        }
    }
    let mut quality = 0.0;
    if let Some((q, regions)) = best {
        quality = q;
        for (f, r) in faces.iter().zip(regions) {
            s.region[*f as usize] = r;
        }
    }
    let mut out = vec![Vec::new(); k];
    for f in faces {
        let r = s.region[*f as usize];
        if r != NONE {
            out[r as usize].push(*f);
        }
    }
    out.retain(|p| !p.is_empty());
    (out, draws, quality)
}

/// One split of `faces` (a connected set) into `k` regions with at most `max_draws` seed draws,
/// as [`build`] does it with [`SEED_DRAWS`]: `(regions, draws, quality)` (module doc).
pub fn split_faces(
    surface: &Surface,
    topo: &Topology,
    faces: &[u32],
    k: usize,
    max_draws: usize,
    seed: u64,
) -> (Vec<Vec<u32>>, usize, f32) {
    let nf = surface.face_count();
    if k == 0 || faces.len() < k || faces.iter().any(|f| *f as usize >= nf) {
        return (vec![faces.to_vec()], 0, 0.0);
    }
    let centroids: Vec<[f32; 3]> = (0..nf)
        .map(|f| {
            let p = surface.face_positions(f);
            [0, 1, 2].map(|c| (p[0][c] + p[1][c] + p[2][c]) / 3.0)
        })
        .collect();
    let mut rng = SplitMix64::new(seed);
    let mut scratch = Scratch::new(nf);
    split(
        faces,
        surface,
        topo,
        &centroids,
        (k, max_draws),
        &mut rng,
        &mut scratch,
    )
}

/// One draw: `k` random seeds grown together, the smallest region first, then regularised.
fn grow(
    faces: &[u32],
    topo: &Topology,
    centroids: &[[f32; 3]],
    k: usize,
    rng: &mut SplitMix64,
    s: &mut Scratch,
) {
    let stamp = s.stamp;
    for f in faces {
        s.region[*f as usize] = NONE;
    }
    // Distinct random seeds.
    let mut seeds: Vec<u32> = Vec::with_capacity(k);
    while seeds.len() < k {
        let f = faces[rng.below(faces.len() as u64) as usize];
        if !seeds.contains(&f) {
            seeds.push(f);
        }
    }
    let mut heaps: Vec<BinaryHeap<Reverse<(u32, u32)>>> = vec![BinaryHeap::new(); k];
    let mut size = vec![0usize; k];
    for (r, f) in seeds.iter().enumerate() {
        heaps[r].push(Reverse((0, *f)));
    }
    // Distances are compared as f32 bits (non-negative floats order like their bits).
    let mut assigned = 0;
    while assigned < faces.len() {
        let Some(r) = (0..k)
            .filter(|r| !heaps[*r].is_empty())
            .min_by_key(|r| size[*r])
        else {
            break;
        };
        while let Some(Reverse((d, f))) = heaps[r].pop() {
            let fi = f as usize;
            if s.region[fi] != NONE {
                continue;
            }
            s.region[fi] = r as u32;
            size[r] += 1;
            assigned += 1;
            let d = f32::from_bits(d);
            for n in topo.face_neighbors[fi].iter().flatten() {
                let ni = *n as usize;
                if s.in_set[ni] == stamp && s.region[ni] == NONE {
                    let nd = d + dist(centroids[fi], centroids[ni]);
                    heaps[r].push(Reverse((nd.to_bits(), *n)));
                }
            }
            break;
        }
    }
    regularise(faces, topo, s, &mut size);
}

/// The smallest [`control_quality`] over the regions of the current split (`s.region`), with the
/// control vertices found inside the parent (everything outside the parent and an open boundary
/// count together as one region).
fn split_quality(faces: &[u32], surface: &Surface, topo: &Topology, k: usize, s: &Scratch) -> f32 {
    const OUTSIDE: u32 = NONE - 1;
    let mut verts: Vec<u32> = faces
        .iter()
        .flat_map(|f| surface.faces[*f as usize])
        .collect();
    verts.sort_unstable();
    verts.dedup();
    let mut controls: Vec<Vec<[f32; 3]>> = vec![Vec::new(); k];
    let mut around: Vec<u32> = Vec::new();
    for v in verts {
        around.clear();
        for f in topo.vertex_faces(v as usize) {
            let fi = *f as usize;
            let inside = s.in_set[fi] == s.stamp && s.region[fi] != NONE;
            let label = if inside { s.region[fi] } else { OUTSIDE };
            if !around.contains(&label) {
                around.push(label);
            }
            let fv = surface.faces[fi];
            let open = (0..3).any(|e| {
                (fv[e] == v || fv[(e + 1) % 3] == v) && topo.face_neighbors[fi][e].is_none()
            });
            if open && !around.contains(&OUTSIDE) {
                around.push(OUTSIDE);
            }
        }
        if around.len() >= 3 {
            for r in &around {
                if *r != OUTSIDE {
                    controls[*r as usize].push(surface.positions[v as usize]);
                }
            }
        }
    }
    controls
        .iter()
        .map(Vec::as_slice)
        .map(control_quality)
        .fold(f32::INFINITY, f32::min)
}

/// `min(A / (ALIGN_MIN · d_max²), d_min / (CLOSE_MIN · d_max))` of a region's control vertices
/// (module doc); 0 for fewer than three. At most the first 24 points are examined (O(n³)).
pub fn control_quality(points: &[[f32; 3]]) -> f32 {
    let p = &points[..points.len().min(24)];
    if p.len() < 3 {
        return 0.0;
    }
    let sub = |a: [f32; 3], b: [f32; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let (mut dmin, mut dmax) = (f32::INFINITY, 0.0f32);
    for (i, a) in p.iter().enumerate() {
        for b in &p[i + 1..] {
            let d = dist(*a, *b);
            dmin = dmin.min(d);
            dmax = dmax.max(d);
        }
    }
    if dmax <= 0.0 || !dmax.is_finite() {
        return 0.0;
    }
    let mut area = 0.0f32;
    for (i, o) in p.iter().enumerate() {
        for (j, q) in p.iter().enumerate().skip(i + 1) {
            for r in &p[j + 1..] {
                let (a, b) = (sub(*q, *o), sub(*r, *o));
                let c = [
                    a[1] * b[2] - a[2] * b[1],
                    a[2] * b[0] - a[0] * b[2],
                    a[0] * b[1] - a[1] * b[0],
                ];
                area = area.max(0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt());
            }
        }
    }
    (area / (ALIGN_MIN * dmax * dmax)).min(dmin / (CLOSE_MIN * dmax))
}

/// Border regularisation by exchanging triangles (see the module doc).
fn regularise(faces: &[u32], topo: &Topology, s: &mut Scratch, size: &mut [usize]) {
    let stamp = s.stamp;
    for _ in 0..REGULARISE_PASSES {
        let mut moved = 0;
        for f in faces {
            let fi = *f as usize;
            let own = s.region[fi];
            let mut counts = [(NONE, 0u32); 3];
            let mut own_count = 0;
            for n in topo.face_neighbors[fi].iter().flatten() {
                let ni = *n as usize;
                if s.in_set[ni] != stamp {
                    continue;
                }
                let r = s.region[ni];
                if r == own {
                    own_count += 1;
                } else if let Some(slot) = counts.iter_mut().find(|c| c.0 == r || c.0 == NONE) {
                    slot.0 = r;
                    slot.1 += 1;
                }
            }
            if own_count > 1 || size[own as usize] <= 1 {
                continue;
            }
            if let Some((r, _)) = counts.iter().find(|c| c.0 != NONE && c.1 >= 2) {
                s.region[fi] = *r;
                size[own as usize] -= 1;
                size[*r as usize] += 1;
                moved += 1;
            }
        }
        if moved == 0 {
            break;
        }
    }
}

/// The cluster of `face` at `level` (its deepest ancestor at or above that level).
fn cluster_at(h: &Hierarchy, face: u32, level: u32) -> u32 {
    let mut c = h.face_leaf[face as usize];
    while h.clusters[c as usize].level > level {
        c = h.clusters[c as usize].parent.unwrap_or(c);
    }
    c
}

/// Border and control vertices, same-level neighbours and the disc test of the clusters of
/// one level.
fn annotate_level(h: &mut Hierarchy, surface: &Surface, topo: &Topology, level: u32) {
    let nf = surface.face_count();
    let label: Vec<u32> = (0..nf as u32).map(|f| cluster_at(h, f, level)).collect();
    let ids: Vec<u32> = (0..h.clusters.len() as u32)
        .filter(|c| h.clusters[*c as usize].level == level)
        .collect();
    for id in ids {
        let faces = std::mem::take(&mut h.clusters[id as usize].faces);
        let mut verts: Vec<u32> = Vec::with_capacity(faces.len() * 3);
        let mut border_edges: Vec<(u32, u32)> = Vec::new();
        let mut neighbours: Vec<u32> = Vec::new();
        for f in &faces {
            let fv = surface.faces[*f as usize];
            verts.extend_from_slice(&fv);
            for e in 0..3 {
                let other = topo.face_neighbors[*f as usize][e];
                let (a, b) = (fv[e], fv[(e + 1) % 3]);
                match other {
                    Some(o) if label[o as usize] == id => {}
                    Some(o) => {
                        neighbours.push(label[o as usize]);
                        border_edges.push((a.min(b), a.max(b)));
                    }
                    None => border_edges.push((a.min(b), a.max(b))),
                }
            }
        }
        verts.sort_unstable();
        verts.dedup();
        neighbours.sort_unstable();
        neighbours.dedup();
        let mut border: Vec<u32> = border_edges.iter().flat_map(|e| [e.0, e.1]).collect();
        border.sort_unstable();
        let degree_two = border.chunk_by(|a, b| a == b).all(|run| run.len() == 2);
        border.dedup();
        let edges = (3 * faces.len() + border_edges.len()) / 2;
        let chi = verts.len() as i64 - edges as i64 + faces.len() as i64;
        let control: Vec<u32> = border
            .iter()
            .copied()
            .filter(|v| regions_at(surface, topo, &label, *v) >= 3)
            .collect();
        let c = &mut h.clusters[id as usize];
        c.faces = faces;
        c.disc = chi == 1 && degree_two && !border.is_empty();
        c.border = border;
        c.control = control;
        c.neighbours = neighbours;
    }
}

/// Distinct regions around a vertex, the outside of an open boundary counting as one.
fn regions_at(surface: &Surface, topo: &Topology, label: &[u32], v: u32) -> usize {
    let mut seen: Vec<u32> = Vec::new();
    let mut open = false;
    for f in topo.vertex_faces(v as usize) {
        let l = label[*f as usize];
        if !seen.contains(&l) {
            seen.push(l);
        }
        let fv = surface.faces[*f as usize];
        for e in 0..3 {
            let touches = fv[e] == v || fv[(e + 1) % 3] == v;
            if touches && topo.face_neighbors[*f as usize][e].is_none() {
                open = true;
            }
        }
    }
    seen.len() + usize::from(open)
}
