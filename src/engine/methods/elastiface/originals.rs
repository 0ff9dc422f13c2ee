//! Registration of the originals (§3.3, last paragraph), with backward fitting rounds.
//!
//! **The paper's solve.** The original source is fitted to the original target from the base
//! stage's closest points carried to the original target as (triangle, barycentric): bending
//! relative to the original source with its areas, `μ2 = 300`, `μ1 = μ3 = 0.1`.
//!
//! **Deviation: closest-point rounds with backward pairs** (after the non-rigid ICP variants of
//! Amberg et al. 2007 and Li et al. 2008, which the paper does not use). The joint fairing
//! collapses deep concavities (a scan's nostril tunnels, about 12 % of the diagonal deep), so
//! the carried points land at their openings and the paper's stage, with its fitting weight of
//! 300, pins the template there: the target → fitted Hausdorff distance of a scan stays at 6.8 %
//! (README "elastiface"). After the paper's solve, `levels` stiffness levels with bending
//! `μ1` falling in the 1-3-10 series to the paper's 0.1 (default 4 levels: 3, 1, 0.3, 0.1; the
//! sweep's 10, 1, 0.1 pulled an open disc's boundary off the target) run `per_level` (default 2)
//! solves each; every solve recomputes the forward closest points on the original target and adds the
//! **backward** term `μ_b/m Σ_j ‖Σ_k b_jk x_k − t_j‖²`: each of the `m` target vertices `t_j`
//! pulls its closest point on the current fitted source (a barycentric row `b_j` of one source
//! triangle) toward itself. A backward pair is dropped when that closest point lies on the
//! source's boundary (where the target covers more than the template, e.g. shoulders), when it
//! is farther than `max_distance` (default 0.1 of the target's diagonal), or when the source
//! triangle's normal and the target vertex normal make a cosine below `min_cos` (default 0.5:
//! the other side of a thin part). `μ_b` defaults to 300, the forward fitting weight, so both
//! directions count alike; `μ2` and `μ3` keep the paper's 300 and 0.1 in these rounds.
//! The matrix changes with the backward rows, so each round factorises numerically (the pattern
//! already holds every source triangle, so the symbolic analysis is shared). The defaults come
//! from the sweep in README "elastiface" (backward weight 100 / 300 / 1000, cosine 0 / 0.5,
//! distance 0.03 / 0.1, schedules 0.1 / 1, 0.1 / 10, 1, 0.1 / 3, 1, 0.3, 0.1, one or two or three
//! solves per level, a flip guard); `backward_weight = 0` with `stiffness_levels = 1` and
//! `original_iterations = 1` is the paper's stage.
//!
//! **Boundary onto boundary** ([`super::boundary_fit`], `boundary_to_boundary`, default on):
//! in the rounds, the vertices of a paired source boundary loop fit onto their closest point on
//! the paired target loop instead of the target surface.
//!
//! **Free vertices** ([`super::free`], `free_visibility` > 0): in the rounds a free vertex has
//! no forward fitting term (its weight on the diagonal and right-hand side scaled by 0) and no
//! backward pair lands on a triangle whose corners are all free, so it follows its fitted
//! neighbours through the bending term.
//!
//! Speed (the same results): the fitted source's hierarchy for the backward searches is built
//! at the first round and refitted to the moved vertices at the later ones
//! ([`crate::engine::spatial::refit`]); forward and backward searches are bounded by the distance
//! to the face found in the previous round (the first forward round by the carried faces).

use std::collections::HashSet;

use rayon::prelude::*;

use crate::engine::control::Control;
use crate::engine::linalg::NumericCholesky;
use crate::engine::math::{cross, dot, length, sub};
use crate::engine::spatial::{Bvh, ClosestHit};

use super::boundary_fit::BoundaryFit;
use super::refs::RefRow;
use super::register::{near_bound, rms, Closest, Extra, FitTarget, Mu, Registration, StageReport};
use super::system::voronoi_areas;
use super::MethodError;

/// The rounds after the paper's solve (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct Rounds<'a> {
    /// Stiffness levels (bending [`STIFFNESS`]`[levels − 1 − k]`, at most its length).
    pub levels: usize,
    /// Solves per level.
    pub per_level: usize,
    /// Backward weight `μ_b` (0: forward closest points only).
    pub backward_weight: f64,
    /// Largest backward distance, in solve units.
    pub max_distance: f64,
    /// Smallest cosine between the source triangle's and the target vertex's normals.
    pub min_cos: f64,
    /// Per source vertex: free ([`super::free`]; empty: none).
    pub free: &'a [bool],
    /// Paired boundary loops whose source vertices fit onto their target loop
    /// ([`super::boundary_fit`]; `None`: the surface's closest point for every vertex).
    pub boundary: Option<&'a BoundaryFit>,
}

/// The paper's solve of the originals, prepared ([`Registration::paper_start`]).
pub struct PaperStart {
    areas: Vec<f64>,
    target_refs: Vec<[f64; 3]>,
    factor: NumericCholesky,
    fixed: Vec<Vec<f64>>,
}

/// Bending weights of the rounds, read from the end: the last level is the paper's 0.1.
pub const STIFFNESS: [f64; 6] = [0.1, 0.3, 1.0, 3.0, 10.0, 30.0];

/// The paper's weights of the originals stage.
const PAPER: Mu = Mu {
    bend: 0.1,
    fit: 300.0,
    refs: 0.1,
};

fn unit_normal(x: &[[f64; 3]], f: [u32; 3]) -> [f64; 3] {
    let n = cross(
        sub(x[f[1] as usize], x[f[0] as usize]),
        sub(x[f[2] as usize], x[f[0] as usize]),
    );
    let l = length(n);
    if l > 0.0 {
        n.map(|c| c / l)
    } else {
        n
    }
}

/// Area-weighted unit vertex normals.
fn vertex_normals(x: &[[f64; 3]], faces: &[[u32; 3]]) -> Vec<[f64; 3]> {
    let mut n = vec![[0.0; 3]; x.len()];
    for f in faces {
        let fn_ = cross(
            sub(x[f[1] as usize], x[f[0] as usize]),
            sub(x[f[2] as usize], x[f[0] as usize]),
        );
        for &v in f {
            (0..3).for_each(|d| n[v as usize][d] += fn_[d]);
        }
    }
    for v in &mut n {
        let l = length(*v);
        if l > 0.0 {
            *v = v.map(|c| c / l);
        }
    }
    n
}

/// Boundary edges (as sorted pairs) and boundary vertices of a face list.
fn boundary(faces: &[[u32; 3]]) -> (HashSet<(u32, u32)>, HashSet<u32>) {
    let mut count = std::collections::HashMap::new();
    for f in faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_insert(0u32) += 1;
        }
    }
    let edges: HashSet<(u32, u32)> = count
        .into_iter()
        .filter(|&(_, c)| c == 1)
        .map(|(e, _)| e)
        .collect();
    let vertices = edges.iter().flat_map(|&(a, b)| [a, b]).collect();
    (edges, vertices)
}

/// The backward pairs: target vertices pulling their closest points on the fitted source.
struct Backward<'a> {
    target: &'a FitTarget<'a>,
    normals: Vec<[f64; 3]>,
    edges: HashSet<(u32, u32)>,
    vertices: HashSet<u32>,
    rounds: Rounds<'a>,
    /// The fitted source's hierarchy: built at the first round, refitted at the later ones.
    bvh: Option<Bvh>,
    /// Per target vertex, the source face of its last closest point (`u32::MAX`: none yet).
    near: Vec<u32>,
}

/// The rows of one round and the source face of each.
type Rows = (Vec<(RefRow, f64, [f64; 3])>, Vec<u32>);

impl Backward<'_> {
    /// Every kept target vertex's row (see the module docs for the rejections). Each search is
    /// bounded by [`near_bound`] of the vertex's face of the previous round as well as by
    /// `max_distance` (and retried with `max_distance` alone when that finds nothing), so the
    /// hits are those of the search bounded by `max_distance` only.
    fn rows(&mut self, x: &[[f64; 3]], faces: &[[u32; 3]]) -> Rows {
        if self.rounds.backward_weight <= 0.0 {
            return (Vec::new(), Vec::new());
        }
        let x32: Vec<[f32; 3]> = x.iter().map(|p| p.map(|c| c as f32)).collect();
        let bvh = match self.bvh.take() {
            Some(mut b) => {
                b.refit(&x32, faces);
                b
            }
            None => Bvh::build(&x32, faces),
        };
        let limit = self.rounds.max_distance as f32;
        if self.near.len() != self.target.x.len() {
            self.near = vec![u32::MAX; self.target.x.len()];
        }
        let hits: Vec<Option<ClosestHit>> = self
            .target
            .x
            .par_iter()
            .zip(&self.near)
            .map(|(t, &near)| {
                let q = t.map(|c| c as f32);
                let bound = faces.get(near as usize).map_or(limit, |f| {
                    limit.min(near_bound(q, f.map(|v| x32[v as usize])))
                });
                bvh.closest_point(q, bound).or_else(|| {
                    (bound < limit)
                        .then(|| bvh.closest_point(q, limit))
                        .flatten()
                })
            })
            .collect();
        self.bvh = Some(bvh);
        self.near = hits
            .iter()
            .map(|h| h.map_or(u32::MAX, |h| h.face))
            .collect();
        let w = self.rounds.backward_weight / self.target.x.len().max(1) as f64;
        let mut rows = Vec::new();
        let mut row_faces = Vec::new();
        for ((t, nt), h) in self.target.x.iter().zip(&self.normals).zip(hits) {
            let Some(h) = h else { continue };
            let f = faces[h.face as usize];
            let on: Vec<u32> = (0..3).filter(|&k| h.bary[k] > 1e-6).map(|k| f[k]).collect();
            let on_boundary = match on.as_slice() {
                [a, b] => self.edges.contains(&((*a).min(*b), (*a).max(*b))),
                [a] => self.vertices.contains(a),
                _ => false,
            };
            let free = self.rounds.free;
            let free = !free.is_empty() && f.iter().all(|&v| free[v as usize]);
            if free || on_boundary || dot(unit_normal(x, f), *nt) < self.rounds.min_cos {
                continue;
            }
            rows.push((RefRow::face(f, h.bary), w, *t));
            row_faces.push(h.face);
        }
        (rows, row_faces)
    }
}

impl Registration<'_> {
    /// The originals: the paper's solve from `carried` (the base stage's closest points as
    /// (face, barycentric) on the original target), then the closest-point `rounds`. `rest` is
    /// the original source.
    ///
    /// # Errors
    /// [`MethodError::Internal`], [`MethodError::Cancelled`].
    pub fn originals(
        &self,
        rest: &[[f64; 3]],
        target: &FitTarget<'_>,
        carried: &Closest,
        rounds: Rounds<'_>,
        control: &Control,
    ) -> Result<(Vec<[f64; 3]>, StageReport), MethodError> {
        let start = self.paper_start(rest, target.x)?;
        self.originals_from(start, rest, target, carried, rounds, control)
    }

    /// What the paper's solve of the originals needs besides the carried points: the rest
    /// areas, the target's reference points, the factor and the fixed right-hand side. They
    /// depend on neither stage before, so they can be computed while those run.
    ///
    /// # Errors
    /// [`MethodError::Internal`] if the factorisation fails.
    pub fn paper_start(
        &self,
        rest: &[[f64; 3]],
        target_x: &[[f64; 3]],
    ) -> Result<PaperStart, MethodError> {
        let areas = voronoi_areas(rest, self.faces)?;
        let target_refs: Vec<[f64; 3]> =
            self.pairs.iter().map(|p| p.target.eval(target_x)).collect();
        let none = Extra::default();
        let factor = self.factor_extra(&areas, PAPER, &none)?;
        let fixed = self.fixed_rhs_extra(rest, &areas, &target_refs, PAPER, &none);
        Ok(PaperStart {
            areas,
            target_refs,
            factor,
            fixed,
        })
    }

    /// [`Self::originals`] from a [`Self::paper_start`] of the same `rest` and target.
    ///
    /// # Errors
    /// [`MethodError::Internal`], [`MethodError::Cancelled`].
    pub fn originals_from(
        &self,
        start: PaperStart,
        rest: &[[f64; 3]],
        target: &FitTarget<'_>,
        carried: &Closest,
        rounds: Rounds<'_>,
        control: &Control,
    ) -> Result<(Vec<[f64; 3]>, StageReport), MethodError> {
        let PaperStart {
            areas,
            target_refs,
            factor,
            fixed,
        } = start;
        let (edges, vertices) = boundary(self.faces);
        let mut back = Backward {
            target,
            normals: vertex_normals(target.x, target.faces),
            edges,
            vertices,
            rounds,
            bvh: None,
            near: Vec::new(),
        };
        let free = rounds.free;
        let scale: Vec<f64> = free.iter().map(|&f| if f { 0.0 } else { 1.0 }).collect();
        let fit_scale = (!free.is_empty()).then_some(scale.as_slice());
        let work = control.stage(
            "registration_originals",
            (1 + rounds.levels.clamp(1, STIFFNESS.len()) * rounds.per_level) as u64,
        )?;
        let mut x = self.solve(&factor, &fixed, &target.points(carried), PAPER)?;
        // Warm starts of the closest-point searches: the carried faces are faces of this target.
        let mut previous: Closest = carried.clone();
        let mut report = StageReport {
            solves: 1,
            factorisations: 1,
            ..Default::default()
        };
        work.tick(1)?;
        let levels = rounds.levels.clamp(1, STIFFNESS.len());
        for k in 0..levels {
            let mu = Mu {
                bend: STIFFNESS[levels - 1 - k],
                ..PAPER
            };
            for _ in 0..rounds.per_level {
                let (rows, faces) = back.rows(&x, self.faces);
                let extra = Extra {
                    rows: &rows,
                    faces: &faces,
                    fit_scale,
                };
                // The factorisation runs on one core; the forward closest points and the
                // right-hand side, which the matrix does not need, on the other meanwhile.
                let (factor, (near, c, fixed)) = rayon::join(
                    || self.factor_extra(&areas, mu, &extra),
                    || {
                        let near = target.closest_near(&x, Some(&previous));
                        let mut c = target.points(&near);
                        if let Some(b) = rounds.boundary {
                            b.snap(&x, &mut c);
                        }
                        let fixed = self.fixed_rhs_extra(rest, &areas, &target_refs, mu, &extra);
                        (near, c, fixed)
                    },
                );
                previous = near;
                x = self.solve_scaled(&factor?, &fixed, &c, mu, fit_scale)?;
                report.factorisations += 1;
                report.solves += 1;
                work.tick(1)?;
            }
        }
        report.rms_fit = rms(
            &x,
            &target.points(&target.closest_near(&x, Some(&previous))),
        );
        Ok((x, report))
    }
}
