//! Flattening of a cluster and its flatness error (Soler et al. 2002, §3.2, eq. 1).
//!
//! Deviation from the paper: the paper flattens a cluster through its control polygon (edge
//! lengths and angles kept as far as possible) and places the sub-clusters' control vertices
//! relative to the parent's, recursively down to the faces. Here every disc cluster is
//! flattened directly with free-boundary least-squares conformal maps (Lévy et al. 2002,
//! LSCM: two border vertices pinned, one sparse Cholesky solve), then scaled so that the
//! texture area equals the surface area. Why: the recursion of the paper's topological
//! coordinates is garbled in the available text, and LSCM maps every developable cluster
//! (a flat or folded sheet) isometrically, which is what the issue requires of flat clusters,
//! while curved clusters get a conformal map whose area distortion measures how far they are
//! from flat. Since a cluster's texture coordinates come from one solve over its own vertices,
//! sub-clusters never crack inside a patch (§4.3's averaging is not needed).
//!
//! Flatness error (eq. 1 reads E_flat = |r − 1| with r the surface / texture area ratio): since
//! the total ratio is 1 after scaling, E_flat is the area-weighted mean over faces of
//! |r_f − 1|, r_f = surface area / texture area of face f. Any triangle whose texture area is
//! not positive (flipped or collapsed) makes the cluster "not flat".

use std::sync::Arc;

use crate::engine::linalg::{SparsityPattern, SymbolicCholesky, SymmetricMatrix};
use crate::engine::mesh::Surface;

/// Relative diagonal shift keeping the normal equations positive definite on slivers.
const REGULARISATION: f64 = 1e-10;

/// A flattened cluster.
#[derive(Clone, Debug)]
pub struct Flat {
    /// The cluster's vertices (sorted surface indices).
    pub vertices: Vec<u32>,
    /// Their flattened positions, world units, x right and y down as the image's pixels: a
    /// front-facing (counter-clockwise) face is clockwise here, so the pattern placed by a
    /// rotation and a translation is not mirrored.
    pub frame: Vec<[f64; 2]>,
    /// Area-weighted mean |r_f − 1|.
    pub e_flat: f32,
    /// Triangles with a non-positive texture area.
    pub flipped: usize,
}

impl Flat {
    /// Local index of a surface vertex.
    pub fn local(&self, v: u32) -> Option<usize> {
        self.vertices.binary_search(&v).ok()
    }

    /// Flattened position of a surface vertex of the cluster.
    pub fn at(&self, v: u32) -> Option<[f64; 2]> {
        self.local(v).map(|i| self.frame[i])
    }

    /// Whether the cluster counts as flat enough.
    pub fn is_flat(&self, threshold: f32) -> bool {
        self.flipped == 0 && self.e_flat <= threshold
    }

    /// Bounding box of the frame, `[min, max]`.
    pub fn bbox(&self) -> [[f64; 2]; 2] {
        let mut b = [[f64::MAX; 2], [f64::MIN; 2]];
        for p in &self.frame {
            for k in 0..2 {
                b[0][k] = b[0][k].min(p[k]);
                b[1][k] = b[1][k].max(p[k]);
            }
        }
        b
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| f64::from(a[k]) - f64::from(b[k]))
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The triangle in its own plane: corners 2-D (counter-clockwise) and its area.
pub fn local_triangle(p: [[f32; 3]; 3]) -> ([[f64; 2]; 3], f64) {
    let e1 = sub(p[1], p[0]);
    let e2 = sub(p[2], p[0]);
    let l1 = dot(e1, e1).sqrt().max(1e-300);
    let x = e1.map(|c| c / l1);
    let n = cross(e1, e2);
    let area = 0.5 * dot(n, n).sqrt();
    let y0 = cross(n, x);
    let ly = dot(y0, y0).sqrt().max(1e-300);
    let y = y0.map(|c| c / ly);
    ([[0.0, 0.0], [l1, 0.0], [dot(e2, x), dot(e2, y)]], area)
}

/// Signed area of a 2-D triangle.
pub fn signed_area(q: [[f64; 2]; 3]) -> f64 {
    0.5 * ((q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]))
}

/// Flattens a disc cluster (see the module doc). `None` if the solve fails (degenerate input).
pub fn flatten(surface: &Surface, faces: &[u32]) -> Option<Flat> {
    let mut vertices: Vec<u32> = faces
        .iter()
        .flat_map(|f| surface.faces[*f as usize])
        .collect();
    vertices.sort_unstable();
    vertices.dedup();
    let n = vertices.len();
    let local = |v: u32| vertices.binary_search(&v).unwrap_or(0);
    let frame = if faces.len() == 1 {
        let (q, _) = local_triangle(surface.face_positions(faces[0] as usize));
        let fv = surface.faces[faces[0] as usize];
        let mut frame = vec![[0.0; 2]; n];
        for k in 0..3 {
            frame[local(fv[k])] = q[k];
        }
        frame
    } else {
        lscm(surface, faces, &vertices)?
    };
    let mut flat = Flat {
        vertices,
        frame,
        e_flat: 0.0,
        flipped: 0,
    };
    normalise(surface, faces, &mut flat);
    Some(flat)
}

/// Two border-ish pins far apart: the vertex farthest from the first, and the one farthest
/// from that.
fn pins(surface: &Surface, vertices: &[u32]) -> (usize, usize) {
    let far = |from: usize| {
        let p = surface.positions[vertices[from] as usize];
        (0..vertices.len())
            .max_by(|a, b| {
                let da = dot(
                    sub(surface.positions[vertices[*a] as usize], p),
                    sub(surface.positions[vertices[*a] as usize], p),
                );
                let db = dot(
                    sub(surface.positions[vertices[*b] as usize], p),
                    sub(surface.positions[vertices[*b] as usize], p),
                );
                da.total_cmp(&db)
            })
            .unwrap_or(0)
    };
    let a = far(0);
    let b = far(a);
    (a, b)
}

/// Free-boundary LSCM: minimises Σ_t A_t |∇v − rot90(∇u)|² with two pinned vertices.
fn lscm(surface: &Surface, faces: &[u32], vertices: &[u32]) -> Option<Vec<[f64; 2]>> {
    let n = vertices.len();
    let (pa, pb) = pins(surface, vertices);
    if pa == pb {
        return None;
    }
    let d = dot(
        sub(
            surface.positions[vertices[pa] as usize],
            surface.positions[vertices[pb] as usize],
        ),
        sub(
            surface.positions[vertices[pa] as usize],
            surface.positions[vertices[pb] as usize],
        ),
    )
    .sqrt();
    // Unknowns: u_i at 2i, v_i at 2i + 1; pinned ones carry a value instead.
    let mut fixed: Vec<Option<f64>> = vec![None; 2 * n];
    fixed[2 * pa] = Some(0.0);
    fixed[2 * pa + 1] = Some(0.0);
    fixed[2 * pb] = Some(d);
    fixed[2 * pb + 1] = Some(0.0);
    let mut free = vec![usize::MAX; 2 * n];
    let mut m = 0;
    for (i, f) in fixed.iter().enumerate() {
        if f.is_none() {
            free[i] = m;
            m += 1;
        }
    }
    let mut triplets: Vec<(usize, usize, f64)> = Vec::with_capacity(faces.len() * 36);
    let mut rhs = vec![0.0f64; m];
    for f in faces {
        let fv = surface.faces[*f as usize];
        let (q, area) = local_triangle(surface.face_positions(*f as usize));
        if area <= 0.0 {
            continue;
        }
        let w = area.sqrt();
        let mut g = [[0.0f64; 2]; 3];
        for j in 0..3 {
            let e = [
                q[(j + 2) % 3][0] - q[(j + 1) % 3][0],
                q[(j + 2) % 3][1] - q[(j + 1) % 3][1],
            ];
            g[j] = [-e[1] / (2.0 * area), e[0] / (2.0 * area)];
        }
        for c in 0..2 {
            // rot90(g) = (−g.y, g.x); residual = Σ v_j g_j[c] − Σ u_j rot90(g_j)[c].
            let mut row: Vec<(usize, f64)> = Vec::with_capacity(6);
            for j in 0..3 {
                let li = vertices.binary_search(&fv[j]).ok()?;
                let rot = if c == 0 { -g[j][1] } else { g[j][0] };
                row.push((2 * li, -rot * w));
                row.push((2 * li + 1, g[j][c] * w));
            }
            let mut b = 0.0;
            for (idx, coef) in &row {
                if let Some(val) = fixed[*idx] {
                    b -= coef * val;
                }
            }
            for (i, ci) in &row {
                if free[*i] == usize::MAX {
                    continue;
                }
                rhs[free[*i]] += ci * b;
                for (j, cj) in &row {
                    if free[*j] != usize::MAX {
                        triplets.push((free[*i], free[*j], ci * cj));
                    }
                }
            }
        }
    }
    let x = solve_normal(m, triplets, &rhs)?;
    let value = |i: usize| fixed[i].unwrap_or_else(|| x[free[i]]);
    Some((0..n).map(|i| [value(2 * i), value(2 * i + 1)]).collect())
}

/// Solves the assembled symmetric positive system.
fn solve_normal(m: usize, mut triplets: Vec<(usize, usize, f64)>, rhs: &[f64]) -> Option<Vec<f64>> {
    let mut columns: Vec<Vec<usize>> = vec![Vec::new(); m];
    for (i, j, _) in &triplets {
        columns[*j].push(*i);
    }
    let pattern = Arc::new(SparsityPattern::from_columns(&columns).ok()?);
    let mut values = vec![0.0f64; pattern.nnz()];
    let mut max_diag = 0.0f64;
    triplets.sort_unstable_by_key(|t| (t.1, t.0));
    for (i, j, v) in &triplets {
        values[pattern.find(*i, *j)?] += v;
        if i == j {
            max_diag = max_diag.max(values[pattern.find(*i, *j)?]);
        }
    }
    for p in pattern.diagonal_positions() {
        values[p] += REGULARISATION * max_diag.max(1e-300);
    }
    let matrix = SymmetricMatrix::new(pattern.clone(), values).ok()?;
    let factor = SymbolicCholesky::new(pattern).ok()?.factor(&matrix).ok()?;
    let x = factor.solve(rhs).ok()?;
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Mirrors a clockwise result, scales texture area to surface area, measures E_flat and flips.
fn normalise(surface: &Surface, faces: &[u32], flat: &mut Flat) {
    let tri = |flat: &Flat, f: u32| {
        let fv = surface.faces[f as usize];
        fv.map(|v| flat.at(v).unwrap_or([0.0; 2]))
    };
    let mut a2 = 0.0;
    let mut a3 = 0.0;
    for f in faces {
        a2 += signed_area(tri(flat, *f));
        a3 += f64::from(surface.face_area(*f as usize));
    }
    if a2 < 0.0 {
        for p in &mut flat.frame {
            p[1] = -p[1];
        }
        a2 = -a2;
    }
    let s = if a2 > 0.0 { (a3 / a2).sqrt() } else { 1.0 };
    for p in &mut flat.frame {
        p[0] *= s;
        p[1] *= s;
    }
    let mut err = 0.0;
    let mut flipped = 0;
    for f in faces {
        let area3 = f64::from(surface.face_area(*f as usize));
        let area2 = signed_area(tri(flat, *f));
        if area2 <= area3 * 1e-9 {
            flipped += 1;
            continue;
        }
        err += area3 * (area3 / area2 - 1.0).abs();
    }
    flat.flipped = flipped;
    flat.e_flat = if a3 > 0.0 { (err / a3) as f32 } else { 0.0 };
    // Image convention (y down): seen from the front, the image's top is the frame's −y, so
    // the pattern is not mirrored.
    for p in &mut flat.frame {
        p[1] = -p[1];
    }
}
