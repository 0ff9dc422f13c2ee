//! One decimation step of the MeshMatch hierarchy (Chen et al. 2012, §4, "iterative mesh
//! decimation ... edges are collapsed in shortest-first order, positioning new vertices at the
//! midpoint of the collapsed edge"): collapse the shortest admissible edge until the vertex count
//! reaches a target, and record which coarse vertex each fine vertex merged into.
//!
//! An edge `(a, b)` is admissible when
//! - neither end is *locked*: a vertex is locked when its faces do not form a single consistently
//!   oriented fan (a cycle inside, an open fan on the boundary), i.e. at non-manifold vertices and
//!   edges and where neighbouring faces disagree on winding. Locked vertices never move;
//! - it is used by one face (boundary edge) or two faces (interior edge);
//! - the **link condition** holds (Dey et al. 1999; Hoppe 1993): the vertices adjacent to both `a`
//!   and `b` are exactly the opposite corners of the edge's faces. With the next rule this keeps a
//!   2-manifold a 2-manifold of the same topology;
//! - no opposite corner would be left with too few faces (an interior corner with three faces is
//!   a tetrahedron; a boundary corner with one face would become isolated);
//! - boundaries stay on boundaries: an interior edge between two boundary vertices is rejected
//!   (it would pinch the surface); a boundary edge collapses to its midpoint, and only where the
//!   boundary turns by at most `max_boundary_turn_degrees` at both ends (so corners stay and the
//!   midpoint stays on the boundary curve); an edge from a boundary vertex to an interior one
//!   collapses onto the boundary vertex (the one exception to the midpoint rule);
//! - no surviving face turns by more than `max_normal_change_degrees` (so none flips), and the
//!   worst surviving face around the edge is at least `min_triangle_quality` or no worse than the
//!   worst face there before (the two faces that disappear included). Quality is
//!   `4√3·area / (l₀² + l₁² + l₂²)`: 1 for an equilateral triangle, 0 for a degenerate one.
//!   The rule compares the worst faces, not each face with its old self: a per-face rule refuses
//!   every collapse next to a fan of slivers (the 256-face poles of a UV capsule: moving a ring
//!   vertex half a step makes some neighbouring sliver a little worse), so the hierarchy stalled
//!   at a few thousand vertices with the poles intact; the worst-face rule lets the slivers be
//!   collapsed away and still never lowers a level's worst face below min(threshold, before).
//!
//! Rejected edges are retried (up to [`RETRY_ROUNDS`] times) once other collapses have changed
//! their neighbourhood. Candidates are ordered by squared length, ties by the order they were
//! queued; the process is sequential, so the result is deterministic.
//!
//! Written by hand: the collapse rules (midpoint placement, vertex tree) are MeshMatch's own; the
//! general-purpose decimation crates place vertices by quadrics and keep no vertex tree.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::engine::control::{Cancelled, StageProgress};
use crate::engine::math::{cross, dot, sub};

/// How often a level retries edges rejected earlier.
pub(crate) const RETRY_ROUNDS: usize = 4;
/// Collapses between progress ticks (a few milliseconds of work).
const TICK: u64 = 1024;

/// Geometric admissibility thresholds (see the module docs).
#[derive(Clone, Copy, Debug)]
pub(crate) struct CollapseRules {
    /// `cos` of the largest allowed face-normal change.
    pub cos_max_normal_change: f64,
    /// Smallest allowed triangle quality (unless a face was already worse).
    pub min_quality: f64,
    /// `cos` of the largest boundary turning angle at either end of a collapsed boundary edge.
    pub cos_max_boundary_turn: f64,
}

/// Result of one decimation step.
#[derive(Clone, Debug)]
pub(crate) struct Decimated {
    /// Coarse positions.
    pub positions: Vec<[f32; 3]>,
    /// Coarse faces (winding kept).
    pub faces: Vec<[u32; 3]>,
    /// For every fine vertex, the coarse vertex it merged into.
    pub parent: Vec<u32>,
}

/// The candidate queue: a min-heap of `squared length bits << 32 | record index` (non-negative
/// floats order like their bits; equal lengths go to the earlier push), with the records (low
/// end, high end, and both ends' versions when pushed) beside it. Eight-byte heap entries keep
/// the heap small and cache friendly.
#[derive(Default)]
struct Queue {
    heap: BinaryHeap<Reverse<u64>>,
    records: Vec<(u32, u32, u32, u32)>,
}

impl Queue {
    fn push(&mut self, len2: f32, record: (u32, u32, u32, u32)) {
        let key = ((len2.to_bits() as u64) << 32) | self.records.len() as u64;
        self.records.push(record);
        self.heap.push(Reverse(key));
    }

    fn pop(&mut self) -> Option<(u32, u32, u32, u32)> {
        self.heap
            .pop()
            .map(|Reverse(k)| self.records[(k & 0xFFFF_FFFF) as usize])
    }
}

struct Mesh {
    pos: Vec<[f64; 3]>,
    faces: Vec<[u32; 3]>,
    face_alive: Vec<bool>,
    vfaces: Vec<Vec<u32>>,
    alive: Vec<bool>,
    boundary: Vec<bool>,
    locked: Vec<bool>,
    version: Vec<u32>,
    merged_into: Vec<u32>,
}

/// Scratch buffers reused by every candidate check.
#[derive(Default)]
struct Scratch {
    shared: Vec<u32>,
    na: Vec<u32>,
    nb: Vec<u32>,
}

/// Triangle quality `4√3·area / Σ l²` and the unnormalized normal.
fn quality_and_normal(p: [[f64; 3]; 3]) -> (f64, [f64; 3]) {
    let e0 = sub(p[1], p[0]);
    let e1 = sub(p[2], p[1]);
    let e2 = sub(p[0], p[2]);
    let n = cross(e0, sub(p[2], p[0]));
    let area2 = dot(n, n).sqrt(); // twice the area
    let l2 = dot(e0, e0) + dot(e1, e1) + dot(e2, e2);
    let q = if l2 > 0.0 {
        2.0 * 3f64.sqrt() * area2 / l2
    } else {
        0.0
    };
    (q, n)
}

impl Mesh {
    fn new(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Mesh {
        let nv = positions.len();
        let mut vfaces: Vec<Vec<u32>> = vec![Vec::new(); nv];
        for (f, face) in faces.iter().enumerate() {
            for &v in face {
                vfaces[v as usize].push(f as u32);
            }
        }
        let mut m = Mesh {
            pos: positions.iter().map(|p| p.map(|c| c as f64)).collect(),
            faces: faces.to_vec(),
            face_alive: vec![true; faces.len()],
            vfaces,
            alive: vec![true; nv],
            boundary: vec![false; nv],
            locked: vec![false; nv],
            version: vec![0; nv],
            merged_into: (0..nv as u32).collect(),
        };
        for v in 0..nv {
            let (boundary, regular) = m.classify(v as u32);
            m.boundary[v] = boundary;
            m.locked[v] = !regular;
        }
        m
    }

    /// (is on the boundary, has a single consistently oriented fan).
    fn classify(&self, v: u32) -> (bool, bool) {
        let fs = &self.vfaces[v as usize];
        // Outgoing (v → next) and incoming (prev → v) neighbours per face.
        let mut next = Vec::with_capacity(fs.len());
        let mut prev = Vec::with_capacity(fs.len());
        for &f in fs {
            let face = self.faces[f as usize];
            let k = match face.iter().position(|&x| x == v) {
                Some(k) => k,
                None => return (false, false),
            };
            let (n, p) = (face[(k + 1) % 3], face[(k + 2) % 3]);
            if n == v || p == v || n == p {
                return (false, false);
            }
            next.push(n);
            prev.push(p);
        }
        // Each neighbour at most once as `next` and once as `prev`.
        let mut sorted = next.clone();
        sorted.sort_unstable();
        if sorted.windows(2).any(|w| w[0] == w[1]) {
            return (false, false);
        }
        let mut sorted_prev = prev.clone();
        sorted_prev.sort_unstable();
        if sorted_prev.windows(2).any(|w| w[0] == w[1]) {
            return (false, false);
        }
        // Walk the fan: from face i, the next face around v is the one whose `prev` is this
        // face's `next`... Count fans with a union-find over the local faces.
        let nfan = fs.len();
        let mut root: Vec<usize> = (0..nfan).collect();
        fn find(r: &mut [usize], mut x: usize) -> usize {
            while r[x] != x {
                r[x] = r[r[x]];
                x = r[x];
            }
            x
        }
        let mut open_ends = 0;
        for i in 0..nfan {
            match prev.iter().position(|&p| p == next[i]) {
                Some(j) => {
                    let (ri, rj) = (find(&mut root, i), find(&mut root, j));
                    root[ri.max(rj)] = ri.min(rj);
                }
                None => open_ends += 1,
            }
        }
        let fans = (0..nfan).filter(|&i| find(&mut root, i) == i).count();
        let boundary = open_ends > 0;
        (boundary, fans == 1 && open_ends <= 1)
    }

    fn len2(&self, a: u32, b: u32) -> f64 {
        let d = sub(self.pos[a as usize], self.pos[b as usize]);
        dot(d, d)
    }

    fn push_edge(&self, heap: &mut Queue, a: u32, b: u32) {
        let (lo, hi) = (a.min(b), a.max(b));
        let l2 = self.len2(lo, hi) as f32;
        heap.push(
            l2,
            (lo, hi, self.version[lo as usize], self.version[hi as usize]),
        );
    }

    /// Distinct neighbours of `v` (excluding `skip`) into `out`, sorted.
    fn neighbours(&self, v: u32, skip: u32, out: &mut Vec<u32>) {
        out.clear();
        for &f in &self.vfaces[v as usize] {
            for &x in &self.faces[f as usize] {
                if x != v && x != skip {
                    out.push(x);
                }
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    /// The other end of the boundary edge at `v` that does not lead to `other` (`None` when `v`
    /// does not have exactly two boundary edges).
    fn boundary_neighbour(&self, v: u32, other: u32) -> Option<u32> {
        let mut found = None;
        let mut count = 0;
        for &f in &self.vfaces[v as usize] {
            for &x in &self.faces[f as usize] {
                if x == v {
                    continue;
                }
                let shared = self.vfaces[v as usize]
                    .iter()
                    .filter(|&&g| self.faces[g as usize].contains(&x))
                    .count();
                if shared == 1 {
                    count += 1;
                    if x != other {
                        found = Some(x);
                    }
                }
            }
        }
        (count == 2).then_some(found).flatten()
    }

    /// Checks the collapse of `(a, b)`; on success returns the new position of the survivor.
    fn admissible(
        &self,
        a: u32,
        b: u32,
        rules: &CollapseRules,
        s: &mut Scratch,
    ) -> Option<[f64; 3]> {
        let (ai, bi) = (a as usize, b as usize);
        if self.locked[ai] || self.locked[bi] {
            return None;
        }
        // Faces containing both ends.
        s.shared.clear();
        for &f in &self.vfaces[ai] {
            if self.faces[f as usize].contains(&b) {
                s.shared.push(f);
            }
        }
        let boundary_edge = match s.shared.len() {
            1 => true,
            2 => false,
            _ => return None,
        };
        if !boundary_edge && self.boundary[ai] && self.boundary[bi] {
            return None;
        }
        // Link condition: common neighbours == opposite corners.
        self.neighbours(a, b, &mut s.na);
        self.neighbours(b, a, &mut s.nb);
        let mut opposite = [u32::MAX; 2];
        for (k, &f) in s.shared.iter().enumerate() {
            let face = self.faces[f as usize];
            opposite[k] = face.iter().copied().find(|&x| x != a && x != b)?;
        }
        let mut common = 0;
        let (mut i, mut j) = (0, 0);
        while i < s.na.len() && j < s.nb.len() {
            match s.na[i].cmp(&s.nb[j]) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    if !opposite.contains(&s.na[i]) {
                        return None;
                    }
                    common += 1;
                    i += 1;
                    j += 1;
                }
            }
        }
        if common != s.shared.len() {
            return None;
        }
        // Opposite corners keep enough faces.
        for &c in opposite.iter().take(s.shared.len()) {
            let need = if self.boundary[c as usize] { 2 } else { 4 };
            if self.vfaces[c as usize].len() < need {
                return None;
            }
        }
        // Placement.
        let (pa, pb) = (self.pos[ai], self.pos[bi]);
        if boundary_edge {
            // The boundary must run nearly straight through both ends, so the midpoint stays on
            // the boundary curve (corners never move).
            let d = sub(pb, pa);
            for (v, other, dir) in [(a, b, 1.0), (b, a, -1.0)] {
                let w = self.boundary_neighbour(v, other)?;
                let e = sub(self.pos[v as usize], self.pos[w as usize]);
                let e = [e[0] * dir, e[1] * dir, e[2] * dir];
                let (le, ld) = (dot(e, e).sqrt(), dot(d, d).sqrt());
                if dot(e, d) < rules.cos_max_boundary_turn * le * ld {
                    return None;
                }
            }
        }
        let p = if boundary_edge || self.boundary[ai] == self.boundary[bi] {
            [
                0.5 * (pa[0] + pb[0]),
                0.5 * (pa[1] + pb[1]),
                0.5 * (pa[2] + pb[2]),
            ]
        } else if self.boundary[ai] {
            pa
        } else {
            pb
        };
        // Geometry of every face around a and b: no surviving face turns too far, and the worst
        // surviving face is no worse than min(min_quality, the worst face there before,
        // including the two that disappear).
        let (mut worst_before, mut worst_after) = (f64::INFINITY, f64::INFINITY);
        for (v, fs) in [(a, &self.vfaces[ai]), (b, &self.vfaces[bi])] {
            for &f in fs {
                let face = self.faces[f as usize];
                let old = face.map(|x| self.pos[x as usize]);
                let (q0, n0) = quality_and_normal(old);
                worst_before = worst_before.min(q0);
                if face.contains(&a) && face.contains(&b) {
                    continue;
                }
                let new = face.map(|x| if x == v { p } else { self.pos[x as usize] });
                let (q1, n1) = quality_and_normal(new);
                let (l0, l1) = (dot(n0, n0).sqrt(), dot(n1, n1).sqrt());
                if l1 <= 0.0 || dot(n0, n1) <= rules.cos_max_normal_change * l0 * l1 {
                    return None;
                }
                worst_after = worst_after.min(q1);
            }
        }
        if worst_after < rules.min_quality && worst_after < worst_before {
            return None;
        }
        Some(p)
    }

    /// Collapses `b` into `a` at `p` (already checked) and pushes the changed edges.
    fn collapse(&mut self, a: u32, b: u32, p: [f64; 3], heap: &mut Queue, s: &mut Scratch) {
        let (ai, bi) = (a as usize, b as usize);
        s.shared.clear();
        for &f in &self.vfaces[ai] {
            if self.faces[f as usize].contains(&b) {
                s.shared.push(f);
            }
        }
        for &f in &s.shared {
            self.face_alive[f as usize] = false;
            for &c in &self.faces[f as usize] {
                if c != a && c != b {
                    self.vfaces[c as usize].retain(|&g| g != f);
                }
            }
        }
        let fb = std::mem::take(&mut self.vfaces[bi]);
        let mut fa = std::mem::take(&mut self.vfaces[ai]);
        fa.retain(|f| !s.shared.contains(f));
        for f in fb {
            if s.shared.contains(&f) {
                continue;
            }
            for x in self.faces[f as usize].iter_mut() {
                if *x == b {
                    *x = a;
                }
            }
            fa.push(f);
        }
        fa.sort_unstable();
        self.vfaces[ai] = fa;
        self.pos[ai] = p;
        self.alive[bi] = false;
        self.merged_into[bi] = a;
        self.boundary[ai] |= self.boundary[bi];
        self.version[ai] = self.version[ai].wrapping_add(1);
        self.neighbours(a, a, &mut s.na);
        for k in 0..s.na.len() {
            self.push_edge(heap, a, s.na[k]);
        }
    }
}

/// Collapses edges of `(positions, faces)` shortest-first until at most `target` vertices remain
/// or no admissible edge is left. Every vertex must be used by a face.
pub(crate) fn decimate(
    positions: &[[f32; 3]],
    faces: &[[u32; 3]],
    target: usize,
    rules: &CollapseRules,
    stage: &StageProgress<'_>,
) -> Result<Decimated, Cancelled> {
    let mut m = Mesh::new(positions, faces);
    let mut live = positions.len();
    let mut heap = Queue::default();
    for face in faces {
        for k in 0..3 {
            // Each undirected edge once: a consistently wound interior edge appears as a → b in
            // one face and b → a in the other. (Duplicates would be harmless: a stale copy is
            // skipped, and rejected pairs are deduplicated before a retry.)
            let (a, b) = (face[k], face[(k + 1) % 3]);
            if a < b || is_boundary_edge(&m, a, b) {
                m.push_edge(&mut heap, a, b);
            }
        }
    }
    let mut s = Scratch::default();
    let mut rejected: Vec<(u32, u32)> = Vec::new();
    let mut since_tick = 0u64;
    let mut round = 0;
    while live > target {
        let Some((a, b, va, vb)) = heap.pop() else {
            // Retry rejected edges whose surroundings may have changed.
            if rejected.is_empty() || round >= RETRY_ROUNDS {
                break;
            }
            round += 1;
            let mut retry = std::mem::take(&mut rejected);
            retry.sort_unstable();
            retry.dedup();
            for (a, b) in retry {
                if m.alive[a as usize] && m.alive[b as usize] {
                    m.push_edge(&mut heap, a, b);
                }
            }
            if heap.heap.is_empty() {
                break;
            }
            continue;
        };
        let (ai, bi) = (a as usize, b as usize);
        if !m.alive[ai] || !m.alive[bi] || m.version[ai] != va || m.version[bi] != vb {
            continue;
        }
        match m.admissible(a, b, rules, &mut s) {
            Some(p) => {
                m.collapse(a, b, p, &mut heap, &mut s);
                live -= 1;
                since_tick += 1;
                if since_tick == TICK {
                    stage.tick(since_tick)?;
                    since_tick = 0;
                }
            }
            None => rejected.push((a, b)),
        }
    }
    stage.tick(since_tick)?;

    // Compact: survivors keep their fine order; faces keep theirs.
    let nv = positions.len();
    let mut coarse_of = vec![u32::MAX; nv];
    let mut out_pos = Vec::with_capacity(live);
    for v in 0..nv {
        if m.alive[v] {
            coarse_of[v] = out_pos.len() as u32;
            let p = m.pos[v];
            out_pos.push([p[0] as f32, p[1] as f32, p[2] as f32]);
        }
    }
    let mut parent = vec![0u32; nv];
    for v in 0..nv {
        let mut r = v as u32;
        while m.merged_into[r as usize] != r {
            r = m.merged_into[r as usize];
        }
        parent[v] = coarse_of[r as usize];
    }
    let out_faces = m
        .faces
        .iter()
        .zip(&m.face_alive)
        .filter(|(_, &alive)| alive)
        .map(|(f, _)| f.map(|x| coarse_of[x as usize]))
        .collect();
    Ok(Decimated {
        positions: out_pos,
        faces: out_faces,
        parent,
    })
}

/// Whether the edge `(a, b)` is used by exactly one face.
fn is_boundary_edge(m: &Mesh, a: u32, b: u32) -> bool {
    m.vfaces[a as usize]
        .iter()
        .filter(|&&f| m.faces[f as usize].contains(&b))
        .count()
        == 1
}
