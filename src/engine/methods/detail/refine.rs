//! Texture-space high-frequency refinement (Berkiten et al. 2017, §3.3.2, Fig. 8): detail finer
//! than the finest synthesis level, carried from the source into the target's textures.
//!
//! The paper rasterises the synthesised per-vertex displacement into the target's texture, takes
//! a small source patch around every vertex at its corresponding location, warps it to the
//! target's UV layout, refines its translation against the target texture, and adds only the
//! frequencies above a cutoff set by the median UV edge length. Here, per step:
//!
//! 1. **Correspondence.** Every finest target vertex `v` has the source point `S_v` its value was
//!    read from by its strongest patch in the last synthesis pass
//!    ([`super::synthesis::Synthesis::finest_source_points`]).
//! 2. **Translation refinement** (per vertex, [`Refinement::new`]): `S_v` moves by `δ` in the
//!    source's tangent plane so that the source's finest-level displacement around it matches
//!    the synthesised target displacement on `v` and its one ring (least squares on both sides'
//!    values minus their ring means, Gauss-Newton on the source level's piecewise-linear
//!    displacement, `iterations` steps, `|δ| ≤ max_translation` finest edges; a step is kept only
//!    if it lowers the mismatch). The ring is placed around `S_v` by the tangent frames of the
//!    synthesis' convention (`u` = `(1, 0, 0)` projected onto the tangent plane, `(0, 1, 0)`
//!    where that is shorter than 0.1, `v = n × u`). The translations are then averaged over
//!    coherent neighbours (`smoothing` steps; ours): independent per-vertex moves made
//!    neighbouring vertices read different phases of the same ripple, and their blend lost
//!    15 % of the ripples' energy (README sweep).
//! 3. **Warp** (per texel, [`Refinement::at`]): the texel's point `p` on the finest target level
//!    lies in a face with corners `k` and weights `b_k`. Each corner maps it through its own
//!    frames, `q_k = S_k + a u_s + b v_s` with `(a, b)` the offset `p − x_k` in the target
//!    frame: the paper's per-vertex patch warped to the target's layout. The reads at the `q_k`
//!    are blended by `b_k`, which is continuous across faces (a corner maps a point the same way
//!    in all its faces). The map of a corner is linear, fitted by least squares to its ring's
//!    source points (those the map keeps at their distance within a factor 2), so inside one
//!    synthesised patch the corners' images agree to second order; the frames stand in where
//!    no fit is possible. Where the `q_k` lie within `c` (a quarter of the source's sampling or
//!    of the finest edge, the smaller) of their weighted mean, one read there stands for the
//!    three; from `3c` the three reads are blended; between, both, linearly (continuous).
//! 4. **High frequencies only.** At the mapped source point `P` (closest point on the finest
//!    source level) the added value is `d_fine(P) − d_level(P)`: the source's full-resolution
//!    displacement ([`FineDetail`]: a ray to the detailed mesh, or the source's displacement
//!    map) minus the finest source level's piecewise-linear interpolation of it. The finest
//!    source level shares the target's finest edge length (§3.1), so this residual holds
//!    exactly the frequencies the target's finest level cannot carry: the cutoff is the mesh's
//!    own sampling, not a filter kernel. `d_fine` is read from the base, not from the flat face:
//!    the curved base lies off a face by about `½ Σ_{i<j} b_i b_j (x_j − x_i)·(n_j − n_i)` (the
//!    sagitta, exact on a circular arc), which would otherwise enter the residual with one sign
//!    over every convex part. A ray takes the hit nearest to the level's value (not to
//!    the base: a fold of the detailed surface would otherwise jump to another sheet), and the
//!    residual is bounded by one finest edge (detail narrower than two edges and taller than one
//!    would be steeper than `π`; what exceeds it is a sheet jump, not detail: a constant of
//!    ours). **Replaced step:** the paper's cutoff comes from the
//!    median UV edge length and filters the texture; the residual is used instead because it
//!    needs no image filter across UV seams (a filter in texture space would mix texels of
//!    neighbouring charts) and has no free width. The UV edge length decides *whether* to refine:
//!    with fewer than `min_texels_per_edge` texels per finest edge (default 2, the Nyquist limit
//!    of the texture) there is no band for the residual to fill and the step is skipped.
//! 5. **Normal map.** The residual's surface gradient (`∇d_fine − ∇d_level`, the level's
//!    interpolated per-vertex gradient as the target's own is) is carried to the
//!    target through the frames (`(g·u_s) u_t + (g·v_s) v_t`) and added to the
//!    synthesised gradient, so the normal map carries the same detail as the displacement
//!    texture. For a mesh source `∇d_fine` comes from the detailed surface's interpolated normal
//!    `n_h` at the ray hit (`n_h ∝ n − ∇d` to first order); for a map source from central
//!    differences at `±h` along the tangent frame.
//!
//! Written by hand: the pieces are closest-point queries on the crate's BVH and small least
//! squares; the source reads are [`super::fine_detail`]'s.

use rayon::prelude::*;
use serde::Serialize;

use super::displacement::area_weighted_normals;
use super::fine_detail::tangential;
use crate::engine::math::{add, cross, dot, length, normalize, scale, sub, to_f32, to_f64};
use crate::engine::mesh::csr::vertex_neighbours;
use crate::engine::mesh::Surface;
use crate::engine::spatial::Bvh;

/// The source's full-resolution displacement at a point of its base.
pub trait FineDetail: Sync {
    /// Displacement and its tangential surface gradient at `p` (on the source's base or finest
    /// level) with unit normal `n`, `predicted` the finest level's value there (a ray takes the
    /// hit nearest to it, not a sheet of the surface that happens to lie closer to the base);
    /// `None` where there is no detail to read.
    fn at(&self, p: [f64; 3], n: [f64; 3], predicted: f64) -> Option<(f64, [f64; 3])>;

    /// The world size of the detail's own sampling (mean edge length of a detailed mesh, texel
    /// size of a map): nothing finer than twice this exists to transfer.
    fn sampling(&self) -> f64;
}

/// The synthesis' tangent frame convention at unit normal `n`: `u` = `(1, 0, 0)` projected
/// (`(0, 1, 0)` where that projection is shorter than 0.1), `v = n × u`.
pub fn frame(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let mut u = tangential([1.0, 0.0, 0.0], n);
    if length(u) < 0.1 {
        u = tangential([0.0, 1.0, 0.0], n);
    }
    let u = normalize(u);
    (u, cross(n, u))
}

/// Parameters of the refinement.
#[derive(Clone, Debug, PartialEq)]
pub struct RefineParams {
    /// Run the refinement (the paper's step). Default true.
    pub enabled: bool,
    /// Texels per finest edge below which the step is skipped. Default 2 (Nyquist).
    pub min_texels_per_edge: f64,
    /// Largest translation of a vertex's source point, in finest edges. Default 0.25 (swept in
    /// the README: 0 to 1 change the transferred ripples' energy and their placement on the
    /// crests they belong to by under 1 % with smoothing; 0.25 lowers the level mismatch by a
    /// fifth).
    pub max_translation: f64,
    /// Gauss-Newton steps of the translation. Default 2.
    pub iterations: usize,
    /// Averaging steps of the translations over coherent neighbours. Default 2.
    pub smoothing: usize,
}

impl Default for RefineParams {
    fn default() -> Self {
        Self {
            enabled: true,
            min_texels_per_edge: 2.0,
            max_translation: 0.25,
            iterations: 2,
            smoothing: 2,
        }
    }
}

/// What the refinement did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RefineReport {
    /// Whether residual detail was added to the textures.
    pub applied: bool,
    /// Why not, when it was not.
    pub skipped_because: Option<String>,
    /// Texels of the output textures per finest edge (mean over the UV-mapped surface).
    pub texels_per_edge: f64,
    /// Samples of the source's detail (detailed-mesh edges, map texels) per finest edge.
    pub source_samples_per_edge: f64,
    /// Finest target vertices with a source point.
    pub mapped_vertices: usize,
    /// Finest target vertices.
    pub vertices: usize,
    /// Mean and largest translation, in finest edges.
    pub translation_mean: f64,
    /// See `translation_mean`.
    pub translation_max: f64,
    /// RMS mismatch (world units) between the source level around `S_v` and the synthesised
    /// target on `v`'s ring, before and after the translation.
    pub mismatch_before: f64,
    /// See `mismatch_before`.
    pub mismatch_after: f64,
    /// Seconds of the set-up (translations).
    pub seconds: f64,
    /// Points the textures asked for (every covered texel once: one sample serves the
    /// displacement and the normal map; and the range's samples before the bake) and the source
    /// reads made for them (one where the corners' images agree, up to three where not).
    pub points: u64,
    /// See `points`.
    pub reads: u64,
}

/// What the refinement reads: the finest levels, the synthesis' correspondence and the source's
/// full-resolution detail.
pub struct RefineInput<'a> {
    /// Finest source level.
    pub source: &'a Surface,
    /// Its displacement per vertex.
    pub source_displacement: &'a [f64],
    /// Finest target level.
    pub target: &'a Surface,
    /// The synthesised displacement per vertex of `target`.
    pub target_displacement: &'a [f64],
    /// Per vertex of `target`, its source point.
    pub points: &'a [Option<[f64; 3]>],
    /// The source's full-resolution detail.
    pub fine: &'a dyn FineDetail,
}

/// A point of the finest source level.
struct LevelPoint {
    /// The point on the level's flat face.
    point: [f64; 3],
    /// The base's estimated point above it (the flat face's chord error removed).
    on_base: [f64; 3],
    normal: [f64; 3],
    value: f64,
    gradient: [f64; 3],
}

/// A vertex's source point and its frames on both sides.
#[derive(Clone, Copy)]
struct Mapped {
    point: [f64; 3],
    source_frame: ([f64; 3], [f64; 3]),
    target_frame: ([f64; 3], [f64; 3]),
    /// The images on the source of the target frame's `u` and `v` (the local linear map, fitted
    /// to the ring; the source frame where it cannot be).
    image: ([f64; 3], [f64; 3]),
}

/// A vertex's mapping, its mean squared mismatch before and after the translation, and the
/// translation.
type Translated = (Mapped, f64, f64, [f64; 3]);

/// The prepared refinement (see the module doc).
pub struct Refinement<'a> {
    input: RefineInput<'a>,
    bvh: Bvh,
    source_normals: Vec<[f64; 3]>,
    /// The source level's displacement gradient per vertex (interpolated like the target's,
    /// [`super::outputs`]; a face-constant one would print the level's facets into the map).
    source_gradients: Vec<[f64; 3]>,
    mapped: Vec<Option<Mapped>>,
    /// Images of a point closer than this (world units) are read once.
    coherence: f64,
    /// Finest mean edge length: the residual's bound.
    edge: f64,
    /// Points asked ([`Refinement::at`]) and source reads made for them.
    counts: [std::sync::atomic::AtomicU64; 2],
    /// What was done.
    pub report: RefineReport,
}

impl<'a> Refinement<'a> {
    /// The finest source level at its point closest to `q`.
    fn level_at(&self, q: [f64; 3]) -> Option<LevelPoint> {
        let s = self.input.source;
        // `q` is a tangent-plane step from the level: bounded search first.
        let hit = (self.bvh.closest_point(to_f32(q), self.edge as f32))
            .or_else(|| self.bvh.closest_point(to_f32(q), f32::INFINITY))?;
        let f = hit.face as usize;
        let corners = s.faces[f];
        let b = hit.bary.map(|x| x as f64);
        let mut normal = [0.0; 3];
        let mut value = 0.0;
        for k in 0..3 {
            let v = corners[k] as usize;
            normal = add(normal, scale(self.source_normals[v], b[k]));
            value += b[k] * self.input.source_displacement[v];
        }
        let normal = normalize(normal);
        let gradient = (0..3).fold([0.0; 3], |acc, k| {
            add(acc, scale(self.source_gradients[corners[k] as usize], b[k]))
        });
        let gradient = tangential(gradient, normal);
        // The curved base lies off the flat face by about ½ Σ_{i<j} b_i b_j (x_j − x_i)·(n_j − n_i)
        // along the normal (exact for a circular arc: t(1 − t) L² / 2R).
        let x = corners.map(|c| to_f64(s.positions[c as usize]));
        let nv = corners.map(|c| self.source_normals[c as usize]);
        let sagitta: f64 = [(0, 1), (1, 2), (0, 2)]
            .iter()
            .map(|&(i, j)| 0.5 * b[i] * b[j] * dot(sub(x[j], x[i]), sub(nv[j], nv[i])))
            .sum();
        let point = to_f64(hit.point);
        Some(LevelPoint {
            point,
            on_base: add(point, scale(normal, sagitta)),
            normal,
            value,
            gradient,
        })
    }

    /// The residual (value, source-space gradient) near `q`.
    fn residual(&self, q: [f64; 3]) -> Option<(f64, [f64; 3], LevelPoint)> {
        self.counts[1].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let l = self.level_at(q)?;
        let (d, g) = self.input.fine.at(l.on_base, l.normal, l.value)?;
        let g = tangential(g, l.normal);
        let r = (d - l.value).clamp(-self.edge, self.edge);
        Some((r, sub(g, l.gradient), l))
    }

    /// Prepares the refinement: frames and refined translations per vertex. `edge` is the finest
    /// mean edge length.
    pub fn new(input: RefineInput<'a>, edge: f64, params: &RefineParams) -> Self {
        let clock = std::time::Instant::now();
        let mut r = Refinement {
            bvh: Bvh::build(&input.source.positions, &input.source.faces),
            source_normals: area_weighted_normals(input.source),
            source_gradients: super::maps::vertex_gradients(
                input.source,
                input.source_displacement,
            ),
            mapped: Vec::new(),
            coherence: 0.25 * input.fine.sampling().min(edge),
            edge,
            counts: Default::default(),
            report: RefineReport {
                vertices: input.target.vertex_count(),
                ..RefineReport::default()
            },
            input,
        };
        let target_normals = area_weighted_normals(r.input.target);
        let (offsets, neighbours) = vertex_neighbours(r.input.target);
        let solved: Vec<Option<Translated>> = (0..r.input.target.vertex_count())
            .into_par_iter()
            .map(|v| {
                let s = r.input.points.get(v).copied().flatten()?;
                let l = r.level_at(s)?;
                let ring = &neighbours[offsets[v] as usize..offsets[v + 1] as usize];
                let mapped = Mapped {
                    point: l.point,
                    source_frame: frame(l.normal),
                    target_frame: frame(target_normals[v]),
                    image: frame(l.normal),
                };
                Some(r.translate(v, mapped, ring, edge, params))
            })
            .collect();
        let (mut before, mut after, mut count) = (0.0, 0.0, 0usize);
        for (_, b, a, _) in solved.iter().flatten() {
            before += b;
            after += a;
            count += 1;
        }
        let mut mapped: Vec<Option<Mapped>> = solved.iter().map(|s| s.map(|s| s.0)).collect();
        let mut delta: Vec<[f64; 3]> = solved.iter().map(|s| s.map_or([0.0; 3], |s| s.3)).collect();
        for _ in 0..params.smoothing {
            delta = smooth_translations(r.input.target, &mapped, &delta, (&offsets, &neighbours));
        }
        let (mut moved, mut largest) = (0.0, 0.0f64);
        for (m, d) in mapped.iter_mut().zip(&delta) {
            if let Some(m) = m {
                m.point = add(m.point, *d);
                moved += length(*d) / edge;
                largest = largest.max(length(*d) / edge);
            }
        }
        r.report.mapped_vertices = count;
        if count > 0 {
            r.report.translation_mean = moved / count as f64;
            r.report.translation_max = largest;
            r.report.mismatch_before = (before / count as f64).sqrt();
            r.report.mismatch_after = (after / count as f64).sqrt();
        }
        let images: Vec<Option<([f64; 3], [f64; 3])>> = (0..mapped.len())
            .into_par_iter()
            .map(|v| fit_image(r.input.target, &mapped, v, (&offsets, &neighbours)))
            .collect();
        for (m, image) in mapped.iter_mut().zip(images) {
            if let (Some(m), Some(image)) = (m.as_mut(), image) {
                m.image = image;
            }
        }
        r.mapped = mapped;
        r.report.seconds = clock.elapsed().as_secs_f64();
        r
    }

    /// Step 2 for vertex `v`: returns the mapping, the mean squared mismatch before and after
    /// the translation, and the translation.
    fn translate(
        &self,
        v: usize,
        m: Mapped,
        ring: &[u32],
        edge: f64,
        params: &RefineParams,
    ) -> Translated {
        let target = self.input.target;
        let x = to_f64(target.positions[v]);
        let (ut, vt) = m.target_frame;
        let (us, vs) = m.source_frame;
        let offsets: Vec<([f64; 3], f64)> = std::iter::once(v)
            .chain(ring.iter().map(|&j| j as usize))
            .map(|j| {
                let o = sub(to_f64(target.positions[j]), x);
                let off = add(scale(us, dot(o, ut)), scale(vs, dot(o, vt)));
                (off, self.input.target_displacement[j])
            })
            .collect();
        // Mean squared mismatch and the normal equations at translation δ, both sides
        // mean-subtracted over the ring (the synthesised value is a blend of patches whose
        // level differs from any one of them by an offset that no translation should chase).
        let evaluate = |delta: [f64; 3]| {
            let rows: Vec<(f64, [f64; 2])> = offsets
                .iter()
                .filter_map(|(off, dt)| {
                    let l = self.level_at(add(add(m.point, *off), delta))?;
                    Some((dt - l.value, [dot(l.gradient, us), dot(l.gradient, vs)]))
                })
                .collect();
            let n = rows.len().max(1) as f64;
            let mean_r = rows.iter().map(|r| r.0).sum::<f64>() / n;
            let mean_j = [0, 1].map(|k| rows.iter().map(|r| r.1[k]).sum::<f64>() / n);
            let (mut sum, mut a, mut rhs) = (0.0, [[0.0; 2]; 2], [0.0; 2]);
            for (r, j) in &rows {
                let (r, j) = (r - mean_r, [j[0] - mean_j[0], j[1] - mean_j[1]]);
                for p in 0..2 {
                    rhs[p] += j[p] * r;
                    for q in 0..2 {
                        a[p][q] += j[p] * j[q];
                    }
                }
                sum += r * r;
            }
            (sum / n, a, rhs)
        };
        let limit = params.max_translation * edge;
        let mut delta = [0.0; 3];
        let (start, mut a, mut rhs) = evaluate(delta);
        let mut best = start;
        for _ in 0..params.iterations {
            let damping = 1e-3 * (a[0][0] + a[1][1]) + 1e-12;
            let (a00, a11) = (a[0][0] + damping, a[1][1] + damping);
            let det = a00 * a11 - a[0][1] * a[1][0];
            if det.abs() < 1e-30 {
                break;
            }
            let step = [
                (a11 * rhs[0] - a[0][1] * rhs[1]) / det,
                (a00 * rhs[1] - a[1][0] * rhs[0]) / det,
            ];
            let mut next = add(delta, add(scale(us, step[0]), scale(vs, step[1])));
            let len = length(next);
            if len > limit {
                next = scale(next, limit / len);
            }
            let (score, a2, rhs2) = evaluate(next);
            if score >= best {
                break;
            }
            (best, delta, a, rhs) = (score, next, a2, rhs2);
        }
        (m, start, best, delta)
    }

    /// Points asked for and source reads made so far.
    pub fn counts(&self) -> [u64; 2] {
        self.counts
            .each_ref()
            .map(|c| c.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// The lowest and highest displacement `target_displacement + residual` at the centroid
    /// and edge midpoints of every finest target face: the range the textures are encoded in
    /// (widened by a tenth of the residual's own range for the extremes between the samples).
    pub fn sampled_range(&self) -> [f64; 2] {
        let weights = [
            [1.0 / 3.0; 3],
            [0.5, 0.5, 0.0],
            [0.0, 0.5, 0.5],
            [0.5, 0.0, 0.5],
        ];
        let d = self.input.target_displacement;
        let faces = &self.input.target.faces;
        let (lo, hi, rlo, rhi) = (0..faces.len())
            .into_par_iter()
            .flat_map_iter(|f| weights.iter().map(move |&b| (f, b)))
            .filter_map(|(f, b)| {
                let (r, _) = self.at(f, b)?;
                let base: f64 = (0..3).map(|k| b[k] * d[faces[f][k] as usize]).sum();
                Some((base + r, r))
            })
            .fold(
                || (f64::INFINITY, f64::NEG_INFINITY, 0.0f64, 0.0f64),
                |(lo, hi, rlo, rhi), (v, r)| (lo.min(v), hi.max(v), rlo.min(r), rhi.max(r)),
            )
            .reduce(
                || (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0),
                |a, b| (a.0.min(b.0), a.1.max(b.1), a.2.min(b.2), a.3.max(b.3)),
            );
        let margin = 0.1 * (rhi - rlo);
        [lo - margin, hi + margin]
    }

    /// The residual detail at the point with weights `b` in face `f` of the finest target level:
    /// (value, world-space gradient on the target). `None` where no corner has a source point.
    pub fn at(&self, f: usize, b: [f64; 3]) -> Option<(f64, [f64; 3])> {
        self.counts[0].fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let target = self.input.target;
        let corners = target.faces[f];
        let x = corners.map(|c| to_f64(target.positions[c as usize]));
        let p = (0..3).fold([0.0; 3], |acc, k| add(acc, scale(x[k], b[k])));
        // Each mapped corner's image of the point, through its own frames.
        let mut images: [Option<([f64; 3], Mapped)>; 3] = [None; 3];
        for k in 0..3 {
            let Some(m) = self.mapped.get(corners[k] as usize).copied().flatten() else {
                continue;
            };
            let o = sub(p, x[k]);
            let ((ut, vt), (us, vs)) = (m.target_frame, m.image);
            let q = add(m.point, add(scale(us, dot(o, ut)), scale(vs, dot(o, vt))));
            images[k] = Some((q, m));
        }
        let wsum: f64 = (0..3).filter(|&k| images[k].is_some()).map(|k| b[k]).sum();
        if wsum <= 0.0 {
            return None;
        }
        // Where the images agree (one coherent piece of source) one read at their weighted
        // mean; else one read per corner, blended by the weights (continuous across faces:
        // a corner maps the point the same way in all its faces).
        let mean = (0..3).fold([0.0; 3], |acc, k| match images[k] {
            Some((q, _)) => add(acc, scale(q, b[k] / wsum)),
            None => acc,
        });
        let spread = images
            .iter()
            .flatten()
            .map(|(q, _)| length(sub(*q, mean)))
            .fold(0.0, f64::max);
        let pull = |g: [f64; 3], m: &Mapped| {
            let ((ut, vt), (us, vs)) = (m.target_frame, m.image);
            add(scale(ut, dot(g, us)), scale(vt, dot(g, vs)))
        };
        // Blend weight of the per-corner reads: 0 up to `coherence`, 1 from three times it,
        // linear between (both computed there), so the value stays continuous.
        let w_corners = ((spread - self.coherence) / (2.0 * self.coherence)).clamp(0.0, 1.0);
        let (mut value, mut gradient) = (0.0, [0.0; 3]);
        if w_corners < 1.0 {
            let (d, g, _) = self.residual(mean)?;
            value += (1.0 - w_corners) * d;
            for k in 0..3 {
                if let Some((_, m)) = &images[k] {
                    let w = (1.0 - w_corners) * b[k] / wsum;
                    gradient = add(gradient, scale(pull(g, m), w));
                }
            }
        }
        if w_corners > 0.0 {
            for k in 0..3 {
                let Some((q, m)) = &images[k] else { continue };
                if let Some((d, g, _)) = self.residual(*q) {
                    let w = w_corners * b[k] / wsum;
                    value += w * d;
                    gradient = add(gradient, scale(pull(g, m), w));
                }
            }
        }
        Some((value, gradient))
    }
}

/// Whether target vertices `dt` apart whose source points are `ds` apart belong to one coherent
/// piece of source (the map keeps their distance within a factor 2).
fn coherent(dt: f64, ds: f64) -> bool {
    ds <= 2.0 * dt && ds >= 0.5 * dt
}

/// The linear map from vertex `v`'s target tangent plane to the source, fitted by least squares
/// to its coherent ring neighbours (`A [a b]ᵀ ≈ S_j − S_v` for the neighbour's target-frame
/// offset `(a, b)`), its columns projected onto the source's tangent plane: the images of the
/// target frame's `u` and `v`. `None` (keep the frames) with fewer than two neighbours or a
/// degenerate ring.
fn fit_image(
    target: &Surface,
    mapped: &[Option<Mapped>],
    v: usize,
    (offsets, neighbours): (&[u32], &[u32]),
) -> Option<([f64; 3], [f64; 3])> {
    let mv = mapped[v]?;
    let x = to_f64(target.positions[v]);
    let (ut, vt) = mv.target_frame;
    let (mut aa, mut sa) = ([[0.0; 2]; 2], [[0.0; 3]; 2]);
    let mut count = 0;
    for &j in &neighbours[offsets[v] as usize..offsets[v + 1] as usize] {
        let Some(mj) = mapped[j as usize] else {
            continue;
        };
        let o = sub(to_f64(target.positions[j as usize]), x);
        let d = sub(mj.point, mv.point);
        if !coherent(length(o), length(d)) {
            continue;
        }
        let a = [dot(o, ut), dot(o, vt)];
        for p in 0..2 {
            for q in 0..2 {
                aa[p][q] += a[p] * a[q];
            }
            sa[p] = add(sa[p], scale(d, a[p]));
        }
        count += 1;
    }
    let det = aa[0][0] * aa[1][1] - aa[0][1] * aa[1][0];
    if count < 2 || det.abs() <= 1e-12 * (aa[0][0] * aa[1][1]).max(f64::MIN_POSITIVE) {
        return None;
    }
    // A = S Aᵀ (A Aᵀ)⁻¹, column by column.
    let inv = [
        [aa[1][1] / det, -aa[0][1] / det],
        [-aa[1][0] / det, aa[0][0] / det],
    ];
    let n = cross(mv.source_frame.0, mv.source_frame.1);
    let column = |c: usize| tangential(add(scale(sa[0], inv[0][c]), scale(sa[1], inv[1][c])), n);
    Some((column(0), column(1)))
}

/// One averaging step of the translations: each mapped vertex takes the mean of its own and
/// its mapped ring neighbours' whose source points lie as far apart as the vertices (within a
/// factor 2: the same coherent piece of source; across a patch seam they do not share).
fn smooth_translations(
    target: &Surface,
    mapped: &[Option<Mapped>],
    delta: &[[f64; 3]],
    (offsets, neighbours): (&[u32], &[u32]),
) -> Vec<[f64; 3]> {
    (0..delta.len())
        .into_par_iter()
        .map(|v| {
            let Some(mv) = mapped[v] else {
                return delta[v];
            };
            let x = to_f64(target.positions[v]);
            let (mut sum, mut n) = (delta[v], 1.0);
            for &j in &neighbours[offsets[v] as usize..offsets[v + 1] as usize] {
                let j = j as usize;
                let Some(mj) = mapped[j] else { continue };
                let dt = length(sub(to_f64(target.positions[j]), x));
                let ds = length(sub(mj.point, mv.point));
                if coherent(dt, ds) {
                    sum = add(sum, delta[j]);
                    n += 1.0;
                }
            }
            scale(sum, 1.0 / n)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_and_follows_x() {
        let (u, v) = frame(normalize([0.0, 0.3, 1.0]));
        assert!((length(u) - 1.0).abs() < 1e-12 && dot(u, v).abs() < 1e-12);
        assert!(u[0] > 0.99, "{u:?}");
        let (u, _) = frame([1.0, 0.0, 0.0]);
        assert!(u[1] > 0.99, "{u:?}");
    }
}
