//! Non-rigid registration (§3.3, eqs. 6-8) of the source onto the target, first between the base
//! meshes, then between the originals. The source vertices `x` minimise
//!
//! `μ1/ΣÂ Σ Â_i ‖Δ(x_i − x̂_i)‖² + μ2/n Σ ‖x_i − c_i‖² + μ3/K Σ w_k ‖r_k^s − r̂_k^t‖²`
//!
//! with `Δ` the cotan Laplacian of the *original* source divided by the areas `Â` (those of the
//! rest shape `x̂`), `c_i` the closest point of `x_i` on the target (exact point-triangle distance
//! through the BVH), `r̂^t` the reference points on the target and `K = Σ w_k`. The normal
//! equations `(μ1/ΣÂ Lᵀ Â⁻¹ L + μ2/n I + μ3/K Σ w BᵀB) x = μ1/ΣÂ Lᵀ Â⁻¹ L x̂ + μ2/n c + μ3/K Σ w Bᵀ r̂`
//! share one pattern for both stages, so one symbolic analysis serves every solve; the matrix
//! changes only with the weights, so it is factorised once per stiffness and the ICP updates of
//! `c` only re-solve.
//!
//! Schedules (ours where the paper gives ranges): base meshes with `μ1 = 10 → 1 → 0.1`,
//! `μ2 = 1`, `μ3 = 10` and `per_stiffness` (default 3) closest-point updates each, 9 solves in
//! all (the paper: "about 10"; its §6 timing mentions five). Originals: `μ2 = 300`,
//! `μ1 = μ3 = 0.1`, bending relative to the original source, the first solve using the base
//! stage's last closest points carried to the original target as (triangle, barycentric), each
//! further one recomputing them on the original target ([`super::originals`]).
//!
//! Speed (the same results; techniques of ours, not the paper's): the bending term's values go
//! through slots computed once with the pattern ([`super::system::BilaplacianSlots`]), the fitting
//! term through the diagonal's positions and backward rows through per-face slots, so a
//! re-assembly searches nothing; the three coordinates are solved as one block; every
//! closest-point search after the first is bounded by the distance to the point's previous
//! closest face ([`FitTarget::closest_near`], [`near_bound`]), which prunes most of the
//! hierarchy and returns the same answer as the unbounded search.

use rayon::prelude::*;

use crate::engine::control::{Control, StageProgress};
use crate::engine::linalg::{NumericCholesky, SparsityPattern, SymbolicCholesky};
use crate::engine::spatial::{point_triangle_distance_squared, Bvh};
use std::sync::Arc;

use super::refs::{RefPair, RefRow};
use super::system::{face_slots, voronoi_areas, BilaplacianSlots, LapRows, PatternBuilder, Values};
use super::MethodError;

/// Closest points of the source vertices on a target: per vertex (target face, barycentric).
pub type Closest = Vec<(u32, [f32; 3])>;

/// A target surface to fit to.
pub struct FitTarget<'a> {
    /// Positions.
    pub x: &'a [[f64; 3]],
    /// Faces.
    pub faces: &'a [[u32; 3]],
    /// BVH over `x` (as f32) and `faces`.
    pub bvh: &'a Bvh,
}

impl FitTarget<'_> {
    /// The closest point of every `p` (parallel; independent of the thread count).
    pub fn closest(&self, points: &[[f64; 3]]) -> Closest {
        self.closest_near(points, None)
    }

    /// [`Self::closest`], each query bounded by its distance to a nearby face (`near[i]`, e.g.
    /// the previous iteration's closest face of point `i`) so that the search prunes most of
    /// the hierarchy. The bound is widened by a relative 1e-4, so the exact closest point and
    /// any tie are still found: the answers are those of the unbounded search.
    pub fn closest_near(&self, points: &[[f64; 3]], near: Option<&Closest>) -> Closest {
        points
            .par_iter()
            .enumerate()
            .map(|(i, p)| {
                let q = p.map(|c| c as f32);
                let bound = near.map_or(f32::INFINITY, |c| self.bound(c[i].0, q));
                self.bvh
                    .closest_point(q, bound)
                    .or_else(|| self.bvh.closest_point(q, f32::INFINITY))
                    .map_or((0, [1.0, 0.0, 0.0]), |h| (h.face, h.bary))
            })
            .collect()
    }

    /// [`near_bound`] for `face` of this target (its corners as the hierarchy holds them).
    fn bound(&self, face: u32, q: [f32; 3]) -> f32 {
        match self.faces.get(face as usize) {
            Some(f) => near_bound(q, f.map(|v| self.x[v as usize].map(|x| x as f32))),
            None => f32::INFINITY,
        }
    }

    /// Positions of (face, barycentric) points.
    pub fn points(&self, closest: &Closest) -> Vec<[f64; 3]> {
        closest
            .iter()
            .map(|&(f, b)| RefRow::face(self.faces[f as usize], b).eval(self.x))
            .collect()
    }
}

/// The distance from `q` to the triangle `corners` (in f32, as a hierarchy holds them), widened
/// by a relative 1e-4 (and 1e-12): a closest-point search bounded by it still finds that
/// triangle and any tie, so it returns what the unbounded search would (the warm start of
/// repeated searches from nearby points, as the texel loop's `Surface::hint_bound`).
pub(super) fn near_bound(q: [f32; 3], corners: [[f32; 3]; 3]) -> f32 {
    let [a, b, c] = corners;
    let (d2, _, _) = point_triangle_distance_squared(q, a, b, c);
    d2.sqrt() * (1.0 + 1e-4) + 1e-12
}

/// The registration system of one source mesh: pattern and symbolic analysis.
pub struct Registration<'a> {
    pub(super) lap: &'a LapRows,
    pub(super) faces: &'a [[u32; 3]],
    pub(super) pairs: &'a [RefPair],
    pattern: Arc<SparsityPattern>,
    symbolic: SymbolicCholesky,
    /// Value slots of the bending term.
    bending: BilaplacianSlots,
    /// Value positions of the diagonal (the fitting term).
    diagonal: Vec<usize>,
    /// Value slots of every source face's corners (the backward rows).
    face_slots: Vec<[u32; 9]>,
    k_total: f64,
}

/// Extra terms of a factorisation (the originals stage's backward pairs,
/// [`super::originals`]): weighted rows `w ‖row · x − t‖²`.
#[derive(Default)]
pub(super) struct Extra<'e> {
    /// Barycentric rows with their weights and the points `t` they are pulled to.
    pub rows: &'e [(RefRow, f64, [f64; 3])],
    /// The source face of each row (its corners are the row's vertices).
    pub faces: &'e [u32],
    /// Per source vertex, a factor on its forward fitting weight (absent: 1 for every vertex).
    pub fit_scale: Option<&'e [f64]>,
}

/// The weights of one stiffness level.
#[derive(Clone, Copy, Debug)]
pub struct Mu {
    /// Bending μ1.
    pub bend: f64,
    /// Fitting μ2.
    pub fit: f64,
    /// Reference points μ3.
    pub refs: f64,
}

/// The state of the base stage's closest-point iterations.
struct Icp<'s, 't> {
    target: &'s FitTarget<'t>,
    x: &'s mut Vec<[f64; 3]>,
    previous: &'s mut Option<Closest>,
    work: &'s StageProgress<'s>,
}

/// What a registration stage did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StageReport {
    /// Linear solves (closest-point updates).
    pub solves: usize,
    /// Numeric factorisations.
    pub factorisations: usize,
    /// RMS distance of the source vertices to their last closest points, in output units.
    pub rms_fit: f64,
}

impl<'a> Registration<'a> {
    /// Builds the pattern (two-rings of the source plus reference cliques) and analyses it.
    ///
    /// # Errors
    /// [`MethodError::Internal`] if the analysis fails.
    pub fn new(
        lap: &'a LapRows,
        faces: &'a [[u32; 3]],
        pairs: &'a [RefPair],
    ) -> Result<Self, MethodError> {
        let mut pb = PatternBuilder::new(lap.len());
        pb.bilaplacian(lap, 0);
        for p in pairs {
            pb.reference(&[(p.source, 0)]);
        }
        let pattern = pb.build()?;
        let symbolic = SymbolicCholesky::new(pattern.clone())
            .map_err(|e| MethodError::Internal(format!("registration analysis: {e}")))?;
        Ok(Self {
            lap,
            faces,
            pairs,
            bending: BilaplacianSlots::new(&pattern, lap, 0)?,
            diagonal: pattern.diagonal_positions(),
            face_slots: face_slots(&pattern, faces)?,
            pattern,
            symbolic,
            k_total: pairs
                .iter()
                .map(|p| p.weight)
                .sum::<f64>()
                .max(f64::MIN_POSITIVE),
        })
    }

    fn factor(&self, areas: &[f64], mu: Mu) -> Result<NumericCholesky, MethodError> {
        self.factor_extra(areas, mu, &Extra::default())
    }

    /// [`Self::factor`] with extra terms.
    pub(super) fn factor_extra(
        &self,
        areas: &[f64],
        mu: Mu,
        extra: &Extra<'_>,
    ) -> Result<NumericCholesky, MethodError> {
        let n = self.lap.len();
        let total: f64 = areas.iter().sum();
        let mut v = Values::zeros(&self.pattern);
        v.add_bilaplacian_at(&self.bending, self.lap, areas, mu.bend / total);
        for (k, (row, w, _)) in extra.rows.iter().enumerate() {
            match extra.faces.get(k) {
                Some(&f) => v.add_face_outer(&self.face_slots[f as usize], row, *w),
                None => v.add_outer(&row.entries(0), *w),
            }
        }
        match extra.fit_scale {
            Some(scale) => v.add_diagonal_scaled(&self.diagonal, mu.fit / n as f64, scale),
            None => v.add_diagonal(&self.diagonal, mu.fit / n as f64),
        }
        for p in self.pairs {
            v.add_outer(&p.source.entries(0), mu.refs * p.weight / self.k_total);
        }
        self.symbolic
            .factor_sequential(&v.into_matrix()?)
            .map_err(|e| MethodError::Internal(format!("registration factorisation: {e}")))
    }

    /// The right-hand side without the fitting term.
    fn fixed_rhs(
        &self,
        rest: &[[f64; 3]],
        areas: &[f64],
        target_refs: &[[f64; 3]],
        mu: Mu,
    ) -> Vec<Vec<f64>> {
        self.fixed_rhs_extra(rest, areas, target_refs, mu, &Extra::default())
    }

    /// [`Self::fixed_rhs`] with the extra terms of [`Self::factor_extra`].
    pub(super) fn fixed_rhs_extra(
        &self,
        rest: &[[f64; 3]],
        areas: &[f64],
        target_refs: &[[f64; 3]],
        mu: Mu,
        extra: &Extra<'_>,
    ) -> Vec<Vec<f64>> {
        let n = self.lap.len();
        let total: f64 = areas.iter().sum();
        let inv: Vec<f64> = areas.iter().map(|a| mu.bend / total / a).collect();
        let mut rhs: Vec<Vec<f64>> = (0..3)
            .map(|d| {
                let x: Vec<f64> = rest.iter().map(|p| p[d]).collect();
                self.lap.bilaplacian_mul(&inv, &x)
            })
            .collect();
        for (p, r) in self.pairs.iter().zip(target_refs) {
            let w = mu.refs * p.weight / self.k_total;
            for (i, a) in p.source.entries(0) {
                (0..3).for_each(|d| rhs[d][i] += w * a * r[d]);
            }
        }
        for (row, w, r) in extra.rows {
            for (i, a) in row.entries(0) {
                (0..3).for_each(|d| rhs[d][i] += w * a * r[d]);
            }
        }
        debug_assert_eq!(rhs[0].len(), n);
        rhs
    }

    pub(super) fn solve(
        &self,
        factor: &NumericCholesky,
        fixed: &[Vec<f64>],
        fit: &[[f64; 3]],
        mu: Mu,
    ) -> Result<Vec<[f64; 3]>, MethodError> {
        self.solve_scaled(factor, fixed, fit, mu, None)
    }

    /// [`Self::solve`] with the per-vertex forward weight factors of [`Extra::fit_scale`].
    pub(super) fn solve_scaled(
        &self,
        factor: &NumericCholesky,
        fixed: &[Vec<f64>],
        fit: &[[f64; 3]],
        mu: Mu,
        fit_scale: Option<&[f64]>,
    ) -> Result<Vec<[f64; 3]>, MethodError> {
        let n = self.lap.len();
        let w = mu.fit / n as f64;
        let scale = |i: usize| fit_scale.map_or(1.0, |s| s[i]);
        let mut rhs: Vec<Vec<f64>> = (0..3)
            .map(|d| {
                fixed[d]
                    .iter()
                    .zip(fit)
                    .enumerate()
                    .map(|(i, (b, c))| b + w * scale(i) * c[d])
                    .collect()
            })
            .collect();
        factor
            .solve_block(&mut rhs)
            .map_err(|e| MethodError::Internal(format!("registration solve: {e}")))?;
        Ok((0..n).map(|i| [rhs[0][i], rhs[1][i], rhs[2][i]]).collect())
    }

    /// `rounds` closest-point updates, each followed by a solve with `factor`.
    fn iterate(
        &self,
        icp: &mut Icp<'_, '_>,
        factor: &NumericCholesky,
        fixed: &[Vec<f64>],
        mu: Mu,
        rounds: usize,
    ) -> Result<(), MethodError> {
        for _ in 0..rounds {
            let near = icp.target.closest_near(icp.x, icp.previous.as_ref());
            let c = icp.target.points(&near);
            *icp.previous = Some(near);
            *icp.x = self.solve(factor, fixed, &c, mu)?;
            icp.work.tick(1)?;
        }
        Ok(())
    }

    /// §3.3 on the base meshes: from `rest = B^s`, fit to `target = B^t`. Returns the fitted
    /// positions and their last closest points on the target.
    ///
    /// # Errors
    /// [`MethodError::Internal`], [`MethodError::Cancelled`].
    pub fn base(
        &self,
        rest: &[[f64; 3]],
        target: &FitTarget<'_>,
        per_stiffness: usize,
        control: &Control,
    ) -> Result<(Vec<[f64; 3]>, Closest, StageReport), MethodError> {
        let areas = voronoi_areas(rest, self.faces)?;
        let target_refs: Vec<[f64; 3]> =
            self.pairs.iter().map(|p| p.target.eval(target.x)).collect();
        let mut x = rest.to_vec();
        let mut previous: Option<Closest> = None;
        let mut report = StageReport::default();
        let work = control.stage("registration", 3 * per_stiffness as u64)?;
        let mu = [10.0, 1.0, 0.1].map(|bend| Mu {
            bend,
            fit: 1.0,
            refs: 10.0,
        });
        // The matrices depend on the rest areas and the weights only, not on `x`: the later
        // levels' factorisations run on the other core while the first level iterates.
        let first = self.factor(&areas, mu[0])?;
        let mut icp = Icp {
            target,
            x: &mut x,
            previous: &mut previous,
            work: &work,
        };
        let (done, later) = rayon::join(
            || {
                let fixed = self.fixed_rhs(rest, &areas, &target_refs, mu[0]);
                self.iterate(&mut icp, &first, &fixed, mu[0], per_stiffness)
            },
            || {
                mu[1..]
                    .iter()
                    .map(|&m| self.factor(&areas, m))
                    .collect::<Result<Vec<_>, _>>()
            },
        );
        done?;
        for (factor, &mu) in later?.iter().zip(&mu[1..]) {
            let fixed = self.fixed_rhs(rest, &areas, &target_refs, mu);
            self.iterate(&mut icp, factor, &fixed, mu, per_stiffness)?;
        }
        report.factorisations = 3;
        report.solves = 3 * per_stiffness;
        let closest = target.closest_near(&x, previous.as_ref());
        report.rms_fit = rms(&x, &target.points(&closest));
        Ok((x, closest, report))
    }
}

/// RMS distance between corresponding points.
pub(super) fn rms(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|d| (p[d] - q[d]).powi(2)).sum::<f64>())
        .sum();
    (s / a.len().max(1) as f64).sqrt()
}
