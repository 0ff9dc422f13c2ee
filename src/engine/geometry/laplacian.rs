//! Cotan Laplacian (Pinkall & Polthier 1993, "Computing discrete minimal surfaces and their
//! conjugates", section 3; Meyer, Desbrun, Schröder & Barr 2003, "Discrete differential-geometry
//! operators for triangulated 2-manifolds", section 3.3) and mass matrices (Meyer et al. 2003
//! section 3.4 mixed Voronoi areas, or lumped barycentric areas).
//!
//! **Sign convention.** `L_ij = ½ (cot α_ij + cot β_ij)` for every edge `ij` (α, β the angles
//! opposite the edge; one of them on a boundary edge), `L_ii = -Σ_j L_ij`. `L` is symmetric
//! and negative semi-definite and integrates the Laplace–Beltrami operator:
//! `(L f)_i ≈ A_i (Δf)(x_i)` with `A_i` the vertex area (`M_ii`), so `L f ≈ M Δf`. This is the
//! convention of libigl's `cotmatrix`. Units: `L` is dimensionless, `M` is world units².
//!
//! **Boundary.** Boundary edges get the single cotangent of their one triangle; this is the
//! natural (zero Neumann) boundary condition.
//!
//! **Robustness.** Computed in f64. A face whose doubled area `|(b - a) × (c - a)|` is at most
//! `f64::EPSILON · (longest edge)²` is treated as having zero area and contributes nothing to `L`
//! or `M`. A face whose largest cotangent magnitude exceeds `max_cotangent` has its three
//! cotangents scaled together down to that bound, so that slivers cannot create huge weights.
//! Scaling, not clamping each one: a face's exact cotangents form a positive semi-definite
//! element matrix (the P1 stiffness `∫∇φ_i·∇φ_j`), and a positive multiple of it stays so, while
//! clamping only the needle's angle made the element indefinite (`c₁c₂ + c₂c₃ + c₃c₁ = 1` for
//! exact cotangents, negative after clamping `c₁`). A remeshed koala level with one needle of
//! angle below 1e-5 rad gave a `−L + σM` without a Cholesky factor that way.
//! Obtuse triangles keep their (negative) cotangents, as the operator requires, and the mixed
//! Voronoi mass handles them as in Meyer et al. (area/2 at the obtuse corner, area/4 at the
//! others). Non-manifold edges simply sum all incident triangles.
//!
//! **Parallelism.** Per-face cotangents and areas are computed in parallel; the matrix is
//! assembled in parallel over columns (each column owned by one task), deterministic.
//!
//! Written by hand: assembly from mesh faces is specific to the Surface type; storage and
//! factorization are [`crate::engine::linalg`] (faer).

use std::sync::Arc;

use rayon::prelude::*;

use crate::engine::control::Cancelled;
use crate::engine::linalg::{LinalgError, SparsityPattern, SymmetricMatrix};
use crate::engine::math::{cross, dot, length, sub};
use crate::engine::mesh::csr::vertex_faces;
use crate::engine::mesh::Surface;

/// Errors of the geometry operators.
#[derive(Debug, thiserror::Error)]
pub enum GeometryError {
    /// The surface has no faces.
    #[error("the surface has no faces")]
    EmptySurface,
    /// A vertex position is NaN or infinite.
    #[error("vertex {vertex} has a non-finite position")]
    NonFinitePosition {
        /// The offending vertex.
        vertex: usize,
    },
    /// A parameter is outside its documented range.
    #[error("parameter {name} = {value} is out of range {range}")]
    InvalidParam {
        /// Parameter name.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// The valid range, as text.
        range: &'static str,
    },
    /// A source point refers to a face or vertex the surface does not have, or has bad
    /// barycentric coordinates.
    #[error("source {index}: {reason}")]
    InvalidSource {
        /// Index of the source in the query.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// The surface is too degenerate for the operator (e.g. zero total area).
    #[error("degenerate surface: {0}")]
    Degenerate(String),
    /// A linear solve failed.
    #[error(transparent)]
    Linalg(#[from] LinalgError),
    /// Cancelled through the Control.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

/// Which lumped (diagonal) mass matrix to build.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MassKind {
    /// One third of each incident triangle's area.
    Barycentric,
    /// Meyer et al. 2003 mixed Voronoi areas (Voronoi region for non-obtuse triangles; area/2 at
    /// an obtuse corner and area/4 at the other two corners of an obtuse triangle).
    #[default]
    MixedVoronoi,
}

/// Parameters of [`cotan_laplacian`].
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LaplacianParams {
    /// Mass matrix to build. Default: `mixed_voronoi`.
    pub mass: MassKind,
    /// A face's cotangents are scaled together so that none exceeds `max_cotangent` in
    /// magnitude (dimensionless).
    /// Default: 1e5 (angles below about 1e-5 rad are treated as 1e-5 rad). Range: [1, ∞].
    pub max_cotangent: f64,
}

impl Default for LaplacianParams {
    fn default() -> Self {
        Self {
            mass: MassKind::MixedVoronoi,
            max_cotangent: 1e5,
        }
    }
}

/// The cotan Laplacian `L` (negative semi-definite) and the diagonal mass matrix `M`.
#[derive(Clone, Debug)]
pub struct Laplacian {
    /// `L`, symmetric, pattern = each vertex and its edge neighbours.
    pub stiffness: SymmetricMatrix,
    /// Diagonal of `M`, world units²; sums to the area of the non-degenerate faces.
    pub mass: Vec<f64>,
}

impl Laplacian {
    /// The shared sparsity pattern of `L` (and of every operator built from it).
    pub fn pattern(&self) -> &Arc<SparsityPattern> {
        self.stiffness.pattern()
    }

    /// The mass with every entry at least `1e-12 ×` the mean vertex area, so that `M − tL`
    /// stays positive definite: a vertex used only by zero-area faces has `M_ii = 0` and an
    /// empty row of `L`, which leaves a zero pivot (isotropic remeshing can leave such faces).
    pub fn definite_mass(&self) -> Vec<f64> {
        let total: f64 = self.mass.iter().sum();
        let floor = 1e-12 * total / self.mass.len().max(1) as f64;
        self.mass.iter().map(|&m| m.max(floor)).collect()
    }
}

/// Per-face geometry in f64: corner cotangents (clamped) and corner areas of the requested kind.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct FaceTerms {
    /// Cotangent of the angle at each corner (0 for a degenerate face).
    pub cot: [f64; 3],
    /// Area assigned to each corner (0 for a degenerate face).
    pub area: [f64; 3],
}

/// Corner positions of `face` in f64.
pub(crate) fn face_points(surface: &Surface, face: usize) -> [[f64; 3]; 3] {
    surface.faces[face].map(|v| surface.positions[v as usize].map(|c| c as f64))
}

/// Whether a face has repeated vertices or (numerically) zero area; see the module docs.
pub(crate) fn is_degenerate(surface: &Surface, face: usize) -> bool {
    let f = surface.faces[face];
    if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
        return true;
    }
    let p = face_points(surface, face);
    let e = [sub(p[1], p[0]), sub(p[2], p[1]), sub(p[0], p[2])];
    let longest2 = e.iter().map(|x| dot(*x, *x)).fold(0.0, f64::max);
    let twice_area = length(cross(e[0], sub(p[2], p[0])));
    twice_area.is_nan() || twice_area <= f64::EPSILON * longest2
}

/// Cotangents and corner areas of one face.
pub(crate) fn face_terms(
    surface: &Surface,
    face: usize,
    kind: MassKind,
    max_cot: f64,
) -> FaceTerms {
    if is_degenerate(surface, face) {
        return FaceTerms::default();
    }
    let p = face_points(surface, face);
    let twice_area = length(cross(sub(p[1], p[0]), sub(p[2], p[0])));
    let area = 0.5 * twice_area;
    let mut raw = [0.0; 3];
    for k in 0..3 {
        let u = sub(p[(k + 1) % 3], p[k]);
        let v = sub(p[(k + 2) % 3], p[k]);
        raw[k] = dot(u, v) / twice_area;
    }
    // The three scaled together (not clamped one by one): the face's element matrix stays
    // positive semi-definite (module docs, "Robustness").
    let largest = raw.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    let scale = if largest > max_cot {
        max_cot / largest
    } else {
        1.0
    };
    let cot = raw.map(|c| c * scale);
    let corner_area = match kind {
        MassKind::Barycentric => [area / 3.0; 3],
        MassKind::MixedVoronoi => {
            if let Some(obtuse) = (0..3).find(|&k| raw[k] < 0.0) {
                std::array::from_fn(|k| if k == obtuse { area / 2.0 } else { area / 4.0 })
            } else {
                std::array::from_fn(|k| {
                    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
                    let eij = sub(p[i], p[k]);
                    let eik = sub(p[j], p[k]);
                    // Edge k→i is opposite corner j, edge k→j opposite corner i.
                    (dot(eij, eij) * raw[j] + dot(eik, eik) * raw[i]) / 8.0
                })
            }
        }
    };
    FaceTerms {
        cot,
        area: corner_area,
    }
}

/// Per-face terms for the whole surface, in parallel.
pub(crate) fn all_face_terms(surface: &Surface, kind: MassKind, max_cot: f64) -> Vec<FaceTerms> {
    (0..surface.faces.len())
        .into_par_iter()
        .with_min_len(4096)
        .map(|f| face_terms(surface, f, kind, max_cot))
        .collect()
}

pub(crate) fn validate_surface(surface: &Surface) -> Result<(), GeometryError> {
    if surface.faces.is_empty() {
        return Err(GeometryError::EmptySurface);
    }
    if let Some(vertex) = surface
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(GeometryError::NonFinitePosition { vertex });
    }
    Ok(())
}

/// Builds the mass matrix diagonal only (world units²).
///
/// # Errors
/// [`GeometryError::EmptySurface`], [`GeometryError::NonFinitePosition`].
pub fn mass_matrix(surface: &Surface, kind: MassKind) -> Result<Vec<f64>, GeometryError> {
    validate_surface(surface)?;
    let terms = all_face_terms(surface, kind, f64::INFINITY);
    Ok(accumulate_mass(surface, &terms))
}

fn accumulate_mass(surface: &Surface, terms: &[FaceTerms]) -> Vec<f64> {
    let mut mass = vec![0.0; surface.positions.len()];
    for (f, t) in surface.faces.iter().zip(terms) {
        for k in 0..3 {
            mass[f[k] as usize] += t.area[k];
        }
    }
    mass
}

/// Builds the cotan Laplacian `L` and the mass matrix `M` (see the module docs for signs).
///
/// # Errors
/// [`GeometryError::EmptySurface`], [`GeometryError::NonFinitePosition`],
/// [`GeometryError::InvalidParam`] for `max_cotangent < 1` or NaN.
pub fn cotan_laplacian(
    surface: &Surface,
    params: &LaplacianParams,
) -> Result<Laplacian, GeometryError> {
    validate_surface(surface)?;
    if params.max_cotangent.is_nan() || params.max_cotangent < 1.0 {
        return Err(GeometryError::InvalidParam {
            name: "max_cotangent",
            value: params.max_cotangent,
            range: "[1, inf]",
        });
    }
    let terms = all_face_terms(surface, params.mass, params.max_cotangent);
    let (offsets, incident) = vertex_faces(surface);
    let nv = surface.positions.len();
    let columns: Vec<(Vec<usize>, Vec<f64>)> = (0..nv)
        .into_par_iter()
        .with_min_len(512)
        .map(|j| {
            let mut entries: Vec<(usize, f64)> = Vec::with_capacity(16);
            let faces = &incident[offsets[j] as usize..offsets[j + 1] as usize];
            for &fi in faces {
                let f = surface.faces[fi as usize];
                if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
                    continue;
                }
                let c = f.iter().position(|&v| v as usize == j).unwrap_or(0);
                let cot = terms[fi as usize].cot;
                // Edge j–f[c+1] is opposite corner c+2 and vice versa.
                entries.push((f[(c + 1) % 3] as usize, 0.5 * cot[(c + 2) % 3]));
                entries.push((f[(c + 2) % 3] as usize, 0.5 * cot[(c + 1) % 3]));
            }
            entries.sort_by_key(|e| e.0);
            let mut rows = Vec::with_capacity(entries.len() + 1);
            let mut vals: Vec<f64> = Vec::with_capacity(entries.len() + 1);
            let mut diag = 0.0;
            let mut diag_at = None;
            for (i, w) in entries {
                if diag_at.is_none() && i > j {
                    diag_at = Some(rows.len());
                    rows.push(j);
                    vals.push(0.0);
                }
                diag -= w;
                if rows.last() == Some(&i) {
                    *vals.last_mut().expect("rows and vals grow together") += w;
                } else {
                    rows.push(i);
                    vals.push(w);
                }
            }
            let at = diag_at.unwrap_or_else(|| {
                rows.push(j);
                vals.push(0.0);
                rows.len() - 1
            });
            vals[at] = diag;
            (rows, vals)
        })
        .collect();
    let mut cols = Vec::with_capacity(nv);
    let mut values = Vec::with_capacity(columns.iter().map(|c| c.1.len()).sum());
    for (rows, vals) in columns {
        cols.push(rows);
        values.extend(vals);
    }
    let pattern = Arc::new(SparsityPattern::from_sorted_columns(cols));
    let stiffness = SymmetricMatrix::new(pattern, values)?;
    let mass = accumulate_mass(surface, &terms);
    Ok(Laplacian { stiffness, mass })
}
