//! The Poisson blend on the template mesh (§5 of Zell & Botsch 2013, after Alexa 2003 with the
//! cotangent Laplacian instead of the uniform one): per-vertex Laplacian coordinates of two
//! functions on the template's connectivity (positions, or colours) are interpolated with a
//! per-vertex weight ω(v) = w·r(v), and the function whose Laplacian matches them is solved for.
//!
//! Discretisation: `K = −L`, `L` the template's cotan Laplacian (symmetric, positive
//! semi-definite after the sign change; integrated form, as in [`super::system`]). One operator
//! for both shapes, the template's (rest-shape cotangents, as the registration's bending term):
//! with one operator the blended coordinates `δ = (1 − ω)∘K a + ω∘K b` are those of the linear
//! blend wherever ω is constant, so a region covering the whole mesh gives back the linear blend
//! exactly. Solve `K x = δ` for the free vertices with **hard** (Dirichlet) constraints: every
//! vertex with r(v) = 0 is fixed to the template's value `a`, so the rest of the template is
//! unchanged to the float round trip.
//!
//! A connected component without any fixed vertex (a region covering a whole component) is
//! defined only up to a constant: its δ is made compatible (the sum of δ over the component,
//! which `1ᵀK = 0` requires to vanish, is removed in proportion to the Voronoi areas), one vertex
//! is pinned to the linear blend, and the component is shifted so that its area-weighted mean
//! is that of the linear blend `(1 − ω)a + ωb`. With a constant ω this is the linear blend.
//!
//! One sparse Cholesky factorisation per region serves every right-hand side (3 coordinates, 4
//! colour channels) and every weight w (the solution is affine in w).

use crate::engine::linalg::{NumericCholesky, SymbolicCholesky};

use super::system::{components, LapRows, PatternBuilder, Values};
use super::MethodError;

/// A factorised Poisson system for one region.
pub struct MeshPoisson<'a> {
    lap: &'a LapRows,
    /// Per vertex: its unknown, or `u32::MAX` when fixed.
    unknown: Vec<u32>,
    /// Unknown → vertex.
    vertices: Vec<usize>,
    /// Components without a fixed vertex: their vertices (the first one pinned).
    floating: Vec<Vec<usize>>,
    areas: Vec<f64>,
    factor: Option<NumericCholesky>,
}

fn internal(what: &str, e: impl std::fmt::Display) -> MethodError {
    MethodError::Internal(format!("region blend {what}: {e}"))
}

impl<'a> MeshPoisson<'a> {
    /// The system for weights `r` (fixed where 0) on the mesh of `lap` / `faces`, with the
    /// template's Voronoi `areas`.
    ///
    /// # Errors
    /// [`MethodError::Internal`] if the factorisation fails.
    pub fn new(
        lap: &'a LapRows,
        faces: &[[u32; 3]],
        r: &[f64],
        areas: Vec<f64>,
    ) -> Result<Self, MethodError> {
        let n = lap.len();
        let (comp, count) = components(n, faces);
        let mut has_fixed = vec![false; count];
        for v in 0..n {
            if r[v] <= 0.0 {
                has_fixed[comp[v] as usize] = true;
            }
        }
        let mut floating: Vec<Vec<usize>> = vec![Vec::new(); count];
        for v in 0..n {
            if !has_fixed[comp[v] as usize] {
                floating[comp[v] as usize].push(v);
            }
        }
        floating.retain(|c| !c.is_empty());
        let mut fixed: Vec<bool> = r.iter().map(|&x| x <= 0.0).collect();
        for c in &floating {
            fixed[c[0]] = true;
        }
        let mut unknown = vec![u32::MAX; n];
        let mut vertices = Vec::new();
        for v in 0..n {
            if !fixed[v] {
                unknown[v] = vertices.len() as u32;
                vertices.push(v);
            }
        }
        let factor = if vertices.is_empty() {
            None
        } else {
            let mut pattern = PatternBuilder::new(vertices.len());
            let mut row = Vec::new();
            for &v in &vertices {
                row.clear();
                row.extend(
                    lap.row(v)
                        .0
                        .iter()
                        .map(|&j| unknown[j as usize])
                        .filter(|&u| u != u32::MAX)
                        .map(|u| u as usize),
                );
                pattern.clique_row(unknown[v] as usize, &row);
            }
            let pattern = pattern.build()?;
            let mut values = Values::zeros(&pattern);
            for &v in &vertices {
                let (cols, vals) = lap.row(v);
                for (&j, &x) in cols.iter().zip(vals) {
                    let u = unknown[j as usize];
                    if u != u32::MAX {
                        values.add(unknown[v] as usize, u as usize, -x);
                    }
                }
            }
            let matrix = values.into_matrix()?;
            let symbolic = SymbolicCholesky::new(matrix.pattern().clone())
                .map_err(|e| internal("analysis", e))?;
            Some(
                symbolic
                    .factor(&matrix)
                    .map_err(|e| internal("factorisation", e))?,
            )
        };
        Ok(Self {
            lap,
            unknown,
            vertices,
            floating,
            areas,
            factor,
        })
    }

    /// The Poisson blend of `a` (weight 1 − ω) and `b` (weight ω), one vector per channel.
    ///
    /// # Errors
    /// [`MethodError::Internal`] if a solve fails.
    pub fn blend(
        &self,
        a: &[Vec<f64>],
        b: &[Vec<f64>],
        omega: &[f64],
    ) -> Result<Vec<Vec<f64>>, MethodError> {
        let n = self.lap.len();
        let mut out = Vec::with_capacity(a.len());
        let mut rhs = Vec::with_capacity(a.len());
        for (ac, bc) in a.iter().zip(b) {
            let (la, lb) = (self.lap.mul(ac), self.lap.mul(bc));
            // δ = (1 − ω)·K a + ω·K b with K = −L.
            let mut delta: Vec<f64> = (0..n)
                .map(|v| -((1.0 - omega[v]) * la[v] + omega[v] * lb[v]))
                .collect();
            let lin: Vec<f64> = (0..n)
                .map(|v| (1.0 - omega[v]) * ac[v] + omega[v] * bc[v])
                .collect();
            for c in &self.floating {
                let s: f64 = c.iter().map(|&v| delta[v]).sum();
                let area: f64 = c.iter().map(|&v| self.areas[v]).sum();
                for &v in c {
                    delta[v] -= s * self.areas[v] / area;
                }
            }
            // Fixed vertices hold the linear blend (the template where r = 0).
            let x = lin.clone();
            let mut f = vec![0.0; self.vertices.len()];
            for (i, &v) in self.vertices.iter().enumerate() {
                let (cols, vals) = self.lap.row(v);
                let mut s = delta[v];
                for (&j, &l) in cols.iter().zip(vals) {
                    if self.unknown[j as usize] == u32::MAX {
                        s += l * x[j as usize];
                    }
                }
                f[i] = s;
            }
            rhs.push(f);
            out.push(x);
            // `lin` is kept in `out` until the solve replaces the free entries.
        }
        if let Some(factor) = &self.factor {
            factor
                .solve_many(&mut rhs)
                .map_err(|e| internal("solve", e))?;
        }
        for (x, sol) in out.iter_mut().zip(&rhs) {
            let lin = x.clone();
            for (i, &v) in self.vertices.iter().enumerate() {
                x[v] = sol[i];
            }
            for c in &self.floating {
                let area: f64 = c.iter().map(|&v| self.areas[v]).sum();
                let shift: f64 = c
                    .iter()
                    .map(|&v| self.areas[v] * (lin[v] - x[v]))
                    .sum::<f64>()
                    / area;
                for &v in c {
                    x[v] += shift;
                }
            }
        }
        Ok(out)
    }
}
