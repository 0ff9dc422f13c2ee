//! Per-chart parameterisation: least-squares conformal maps (Lévy, Petitjean, Ray & Maillot
//! 2002, "Least Squares Conformal Maps for Automatic Texture Atlas Generation", §3: the
//! discrete conformality energy of eq. 3 over the triangles, two vertices pinned, one sparse
//! least-squares solve) and the stretch metric of Sander, Snyder, Gortler & Hoppe 2001
//! ("Texture Mapping Progressive Meshes", §3: singular values Γ, γ of the Jacobian of the map
//! from texture to surface, L2 = √((Γ² + γ²)/2), L∞ = Γ).
//!
//! Shared by the atlas ([`super::atlas`]) and the `pattern` method's flattening
//! (`methods/pattern/flatten.rs`), which calls [`lscm`] instead of holding its own copy.
//!
//! Deviations and constants not in the papers:
//! - Pins: the vertex farthest from the chart's first vertex, and the vertex farthest from
//!   that one, placed at (0, 0) and (d, 0) with d their 3-D distance (the paper pins "two
//!   vertices" on the boundary chosen by the user or by the farthest pair; the two-sweep
//!   farthest pair approximates it in linear time).
//! - The normal equations are solved by sparse Cholesky (faer), retried with a relative diagonal
//!   shift of 1e-10 only when they are not positive definite (slivers); the papers use
//!   conjugate gradients. They
//!   are assembled straight into their compressed-column pattern (vertex pairs sharing a face,
//!   from one sort of the chart's edges), not through sorted triplets. The u–v terms of
//!   interior edges, which cancel exactly, are left out of the pattern, and the unknowns are
//!   ordered by a nested dissection of the chart's graph instead of AMD (see `pattern_of`).
//! - Triangles are weighted by √area per residual row, so the energy is Σ area · |residual|²,
//!   as eq. 3.

use std::sync::Arc;

use crate::engine::linalg::{dissection, SparsityPattern, SymbolicCholesky, SymmetricMatrix};
use crate::engine::mesh::Surface;

/// A face in its own plane (corners and area), `None` for a face without area.
type PlanarFace = Option<([[f64; 2]; 3], f64)>;

/// Relative diagonal shift of the retry when the normal equations are not positive definite
/// (slivers). Never applied otherwise: on a flat 3,600-vertex chart it moved the solution by
/// 3.5e-3 of the chart's size (`tests/engine/uv_lscm.rs`), about the shift times the
/// system's condition number.
const REGULARISATION: f64 = 1e-10;

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

/// Signed area of a 2-D triangle (positive when counter-clockwise).
pub fn signed_area(q: [[f64; 2]; 3]) -> f64 {
    0.5 * ((q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]))
}

/// Stretch of one triangle (Sander et al. 2001, §3): `(L2², Γ, γ)` of the map from the 2-D
/// triangle `uv` to the 3-D triangle `p`. `None` when `uv` has no positive area (flipped or
/// collapsed: infinite stretch).
pub fn triangle_stretch(p: [[f32; 3]; 3], uv: [[f64; 2]; 3]) -> Option<(f64, f64, f64)> {
    let a = signed_area(uv);
    if a <= 0.0 || !a.is_finite() {
        return None;
    }
    let q = p.map(|c| c.map(f64::from));
    let [s1, s2, s3] = [uv[0][0], uv[1][0], uv[2][0]];
    let [t1, t2, t3] = [uv[0][1], uv[1][1], uv[2][1]];
    let ss: [f64; 3] = [0, 1, 2]
        .map(|k| (q[0][k] * (t2 - t3) + q[1][k] * (t3 - t1) + q[2][k] * (t1 - t2)) / (2.0 * a));
    let st: [f64; 3] = [0, 1, 2]
        .map(|k| (q[0][k] * (s3 - s2) + q[1][k] * (s1 - s3) + q[2][k] * (s2 - s1)) / (2.0 * a));
    let (aa, bb, cc) = (dot(ss, ss), dot(ss, st), dot(st, st));
    let root = ((aa - cc).powi(2) + 4.0 * bb * bb).sqrt();
    let big = (0.5 * (aa + cc + root)).max(0.0).sqrt();
    let small = (0.5 * (aa + cc - root)).max(0.0).sqrt();
    Some((0.5 * (aa + cc), big, small))
}

/// Two pins far apart: the vertex farthest from the first, and the one farthest from that.
fn pins(surface: &Surface, vertices: &[u32]) -> (usize, usize) {
    let far = |from: usize| {
        let p = surface.positions[vertices[from] as usize];
        let d = |i: usize| {
            let e = sub(surface.positions[vertices[i] as usize], p);
            dot(e, e)
        };
        (0..vertices.len())
            .max_by(|a, b| d(*a).total_cmp(&d(*b)).then(b.cmp(a)))
            .unwrap_or(0)
    };
    let a = far(0);
    let b = far(a);
    (a, b)
}

/// Each face's corners as indices into `vertices` (sorted surface indices, [`chart_vertices`]);
/// `None` if a corner is missing.
pub(super) fn local_corners(
    surface: &Surface,
    faces: &[u32],
    vertices: &[u32],
) -> Option<Vec<[usize; 3]>> {
    faces
        .iter()
        .map(|f| {
            let fv = surface.faces[*f as usize];
            let mut c = [0usize; 3];
            for k in 0..3 {
                c[k] = vertices.binary_search(&fv[k]).ok()?;
            }
            Some(c)
        })
        .collect()
}

/// Gradients of the barycentric functions of the 2-D triangle `q` (counter-clockwise, area
/// `area` > 0): `∇φ_j = rot90(q_(j+2) − q_(j+1)) / (2 area)`.
pub(super) fn barycentric_gradients(q: [[f64; 2]; 3], area: f64) -> [[f64; 2]; 3] {
    [0, 1, 2].map(|j| {
        let e = [
            q[(j + 2) % 3][0] - q[(j + 1) % 3][0],
            q[(j + 2) % 3][1] - q[(j + 1) % 3][1],
        ];
        [-e[1] / (2.0 * area), e[0] / (2.0 * area)]
    })
}

/// The sorted, deduplicated surface vertices of the faces `faces` (a chart's local indexing).
pub fn chart_vertices(surface: &Surface, faces: &[u32]) -> Vec<u32> {
    let mut vertices: Vec<u32> = faces
        .iter()
        .flat_map(|f| surface.faces[*f as usize])
        .collect();
    vertices.sort_unstable();
    vertices.dedup();
    vertices
}

/// Flattens the disc `faces` (vertices `vertices`, from [`chart_vertices`]): a single triangle
/// exactly (its local frame), more by [`lscm`]. One 2-D position per entry of `vertices`;
/// `None` when the solve fails.
pub fn flatten_chart(surface: &Surface, faces: &[u32], vertices: &[u32]) -> Option<Vec<[f64; 2]>> {
    if let [f] = faces {
        let (q, _) = local_triangle(surface.face_positions(*f as usize));
        let mut frame = vec![[0.0; 2]; vertices.len()];
        for (k, v) in surface.faces[*f as usize].iter().enumerate() {
            frame[vertices.binary_search(v).unwrap_or(0)] = q[k];
        }
        return Some(frame);
    }
    lscm(surface, faces, vertices)
}

/// Free-boundary LSCM of the faces `faces` whose vertices are `vertices` (sorted surface
/// indices): minimises Σ_t A_t |∇v − rot90(∇u)|² with two pinned vertices. Returns one 2-D
/// position per entry of `vertices`, in world units up to the conformal scale, or `None` when
/// the solve fails (degenerate input).
pub fn lscm(surface: &Surface, faces: &[u32], vertices: &[u32]) -> Option<Vec<[f64; 2]>> {
    let n = vertices.len();
    let (pa, pb) = pins(surface, vertices);
    if pa == pb {
        return None;
    }
    let e = sub(
        surface.positions[vertices[pa] as usize],
        surface.positions[vertices[pb] as usize],
    );
    let d = dot(e, e).sqrt();
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
    // Corners in local indices and each face in its own plane (`None`: no area, no term).
    let corners = local_corners(surface, faces, vertices)?;
    let planar: Vec<PlanarFace> = faces
        .iter()
        .map(|f| Some(local_triangle(surface.face_positions(*f as usize))).filter(|t| t.1 > 0.0))
        .collect();
    let (pattern, order) = pattern_of(&corners, &planar, n, &free, m)?;
    let pattern = Arc::new(pattern);
    let mut values = vec![0.0f64; pattern.nnz()];
    let mut rhs = vec![0.0f64; m];
    for (li, tri) in corners.iter().zip(&planar) {
        let Some((q, area)) = *tri else {
            continue;
        };
        let w = area.sqrt();
        let g = barycentric_gradients(q, area);
        for c in 0..2 {
            // rot90(g) = (−g.y, g.x); residual = Σ v_j g_j[c] − Σ u_j rot90(g_j)[c].
            let mut row: [(usize, f64); 6] = [(0, 0.0); 6];
            for j in 0..3 {
                let rot = if c == 0 { -g[j][1] } else { g[j][0] };
                row[2 * j] = (2 * li[j], -rot * w);
                row[2 * j + 1] = (2 * li[j] + 1, g[j][c] * w);
            }
            let mut b = 0.0;
            for (idx, coef) in &row {
                if let Some(val) = fixed[*idx] {
                    b -= coef * val;
                }
            }
            for (i, ci) in &row {
                let fi = free[*i];
                if fi == usize::MAX {
                    continue;
                }
                rhs[fi] += ci * b;
                let rows = pattern.column(fi);
                let base = pattern.col_ptr()[fi];
                for (j, cj) in &row {
                    let fj = free[*j];
                    if fj == usize::MAX {
                        continue;
                    }
                    match rows.binary_search(&fj) {
                        Ok(k) => values[base + k] += ci * cj,
                        // A u–v term of an interior edge: it cancels with the other face's.
                        Err(_) if i % 2 != j % 2 => {}
                        Err(_) => return None,
                    }
                }
            }
        }
    }
    let x = solve_normal(pattern, &order, values, &rhs)?;
    let value = |i: usize| fixed[i].unwrap_or_else(|| x[free[i]]);
    Some((0..n).map(|i| [value(2 * i), value(2 * i + 1)]).collect())
}

/// The sparsity pattern of the LSCM normal equations over the `m` free unknowns (`free` maps
/// unknown `2i + c` of local vertex `i` to its column, `usize::MAX` when pinned), and an
/// elimination order of the unknowns: a nested dissection of the vertex graph ([`dissection`]),
/// each of its blocks (a leaf part or a separator) with its u unknowns first, then its v.
///
/// u couples with u and v with v across every edge (and on the diagonal). u couples with v only
/// across edges that are not interior: the conformal energy is the Dirichlet energy of u and
/// of v minus twice the signed area of the map (Desbrun, Meyer & Alliez 2002, §4.3; Mullen,
/// Tong, Alliez & Desbrun 2008, §3), and the area's u–v terms of an edge shared by two
/// consistently oriented faces cancel (each face gives ±½, with opposite signs), as do those
/// of a vertex with itself. Dropping them keeps the u and v systems apart inside the chart,
/// so that only the boundary couples them. Measured on the four 74k-82k-face charts of the
/// 160k-vertex icosphere (sequential factorisation): AMD on the full pattern 8.7-10.5M factor
/// entries and 190-230 ms; the dissection order 8.0-9.1M and 140-160 ms; with the u–v terms
/// dropped and u, v grouped per block 5.6-6.4M and 100-120 ms. An edge counts as interior when
/// exactly one face with area runs along it in each direction; every other edge (boundary,
/// next to a face without area, inconsistently oriented) keeps its u–v entries.
fn pattern_of(
    corners: &[[usize; 3]],
    planar: &[PlanarFace],
    n: usize,
    free: &[usize],
    m: usize,
) -> Option<(SparsityPattern, Vec<usize>)> {
    let key = |a: usize, b: usize| ((a as u64) << 32) | b as u64;
    let mut pairs: Vec<u64> = Vec::with_capacity(corners.len() * 6 + n);
    let mut directed: Vec<u64> = Vec::with_capacity(corners.len() * 3);
    for (c, tri) in corners.iter().zip(planar) {
        for k in 0..3 {
            let (a, b) = (c[k], c[(k + 1) % 3]);
            pairs.push(key(a, b));
            pairs.push(key(b, a));
            if tri.is_some() {
                directed.push(key(a, b));
            }
        }
    }
    pairs.extend((0..n).map(|i| key(i, i)));
    pairs.sort_unstable();
    pairs.dedup();
    directed.sort_unstable();
    let count = |k: u64| {
        let lo = directed.partition_point(|d| *d < k);
        directed[lo..].iter().take_while(|d| **d == k).count()
    };
    // Edges whose u–v terms do not cancel, both directions, sorted.
    let mut coupled: Vec<u64> = Vec::new();
    let mut at = 0;
    while at < directed.len() {
        let k = directed[at];
        let mut end = at;
        while end < directed.len() && directed[end] == k {
            end += 1;
        }
        let (a, b) = ((k >> 32) as usize, (k & 0xffff_ffff) as usize);
        if !(end - at == 1 && count(key(b, a)) == 1) {
            coupled.push(key(a, b));
            coupled.push(key(b, a));
        }
        at = end;
    }
    coupled.sort_unstable();
    coupled.dedup();
    // Columns come out in order (`free` is increasing) and each column's rows ascending (the
    // pairs are sorted), so the compressed columns are written straight, without a sort.
    let mut col_ptr = Vec::with_capacity(m + 1);
    col_ptr.push(0);
    let mut row_idx = Vec::with_capacity(pairs.len() * 2 + coupled.len() * 2);
    let mut start = 0;
    while start < pairs.len() {
        let a = (pairs[start] >> 32) as usize;
        let mut end = start;
        while end < pairs.len() && (pairs[end] >> 32) as usize == a {
            end += 1;
        }
        for ca in 0..2 {
            if free[2 * a + ca] == usize::MAX {
                continue;
            }
            for p in &pairs[start..end] {
                let b = (p & 0xffff_ffff) as usize;
                let both = b != a && coupled.binary_search(p).is_ok();
                row_idx.extend(
                    (0..2)
                        .filter(|cb| *cb == ca || both)
                        .map(|cb| free[2 * b + cb])
                        .filter(|r| *r != usize::MAX),
                );
            }
            col_ptr.push(row_idx.len());
        }
        start = end;
    }
    let mut offsets = vec![0usize; n + 1];
    for p in &pairs {
        offsets[(p >> 32) as usize + 1] += 1;
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let targets: Vec<u32> = pairs.iter().map(|p| (p & 0xffff_ffff) as u32).collect();
    let (vertex_order, blocks) = dissection::nested_dissection_blocks(&dissection::Graph {
        offsets: &offsets,
        targets: &targets,
    });
    // Per block of the dissection, its u unknowns then its v unknowns: inside the chart they
    // do not couple, and so each set forms its own supernodes.
    let mut order = Vec::with_capacity(m);
    for w in blocks.windows(2) {
        for c in 0..2 {
            order.extend(
                vertex_order[w[0]..w[1]]
                    .iter()
                    .map(|v| free[2 * v + c])
                    .filter(|u| *u != usize::MAX),
            );
        }
    }
    let pattern = SparsityPattern::from_sorted_csc(m, col_ptr, row_idx).ok()?;
    Some((pattern, order))
}

/// Solves the assembled symmetric positive system (values in `pattern`'s order) with the
/// elimination order `order`, factorised on the calling thread (the atlas flattens its charts
/// in parallel).
fn solve_normal(
    pattern: Arc<SparsityPattern>,
    order: &[usize],
    values: Vec<f64>,
    rhs: &[f64],
) -> Option<Vec<f64>> {
    let sy = SymbolicCholesky::with_elimination_order(pattern.clone(), order).ok()?;
    let exact = SymmetricMatrix::new(pattern.clone(), values).ok()?;
    let factor = match sy.factor_sequential(&exact) {
        Ok(f) => f,
        Err(_) => {
            let mut shifted = exact.values().to_vec();
            let diagonal = pattern.diagonal_positions();
            let max_diag = diagonal.iter().map(|p| shifted[*p]).fold(0.0f64, f64::max);
            for p in diagonal {
                shifted[p] += REGULARISATION * max_diag.max(1e-300);
            }
            let matrix = SymmetricMatrix::new(pattern, shifted).ok()?;
            sy.factor_sequential(&matrix).ok()?
        }
    };
    let x = factor.solve(rhs).ok()?;
    x.iter().all(|v| v.is_finite()).then_some(x)
}
