//! Per-vertex principal curvatures and directions, mean and Gaussian curvature, by per-face
//! curvature tensors averaged at vertices (Rusinkiewicz 2004, "Estimating curvatures and their
//! derivatives on triangle meshes", sections 3–4).
//!
//! 1. Vertex normals in f64 with the weights of Max 1999 (`(e₁ × e₂) / (|e₁|² |e₂|²)` per
//!    corner), which are exact for vertices on a sphere.
//! 2. Per face, in an orthonormal frame `(u_f, v_f)` of the face plane, the second fundamental
//!    form `II = [[e, f], [f, g]]` is the least-squares solution of `II · (eᵀu, eᵀv) =
//!    (Δnᵀu, Δnᵀv)` over the three edges `e` and the differences `Δn` of the vertex normals
//!    along them (six equations, three unknowns).
//! 3. Each face tensor is re-expressed in the frame of each of its vertices after rotating the
//!    vertex frame into the face plane (rotation about `n_v × n_f`), and averaged with the corner
//!    areas as weights (Meyer et al. 2003 mixed Voronoi by default, as in the paper).
//! 4. The eigen-decomposition of the averaged 2 × 2 tensor gives `k_max ≥ k_min` and their
//!    directions (unit, tangent, orthogonal); `H = (k_max + k_min)/2`, `K = k_max · k_min`.
//!
//! **Signs.** `II` is the derivative of the unit normal (`dN`), so with outward normals (faces
//! counter-clockwise seen from outside) a sphere of radius ρ has `k_max = k_min = H = 1/ρ` and
//! `K = 1/ρ²`; a convex region has positive mean curvature. Units: 1/world units (`K`:
//! 1/world units²). This is also the sign of libigl's `principal_curvature` (cross-checked in
//! `scripts/crosscheck_libigl.py`).
//!
//! Vertices without a non-degenerate face get zero curvature and zero directions. Boundary
//! vertices average only their existing faces (one-sided estimates).
//!
//! Written by hand: the estimator is specific to the Surface type and small.

use rayon::prelude::*;

use super::laplacian::{
    all_face_terms, face_points, is_degenerate, validate_surface, GeometryError, MassKind,
};
use crate::engine::math::{cross, dot, normalize, scale, sub};
use crate::engine::mesh::csr::vertex_faces;
use crate::engine::mesh::Surface;

/// Parameters of [`principal_curvatures`].
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CurvatureParams {
    /// Corner weights for averaging face tensors at vertices. Default: `mixed_voronoi`
    /// (Rusinkiewicz 2004 section 4); `barycentric` weights each face by a third of its area.
    pub weighting: MassKind,
}

/// Curvature per vertex (see the module docs for signs and units).
#[derive(Clone, Debug, Default)]
pub struct Curvature {
    /// Maximum principal curvature, 1/world units.
    pub k_max: Vec<f64>,
    /// Minimum principal curvature, 1/world units.
    pub k_min: Vec<f64>,
    /// Unit direction of `k_max` (tangent to the vertex normal).
    pub dir_max: Vec<[f64; 3]>,
    /// Unit direction of `k_min`, `normal × dir_max`.
    pub dir_min: Vec<[f64; 3]>,
    /// Mean curvature `(k_max + k_min) / 2`.
    pub mean: Vec<f64>,
    /// Gaussian curvature `k_max · k_min`, 1/world units².
    pub gaussian: Vec<f64>,
    /// The unit vertex normals used (Max 1999 weights).
    pub normals: Vec<[f64; 3]>,
}

/// Vertex normals with Max 1999 weights, f64, unit (zero where undefined).
pub fn max_vertex_normals(surface: &Surface) -> Vec<[f64; 3]> {
    let mut acc = vec![[0.0; 3]; surface.positions.len()];
    for (fi, f) in surface.faces.iter().enumerate() {
        if is_degenerate(surface, fi) {
            continue;
        }
        let p = face_points(surface, fi);
        for k in 0..3 {
            let e1 = sub(p[(k + 1) % 3], p[k]);
            let e2 = sub(p[(k + 2) % 3], p[k]);
            let w = dot(e1, e1) * dot(e2, e2);
            let c = cross(e1, e2);
            let a = &mut acc[f[k] as usize];
            for j in 0..3 {
                a[j] += c[j] / w;
            }
        }
    }
    acc.into_iter().map(normalize).collect()
}

/// A unit tangent vector at normal `n` (deterministic: from the axis least aligned with `n`).
fn tangent_of(n: [f64; 3]) -> [f64; 3] {
    let k = (0..3)
        .min_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs()))
        .unwrap_or(0);
    let mut axis = [0.0; 3];
    axis[k] = 1.0;
    normalize(sub(axis, scale(n, dot(axis, n))))
}

/// Rotates `x` (tangent at unit normal `a`) into the plane of unit normal `b`, about `a × b`.
fn rotate_tangent(x: [f64; 3], a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let c = dot(a, b);
    if c <= -1.0 + 1e-12 {
        return scale(x, -1.0);
    }
    let s = dot(x, b) / (1.0 + c);
    [
        x[0] - s * (a[0] + b[0]),
        x[1] - s * (a[1] + b[1]),
        x[2] - s * (a[2] + b[2]),
    ]
}

/// Per face: frame `(u, v, n)` and the tensor `(e, f, g)` in it; `None` for degenerate faces.
type FaceTensor = Option<([[f64; 3]; 3], [f64; 3])>;

fn face_tensor(surface: &Surface, fi: usize, normals: &[[f64; 3]]) -> FaceTensor {
    if is_degenerate(surface, fi) {
        return None;
    }
    let f = surface.faces[fi];
    let p = face_points(surface, fi);
    let n = f.map(|v| normals[v as usize]);
    let uf = normalize(sub(p[1], p[0]));
    let nf = normalize(cross(sub(p[1], p[0]), sub(p[2], p[0])));
    let vf = cross(nf, uf);
    // Normal equations of the 6 × 3 least-squares system.
    let mut m = [[0.0; 3]; 3];
    let mut r = [0.0; 3];
    for k in 0..3 {
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        let e = sub(p[j], p[i]);
        let dn = sub(n[j], n[i]);
        let (eu, ev) = (dot(e, uf), dot(e, vf));
        let (nu, nv) = (dot(dn, uf), dot(dn, vf));
        // Row (eu, ev, 0) = nu and row (0, eu, ev) = nv.
        m[0][0] += eu * eu;
        m[0][1] += eu * ev;
        m[1][1] += ev * ev + eu * eu;
        m[1][2] += eu * ev;
        m[2][2] += ev * ev;
        r[0] += eu * nu;
        r[1] += ev * nu + eu * nv;
        r[2] += ev * nv;
    }
    m[1][0] = m[0][1];
    m[2][1] = m[1][2];
    let x = solve3(m, r)?;
    Some(([uf, vf, nf], x))
}

/// Solves a symmetric 3 × 3 system by Cramer's rule; `None` when singular.
fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det(m);
    let scale = m.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
    if d.is_nan() || d.abs() <= 1e-14 * scale * scale * scale {
        return None;
    }
    Some(std::array::from_fn(|c| {
        let mut a = m;
        for row in 0..3 {
            a[row][c] = r[row];
        }
        det(a) / d
    }))
}

/// Principal curvatures and directions, mean and Gaussian curvature per vertex.
///
/// # Errors
/// [`GeometryError::EmptySurface`], [`GeometryError::NonFinitePosition`].
pub fn principal_curvatures(
    surface: &Surface,
    params: &CurvatureParams,
) -> Result<Curvature, GeometryError> {
    validate_surface(surface)?;
    let normals = max_vertex_normals(surface);
    let weights = all_face_terms(surface, params.weighting, f64::INFINITY);
    let tensors: Vec<FaceTensor> = (0..surface.faces.len())
        .into_par_iter()
        .with_min_len(2048)
        .map(|f| face_tensor(surface, f, &normals))
        .collect();
    let (offsets, incident) = vertex_faces(surface);
    type VertexResult = (f64, f64, [f64; 3], [f64; 3]);
    let per_vertex: Vec<VertexResult> = (0..surface.positions.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|v| {
            let np = normals[v];
            if np == [0.0; 3] {
                return (0.0, 0.0, [0.0; 3], [0.0; 3]);
            }
            let up = tangent_of(np);
            let vp = cross(np, up);
            let (mut e, mut f, mut g, mut wsum) = (0.0, 0.0, 0.0, 0.0);
            for &fi in &incident[offsets[v] as usize..offsets[v + 1] as usize] {
                let Some(([uf, vf, nf], [te, tf, tg])) = tensors[fi as usize] else {
                    continue;
                };
                let face = surface.faces[fi as usize];
                let corner = face.iter().position(|&x| x as usize == v).unwrap_or(0);
                let w = weights[fi as usize].area[corner];
                let ur = rotate_tangent(up, np, nf);
                let vr = rotate_tangent(vp, np, nf);
                let (u1, u2) = (dot(ur, uf), dot(ur, vf));
                let (v1, v2) = (dot(vr, uf), dot(vr, vf));
                let form = |a1: f64, a2: f64, b1: f64, b2: f64| {
                    te * a1 * b1 + tf * (a1 * b2 + a2 * b1) + tg * a2 * b2
                };
                e += w * form(u1, u2, u1, u2);
                f += w * form(u1, u2, v1, v2);
                g += w * form(v1, v2, v1, v2);
                wsum += w;
            }
            if wsum.is_nan() || wsum <= 0.0 {
                return (0.0, 0.0, [0.0; 3], [0.0; 3]);
            }
            let (e, f, g) = (e / wsum, f / wsum, g / wsum);
            // Eigen-decomposition of [[e, f], [f, g]].
            let mean = 0.5 * (e + g);
            let radius = (0.25 * (e - g).powi(2) + f * f).sqrt();
            let (k1, k2) = (mean + radius, mean - radius);
            let theta = 0.5 * (2.0 * f).atan2(e - g);
            let (c, s) = (theta.cos(), theta.sin());
            let d1 = normalize([
                c * up[0] + s * vp[0],
                c * up[1] + s * vp[1],
                c * up[2] + s * vp[2],
            ]);
            let d2 = cross(np, d1);
            (k1, k2, d1, d2)
        })
        .collect();
    let mut out = Curvature {
        normals,
        ..Default::default()
    };
    for (k1, k2, d1, d2) in per_vertex {
        out.k_max.push(k1);
        out.k_min.push(k2);
        out.dir_max.push(d1);
        out.dir_min.push(d2);
        out.mean.push(0.5 * (k1 + k2));
        out.gaussian.push(k1 * k2);
    }
    Ok(out)
}
