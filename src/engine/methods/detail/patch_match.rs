//! SYNTHESIZE-LEVEL (Berkiten et al. 2017, §3.3.1, Algorithm 2): source patches around evenly
//! spread source vertices, then, per target vertex in sweep order, the two-step matching and
//! the blending of the chosen patch.
//!
//! **Patches.** A patch is the discrete exponential map around its centre
//! ([`crate::engine::geometry::expmap`], the charts [`super::patches`] samples), in the same
//! frames (`u` = `(1, 0, 0)` projected, `v = n × u`), rasterised into a square grid with one
//! step per level (`step`, world units): cell `k` sits at `(k − (side − 1)/2)·step`. Each cell
//! records the face it falls in and its barycentric weights; its *vertex* is the corner with the
//! largest weight. A target patch has side `n`; a source patch side `n + 2s` (`s` the shift
//! range) and stores per cell the barycentric displacement and the vertex; cells outside every
//! mapped face (past a border) are invalid and never compared or copied.
//!
//! **Matching.** Step 1 (features): for every source patch and every integer shift
//! `(dx, dy) ∈ [−s, s]²` (the translational refinement), the mean squared transformed-feature
//! distance over an `m × m` sub-grid of the target patch (`m = min(n, feature_grid)`, evenly
//! spaced cells; features vary slowly, so a sub-grid keeps the cost at `O(S · (2s+1)² · m² · r)`
//! per patch) against the source cells under it; a shift covering fewer than half of the
//! target's valid sub-grid cells is rejected. The `K` best (distance, ties by sample index)
//! are the candidates, parallel over samples. With a reach above `s` (the candidates' wider
//! refinement, [`super::synthesis`], not in the paper), each candidate is then re-aligned by the
//! same feature distance over every shift within the reach (source patches carry that margin:
//! side `n + 2·reach`), and the candidates are ranked by the refined distance. Step 2 (detail):
//! for each candidate and each shift (within `s` of the refined alignment when there is one),
//! the mean squared difference between the target's shown displacement and the source patch over
//! all valid cells, weighted by the target's matching confidence
//! ([`super::blend::Blend::context_weight`]: the current pass's `w_disp`, capped at 1, and the
//! base's confidence); the lowest wins. Where the target has no context yet (all weights 0) the
//! feature-best candidate is taken.
//!
//! **Blending.** Every target vertex of the chart inside the square `|x|, |y| ≤ n/2` (grid
//! steps) gets the source displacement bilinearly interpolated at its chart position (shifted),
//! blended with `w_loc = f(‖x‖ / (n/√2))` (eqs. 5-7, [`super::blend`]).

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use super::blend::{location_weight, Blend};
use super::patches::rasterise_triangle;
use super::sweep::feature_dist2;
use crate::engine::control::{Cancelled, StageProgress};
use crate::engine::geometry::expmap::{
    local_frames, mean_edge_length, ChartBuilder, Connection, ExpMapParams, FrameParams, RadiusUnit,
};
use crate::engine::mesh::csr::vertex_faces;
use crate::engine::mesh::Surface;

const NONE: u32 = u32::MAX;

/// What the charts of one shape share.
pub(super) struct Charts<'a> {
    surface: &'a Surface,
    connection: Connection,
    vf_offsets: Vec<u32>,
    vf_faces: Vec<u32>,
    mean_edge: f32,
}

impl<'a> Charts<'a> {
    pub(super) fn new(surface: &'a Surface) -> Self {
        let frames = local_frames(
            surface,
            &FrameParams {
                up: Some([1.0, 0.0, 0.0]),
                min_up_projection: 0.1,
            },
        );
        let (vf_offsets, vf_faces) = vertex_faces(surface);
        Charts {
            surface,
            connection: Connection::new(surface, &frames),
            vf_offsets,
            vf_faces,
            mean_edge: mean_edge_length(surface),
        }
    }

    pub(super) fn scratch(&self) -> Scratch {
        Scratch {
            builder: ChartBuilder::new(self.surface.vertex_count()),
            slot: vec![NONE; self.surface.vertex_count()],
            vertex: Vec::new(),
            coords: Vec::new(),
            face: Vec::new(),
            bary: Vec::new(),
        }
    }

    /// Rasterises the chart of `centre` into a `side × side` grid of step `step` (see the module
    /// doc); the chart's vertices and coordinates stay in the scratch.
    fn raster(&self, centre: usize, side: usize, step: f64, s: &mut Scratch) {
        let half = (side as f64 - 1.0) / 2.0;
        let radius = ((half + 1.0) * step * std::f64::consts::SQRT_2) as f32 + 2.0 * self.mean_edge;
        let params = ExpMapParams {
            radius,
            radius_unit: RadiusUnit::World,
            ..ExpMapParams::default()
        };
        let chart = s.builder.build(&self.connection, centre, radius, &params);
        s.vertex.clear();
        s.vertex.extend_from_slice(chart.vertex);
        s.coords.clear();
        s.coords.extend_from_slice(chart.coords);
        s.face.clear();
        s.face.resize(side * side, NONE);
        s.bary.clear();
        s.bary.resize(side * side, [0.0; 3]);
        for (i, &v) in s.vertex.iter().enumerate() {
            s.slot[v as usize] = i as u32;
        }
        let to_grid = |c: [f32; 2]| [c[0] as f64 / step + half, c[1] as f64 / step + half];
        for (i, &v) in s.vertex.iter().enumerate() {
            let range =
                self.vf_offsets[v as usize] as usize..self.vf_offsets[v as usize + 1] as usize;
            for &f in &self.vf_faces[range] {
                let corners = self.surface.faces[f as usize];
                let slots = corners.map(|c| s.slot[c as usize]);
                // Each face once: from its corner with the lowest chart slot.
                if slots.contains(&NONE) || slots.iter().min() != Some(&(i as u32)) {
                    continue;
                }
                let pts = slots.map(|k| to_grid(s.coords[k as usize]));
                // The first face to reach a cell keeps it.
                rasterise_triangle(pts, side, |k, [wa, wb, wc]| {
                    if s.face[k] == NONE {
                        s.face[k] = f;
                        s.bary[k] = [wa as f32, wb as f32, wc as f32];
                    }
                });
            }
        }
        for &v in &s.vertex {
            s.slot[v as usize] = NONE;
        }
    }
}

/// Scratch of one worker.
pub(super) struct Scratch {
    builder: ChartBuilder,
    slot: Vec<u32>,
    vertex: Vec<u32>,
    coords: Vec<[f32; 2]>,
    face: Vec<u32>,
    bary: Vec<[f32; 3]>,
}

/// The corner with the largest weight of each cell (`NONE` where uncovered).
fn cell_vertices(surface: &Surface, s: &Scratch, out: &mut Vec<u32>) {
    out.clear();
    out.extend(s.face.iter().zip(&s.bary).map(|(&f, w)| {
        if f == NONE {
            return NONE;
        }
        let k = (0..3).fold(0, |b, k| if w[k] > w[b] { k } else { b });
        surface.faces[f as usize][k]
    }));
}

/// One source patch: per cell the vertex, the (normalised) displacement and the surface point,
/// NaN where invalid.
pub(super) struct SourcePatch {
    vertex: Vec<u32>,
    disp: Vec<f32>,
    point: Vec<[f32; 3]>,
}

/// The strongest contribution a target vertex received in a pass: the patch and the (shifted)
/// grid position in it that its value was read at, and its `w_loc`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Record {
    weight: f32,
    patch: u32,
    position: [f32; 2],
}

impl Default for Record {
    fn default() -> Self {
        Record {
            weight: 0.0,
            patch: NONE,
            position: [0.0; 2],
        }
    }
}

impl Record {
    /// Whether the vertex received a contribution.
    pub(super) fn is_set(&self) -> bool {
        self.patch != NONE
    }
}

/// The source surface point a [`Record`] read its value at: the bilinear interpolation of the
/// patch's cell points (valid cells only); `None` for an unset record or no valid cell.
pub(super) fn recorded_point(patches: &[SourcePatch], r: &Record, side: usize) -> Option<[f64; 3]> {
    let p = patches.get(r.patch as usize)?;
    let (x, y) = (r.position[0] as f64, r.position[1] as f64);
    let (x0, y0) = (x.floor().max(0.0) as usize, y.floor().max(0.0) as usize);
    let (x1, y1) = ((x0 + 1).min(side - 1), (y0 + 1).min(side - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let mut sum = [0.0; 3];
    let mut wsum = 0.0;
    for (cx, cy, w) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x1, y0, fx * (1.0 - fy)),
        (x0, y1, (1.0 - fx) * fy),
        (x1, y1, fx * fy),
    ] {
        let q = p.point.get(cy * side + cx)?;
        if w > 0.0 && !q[0].is_nan() {
            for k in 0..3 {
                sum[k] += w * q[k] as f64;
            }
            wsum += w;
        }
    }
    (wsum > 1e-9).then(|| sum.map(|s| s / wsum))
}

/// Samples the source patches (side `side`) around `samples`, parallel.
pub(super) fn source_patches(
    charts: &Charts<'_>,
    displacement: &[f64],
    samples: &[usize],
    side: usize,
    step: f64,
    stage: &StageProgress<'_>,
) -> Result<Vec<SourcePatch>, Cancelled> {
    samples
        .par_iter()
        .map_init(
            || (charts.scratch(), Vec::new()),
            |(scratch, cells), &c| {
                charts.raster(c, side, step, scratch);
                cell_vertices(charts.surface, scratch, cells);
                let disp = (scratch.face.iter().zip(&scratch.bary))
                    .map(|(&f, w)| {
                        if f == NONE {
                            return f32::NAN;
                        }
                        let corners = charts.surface.faces[f as usize];
                        (0..3)
                            .map(|k| w[k] as f64 * displacement[corners[k] as usize])
                            .sum::<f64>() as f32
                    })
                    .collect();
                let point = (scratch.face.iter().zip(&scratch.bary))
                    .map(|(&f, w)| match f {
                        NONE => [f32::NAN; 3],
                        _ => charts.surface.face_point(f as usize, *w),
                    })
                    .collect();
                stage.tick(1)?;
                Ok(SourcePatch {
                    vertex: cells.clone(),
                    disp,
                    point,
                })
            },
        )
        .collect()
}

/// `(Σ term, Σ weight)` over the items whose `term` is `Some((term, weight))`, terms
/// non-negative; `None` once the running term sum exceeds `limit` (checked every `chunk`
/// items, with a relative margin of 1e-9 so that rounding never abandons a tie). The matching
/// steps' exact pruning: a score `Σ term / Σ weight` is at least the partial sum over the
/// largest possible weight, which the callers fold into `limit`.
fn pruned_sum<T>(
    items: &[T],
    chunk: usize,
    limit: f64,
    mut term: impl FnMut(&T) -> Option<(f64, f64)>,
) -> Option<(f64, f64)> {
    let limit = limit * (1.0 + 1e-9);
    let (mut sum, mut weight) = (0.0, 0.0);
    for part in items.chunks(chunk) {
        for (t, w) in part.iter().filter_map(&mut term) {
            sum += t;
            weight += w;
        }
        if sum > limit {
            return None;
        }
    }
    Some((sum, weight))
}

/// How a pass chooses its patches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Choice {
    /// The two-step matching (the paper's).
    Matched,
    /// A uniformly random source patch, no shift (a baseline for tests), seeded.
    Random(u64),
}

/// Everything a pass of one level reads.
pub(super) struct Level<'a> {
    pub target: &'a Charts<'a>,
    pub target_features: &'a [f64],
    pub source_features: &'a [f64],
    pub patches: &'a [SourcePatch],
    pub r: usize,
    pub n: usize,
    pub step: f64,
    pub shift: usize,
    /// At least `shift` ([`super::synthesis`]'s `candidate_reach`).
    pub reach: usize,
    pub candidates: usize,
    pub feature_grid: usize,
    pub choice: Choice,
}

/// What a pass did.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct PassStats {
    /// Patches blended.
    pub patches: usize,
    /// Vertices skipped (`w_disp > 0.5`).
    pub skipped: usize,
    /// Patches where step 2 chose another candidate than step 1's best.
    pub step2_changed: usize,
    /// Patches chosen without any synthesised context (step 1's best).
    pub without_context: usize,
}

impl Level<'_> {
    /// Side of a source patch: the target's `n` plus the reach on both sides.
    pub(super) fn side(&self) -> usize {
        self.n + 2 * self.reach
    }

    /// The shifts within `range` of `centre` that stay inside the source patch.
    fn shifts_around(
        &self,
        centre: (isize, isize),
        range: usize,
    ) -> impl Iterator<Item = (isize, isize)> + Clone {
        let (r, m) = (range as isize, self.reach as isize);
        let (x0, x1) = ((centre.0 - r).max(-m), (centre.0 + r).min(m));
        let (y0, y1) = ((centre.1 - r).max(-m), (centre.1 + r).min(m));
        (y0..=y1).flat_map(move |dy| (x0..=x1).map(move |dx| (dx, dy)))
    }

    /// Source cell under target cell `(ix, iy)` shifted by `(dx, dy)`.
    fn source_cell(&self, ix: usize, iy: usize, (dx, dy): (isize, isize)) -> usize {
        let s = self.reach as isize;
        let (x, y) = (ix as isize + s + dx, iy as isize + s + dy);
        y as usize * self.side() + x as usize
    }

    /// Step 1 for one source patch: the best (distance, shift) over the shifts, or infinity
    /// when every shift's distance is above `bound`. Exact pruning: a distance `sum / count` is
    /// at least the partial sum over `sub.len()` (`count` never exceeds it), so a shift is
    /// abandoned once that exceeds `bound` or the patch's best so far (only strictly worse
    /// shifts are abandoned, so ties resolve as without pruning).
    fn feature_match(
        &self,
        sub: &[(usize, usize, u32)],
        p: &SourcePatch,
        bound: f64,
        range: usize,
    ) -> (f64, (isize, isize)) {
        let r = self.r;
        let cells = sub.len() as f64;
        let mut best = (f64::INFINITY, (0, 0));
        for sh in self.shifts_around((0, 0), range) {
            let limit = best.0.min(bound) * cells;
            let summed = pruned_sum(sub, 8, limit, |&(ix, iy, tv)| {
                let sv = p.vertex[self.source_cell(ix, iy, sh)];
                (sv != NONE).then(|| {
                    let t = &self.target_features[tv as usize * r..(tv as usize + 1) * r];
                    let f = &self.source_features[sv as usize * r..(sv as usize + 1) * r];
                    (feature_dist2(t, f), 1.0)
                })
            });
            if let Some((sum, count)) = summed {
                if count > 0.0 && 2.0 * count >= cells && sum / count < best.0 {
                    best = (sum / count, sh);
                }
            }
        }
        best
    }

    /// Step 1 over all source patches: (distance, patch, shift) of every patch within reach of
    /// the `k` best. A strided quarter of the patches is matched in full first; its `k`-th best
    /// distance bounds the `k`-th best of all (a subset's `k`-th best is never better), so the
    /// other patches are matched with that bound ([`Self::feature_match`]) and only patches
    /// that cannot be among the `k` best are dropped. The `k` best are those without pruning.
    fn feature_candidates(
        &self,
        sub: &[(usize, usize, u32)],
        k: usize,
    ) -> Vec<(f64, usize, (isize, isize))> {
        const STRIDE: usize = 4;
        let matched = |bound: f64, first: bool| {
            self.patches
                .par_iter()
                .enumerate()
                .filter(|(i, _)| (i % STRIDE == 0) == first)
                .map(|(i, p)| {
                    let (d, sh) = self.feature_match(sub, p, bound, self.shift);
                    (d, i, sh)
                })
                .filter(|c| c.0.is_finite())
                .collect::<Vec<_>>()
        };
        let mut ranked = matched(f64::INFINITY, true);
        let bound = if ranked.len() >= k && k > 0 {
            let mut d: Vec<f64> = ranked.iter().map(|c| c.0).collect();
            *d.select_nth_unstable_by(k - 1, f64::total_cmp).1
        } else {
            f64::INFINITY
        };
        ranked.extend(matched(bound, false));
        ranked
    }

    /// Step 2 for one candidate: the best (score, shift) against the weighted context, or
    /// infinity when every shift scores above `bound` (the best score of any candidate so far,
    /// shared). Exact pruning: a shift's score `sum / wsum` is at least its partial sum over
    /// `weight_total` (all the context's weight), so a shift is abandoned once that exceeds the
    /// bound, which no longer changes which candidate and shift win (ties included: only
    /// strictly worse shifts are abandoned).
    fn detail_match(
        &self,
        context: &[(usize, usize, f64, f64)],
        weight_total: f64,
        p: &SourcePatch,
        centre: (isize, isize),
        bound: &AtomicU64,
    ) -> (f64, (isize, isize)) {
        let mut best = (f64::INFINITY, centre);
        for sh in self.shifts_around(centre, self.shift) {
            let limit = best.0.min(f64::from_bits(bound.load(Ordering::Relaxed))) * weight_total;
            let summed = pruned_sum(context, 32, limit, |&(ix, iy, value, w)| {
                let d = p.disp[self.source_cell(ix, iy, sh)];
                (!d.is_nan()).then(|| (w * (value - d as f64).powi(2), w))
            });
            if let Some((sum, wsum)) = summed {
                if wsum > 0.0 && sum / wsum < best.0 {
                    best = (sum / wsum, sh);
                    // Non-negative floats order as their bit patterns.
                    bound.fetch_min(best.0.to_bits(), Ordering::Relaxed);
                }
            }
        }
        best
    }

    /// The two-step choice for the target patch whose cell vertices are `cells`; `None` when no
    /// source patch covers enough of it.
    fn choose(
        &self,
        cells: &[u32],
        blend: &Blend,
        stats: &mut PassStats,
    ) -> Option<(usize, (isize, isize))> {
        let n = self.n;
        let m = self.feature_grid.clamp(1, n);
        let pick = |j: usize| {
            if m == 1 {
                n / 2
            } else {
                (j * (n - 1) + (m - 1) / 2) / (m - 1)
            }
        };
        let sub: Vec<(usize, usize, u32)> = (0..m)
            .flat_map(|b| (0..m).map(move |a| (pick(a), pick(b))))
            .filter_map(|(ix, iy)| {
                let tv = cells[iy * n + ix];
                (tv != NONE).then_some((ix, iy, tv))
            })
            .collect();
        let mut ranked = self.feature_candidates(&sub, self.candidates.max(1));
        let k = self.candidates.max(1).min(ranked.len());
        if k == 0 {
            return None;
        }
        if k < ranked.len() {
            ranked.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            ranked.truncate(k);
        }
        if self.reach > self.shift {
            // The candidates' wider refinement (see the module doc): a full search of the
            // shifts within the reach, which contains step 1's own shifts.
            ranked = ranked
                .par_iter()
                .map(|&(d1, i, sh)| {
                    let (d, refined) = self.feature_match(&sub, &self.patches[i], d1, self.reach);
                    if d <= d1 {
                        (d, i, refined)
                    } else {
                        (d1, i, sh)
                    }
                })
                .collect();
        }
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let context: Vec<(usize, usize, f64, f64)> = (0..n * n)
            .filter_map(|c| {
                let tv = cells[c] as usize;
                let w = if cells[c] == NONE {
                    0.0
                } else {
                    blend.context_weight(tv)
                };
                (w > 0.0).then(|| (c % n, c / n, blend.current(tv), w))
            })
            .collect();
        if context.is_empty() {
            stats.without_context += 1;
            return Some((ranked[0].1, ranked[0].2));
        }
        let weight_total: f64 = context.iter().map(|c| c.3).sum();
        let bound = AtomicU64::new(f64::INFINITY.to_bits());
        let scored: Vec<(f64, (isize, isize))> = ranked
            .par_iter()
            .map(|c| {
                let p = &self.patches[c.1];
                // Around the refined alignment; without the refinement, the shift range itself.
                let centre = if self.reach > self.shift { c.2 } else { (0, 0) };
                self.detail_match(&context, weight_total, p, centre, &bound)
            })
            .collect();
        let best = (0..k).fold(0, |b, i| if scored[i].0 < scored[b].0 { i } else { b });
        if best != 0 {
            stats.step2_changed += 1;
        }
        Some((ranked[best].1, scored[best].1))
    }

    /// Blends source patch `p` shifted by `sh` into the chart in `s` (see the module doc).
    fn blend_patch(
        &self,
        s: &Scratch,
        (index, sh): (usize, (isize, isize)),
        blend: &mut Blend,
        mut record: Option<&mut [Record]>,
    ) {
        let p = &self.patches[index];
        let g = self.side();
        let centre = (g as f64 - 1.0) / 2.0;
        let half = self.n as f64 / 2.0;
        for (&v, c) in s.vertex.iter().zip(&s.coords) {
            let q = [c[0] as f64 / self.step, c[1] as f64 / self.step];
            if q[0].abs() > half || q[1].abs() > half {
                continue;
            }
            let x = (q[0] + centre + sh.0 as f64).clamp(0.0, g as f64 - 1.0);
            let y = (q[1] + centre + sh.1 as f64).clamp(0.0, g as f64 - 1.0);
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(g - 1), (y0 + 1).min(g - 1));
            let (fx, fy) = (x - x0 as f64, y - y0 as f64);
            let (mut sum, mut wsum) = (0.0, 0.0);
            for (cx, cy, w) in [
                (x0, y0, (1.0 - fx) * (1.0 - fy)),
                (x1, y0, fx * (1.0 - fy)),
                (x0, y1, (1.0 - fx) * fy),
                (x1, y1, fx * fy),
            ] {
                let d = p.disp[cy * g + cx];
                if w > 0.0 && !d.is_nan() {
                    sum += w * d as f64;
                    wsum += w;
                }
            }
            if wsum > 1e-9 {
                let dist = (q[0] * q[0] + q[1] * q[1]).sqrt();
                let w = location_weight(dist, self.n);
                blend.add(v as usize, sum / wsum, w);
                if let Some(r) = record.as_deref_mut().and_then(|r| r.get_mut(v as usize)) {
                    if w as f32 > r.weight {
                        *r = Record {
                            weight: w as f32,
                            patch: index as u32,
                            position: [x as f32, y as f32],
                        };
                    }
                }
            }
        }
    }

    /// One SYNTHESIZE-LEVEL pass over `order`; `record` (one per target vertex), when given,
    /// receives each vertex's strongest contribution.
    pub(super) fn pass(
        &self,
        order: &[usize],
        blend: &mut Blend,
        rng: &mut u64,
        stage: &StageProgress<'_>,
        mut record: Option<&mut [Record]>,
    ) -> Result<PassStats, Cancelled> {
        let mut stats = PassStats::default();
        let mut scratch = self.target.scratch();
        let mut cells = Vec::new();
        for (i, &c) in order.iter().enumerate() {
            if i % 32 == 31 {
                stage.tick(32)?;
            }
            if blend.skip(c) {
                stats.skipped += 1;
                continue;
            }
            self.target.raster(c, self.n, self.step, &mut scratch);
            cell_vertices(self.target.surface, &scratch, &mut cells);
            let chosen = match self.choice {
                Choice::Matched => self.choose(&cells, blend, &mut stats),
                Choice::Random(_) if self.patches.is_empty() => None,
                Choice::Random(_) => {
                    Some(((splitmix(rng) % self.patches.len() as u64) as usize, (0, 0)))
                }
            };
            if let Some(choice) = chosen {
                self.blend_patch(&scratch, choice, blend, record.as_deref_mut());
                stats.patches += 1;
            }
        }
        stage.tick((order.len() % 32) as u64)?;
        Ok(stats)
    }
}

/// SplitMix64 step.
pub(super) fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
