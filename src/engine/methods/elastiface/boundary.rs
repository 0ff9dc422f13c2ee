//! Boundary-loop correspondences (§3.1, Fig. 5): from one or more hand-placed correspondences on
//! a boundary loop, every other vertex of the source loop gets a target position on the target
//! loop by relative arc length.
//!
//! - **Loops**: the boundary edges (edges of exactly one face) of the welded surface, each
//!   directed as in its face, chained head to tail. Where a vertex starts several boundary edges
//!   (non-manifold) the first one found is followed. Both meshes are assumed consistently
//!   oriented (outward normals), so corresponding loops run the same way and are traversed in
//!   their own edge direction.
//! - **Anchors**: a hand-placed pair is an anchor when its source point lies on a source loop and
//!   its target point on a target loop, each within `1e-4 ×` its surface's bounding-box diagonal
//!   (a constant of ours: points placed on a boundary vertex or snapped onto a boundary edge lie
//!   exactly on it). A loop pair is identified by its anchors: every anchor of one source loop
//!   must lie on the same target loop (else an error names the correspondence), and anchors must
//!   come in the same cyclic order on both loops (else an error).
//! - **Splitting**: the anchors cut the source loop into arcs (one anchor: the whole loop from
//!   it); a source vertex at relative arc length `f` along its arc is paired with the point at
//!   relative arc length `f` along the corresponding target arc (a point on a boundary edge, a
//!   barycentric combination of its two vertices as in eq. 1).
//! - **Weights** (ours, the paper gives none): every derived pair weighs
//!   `min(1, hand-placed pairs / derived pairs)`, so all derived pairs together never weigh more
//!   than the hand-placed ones and a long loop does not drown them.

use std::collections::HashMap;

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::math::{dot, length, sub};

use super::refs::{RefPair, RefRow};

/// One boundary loop.
#[derive(Clone, Debug)]
pub struct Loop {
    /// Vertices in traversal order (edge `i` runs from `verts[i]` to `verts[(i + 1) % len]`).
    pub verts: Vec<u32>,
    /// Arc length at each vertex from `verts[0]`.
    pub arc: Vec<f64>,
    /// Total length.
    pub length: f64,
}

/// The boundary loops of a surface.
pub fn boundary_loops(positions: &[[f64; 3]], faces: &[[u32; 3]]) -> Vec<Loop> {
    let mut count: HashMap<(u32, u32), u32> = HashMap::new();
    for f in faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut next: HashMap<u32, u32> = HashMap::new();
    let mut starts = Vec::new();
    for f in faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            if count[&(a.min(b), a.max(b))] == 1 && !next.contains_key(&a) {
                next.insert(a, b);
                starts.push(a);
            }
        }
    }
    let mut used: HashMap<u32, bool> = HashMap::new();
    let mut loops = Vec::new();
    for s in starts {
        if used.contains_key(&s) {
            continue;
        }
        let mut verts = vec![s];
        used.insert(s, true);
        let mut v = s;
        while let Some(&n) = next.get(&v) {
            if n == s || used.contains_key(&n) {
                break;
            }
            used.insert(n, true);
            verts.push(n);
            v = n;
        }
        if verts.len() < 3 {
            continue;
        }
        let mut arc = Vec::with_capacity(verts.len());
        let mut total = 0.0;
        for i in 0..verts.len() {
            arc.push(total);
            let (a, b) = (verts[i], verts[(i + 1) % verts.len()]);
            total += length(sub(positions[b as usize], positions[a as usize]));
        }
        loops.push(Loop {
            verts,
            arc,
            length: total,
        });
    }
    loops
}

/// Where a point lies on the loops: (loop, arc length), if within `tolerance`.
fn locate(loops: &[Loop], x: &[[f64; 3]], p: [f64; 3], tolerance: f64) -> Option<(usize, f64)> {
    let mut best: Option<(f64, usize, f64)> = None;
    for (l, lp) in loops.iter().enumerate() {
        let n = lp.verts.len();
        for i in 0..n {
            let a = x[lp.verts[i] as usize];
            let b = x[lp.verts[(i + 1) % n] as usize];
            let e = sub(b, a);
            let len2 = dot(e, e);
            let u = if len2 > 0.0 {
                (dot(sub(p, a), e) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let q = [a[0] + u * e[0], a[1] + u * e[1], a[2] + u * e[2]];
            let d = length(sub(p, q));
            if best.is_none_or(|b| d < b.0) {
                best = Some((d, l, lp.arc[i] + u * len2.sqrt()));
            }
        }
    }
    best.filter(|b| b.0 <= tolerance).map(|b| (b.1, b.2))
}

/// The point at arc length `t` on a loop.
fn point_at(lp: &Loop, x: &[[f64; 3]], t: f64) -> RefRow {
    let n = lp.verts.len();
    let t = t.rem_euclid(lp.length);
    let i = lp.arc.partition_point(|&a| a <= t).saturating_sub(1);
    let a = lp.verts[i];
    let b = lp.verts[(i + 1) % n];
    let len = length(sub(x[b as usize], x[a as usize]));
    let u = if len > 0.0 {
        ((t - lp.arc[i]) / len).clamp(0.0, 1.0)
    } else {
        0.0
    };
    RefRow::segment(a, b, u)
}

/// An anchor: a hand-placed pair on a source and a target loop.
#[derive(Clone, Copy, Debug)]
struct Anchor {
    correspondence: usize,
    target_loop: usize,
    s: f64,
    t: f64,
}

/// What the boundary step derived.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct BoundaryReport {
    /// Boundary loops of the source surface.
    pub source_loops: usize,
    /// Boundary loops of the target surface.
    pub target_loops: usize,
    /// Loop pairs with at least one anchor.
    pub paired_loops: usize,
    /// Derived pairs (one per non-anchor source loop vertex of a paired loop).
    pub derived_pairs: usize,
    /// The weight of each derived pair.
    pub derived_weight: f64,
}

/// A paired loop: the source loop's vertices and the target loop's, each in traversal order.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopPair {
    /// Source loop vertices.
    pub source: Vec<u32>,
    /// Target loop vertices (edge `i` from `target[i]` to `target[(i + 1) % len]`).
    pub target: Vec<u32>,
}

/// One side: welded positions, faces and bounding-box diagonal.
pub struct LoopSide<'a> {
    /// Positions.
    pub x: &'a [[f64; 3]],
    /// Faces.
    pub faces: &'a [[u32; 3]],
    /// Bounding-box diagonal.
    pub diagonal: f64,
}

/// What [`derive_boundary_pairs`] gives: the derived pairs, their figures and the loop pairs.
pub type DerivedLoops = (Vec<RefPair>, BoundaryReport, Vec<LoopPair>);

/// The derived pairs of every boundary loop pair (see the module docs).
///
/// # Errors
/// A [`ConstraintsError`] naming a correspondence whose loops do not pair up.
pub fn derive_boundary_pairs(
    source: &LoopSide<'_>,
    target: &LoopSide<'_>,
    hand: &[RefPair],
) -> Result<DerivedLoops, ConstraintsError> {
    let src_loops = boundary_loops(source.x, source.faces);
    let tgt_loops = boundary_loops(target.x, target.faces);
    let mut report = BoundaryReport {
        source_loops: src_loops.len(),
        target_loops: tgt_loops.len(),
        ..Default::default()
    };
    let mut by_loop: Vec<Vec<Anchor>> = vec![Vec::new(); src_loops.len()];
    for (k, pair) in hand.iter().enumerate() {
        let on_s = locate(
            &src_loops,
            source.x,
            pair.source.eval(source.x),
            1e-4 * source.diagonal,
        );
        let on_t = locate(
            &tgt_loops,
            target.x,
            pair.target.eval(target.x),
            1e-4 * target.diagonal,
        );
        if let (Some((ls, s)), Some((lt, t))) = (on_s, on_t) {
            let i = pair.correspondence.unwrap_or(k);
            by_loop[ls].push(Anchor {
                correspondence: i,
                target_loop: lt,
                s,
                t,
            });
        }
    }
    let mut target_owner: HashMap<usize, usize> = HashMap::new();
    let mut derived = Vec::new();
    let mut loop_pairs = Vec::new();
    for (ls, anchors) in by_loop.iter_mut().enumerate() {
        if anchors.is_empty() {
            continue;
        }
        let lt = anchors[0].target_loop;
        for a in anchors.iter() {
            if a.target_loop != lt {
                return Err(ConstraintsError::new(
                    format!("correspondences[{}].target", a.correspondence),
                    format!(
                        "lies on a different target boundary loop than correspondences[{}], \
                         whose source lies on the same source loop",
                        anchors[0].correspondence
                    ),
                ));
            }
        }
        if let Some(&other) = target_owner.get(&lt) {
            if other != ls {
                return Err(ConstraintsError::new(
                    format!("correspondences[{}].target", anchors[0].correspondence),
                    "two source boundary loops are anchored on the same target boundary loop",
                ));
            }
        }
        target_owner.insert(lt, ls);
        anchors.sort_by(|a, b| a.s.total_cmp(&b.s));
        derived.extend(split_loop(
            &src_loops[ls],
            &tgt_loops[lt],
            target.x,
            anchors,
        )?);
        loop_pairs.push(LoopPair {
            source: src_loops[ls].verts.clone(),
            target: tgt_loops[lt].verts.clone(),
        });
        report.paired_loops += 1;
    }
    let weight = if derived.is_empty() {
        0.0
    } else {
        (hand.len() as f64 / derived.len() as f64).min(1.0)
    };
    for d in &mut derived {
        d.weight = weight;
    }
    report.derived_pairs = derived.len();
    report.derived_weight = weight;
    Ok((derived, report, loop_pairs))
}

/// The derived pairs of one loop pair, anchors sorted by source arc length.
fn split_loop(
    src: &Loop,
    tgt: &Loop,
    tx: &[[f64; 3]],
    anchors: &[Anchor],
) -> Result<Vec<RefPair>, ConstraintsError> {
    let (ls, lt) = (src.length, tgt.length);
    let m = anchors.len();
    let seg = |i: usize| -> (f64, f64) {
        if m == 1 {
            return (ls, lt);
        }
        let (a, b) = (anchors[i], anchors[(i + 1) % m]);
        ((b.s - a.s).rem_euclid(ls), (b.t - a.t).rem_euclid(lt))
    };
    if m > 1 {
        let total: f64 = (0..m).map(|i| seg(i).1).sum();
        if (total - lt).abs() > 1e-6 * lt {
            return Err(ConstraintsError::new(
                format!("correspondences[{}]", anchors[0].correspondence),
                "the correspondences on this boundary loop are not in the same order on the \
                 source and the target loop",
            ));
        }
    }
    let mut out = Vec::new();
    for (i, &v) in src.verts.iter().enumerate() {
        let s = src.arc[i];
        if anchors.iter().any(|a| (a.s - s).abs() <= 1e-9 * ls) {
            continue;
        }
        let k = anchors.iter().rposition(|a| a.s <= s).unwrap_or(m - 1);
        let (ds, dt) = seg(k);
        let f = if ds > 0.0 {
            (s - anchors[k].s).rem_euclid(ls) / ds
        } else {
            0.0
        };
        out.push(RefPair {
            source: RefRow {
                idx: [v, v, v],
                w: [1.0, 0.0, 0.0],
            },
            target: point_at(tgt, tx, anchors[k].t + f * dt),
            weight: 1.0,
            correspondence: None,
        });
    }
    Ok(out)
}
