//! The driver (Soler et al. 2002, §2.2): which cluster is textured when, and how.
//!
//! 1. Per connected component, the first patch: the coarsest flat-enough ancestor of
//!    `first_face` when given (in its component), else the largest flat-enough cluster of the
//!    coarsest level that has one. It is placed at the user's scale and orientation: the
//!    target's up axis (+y) projected onto the surface points to the image's top, turned by
//!    `orientation_deg`, the patch centred on the image. With a non-toroidal pattern a cluster
//!    that does not fit inside the image that way is split instead (its children are tried at
//!    the next level); only a single face can still overflow, and the output clamps its UVs.
//! 2. Level by level from the roots, a priority queue by the number of already-textured
//!    neighbour patches. A cluster that is not a disc, not flat enough, partly textured, or
//!    whose best fit (after relaxation) is above `fit_threshold`, is split into its children
//!    (they go to the next level); a leaf accepts its best fit. A cluster with no textured
//!    neighbour waits for the next level while other clusters there may texture its
//!    surroundings; when none can, it is placed like a first patch.
//! 3. A fit: the neighbours' band triangles ([`super::bands`]) rasterised as the mask, the best
//!    placement over all orientations by FFT ([`super::fit::best_fit`]), then the local
//!    relaxation of the cluster's shared border vertices ([`super::relax::relax`]).
//!
//! Fit error as thresholded: the fit's mean squared colour error per mask pixel divided by the
//! mean squared colour difference of two random pattern pixels ([`random_pair_error`]), so 1 is
//! what a random placement scores whatever the pattern's contrast; after the relaxation it is
//! multiplied by the relaxation's error ratio (after / before) along the seams.
//!
//! Constants the paper does not publish: the relaxation radius, 0.1 × the square root of the
//! cluster's area in pixels (it shrinks with the cluster, so per level), at most 0.2 × the
//! shortest shared edge in pixels (with the area bound alone, border moves stretched the
//! border triangles of a 2,208-face sphere: 10% of the area above anisotropy 2.2; with a
//! quarter of the mean shared edge, 10% above 1.4).

use std::collections::BinaryHeap;

use super::bands::{band_triangles, seam_edges, shared_edges, BandInput, Patch};
use super::fit::{best_fit, Placement};
use super::flatten::{flatten, local_triangle, Flat};
use super::hierarchy::{Hierarchy, NONE};
use super::mask::rasterise_mask;
use super::params::PatternParams;
use super::relax::{relax, Corner, RelaxProblem};
use super::report::{DriverStats, LevelStats};
use super::texture::PatternTexture;
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::{Surface, Topology};
use crate::engine::rng::SplitMix64;

/// Pixel pairs drawn by [`random_pair_error`].
const RANDOM_PAIRS: usize = 4096;

/// Relaxation radius as a fraction of the square root of the cluster's area in pixels.
const RELAX_RADIUS: f32 = 0.1;

/// ... and at most this fraction of the shortest shared border edge in pixels, so a move cannot
/// stretch a border triangle beyond recognition.
const RELAX_EDGE: f32 = 0.2;

/// Shortest shared edge in pattern pixels.
fn min_edge_px(surface: &Surface, edges: &[super::bands::SharedEdge], ppw: f64) -> f32 {
    let mut min = f64::MAX;
    for e in edges {
        let a = surface.positions[e.vertices[0] as usize];
        let b = surface.positions[e.vertices[1] as usize];
        let l = (0..3)
            .map(|k| f64::from(a[k] - b[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        min = min.min(l);
    }
    if edges.is_empty() {
        return 0.0;
    }
    (min * ppw) as f32
}

/// What the driver reads.
pub struct DriverInput<'a> {
    /// The target surface.
    pub surface: &'a Surface,
    /// Its adjacency.
    pub topo: &'a Topology,
    /// Its cluster hierarchy.
    pub hierarchy: &'a Hierarchy,
    /// The pattern.
    pub texture: &'a PatternTexture,
    /// The params.
    pub params: &'a PatternParams,
    /// World units per image width.
    pub scale: f32,
    /// Surface face of `first_face`, if given.
    pub first_face: Option<u32>,
    /// The job's seed.
    pub seed: u64,
}

/// What the driver produces.
pub struct DriverOutput {
    /// Accepted patches.
    pub patches: Vec<Patch>,
    /// Patch of each surface face.
    pub face_patch: Vec<u32>,
    /// Figures for the report.
    pub stats: DriverStats,
}

/// Mean squared colour difference (summed over the three channels) of two random pattern
/// pixels: what a random placement scores.
pub fn random_pair_error(texture: &PatternTexture, seed: u64) -> f32 {
    let mut rng = SplitMix64::new(seed);
    let (w, h) = (texture.width() as f32, texture.height() as f32);
    let mut sum = 0.0f64;
    for _ in 0..RANDOM_PAIRS {
        let a = texture.sample([rng.unit_f32() * w, rng.unit_f32() * h]);
        let b = texture.sample([rng.unit_f32() * w, rng.unit_f32() * h]);
        sum += (0..3)
            .map(|k| f64::from((a[k] - b[k]).powi(2)))
            .sum::<f64>();
    }
    ((sum / RANDOM_PAIRS as f64) as f32).max(1e-12)
}

struct State<'a> {
    input: &'a DriverInput<'a>,
    px_per_world: f64,
    random_error: f32,
    patches: Vec<Patch>,
    face_patch: Vec<u32>,
    component_patches: Vec<usize>,
    stats: DriverStats,
    rng: SplitMix64,
}

/// Runs the driver.
///
/// # Errors
/// [`Cancelled`].
pub fn run(input: &DriverInput<'_>, control: &Control) -> Result<DriverOutput, Cancelled> {
    let h = input.hierarchy;
    let nf = input.surface.face_count();
    let random_error = random_pair_error(input.texture, crate::engine::rng::mix(input.seed, 7, 7));
    let mut st = State {
        input,
        px_per_world: f64::from(input.texture.width()) / f64::from(input.scale),
        random_error,
        patches: Vec::new(),
        face_patch: vec![NONE; nf],
        component_patches: vec![0; h.roots.len()],
        stats: DriverStats {
            random_pair_error: random_error,
            ..Default::default()
        },
        rng: SplitMix64::new(crate::engine::rng::mix(input.seed, 0x7061_7474, 2)),
    };
    let stage = control.stage("driver", nf as u64)?;
    if let Some(f) = input.first_face {
        if let Some((c, flat, px)) = coarsest_flat_ancestor(&st, f) {
            place_fresh(&mut st, c, &flat, px, true);
        }
    }
    let mut current: Vec<u32> = h.roots.clone();
    let mut level = 0usize;
    while !current.is_empty() {
        control.check()?;
        let mut ls = LevelStats {
            level,
            ..Default::default()
        };
        let next = run_level(&mut st, &current, &mut ls);
        stage.tick(0)?;
        st.stats.levels.push(ls);
        current = next;
        level += 1;
    }
    stage.tick(nf as u64)?;
    Ok(DriverOutput {
        patches: st.patches,
        face_patch: st.face_patch,
        stats: st.stats,
    })
}

/// The coarsest ancestor of `face` that is a flat-enough disc and, placed fresh, fits the image
/// (a leaf always does), with its fresh placement.
fn coarsest_flat_ancestor(st: &State<'_>, face: u32) -> Option<(u32, Flat, Vec<[f32; 2]>)> {
    let h = st.input.hierarchy;
    let mut chain = vec![h.face_leaf[face as usize]];
    while let Some(p) = h.clusters[*chain.last()? as usize].parent {
        chain.push(p);
    }
    chain.into_iter().rev().find_map(|c| {
        let flat = flat_enough(st, c)?;
        let px = fresh_px(st, c, &flat)?;
        Some((c, flat, px))
    })
}

/// The flattening of a cluster if it is a disc and flat enough (a leaf always is).
fn flat_enough(st: &State<'_>, c: u32) -> Option<Flat> {
    let h = st.input.hierarchy;
    let cl = &h.clusters[c as usize];
    if !cl.disc && !h.is_leaf(c) {
        return None;
    }
    let flat = flatten(st.input.surface, &cl.faces)?;
    (h.is_leaf(c) || flat.is_flat(st.input.params.flatness_threshold)).then_some(flat)
}

/// One level of the driver; returns the clusters of the next level.
fn run_level(st: &mut State<'_>, current: &[u32], ls: &mut LevelStats) -> Vec<u32> {
    let h = st.input.hierarchy;
    let mut next = Vec::new();
    let mut ready: Vec<(u32, Flat)> = Vec::new();
    for &c in current {
        let cl = &h.clusters[c as usize];
        let textured = cl
            .faces
            .iter()
            .filter(|f| st.face_patch[**f as usize] != NONE)
            .count();
        if textured == cl.faces.len() {
            continue;
        }
        ls.clusters += 1;
        if textured > 0 {
            ls.split += 1;
            next.extend_from_slice(&cl.children);
            continue;
        }
        match flat_enough(st, c) {
            Some(flat) => ready.push((c, flat)),
            None => {
                if cl.disc {
                    ls.not_flat += 1;
                } else {
                    ls.not_disc += 1;
                }
                ls.split += 1;
                next.extend_from_slice(&cl.children);
            }
        }
    }
    // Components without a patch get their first one: the largest flat cluster.
    ready.sort_by_key(|(c, _)| std::cmp::Reverse(h.clusters[*c as usize].faces.len()));
    let mut rest = Vec::new();
    for (c, flat) in ready {
        let comp = h.clusters[c as usize].component as usize;
        if st.component_patches[comp] == 0 {
            if let Some(px) = fresh_px(st, c, &flat) {
                place_fresh(st, c, &flat, px, true);
                ls.textured += 1;
            } else {
                ls.too_large += 1;
                ls.split += 1;
                next.extend_from_slice(&h.clusters[c as usize].children);
            }
        } else {
            rest.push((c, flat));
        }
    }
    let mut flats: Vec<Option<Flat>> = Vec::new();
    let mut heap = BinaryHeap::new();
    for (c, flat) in rest {
        let k = flats.len();
        flats.push(Some(flat));
        heap.push((neighbour_count(st, c), k, c));
    }
    let mut waiting: Vec<(usize, u32)> = Vec::new();
    loop {
        if let Some((count, k, c)) = heap.pop() {
            let now = neighbour_count(st, c);
            if now != count {
                heap.push((now, k, c));
                continue;
            }
            if now == 0 {
                waiting.push((k, c));
                continue;
            }
            let Some(flat) = flats[k].take() else {
                continue;
            };
            if try_fit(st, c, &flat, ls) {
                ls.textured += 1;
            } else {
                ls.split += 1;
                next.extend_from_slice(&h.clusters[c as usize].children);
            }
            continue;
        }
        if waiting.is_empty() {
            break;
        }
        let mut any = false;
        for (k, c) in std::mem::take(&mut waiting) {
            let n = neighbour_count(st, c);
            any |= n > 0;
            heap.push((n, k, c));
        }
        if any {
            continue;
        }
        if !next.is_empty() {
            // Nothing around them is textured yet: they wait for the next level.
            while let Some((_, k, c)) = heap.pop() {
                if let Some(flat) = flats[k].take() {
                    ls.deferred += 1;
                    drop(flat);
                    next.push(c);
                }
            }
            break;
        }
        if let Some((_, k, c)) = heap.pop() {
            if let Some(flat) = flats[k].take() {
                if let Some(px) = fresh_px(st, c, &flat) {
                    place_fresh(st, c, &flat, px, false);
                    ls.textured += 1;
                } else {
                    ls.too_large += 1;
                    ls.split += 1;
                    next.extend_from_slice(&h.clusters[c as usize].children);
                }
            }
        }
    }
    next
}

/// Distinct textured patches sharing an edge with the cluster.
fn neighbour_count(st: &State<'_>, c: u32) -> usize {
    let cl = &st.input.hierarchy.clusters[c as usize];
    let mut seen: Vec<u32> = Vec::new();
    for f in &cl.faces {
        for o in st.input.topo.face_neighbors[*f as usize].iter().flatten() {
            let p = st.face_patch[*o as usize];
            if p != NONE && !seen.contains(&p) {
                seen.push(p);
            }
        }
    }
    seen.len()
}

/// The frame direction of the target's up axis on the cluster (its central face's plane).
fn frame_up(st: &State<'_>, c: u32, flat: &Flat) -> [f64; 2] {
    let surface = st.input.surface;
    let cl = &st.input.hierarchy.clusters[c as usize];
    let mut best = (f64::MAX, cl.faces[0]);
    let centre = {
        let b = flat.bbox();
        [(b[0][0] + b[1][0]) / 2.0, (b[0][1] + b[1][1]) / 2.0]
    };
    for f in &cl.faces {
        let fv = surface.faces[*f as usize];
        let mut m = [0.0; 2];
        for v in fv {
            let p = flat.at(v).unwrap_or([0.0; 2]);
            m[0] += p[0] / 3.0;
            m[1] += p[1] / 3.0;
        }
        let d = (m[0] - centre[0]).powi(2) + (m[1] - centre[1]).powi(2);
        if d < best.0 {
            best = (d, *f);
        }
    }
    let f = best.1 as usize;
    let fv = surface.faces[f];
    let p = surface.face_positions(f);
    let n = surface.face_normal(f).map(f64::from);
    let up = [0.0, 1.0, 0.0];
    let dn: f64 = up.iter().zip(&n).map(|(a, b)| a * b).sum();
    let mut t: [f64; 3] = [0, 1, 2].map(|k| up[k] - dn * n[k]);
    let tl = t.iter().map(|x| x * x).sum::<f64>().sqrt();
    if tl < 0.1 {
        t = [1.0, 0.0, 0.0];
    }
    // Local 2-D coordinates of the face and of t, then the linear map local → frame.
    let (q, _) = local_triangle(p);
    let e1: [f64; 3] = [0, 1, 2].map(|k| f64::from(p[1][k]) - f64::from(p[0][k]));
    let l1 = e1.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-300);
    let x = e1.map(|c| c / l1);
    let y = [
        n[1] * x[2] - n[2] * x[1],
        n[2] * x[0] - n[0] * x[2],
        n[0] * x[1] - n[1] * x[0],
    ];
    let tl2 = [
        t.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>(),
        t.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>(),
    ];
    let fr: Vec<[f64; 2]> = fv.iter().map(|v| flat.at(*v).unwrap_or([0.0; 2])).collect();
    // Solve A · [q1-q0, q2-q0] = [f1-f0, f2-f0] for the 2×2 map A.
    let (a, b) = (
        [q[1][0] - q[0][0], q[1][1] - q[0][1]],
        [q[2][0] - q[0][0], q[2][1] - q[0][1]],
    );
    let (fa, fb) = (
        [fr[1][0] - fr[0][0], fr[1][1] - fr[0][1]],
        [fr[2][0] - fr[0][0], fr[2][1] - fr[0][1]],
    );
    let det = a[0] * b[1] - b[0] * a[1];
    if det.abs() < 1e-300 {
        return [0.0, 1.0];
    }
    // inverse of [a b] (columns)
    let inv = [[b[1] / det, -b[0] / det], [-a[1] / det, a[0] / det]];
    let l = [
        inv[0][0] * tl2[0] + inv[0][1] * tl2[1],
        inv[1][0] * tl2[0] + inv[1][1] * tl2[1],
    ];
    [fa[0] * l[0] + fb[0] * l[1], fa[1] * l[0] + fb[1] * l[1]]
}

/// The pattern pixels of a cluster placed at the user's scale and orientation, centred on the
/// image. For a non-toroidal pattern a cluster that does not fit inside the image gives `None`
/// (the caller splits it, §4.2: the patch must stay inside); a leaf always gets its placement
/// (a single face larger than the image cannot be split: the output clamps its UVs and warns).
fn fresh_px(st: &State<'_>, c: u32, flat: &Flat) -> Option<Vec<[f32; 2]>> {
    let ppw = st.px_per_world;
    let up = frame_up(st, c, flat);
    let phi = f64::from(st.input.params.orientation_deg).to_radians();
    // Desired pattern direction of the surface's up: the image's top (−y), turned by phi.
    let want = [-phi.sin(), -phi.cos()];
    let rotation = (want[1].atan2(want[0]) - up[1].atan2(up[0])) as f32;
    let b = flat.bbox();
    let centre = [
        (b[0][0] + b[1][0]) / 2.0 * ppw,
        (b[0][1] + b[1][1]) / 2.0 * ppw,
    ];
    let zero = Placement {
        rotation,
        translation_px: [0.0, 0.0],
    };
    let rc = zero.apply([centre[0] as f32, centre[1] as f32]);
    let tex = st.input.texture;
    let (w, h) = (tex.width() as f32, tex.height() as f32);
    let placement = Placement {
        rotation,
        translation_px: [w / 2.0 - rc[0], h / 2.0 - rc[1]],
    };
    let px: Vec<[f32; 2]> = frame_px(flat, ppw)
        .into_iter()
        .map(|p| placement.apply(p))
        .collect();
    let inside = |p: &[f32; 2]| (0.0..=w).contains(&p[0]) && (0.0..=h).contains(&p[1]);
    let fits = tex.toroidal() || st.input.hierarchy.is_leaf(c) || px.iter().all(inside);
    fits.then_some(px)
}

/// Accepts a cluster placed by [`fresh_px`].
fn place_fresh(st: &mut State<'_>, c: u32, flat: &Flat, px: Vec<[f32; 2]>, first: bool) {
    if first {
        st.stats.first_patches += 1;
    } else {
        st.stats.fresh_patches += 1;
    }
    accept(st, c, flat, px, None);
}

fn frame_px(flat: &Flat, ppw: f64) -> Vec<[f32; 2]> {
    flat.frame
        .iter()
        .map(|p| [(p[0] * ppw) as f32, (p[1] * ppw) as f32])
        .collect()
}

/// Records an accepted patch.
fn accept(st: &mut State<'_>, c: u32, flat: &Flat, px: Vec<[f32; 2]>, fit_error: Option<f32>) {
    let h = st.input.hierarchy;
    let cl = &h.clusters[c as usize];
    let id = st.patches.len() as u32;
    for f in &cl.faces {
        st.face_patch[*f as usize] = id;
    }
    st.component_patches[cl.component as usize] += 1;
    st.stats
        .record_patch(cl.faces.len(), flat.e_flat, fit_error);
    st.patches.push(Patch {
        cluster: c,
        vertices: flat.vertices.clone(),
        px,
    });
}

/// Fits a cluster against its textured neighbours; accepts it (true) or leaves it to be split.
fn try_fit(st: &mut State<'_>, c: u32, flat: &Flat, ls: &mut LevelStats) -> bool {
    let h = st.input.hierarchy;
    let leaf = h.is_leaf(c);
    let cl = &h.clusters[c as usize];
    let edges = shared_edges(st.input.surface, st.input.topo, &st.face_patch, &cl.faces);
    let band = BandInput {
        surface: st.input.surface,
        topo: st.input.topo,
        patches: &st.patches,
        face_patch: &st.face_patch,
        px_per_world: st.px_per_world,
        band: st.input.params.band,
    };
    let triangles = band_triangles(&band, flat, &edges);
    let mask = rasterise_mask(st.input.texture, &triangles);
    let b = flat.bbox();
    let ppw = st.px_per_world;
    let bbox_px = [
        [(b[0][0] * ppw) as f32, (b[0][1] * ppw) as f32],
        [(b[1][0] * ppw) as f32, (b[1][1] * ppw) as f32],
    ];
    st.stats.fits += 1;
    ls.fits += 1;
    let Some(fit) = best_fit(st.input.texture, &mask, bbox_px) else {
        if leaf {
            if let Some(px) = fresh_px(st, c, flat) {
                place_fresh(st, c, flat, px, false);
            }
            return true;
        }
        ls.fit_rejected += 1;
        return false;
    };
    let fpx = frame_px(flat, ppw);
    let mut px: Vec<[f32; 2]> = fpx.iter().map(|p| fit.placement.apply(*p)).collect();
    // Local relaxation of the shared border vertices.
    let mut movable: Vec<u32> = edges.iter().flat_map(|e| e.vertices).collect();
    movable.sort_unstable();
    movable.dedup();
    let seams = seam_edges(&st.patches, &edges, &movable);
    let local = |v: u32| flat.local(v).unwrap_or(0);
    let start_px: Vec<[f32; 2]> = movable.iter().map(|v| px[local(*v)]).collect();
    let triangles: Vec<[Corner; 3]> = cl
        .faces
        .iter()
        .map(|f| {
            st.input.surface.faces[*f as usize].map(|v| match movable.binary_search(&v) {
                Ok(i) => Corner::Movable(i),
                Err(_) => Corner::Fixed(px[local(v)]),
            })
        })
        .collect();
    let area_px: f64 = cl
        .faces
        .iter()
        .map(|f| f64::from(st.input.surface.face_area(*f as usize)))
        .sum::<f64>()
        * ppw
        * ppw;
    let edge_px = min_edge_px(st.input.surface, &edges, ppw);
    let problem = RelaxProblem {
        start_px,
        radius_px: (RELAX_RADIUS * area_px.sqrt() as f32).min(RELAX_EDGE * edge_px),
        seams,
        triangles,
    };
    let relaxed = relax(st.input.texture, &problem, &mut st.rng);
    for (v, p) in movable.iter().zip(&relaxed.px) {
        px[local(*v)] = *p;
    }
    let ratio = if relaxed.error_before > 0.0 {
        (relaxed.error_after / relaxed.error_before).clamp(0.0, 1.0)
    } else {
        1.0
    };
    st.stats
        .record_relax(relaxed.error_before, relaxed.error_after);
    let error = fit.error / st.random_error * ratio;
    if error > st.input.params.fit_threshold && !leaf {
        ls.fit_rejected += 1;
        return false;
    }
    accept(st, c, flat, px, Some(error));
    true
}
