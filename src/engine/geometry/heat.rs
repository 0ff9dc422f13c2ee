//! Geodesic distance by the heat method (Crane, Weischedel & Wardetzky 2013, "Geodesics in
//! heat", sections 3.1–3.2, boundary conditions as in section 3.3).
//!
//! Steps, with `L` the cotan Laplacian (negative semi-definite, see [`super::laplacian`]) and `M`
//! the lumped mass matrix:
//! 1. Heat flow for one implicit Euler step of length `t = m·h²` (`h` the mean edge length,
//!    `m` = [`HeatParams::time_factor`]): `(M − tL) u = δ`, with `δ` the unit impulse at the
//!    sources. A source inside a triangle spreads its impulse over the triangle's corners by its
//!    barycentric coordinates.
//! 2. Per face, `X = −∇u / |∇u|` (∇ of the piecewise-linear `u`; `X = 0` where `∇u = 0`).
//! 3. Poisson: `L φ = ∇·X` with the integrated divergence
//!    `(∇·X)_i = ½ Σ_faces [cot θ₁ (e₁·X) + cot θ₂ (e₂·X)]`. Solved as `(−L + εM) φ = −∇·X`
//!    with a tiny shift `ε` (see [`HeatParams::poisson_shift`]) that makes the system positive
//!    definite; the constant it fixes is removed in step 4.
//! 4. `φ` is determined up to a constant per connected component. Each source `s` in face
//!    `(i, j, k)` with barycentric weights `b` estimates it as `Σ b_c (φ_c − |x_c − s|)`: the
//!    value of `φ` at the corners minus their straight-line distance to the source inside the
//!    face (for a vertex source simply `φ` at that vertex). This avoids the bias of
//!    interpolating the cone-shaped `φ` linearly at a point inside a face. The component's
//!    sources' estimates are averaged and subtracted; values below 0 are clamped to 0.
//!    Vertices of components without a source get `f64::INFINITY`.
//!
//! Boundary: [`HeatBoundary::Averaged`] (default) averages the heat of the Neumann problem and of
//! the Dirichlet problem `u = 0` on the boundary, which the paper (section 3.3) recommends for
//! surfaces with boundary; the Dirichlet operator is built on the same sparsity pattern (boundary
//! rows and columns replaced by the identity), so it reuses the symbolic analysis. On closed
//! surfaces only the Neumann problem is factored.
//!
//! [`HeatGeodesics::new`] builds and factors everything once; each query then costs two (three
//! with a boundary) pairs of triangular solves plus O(faces) work. Queries are independent, so
//! [`HeatGeodesics::distance_many`] runs them in parallel.
//!
//! Limits: `u` decays roughly like `exp(−d/√t)`, so beyond about 700 mean edge lengths from
//! every source `u` underflows to 0 and the distance there is unreliable.
//!
//! Written by hand: the method is a few sparse products around the faer Cholesky factors.

use rayon::prelude::*;

use super::laplacian::{all_face_terms, cotan_laplacian, GeometryError, LaplacianParams, MassKind};
use crate::engine::control::Control;
use crate::engine::linalg::{NumericCholesky, SymbolicCholesky};
use crate::engine::math::{cross, dot, length, sub};
use crate::engine::mesh::{topology, Surface};

/// Boundary condition of the heat flow step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HeatBoundary {
    /// Zero Neumann (the natural condition of the cotan Laplacian).
    Neumann,
    /// Mean of the Neumann and the zero-Dirichlet solutions (paper section 3.3).
    #[default]
    Averaged,
}

/// Parameters of [`HeatGeodesics::new`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HeatParams {
    /// `m` in `t = m·h²` (dimensionless). Default: 1 (the paper's choice). Range: (0, 1e4].
    pub time_factor: f64,
    /// Mass matrix. Default: `mixed_voronoi`.
    pub mass: MassKind,
    /// Cotangent clamp, as [`LaplacianParams::max_cotangent`]. Default: 1e5. Range: [1, ∞].
    pub max_cotangent: f64,
    /// Boundary condition of the heat step. Default: `averaged`.
    pub boundary: HeatBoundary,
    /// Relative shift of the Poisson system: `ε = poisson_shift / total area` (dimensionless).
    /// Default: 1e-8. Range: (0, 1e-2].
    pub poisson_shift: f64,
}

impl Default for HeatParams {
    fn default() -> Self {
        Self {
            time_factor: 1.0,
            mass: MassKind::MixedVoronoi,
            max_cotangent: 1e5,
            boundary: HeatBoundary::Averaged,
            poisson_shift: 1e-8,
        }
    }
}

/// A source of a distance query.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// A mesh vertex.
    Vertex(u32),
    /// A point inside (or on) a face, by barycentric weights of the face's corners 0, 1, 2
    /// (each >= 0, normalized to sum 1).
    Point {
        /// Face index.
        face: u32,
        /// Barycentric weights.
        bary: [f64; 3],
    },
}

/// The prepared heat method: factors of the heat and Poisson operators and per-face data.
pub struct HeatGeodesics {
    faces: Vec<[u32; 3]>,
    /// Per face: gradient basis `N × e_i / (2A)` for corner i (zero for degenerate faces).
    grad: Vec<[[f64; 3]; 3]>,
    /// Per face: corner cotangents.
    cot: Vec<[f64; 3]>,
    positions: Vec<[f64; 3]>,
    heat: NumericCholesky,
    heat_dirichlet: Option<(NumericCholesky, Vec<bool>)>,
    poisson: NumericCholesky,
    vertex_component: Vec<u32>,
    time: f64,
    mean_edge: f64,
}

impl std::fmt::Debug for HeatGeodesics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HeatGeodesics")
            .field("vertices", &self.positions.len())
            .field("time", &self.time)
            .field("mean_edge", &self.mean_edge)
            .finish()
    }
}

impl HeatGeodesics {
    /// Builds `L`, `M`, the time step, and factors `M − tL` (and its Dirichlet variant on
    /// surfaces with boundary) and `−L + εM`, all with one symbolic analysis.
    ///
    /// # Errors
    /// Invalid parameters, empty or non-finite surfaces, a zero-area surface, a failed
    /// factorization, or cancellation.
    pub fn new(
        surface: &Surface,
        params: &HeatParams,
        control: &Control,
    ) -> Result<Self, GeometryError> {
        if params.time_factor.is_nan() || params.time_factor <= 0.0 || params.time_factor > 1e4 {
            return Err(GeometryError::InvalidParam {
                name: "time_factor",
                value: params.time_factor,
                range: "(0, 1e4]",
            });
        }
        if params.poisson_shift.is_nan()
            || params.poisson_shift <= 0.0
            || params.poisson_shift > 1e-2
        {
            return Err(GeometryError::InvalidParam {
                name: "poisson_shift",
                value: params.poisson_shift,
                range: "(0, 1e-2]",
            });
        }
        control.stage("heat geodesics: operators", 0)?;
        let lap = cotan_laplacian(
            surface,
            &LaplacianParams {
                mass: params.mass,
                max_cotangent: params.max_cotangent,
            },
        )?;
        let total_area: f64 = lap.mass.iter().sum();
        if total_area.is_nan() || total_area <= 0.0 {
            return Err(GeometryError::Degenerate("zero total area".into()));
        }
        let n = surface.positions.len();
        let pattern = lap.pattern().clone();
        let (mut edge_sum, mut edge_count) = (0.0, 0usize);
        let positions: Vec<[f64; 3]> = surface
            .positions
            .iter()
            .map(|p| p.map(|c| c as f64))
            .collect();
        for j in 0..n {
            for &i in pattern.column(j).iter().filter(|&&i| i > j) {
                edge_sum += length(sub(positions[i], positions[j]));
                edge_count += 1;
            }
        }
        let mean_edge = edge_sum / edge_count.max(1) as f64;
        let time = params.time_factor * mean_edge * mean_edge;
        // Vertices used only by zero-area faces get a tiny mass so the operators stay definite.
        let mass = lap.definite_mass();

        let topo = topology(surface);
        let mut vertex_component = vec![u32::MAX; n];
        for (f, face) in surface.faces.iter().enumerate() {
            for &v in face {
                vertex_component[v as usize] = topo.face_component[f];
            }
        }

        control.stage("heat geodesics: factorization", 0)?;
        let symbolic = SymbolicCholesky::new(pattern.clone())?;
        let heat_op = lap.stiffness.scaled_plus_diagonal(-time, 1.0, &mass);
        let heat = symbolic.factor(&heat_op)?;
        let eps = params.poisson_shift / total_area;
        let poisson = symbolic.factor(&lap.stiffness.scaled_plus_diagonal(-1.0, eps, &mass))?;
        let mut on_boundary = vec![false; n];
        for v in topo.boundary_loops.iter().flatten() {
            on_boundary[*v as usize] = true;
        }
        let heat_dirichlet =
            if params.boundary == HeatBoundary::Averaged && on_boundary.iter().any(|&b| b) {
                let mut values = heat_op.values().to_vec();
                for j in 0..n {
                    for (k, &i) in pattern.column(j).iter().enumerate() {
                        if on_boundary[i] || on_boundary[j] {
                            values[pattern.col_ptr()[j] + k] = if i == j { 1.0 } else { 0.0 };
                        }
                    }
                }
                Some((symbolic.factor_values(&values)?, on_boundary))
            } else {
                None
            };
        control.check()?;

        let terms = all_face_terms(surface, params.mass, params.max_cotangent);
        let grad = (0..surface.faces.len())
            .into_par_iter()
            .with_min_len(4096)
            .map(|f| {
                let p = surface.faces[f].map(|v| positions[v as usize]);
                let nrm = cross(sub(p[1], p[0]), sub(p[2], p[0]));
                let twice_area = length(nrm);
                if terms[f].cot == [0.0; 3] || twice_area.is_nan() || twice_area <= 0.0 {
                    return [[0.0; 3]; 3];
                }
                let unit = nrm.map(|c| c / twice_area);
                std::array::from_fn(|i| {
                    let e = sub(p[(i + 2) % 3], p[(i + 1) % 3]);
                    cross(unit, e).map(|c| c / twice_area)
                })
            })
            .collect();
        Ok(Self {
            faces: surface.faces.clone(),
            grad,
            cot: terms.iter().map(|t| t.cot).collect(),
            positions,
            heat,
            heat_dirichlet,
            poisson,
            vertex_component,
            time,
            mean_edge,
        })
    }

    /// The heat time step `t = m·h²`, world units².
    pub fn time(&self) -> f64 {
        self.time
    }

    /// The mean edge length `h`, world units.
    pub fn mean_edge(&self) -> f64 {
        self.mean_edge
    }

    /// The factor of the heat operator `M − tL` (Neumann).
    pub fn heat_factor(&self) -> &NumericCholesky {
        &self.heat
    }

    /// The factor of the Poisson operator `−L + εM`.
    pub fn poisson_factor(&self) -> &NumericCholesky {
        &self.poisson
    }

    /// Geodesic distance from the nearest of `sources` to every vertex, world units.
    ///
    /// # Errors
    /// [`GeometryError::InvalidSource`] for an empty source list or a bad source.
    pub fn distance(&self, sources: &[Source]) -> Result<Vec<f64>, GeometryError> {
        let points = self.resolve(sources)?;
        let n = self.positions.len();
        let mut delta = vec![0.0; n];
        for (face, bary) in &points {
            for k in 0..3 {
                delta[self.faces[*face][k] as usize] += bary[k];
            }
        }
        let mut u = self.heat.solve(&delta)?;
        if let Some((factor, on_boundary)) = &self.heat_dirichlet {
            let mut rhs = delta;
            for (r, &b) in rhs.iter_mut().zip(on_boundary) {
                if b {
                    *r = 0.0;
                }
            }
            factor.solve_in_place(&mut rhs)?;
            for (a, b) in u.iter_mut().zip(&rhs) {
                *a = 0.5 * (*a + b);
            }
        }
        let mut rhs = self.neg_divergence_of_normalized_gradient(&u);
        self.poisson.solve_in_place(&mut rhs)?;
        Ok(self.shift_to_sources(rhs, &points))
    }

    /// [`HeatGeodesics::distance`] for many independent queries, in parallel; checks `control`
    /// for cancellation between queries.
    ///
    /// # Errors
    /// The first error of any query, or [`GeometryError::Cancelled`].
    pub fn distance_many(
        &self,
        queries: &[Vec<Source>],
        control: &Control,
    ) -> Result<Vec<Vec<f64>>, GeometryError> {
        let stage = control.stage("heat geodesics: queries", queries.len() as u64)?;
        queries
            .par_iter()
            .map(|q| {
                stage.tick(1)?;
                self.distance(q)
            })
            .collect()
    }

    fn resolve(&self, sources: &[Source]) -> Result<Vec<(usize, [f64; 3])>, GeometryError> {
        if sources.is_empty() {
            return Err(GeometryError::InvalidSource {
                index: 0,
                reason: "no sources".into(),
            });
        }
        let bad = |index: usize, reason: String| GeometryError::InvalidSource { index, reason };
        sources
            .iter()
            .enumerate()
            .map(|(index, s)| match *s {
                Source::Vertex(v) => {
                    let f = self
                        .first_face_of(v)
                        .ok_or_else(|| bad(index, format!("vertex {v} is not used by any face")))?;
                    let k = self.faces[f].iter().position(|&x| x == v).unwrap_or(0);
                    let mut bary = [0.0; 3];
                    bary[k] = 1.0;
                    Ok((f, bary))
                }
                Source::Point { face, bary } => {
                    if face as usize >= self.faces.len() {
                        return Err(bad(index, format!("face {face} out of range")));
                    }
                    let sum: f64 = bary.iter().sum();
                    if !bary.iter().all(|b| b.is_finite() && *b >= -1e-9)
                        || sum.is_nan()
                        || sum <= 0.0
                    {
                        return Err(bad(index, format!("invalid barycentric {bary:?}")));
                    }
                    Ok((face as usize, bary.map(|b| b.max(0.0) / sum)))
                }
            })
            .collect()
    }

    fn first_face_of(&self, v: u32) -> Option<usize> {
        self.faces.iter().position(|f| f.contains(&v))
    }

    /// `−(∇·X)` with `X = −∇u/|∇u|` per face.
    fn neg_divergence_of_normalized_gradient(&self, u: &[f64]) -> Vec<f64> {
        let contributions: Vec<[f64; 3]> = (0..self.faces.len())
            .into_par_iter()
            .with_min_len(4096)
            .map(|f| {
                let face = self.faces[f];
                let g = &self.grad[f];
                let mut gu = [0.0; 3];
                for i in 0..3 {
                    let ui = u[face[i] as usize];
                    for k in 0..3 {
                        gu[k] += ui * g[i][k];
                    }
                }
                let len = length(gu);
                if !len.is_finite() || len <= 0.0 {
                    return [0.0; 3];
                }
                let x = gu.map(|c| -c / len);
                let p = face.map(|v| self.positions[v as usize]);
                let cot = self.cot[f];
                std::array::from_fn(|c| {
                    let (a, b) = ((c + 1) % 3, (c + 2) % 3);
                    let e1 = sub(p[a], p[c]);
                    let e2 = sub(p[b], p[c]);
                    -0.5 * (cot[b] * dot(e1, x) + cot[a] * dot(e2, x))
                })
            })
            .collect();
        let mut out = vec![0.0; self.positions.len()];
        for (face, c) in self.faces.iter().zip(&contributions) {
            for k in 0..3 {
                out[face[k] as usize] += c[k];
            }
        }
        out
    }

    fn shift_to_sources(&self, mut phi: Vec<f64>, points: &[(usize, [f64; 3])]) -> Vec<f64> {
        let ncomp = self
            .vertex_component
            .iter()
            .filter(|&&c| c != u32::MAX)
            .map(|&c| c as usize + 1)
            .max()
            .unwrap_or(0);
        let mut sum = vec![0.0; ncomp];
        let mut count = vec![0usize; ncomp];
        for (face, bary) in points {
            let f = self.faces[*face];
            let p = f.map(|v| self.positions[v as usize]);
            let src: [f64; 3] =
                std::array::from_fn(|k| bary[0] * p[0][k] + bary[1] * p[1][k] + bary[2] * p[2][k]);
            let value: f64 = (0..3)
                .map(|k| bary[k] * (phi[f[k] as usize] - length(sub(p[k], src))))
                .sum();
            let c = self.vertex_component[f[0] as usize] as usize;
            sum[c] += value;
            count[c] += 1;
        }
        for (v, d) in phi.iter_mut().enumerate() {
            let c = self.vertex_component[v] as usize;
            *d = match count.get(c) {
                Some(&k) if k > 0 => (*d - sum[c] / k as f64).max(0.0),
                _ => f64::INFINITY,
            };
        }
        phi
    }
}
