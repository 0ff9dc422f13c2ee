//! Isotropic remeshing (Botsch & Kobbelt, *A remeshing approach to multiresolution modeling*,
//! SGP 2004, §4), the hierarchy step of the `detail` method (Berkiten et al. 2017, §3.1).
//!
//! For a target edge length `L`, each iteration runs, on a [`HalfEdgeMesh`]:
//! 1. **Split** every edge longer than `4/3 L` at its midpoint (repeated until none is).
//! 2. **Collapse** every edge shorter than `4/5 L` (into its midpoint, or onto the end that is on
//!    a chain or locked when only one is), unless the result would have an edge longer
//!    than `4/3 L`, break the link condition, or turn a face by more than 60° (the normal check
//!    is not in the paper: it keeps collapses from folding thin regions).
//! 3. **Flip** interior edges when that lowers `Σ (valence − target)²` over the four vertices
//!    involved (target 6 inside, 4 on the boundary), unless a new face would be degenerate or
//!    turn more than ~73° (cos > 0.3) from the pair's old mean normal.
//! 4. **Tangential relaxation**: each free vertex moves to the uniform centroid of its
//!    neighbours, projected onto its tangent plane (area-weighted vertex normal); a vertex on a
//!    boundary or feature chain moves to the midpoint of its two chain neighbours.
//! 5. **Back-projection** of every vertex onto the reference surface (the closest point, from a
//!    BVH of the reference's triangles), except where that would make a face around the vertex
//!    degenerate (ours: a scan's spikes drew neighbours onto one point; see `project`).
//!
//! `iterations = 10` by default (B&K report that 5-10 suffice; the tests measure the result).
//!
//! **Boundaries and features.** Boundary edges and feature edges (dihedral angle above
//! `feature_angle_degrees`, 60° by default: a constant the paper does not publish, chosen so that
//! the 90° edges of furniture-like bases are kept and the ~20-40° bends of coarse smooth meshes
//! are not) are *constrained*: never flipped; split at their midpoint (the halves stay
//! constrained); collapsed only along themselves (both ends on the same constrained chain).
//! Vertices on a chain relax only along it (to the midpoint of their chain neighbours; the
//! closest-point projection then lands on the input's crease or boundary, which is exact for
//! straight creases and for boundaries whose surface meets them from one side), and vertices
//! where the number of constrained edges is not 0 or 2 (corners, chain ends) are locked: never
//! collapsed, never moved.
//!
//! Written by hand (no crate offers B&K remeshing); the input must be manifold
//! ([`HalfEdgeError`]).

use super::halfedge::{twin, HalfEdgeError, HalfEdgeMesh, NONE};
use super::surface::Surface;
use crate::engine::control::{Cancelled, Control};
use crate::engine::math::{add, cross, dist2, dot, length, normalize, scale, sub};
use crate::engine::spatial::Bvh;

/// Parameters of [`remesh`].
#[derive(Clone, Debug)]
pub struct RemeshParams {
    /// Target edge length `L` (world units).
    pub target_edge_length: f64,
    /// Split/collapse/flip/relax/project rounds.
    pub iterations: usize,
    /// Dihedral angle above which an edge is a feature, degrees.
    pub feature_angle_degrees: f64,
    /// Refuse a result expected to exceed this many faces.
    pub max_faces: usize,
}

impl Default for RemeshParams {
    fn default() -> Self {
        Self {
            target_edge_length: 1.0,
            iterations: 10,
            feature_angle_degrees: 60.0,
            max_faces: 4_000_000,
        }
    }
}

/// What [`remesh`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RemeshStats {
    /// Target edge length.
    pub target_edge_length: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Edge splits.
    pub splits: usize,
    /// Edge collapses.
    pub collapses: usize,
    /// Edge flips.
    pub flips: usize,
    /// Faces of the result.
    pub faces: usize,
    /// Feature edges found on the start mesh.
    pub feature_edges: usize,
}

/// Errors of [`remesh`].
#[derive(Debug, thiserror::Error)]
pub enum RemeshError {
    /// The input is not a manifold triangle mesh.
    #[error("cannot remesh: {0}")]
    Topology(#[from] HalfEdgeError),
    /// A parameter is out of range.
    #[error("invalid remesh parameter: {0}")]
    Param(String),
    /// The target edge length would give too many faces.
    #[error("target edge length {length} would give about {faces} faces (limit {limit})")]
    TooFine {
        /// Target edge length.
        length: f64,
        /// Expected face count.
        faces: usize,
        /// The limit.
        limit: usize,
    },
    /// Cancelled through the [`Control`].
    #[error("cancelled")]
    Cancelled(#[from] Cancelled),
}

/// Remeshes `surface` onto itself (see the module doc).
///
/// # Errors
/// See [`RemeshError`].
pub fn remesh(
    surface: &Surface,
    params: &RemeshParams,
    control: &Control,
) -> Result<(Surface, RemeshStats), RemeshError> {
    remesh_onto(surface, surface, params, control)
}

/// Remeshes starting from `start`, projecting onto `reference` (the hierarchy starts each level
/// from the previous one and projects onto the input).
///
/// # Errors
/// See [`RemeshError`].
pub fn remesh_onto(
    start: &Surface,
    reference: &Surface,
    params: &RemeshParams,
    control: &Control,
) -> Result<(Surface, RemeshStats), RemeshError> {
    let l = params.target_edge_length;
    if !(l.is_finite() && l > 0.0) {
        return Err(RemeshError::Param(format!(
            "target edge length {l} must be > 0"
        )));
    }
    if !(0.0..=180.0).contains(&params.feature_angle_degrees) {
        return Err(RemeshError::Param(
            "feature angle must be in [0, 180]".into(),
        ));
    }
    let expected = (reference.area() / (0.433 * l * l)).ceil();
    if !expected.is_finite() || expected > params.max_faces as f64 {
        return Err(RemeshError::TooFine {
            length: l,
            faces: expected.min(usize::MAX as f64) as usize,
            limit: params.max_faces,
        });
    }
    let mut mesh = HalfEdgeMesh::build(start)?;
    let feature_edges = mark_features(&mut mesh, params.feature_angle_degrees);
    let mut locked: Vec<bool> = (0..mesh.pos.len() as u32)
        .map(|v| mesh.alive(v) && !matches!(constrained_count(&mesh, v), 0 | 2))
        .collect();
    let bvh = Bvh::build(&reference.positions, &reference.faces);
    let mut stats = RemeshStats {
        target_edge_length: l,
        feature_edges,
        ..Default::default()
    };
    let (hi, lo) = (4.0 / 3.0 * l, 4.0 / 5.0 * l);
    for _ in 0..params.iterations {
        control.check()?;
        stats.splits += split_long(&mut mesh, &mut locked, hi);
        stats.collapses += collapse_short(&mut mesh, &locked, lo, hi);
        stats.flips += equalize_valences(&mut mesh);
        relax(&mut mesh, &locked);
        project(&mut mesh, &bvh);
        stats.iterations += 1;
    }
    let (out, _) = mesh.to_surface();
    stats.faces = out.faces.len();
    Ok((out, stats))
}

fn edge_len2(m: &HalfEdgeMesh, h: u32) -> f64 {
    dist2(m.pos[m.from(h) as usize], m.pos[m.to[h as usize] as usize])
}

fn is_constrained(m: &HalfEdgeMesh, h: u32) -> bool {
    m.is_boundary_edge(h) || m.feature[h as usize]
}

fn constrained_count(m: &HalfEdgeMesh, v: u32) -> usize {
    m.outgoing(v)
        .iter()
        .filter(|&&h| is_constrained(m, h))
        .count()
}

fn face_normal_raw(m: &HalfEdgeMesh, f: u32) -> [f64; 3] {
    let [a, b, c] = m.face_vertices(f).map(|v| m.pos[v as usize]);
    cross(sub(b, a), sub(c, a))
}

/// Marks interior edges whose dihedral angle exceeds `degrees`; returns how many.
fn mark_features(m: &mut HalfEdgeMesh, degrees: f64) -> usize {
    let cos_max = degrees.to_radians().cos();
    let mut count = 0;
    for h in m.edges() {
        if m.is_boundary_edge(h) {
            continue;
        }
        let n0 = normalize(face_normal_raw(m, m.face[h as usize]));
        let n1 = normalize(face_normal_raw(m, m.face[twin(h) as usize]));
        if dot(n0, n1) < cos_max {
            m.feature[h as usize] = true;
            m.feature[twin(h) as usize] = true;
            count += 1;
        }
    }
    count
}

fn split_long(m: &mut HalfEdgeMesh, locked: &mut Vec<bool>, hi: f64) -> usize {
    let mut splits = 0;
    for _pass in 0..32 {
        let mut any = false;
        for h in m.edges() {
            if edge_len2(m, h) > hi * hi {
                let p = scale(
                    add(m.pos[m.from(h) as usize], m.pos[m.to[h as usize] as usize]),
                    0.5,
                );
                m.split(h, p);
                locked.push(false);
                splits += 1;
                any = true;
            }
        }
        if !any {
            break;
        }
    }
    splits
}

/// Whether moving the vertices of `moved` to `p` keeps every other face around them within 60°
/// of its old normal and non-degenerate, and every edge to `p` at most `hi`.
fn collapse_geometry_ok(m: &HalfEdgeMesh, h: u32, p: [f64; 3], hi: f64) -> bool {
    let (a, b) = (m.from(h), m.to[h as usize]);
    let removed = [m.face[h as usize], m.face[twin(h) as usize]];
    for v in [a, b] {
        for x in m.outgoing(v) {
            let w = m.to[x as usize];
            if w != a && w != b && dist2(m.pos[w as usize], p) > hi * hi {
                return false;
            }
            let f = m.face[x as usize];
            if f == NONE || removed.contains(&f) {
                continue;
            }
            let before = face_normal_raw(m, f);
            let vs = m.face_vertices(f);
            let q = vs.map(|u| {
                if u == a || u == b {
                    p
                } else {
                    m.pos[u as usize]
                }
            });
            let after = cross(sub(q[1], q[0]), sub(q[2], q[0]));
            let (lb, la) = (length(before), length(after));
            // A face already degenerate has no normal to keep; it does not block a collapse
            // (which may be what removes it).
            if lb <= 1e-12 * edge_scale2(&vs.map(|u| m.pos[u as usize])) {
                continue;
            }
            if la <= 1e-12 * lb || dot(before, after) < 0.5 * lb * la {
                return false;
            }
        }
    }
    true
}

/// The longest squared edge of a triangle (a length² scale for its cross product).
fn edge_scale2(q: &[[f64; 3]; 3]) -> f64 {
    dist2(q[0], q[1])
        .max(dist2(q[1], q[2]))
        .max(dist2(q[2], q[0]))
}

fn collapse_short(m: &mut HalfEdgeMesh, locked: &[bool], lo: f64, hi: f64) -> usize {
    let mut collapses = 0;
    for e in m.edges() {
        if m.he_dead[e as usize] || edge_len2(m, e) >= lo * lo {
            continue;
        }
        let edge_constrained = is_constrained(m, e);
        for h in [e, twin(e)] {
            let (a, b) = (m.from(h), m.to[h as usize]);
            if locked[a as usize] {
                continue;
            }
            let a_con = constrained_count(m, a) > 0;
            if a_con && !edge_constrained {
                continue;
            }
            let b_con = constrained_count(m, b) > 0 || locked[b as usize];
            if !a_con && edge_constrained {
                continue;
            }
            // Both free, or both on the same chain: the midpoint (projected back later); a
            // free vertex onto a chain or a locked one: `b` stays.
            let p = if locked[b as usize] || (b_con && !a_con) {
                m.pos[b as usize]
            } else {
                scale(add(m.pos[a as usize], m.pos[b as usize]), 0.5)
            };
            if m.collapse_ok(h) && collapse_geometry_ok(m, h, p, hi) {
                m.collapse(h, p);
                collapses += 1;
                break;
            }
        }
    }
    collapses
}

fn target_valence(m: &HalfEdgeMesh, v: u32) -> i64 {
    if m.is_boundary_vertex(v) {
        4
    } else {
        6
    }
}

fn equalize_valences(m: &mut HalfEdgeMesh) -> usize {
    let mut flips = 0;
    for h in m.edges() {
        if !m.flip_ok(h) {
            continue;
        }
        let t = twin(h);
        let (a, b) = (m.from(h), m.to[h as usize]);
        let c = m.to[m.next[h as usize] as usize];
        let d = m.to[m.next[t as usize] as usize];
        let dev = |v: u32, delta: i64| {
            let x = m.valence(v) as i64 + delta - target_valence(m, v);
            x * x
        };
        let before = dev(a, 0) + dev(b, 0) + dev(c, 0) + dev(d, 0);
        let after = dev(a, -1) + dev(b, -1) + dev(c, 1) + dev(d, 1);
        if after >= before {
            continue;
        }
        let p = |v: u32| m.pos[v as usize];
        let old = add(
            normalize(face_normal_raw(m, m.face[h as usize])),
            normalize(face_normal_raw(m, m.face[t as usize])),
        );
        let old = normalize(old);
        let n1 = cross(sub(p(d), p(a)), sub(p(c), p(a)));
        let n2 = cross(sub(p(b), p(d)), sub(p(c), p(d)));
        let ok = [n1, n2].iter().all(|n| {
            let ln = length(*n);
            ln > 1e-12 * dist2(p(a), p(b)) && dot(*n, old) > 0.3 * ln
        });
        if ok {
            m.flip(h);
            flips += 1;
        }
    }
    flips
}

fn vertex_normal(m: &HalfEdgeMesh, v: u32) -> [f64; 3] {
    let mut n = [0.0; 3];
    for h in m.outgoing(v) {
        let f = m.face[h as usize];
        if f != NONE {
            n = add(n, face_normal_raw(m, f));
        }
    }
    normalize(n)
}

fn relax(m: &mut HalfEdgeMesh, locked: &[bool]) {
    let n = m.pos.len() as u32;
    let moves: Vec<(u32, [f64; 3])> = (0..n)
        .filter(|&v| m.alive(v) && !locked[v as usize])
        .filter_map(|v| {
            let ring = m.outgoing(v);
            let chain: Vec<u32> = ring
                .iter()
                .filter(|&&h| is_constrained(m, h))
                .map(|&h| m.to[h as usize])
                .collect();
            match chain.len() {
                // Free vertex: tangential uniform Laplacian.
                0 => {
                    let mut c = [0.0; 3];
                    for &h in &ring {
                        c = add(c, m.pos[m.to[h as usize] as usize]);
                    }
                    let c = scale(c, 1.0 / ring.len() as f64);
                    let nv = vertex_normal(m, v);
                    let d = sub(c, m.pos[v as usize]);
                    Some((v, add(m.pos[v as usize], sub(d, scale(nv, dot(nv, d))))))
                }
                // On a boundary or feature chain: the midpoint of its two chain neighbours
                // (the projection then puts it back on the input).
                2 => Some((
                    v,
                    scale(add(m.pos[chain[0] as usize], m.pos[chain[1] as usize]), 0.5),
                )),
                _ => None,
            }
        })
        .collect();
    // Applied one by one, each only if it leaves no face around its vertex degenerate that was
    // not ([`keeps_faces`]): two chain vertices with the same two chain neighbours (a feature
    // loop of four edges around a scan's spike) would both go to their midpoint.
    for (v, p) in moves {
        if keeps_faces(m, v, p) {
            m.pos[v as usize] = p;
        }
    }
}

/// Smallest sine-like shape measure `|cross| / (longest edge)²` of the faces around `v` with
/// `v` at `p` (about the smallest angle for a thin face; 0 for a degenerate one).
fn worst_face_shape(m: &HalfEdgeMesh, v: u32, p: [f64; 3]) -> f64 {
    let mut worst = f64::INFINITY;
    for h in m.outgoing(v) {
        let f = m.face[h as usize];
        if f == NONE {
            continue;
        }
        let q = m
            .face_vertices(f)
            .map(|u| if u == v { p } else { m.pos[u as usize] });
        let longest = edge_scale2(&q);
        let area2 = length(cross(sub(q[1], q[0]), sub(q[2], q[0])));
        worst = worst.min(if longest > 0.0 { area2 / longest } else { 0.0 });
    }
    worst
}

/// Whether moving `v` to `p` leaves its faces no more degenerate than [`DEGENERATE_SHAPE`], or
/// no worse than they are.
fn keeps_faces(m: &HalfEdgeMesh, v: u32, p: [f64; 3]) -> bool {
    let after = worst_face_shape(m, v, p);
    after >= DEGENERATE_SHAPE || after > worst_face_shape(m, v, m.pos[v as usize])
}

/// A face around a moved vertex thinner than this (`|cross| / longest edge²`, about its
/// smallest angle in radians) is degenerate: the move is not taken.
const DEGENERATE_SHAPE: f64 = 1e-3;

/// Moves every vertex to its closest point on the reference, unless that would leave a face
/// around it degenerate ([`keeps_faces`]): near a sharp vertex of the reference (a scan's
/// spike) a whole cone of space has that vertex as its closest point, so neighbours would land
/// on one point. Such a vertex keeps its relaxed position, within a relaxation step of the
/// surface. Ours; B&K project unconditionally.
fn project(m: &mut HalfEdgeMesh, bvh: &Bvh) {
    for v in 0..m.pos.len() {
        if !m.alive(v as u32) {
            continue;
        }
        let p = m.pos[v].map(|x| x as f32);
        if let Some(hit) = bvh.closest_point(p, f32::INFINITY) {
            let q = hit.point.map(|x| x as f64);
            if keeps_faces(m, v as u32, q) {
                m.pos[v] = q;
            }
        }
    }
}
