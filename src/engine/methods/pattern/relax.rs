//! Local relaxation along the edges a face-cluster shares with textured neighbours (Soler, Cani &
//! Angelidis 2002, §4.4): greedy randomised moves of the cluster's own border and control
//! vertices in texture space that lower the colour difference across the seams.
//!
//! **Seam error.** A seam edge pairs an edge of the current cluster (its two texture-space corners,
//! `ours`) with the same surface edge as the textured neighbour maps it (`theirs_px`). Its error is
//! the mean over `k` samples `s_i = (i + 0.5) / k` of `|T(ours(s_i)) − T(theirs(s_i))|²` in the
//! fitting colour space (`texture.rs`), `k = clamp(⌈length of theirs in px⌉, 4, 32)` (one sample
//! per pattern pixel, the paper's "per pixel, along the common edge"; at least 4, at most 32 so a
//! long edge stays cheap). The problem's error is `Σ weight · error / Σ weight` (the paper's
//! per-vertex influence function of its Figure 6 is the caller's `weight`).
//!
//! **Moves.** [`SWEEPS`] sweeps over the movable vertices in a random order; in sweep `s` each
//! vertex tries [`TRIES`] uniform random positions in the disc of radius `radius_px / 2^s` around
//! where it is (the paper's "smaller and smaller area"; the caller shrinks `radius_px` per
//! hierarchy level), never farther than `radius_px` from its start. A try is kept only if the
//! error of the seams at that vertex drops and none of its triangles changes orientation or
//! degenerates (a triangle that starts degenerate is not checked); with a non-toroidal pattern
//! a try outside the image is never taken (such moves were clamped at the output, a seam the
//! relaxation had not seen). Vertices without seams do not
//! move. Sweep count and tries are not published; 4 × 8 is enough for the error to stop dropping
//! on the test cases (tests/engine/pattern_fit.rs). References to vertices that do not exist and
//! non-finite start positions make their seams and triangles inert instead of panicking.

use crate::engine::rng::SplitMix64;

use super::texture::PatternTexture;

/// Sweeps over the movable vertices.
pub const SWEEPS: usize = 4;
/// Random positions tried per vertex and sweep.
pub const TRIES: usize = 8;

/// A uv corner in pattern pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Corner {
    /// A vertex of the current cluster that may move: index into [`RelaxProblem::start_px`].
    Movable(usize),
    /// A fixed position (pattern pixels).
    Fixed([f32; 2]),
}

/// An edge of the current cluster and the same edge as the textured neighbour maps it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeamEdge {
    /// Our two corners.
    pub ours: [Corner; 2],
    /// The neighbour's positions of the same two surface points, in the same order.
    pub theirs_px: [[f32; 2]; 2],
    /// Weight of this edge in the error (≥ 0).
    pub weight: f32,
}

/// What [`relax`] moves and measures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RelaxProblem {
    /// The movable vertices' placements (pattern pixels).
    pub start_px: Vec<[f32; 2]>,
    /// Move area (shrinks per level; the caller sets it).
    pub radius_px: f32,
    /// The seams to match.
    pub seams: Vec<SeamEdge>,
    /// The cluster's triangles: no move may flip one.
    pub triangles: Vec<[Corner; 3]>,
}

/// The relaxed positions and the seam error before and after.
#[derive(Clone, Debug, PartialEq)]
pub struct Relaxed {
    /// New positions of the movable vertices (same order as `start_px`).
    pub px: Vec<[f32; 2]>,
    /// `Σ weight · error / Σ weight` at the start (0 without seams).
    pub error_before: f32,
    /// The same after the moves (every kept move lowers it).
    pub error_after: f32,
}

/// Minimises the seam error by greedy random moves (module doc).
pub fn relax(texture: &PatternTexture, problem: &RelaxProblem, rng: &mut SplitMix64) -> Relaxed {
    let n = problem.start_px.len();
    let mut px = problem.start_px.clone();
    let movable_ok: Vec<bool> = px
        .iter()
        .map(|p| p[0].is_finite() && p[1].is_finite())
        .collect();
    let valid = |c: &Corner| match c {
        Corner::Movable(i) => *i < n && movable_ok[*i],
        Corner::Fixed(p) => p[0].is_finite() && p[1].is_finite(),
    };
    let seams: Vec<&SeamEdge> = problem
        .seams
        .iter()
        .filter(|s| {
            s.ours.iter().all(valid)
                && s.theirs_px.iter().flatten().all(|v| v.is_finite())
                && s.weight.is_finite()
                && s.weight > 0.0
        })
        .collect();
    let triangles: Vec<&[Corner; 3]> = problem
        .triangles
        .iter()
        .filter(|t| t.iter().all(valid))
        .collect();
    let samples: Vec<usize> = seams.iter().map(|s| sample_count(s)).collect();
    let signs: Vec<f32> = triangles
        .iter()
        .map(|t| signed_area(t, &px).signum())
        .collect();
    // Per vertex: its seams and triangles.
    let mut vertex_seams = vec![Vec::new(); n];
    for (e, s) in seams.iter().enumerate() {
        for c in &s.ours {
            if let Corner::Movable(i) = c {
                vertex_seams[*i].push(e);
            }
        }
    }
    let mut vertex_triangles = vec![Vec::new(); n];
    for (t, tri) in triangles.iter().enumerate() {
        for c in tri.iter() {
            if let Corner::Movable(i) = c {
                vertex_triangles[*i].push(t);
            }
        }
    }
    let weight_sum: f32 = seams.iter().map(|s| s.weight).sum();
    let total = |px: &[[f32; 2]]| -> f32 {
        if weight_sum <= 0.0 {
            return 0.0;
        }
        let e: f32 = (0..seams.len())
            .map(|e| seams[e].weight * seam_error(texture, seams[e], samples[e], px))
            .sum();
        e / weight_sum
    };
    let error_before = total(&px);
    let radius = if problem.radius_px.is_finite() {
        problem.radius_px.max(0.0)
    } else {
        0.0
    };
    let mut order: Vec<usize> = (0..n).filter(|&i| !vertex_seams[i].is_empty()).collect();
    // A non-toroidal pattern's patches stay inside the image (§4.2), moved or not.
    let (w, h) = (texture.width() as f32, texture.height() as f32);
    let inside = |p: [f32; 2]| {
        texture.toroidal() || ((0.0..=w).contains(&p[0]) && (0.0..=h).contains(&p[1]))
    };
    for sweep in 0..SWEEPS {
        let step = radius / (1u32 << sweep) as f32;
        if step <= 0.0 {
            break;
        }
        shuffle(&mut order, rng);
        for &v in &order {
            let local = |px: &[[f32; 2]]| -> f32 {
                vertex_seams[v]
                    .iter()
                    .map(|&e| seams[e].weight * seam_error(texture, seams[e], samples[e], px))
                    .sum()
            };
            let mut current = local(&px);
            for _ in 0..TRIES {
                let old = px[v];
                let candidate = random_in_disc(old, step, rng);
                let start = problem.start_px[v];
                if (candidate[0] - start[0]).hypot(candidate[1] - start[1]) > radius
                    || !inside(candidate)
                {
                    continue;
                }
                px[v] = candidate;
                let keeps_orientation = vertex_triangles[v]
                    .iter()
                    .all(|&t| signs[t] == 0.0 || signed_area(triangles[t], &px) * signs[t] > 0.0);
                let error = if keeps_orientation {
                    local(&px)
                } else {
                    f32::INFINITY
                };
                if error < current {
                    current = error;
                } else {
                    px[v] = old;
                }
            }
        }
    }
    let error_after = total(&px);
    Relaxed {
        px,
        error_before,
        error_after,
    }
}

/// The mean squared colour difference along one seam edge.
fn seam_error(texture: &PatternTexture, seam: &SeamEdge, k: usize, px: &[[f32; 2]]) -> f32 {
    let [a, b] = seam.ours.map(|c| position(&c, px));
    let [c, d] = seam.theirs_px;
    let mut sum = 0.0f32;
    for i in 0..k {
        let s = (i as f32 + 0.5) / k as f32;
        let ours = texture.sample(lerp(a, b, s));
        let theirs = texture.sample(lerp(c, d, s));
        sum += (0..3)
            .map(|ch| (ours[ch] - theirs[ch]).powi(2))
            .sum::<f32>();
    }
    sum / k as f32
}

fn sample_count(seam: &SeamEdge) -> usize {
    let [c, d] = seam.theirs_px;
    let length = (d[0] - c[0]).hypot(d[1] - c[1]);
    (length.ceil() as usize).clamp(4, 32)
}

fn position(c: &Corner, px: &[[f32; 2]]) -> [f32; 2] {
    match c {
        Corner::Movable(i) => px[*i],
        Corner::Fixed(p) => *p,
    }
}

fn lerp(a: [f32; 2], b: [f32; 2], s: f32) -> [f32; 2] {
    [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])]
}

/// Twice the signed area of a triangle; its sign is the triangle's orientation.
fn signed_area(t: &[Corner; 3], px: &[[f32; 2]]) -> f32 {
    let [a, b, c] = t.map(|c| position(&c, px));
    (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
}

fn random_in_disc(centre: [f32; 2], radius: f32, rng: &mut SplitMix64) -> [f32; 2] {
    let r = radius * rng.unit_f32().sqrt();
    let angle = std::f32::consts::TAU * rng.unit_f32();
    [centre[0] + r * angle.cos(), centre[1] + r * angle.sin()]
}

fn shuffle(items: &mut [usize], rng: &mut SplitMix64) {
    for i in (1..items.len()).rev() {
        let j = rng.below(i as u64 + 1) as usize;
        items.swap(i, j);
    }
}
