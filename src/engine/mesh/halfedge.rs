//! An editable half-edge mesh for remeshing ([`super::remesh`]): edge split, half-edge collapse
//! and edge flip on a manifold triangle mesh with boundaries, positions in `f64`.
//!
//! Conventions: half-edges come in pairs, `twin(h) = h ^ 1`. Boundary half-edges exist (face
//! [`NONE`]) and are linked `next`/`prev` along their boundary loop, so circulating around a
//! vertex (`twin(prev(h))`) visits every outgoing half-edge, boundary ones included. A boundary
//! vertex's `out` is its outgoing boundary half-edge. Deleted elements are flagged and dropped by
//! [`HalfEdgeMesh::to_surface`]. Each edge carries a `feature` flag (on both half-edges).
//!
//! Input must be edge- and vertex-manifold with consistent winding ([`HalfEdgeMesh::build`]
//! says which edge or vertex is not). The operations here only check what keeps the structure
//! valid (link condition, valences); geometric checks are the remesher's.

use std::collections::HashMap;

use super::surface::Surface;

/// "No element" marker.
pub const NONE: u32 = u32::MAX;

/// Why a surface cannot become a half-edge mesh.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum HalfEdgeError {
    /// An edge is used by more than two faces, or twice in the same direction.
    #[error("non-manifold or inconsistently wound edge ({0}, {1})")]
    NonManifoldEdge(u32, u32),
    /// The faces around a vertex form more than one fan.
    #[error("non-manifold vertex {0} (its faces form more than one fan)")]
    NonManifoldVertex(u32),
    /// No faces.
    #[error("the surface has no faces")]
    Empty,
}

/// The mesh (see the module doc).
#[derive(Clone, Debug)]
pub struct HalfEdgeMesh {
    /// Vertex positions.
    pub pos: Vec<[f64; 3]>,
    /// An outgoing half-edge per vertex (the boundary one on the boundary); `NONE` if deleted.
    pub out: Vec<u32>,
    /// Per half-edge: the vertex it points to.
    pub to: Vec<u32>,
    /// Per half-edge: the next half-edge of its face (or boundary loop).
    pub next: Vec<u32>,
    /// Per half-edge: the previous one.
    pub prev: Vec<u32>,
    /// Per half-edge: its face, `NONE` on the boundary.
    pub face: Vec<u32>,
    /// Per half-edge: feature (crease) edge.
    pub feature: Vec<bool>,
    /// Per half-edge: deleted.
    pub he_dead: Vec<bool>,
    /// Per face: one of its half-edges; `NONE` if deleted.
    pub face_he: Vec<u32>,
}

/// Twin half-edge.
#[inline]
pub fn twin(h: u32) -> u32 {
    h ^ 1
}

impl HalfEdgeMesh {
    /// Builds the mesh from a surface (unreferenced vertices are kept but isolated: `out =
    /// NONE`).
    ///
    /// # Errors
    /// [`HalfEdgeError`] for non-manifold input or no faces.
    pub fn build(surface: &Surface) -> Result<HalfEdgeMesh, HalfEdgeError> {
        if surface.faces.is_empty() {
            return Err(HalfEdgeError::Empty);
        }
        let nv = surface.positions.len();
        let nf = surface.faces.len();
        let mut m = HalfEdgeMesh {
            pos: surface
                .positions
                .iter()
                .map(|p| p.map(|x| x as f64))
                .collect(),
            out: vec![NONE; nv],
            to: Vec::with_capacity(nf * 3 + 16),
            next: Vec::new(),
            prev: Vec::new(),
            face: Vec::new(),
            feature: Vec::new(),
            he_dead: Vec::new(),
            face_he: vec![NONE; nf],
        };
        let mut edge: HashMap<(u32, u32), u32> = HashMap::with_capacity(nf * 2);
        let mut used = vec![false; 0];
        for (f, tri) in surface.faces.iter().enumerate() {
            let mut hs = [0u32; 3];
            for i in 0..3 {
                let (a, b) = (tri[i], tri[(i + 1) % 3]);
                let key = (a.min(b), a.max(b));
                let h = match edge.get(&key) {
                    Some(&p) => {
                        // The pair exists: this direction must be the unused one.
                        let h = if m.to[p as usize] == b { p } else { twin(p) };
                        if used[h as usize] || m.to[h as usize] != b {
                            return Err(HalfEdgeError::NonManifoldEdge(a, b));
                        }
                        h
                    }
                    None => {
                        let h = m.new_pair(a, b);
                        used.extend([false, false]);
                        edge.insert(key, h);
                        h
                    }
                };
                used[h as usize] = true;
                hs[i] = h;
            }
            for i in 0..3 {
                let h = hs[i] as usize;
                m.next[h] = hs[(i + 1) % 3];
                m.prev[h] = hs[(i + 2) % 3];
                m.face[h] = f as u32;
                m.out[tri[i] as usize] = hs[i];
            }
            m.face_he[f] = hs[0];
        }
        // Boundary half-edges: link them along their loops.
        let mut boundary_out: Vec<u32> = vec![NONE; nv];
        for h in 0..m.to.len() as u32 {
            if m.face[h as usize] == NONE {
                let from = m.to[twin(h) as usize];
                if boundary_out[from as usize] != NONE {
                    return Err(HalfEdgeError::NonManifoldVertex(from));
                }
                boundary_out[from as usize] = h;
            }
        }
        for h in 0..m.to.len() as u32 {
            if m.face[h as usize] == NONE {
                let n = boundary_out[m.to[h as usize] as usize];
                m.next[h as usize] = n;
                m.prev[n as usize] = h;
            }
        }
        // Every vertex's faces must form one fan.
        let mut degree = vec![0u32; nv];
        for &(a, b) in edge.keys() {
            degree[a as usize] += 1;
            degree[b as usize] += 1;
        }
        for v in 0..nv {
            if boundary_out[v] != NONE {
                m.out[v] = boundary_out[v];
            }
            if m.out[v] != NONE && m.valence(v as u32) != degree[v] as usize {
                return Err(HalfEdgeError::NonManifoldVertex(v as u32));
            }
        }
        Ok(m)
    }

    fn new_pair(&mut self, a: u32, b: u32) -> u32 {
        let h = self.to.len() as u32;
        self.to.extend([b, a]);
        self.next.extend([NONE, NONE]);
        self.prev.extend([NONE, NONE]);
        self.face.extend([NONE, NONE]);
        self.feature.extend([false, false]);
        self.he_dead.extend([false, false]);
        h
    }

    /// The vertex `h` starts from.
    #[inline]
    pub fn from(&self, h: u32) -> u32 {
        self.to[twin(h) as usize]
    }

    /// Whether `h`'s edge is on the boundary (either side has no face).
    #[inline]
    pub fn is_boundary_edge(&self, h: u32) -> bool {
        self.face[h as usize] == NONE || self.face[twin(h) as usize] == NONE
    }

    /// Whether `v` is on the boundary.
    #[inline]
    pub fn is_boundary_vertex(&self, v: u32) -> bool {
        let h = self.out[v as usize];
        h != NONE && self.face[h as usize] == NONE
    }

    /// The outgoing half-edges of `v` (empty for a deleted vertex). Bounded by the half-edge
    /// count, so a corrupted ring cannot loop forever.
    pub fn outgoing(&self, v: u32) -> Vec<u32> {
        let start = self.out[v as usize];
        let mut ring = Vec::with_capacity(8);
        if start == NONE {
            return ring;
        }
        let mut h = start;
        loop {
            ring.push(h);
            h = twin(self.prev[h as usize]);
            if h == start || ring.len() > self.to.len() {
                break;
            }
        }
        ring
    }

    /// Number of edges at `v`.
    pub fn valence(&self, v: u32) -> usize {
        self.outgoing(v).len()
    }

    /// Whether `v` is alive.
    #[inline]
    pub fn alive(&self, v: u32) -> bool {
        self.out[v as usize] != NONE
    }

    /// Makes `out[v]` the outgoing boundary half-edge if `v` has one.
    fn fix_out(&mut self, v: u32) {
        if let Some(&h) = self
            .outgoing(v)
            .iter()
            .find(|&&h| self.face[h as usize] == NONE)
        {
            self.out[v as usize] = h;
        }
    }

    /// Splits the edge of `h` at `p`; returns the new vertex. Both adjacent faces are split in
    /// two; the new edges along the old one inherit its feature flag.
    pub fn split(&mut self, h: u32, p: [f64; 3]) -> u32 {
        let t = twin(h);
        let b = self.to[h as usize];
        let m = self.pos.len() as u32;
        self.pos.push(p);
        self.out.push(NONE);
        let e = self.new_pair(m, b); // e: m→b, twin et: b→m
        let et = twin(e);
        let feat = self.feature[h as usize];
        self.feature[e as usize] = feat;
        self.feature[et as usize] = feat;
        self.to[h as usize] = m; // h: a→m; t keeps `to = a`, now m→a
                                 // Side of h.
        if self.face[h as usize] == NONE {
            let hn = self.next[h as usize];
            self.link(h, e);
            self.link(e, hn);
        } else {
            let (h1, h2) = (self.next[h as usize], self.prev[h as usize]);
            let c = self.to[h1 as usize];
            let f0 = self.face[h as usize];
            let f2 = self.face_he.len() as u32;
            self.face_he.push(NONE);
            let s = self.new_pair(m, c); // s: m→c, st: c→m
            let st = twin(s);
            self.set_face(f0, [h, s, h2]);
            self.set_face(f2, [e, h1, st]);
        }
        // Side of t (t: m→a, et: b→m).
        if self.face[t as usize] == NONE {
            let tp = self.prev[t as usize];
            self.link(tp, et);
            self.link(et, t);
        } else {
            let (t1, t2) = (self.next[t as usize], self.prev[t as usize]);
            let d = self.to[t1 as usize];
            let f1 = self.face[t as usize];
            let f3 = self.face_he.len() as u32;
            self.face_he.push(NONE);
            let u = self.new_pair(d, m); // u: d→m, ut: m→d
            let ut = twin(u);
            self.set_face(f1, [t, t1, u]);
            self.set_face(f3, [et, ut, t2]);
        }
        if self.out[b as usize] == t {
            self.out[b as usize] = et;
        }
        self.out[m as usize] = e;
        self.fix_out(m);
        m
    }

    fn link(&mut self, a: u32, b: u32) {
        self.next[a as usize] = b;
        self.prev[b as usize] = a;
    }

    fn set_face(&mut self, f: u32, hs: [u32; 3]) {
        for i in 0..3 {
            self.link(hs[i], hs[(i + 1) % 3]);
            self.face[hs[i] as usize] = f;
        }
        self.face_he[f as usize] = hs[0];
    }

    /// Whether collapsing `h` (its start vertex onto its end) keeps the mesh manifold: the link
    /// condition (the common neighbours are exactly the opposite vertices), no interior edge
    /// between two boundary vertices, and the opposite vertices keep at least 3 (interior) or 2
    /// (boundary) edges' worth of valence.
    pub fn collapse_ok(&self, h: u32) -> bool {
        let t = twin(h);
        let (a, b) = (self.from(h), self.to[h as usize]);
        if self.is_boundary_vertex(a) && self.is_boundary_vertex(b) && !self.is_boundary_edge(h) {
            return false;
        }
        let mut opposite = Vec::with_capacity(2);
        for x in [h, t] {
            if self.face[x as usize] != NONE {
                let c = self.to[self.next[x as usize] as usize];
                let min = if self.is_boundary_vertex(c) { 3 } else { 4 };
                if self.valence(c) < min {
                    return false;
                }
                opposite.push(c);
            }
        }
        let na: Vec<u32> = self
            .outgoing(a)
            .iter()
            .map(|&x| self.to[x as usize])
            .collect();
        let nb: Vec<u32> = self
            .outgoing(b)
            .iter()
            .map(|&x| self.to[x as usize])
            .collect();
        let common = na.iter().filter(|v| nb.contains(v)).count();
        if common != opposite.len() || !opposite.iter().all(|c| na.contains(c)) {
            return false;
        }
        // Do not shrink a closed component below a tetrahedron, nor a boundary triangle fan.
        let nh = na.len() + nb.len();
        nh > 6
    }

    /// Collapses `h` (start `a` onto end `b`, `b` moved to `p`). Call only when
    /// [`HalfEdgeMesh::collapse_ok`] holds. Returns `b`.
    pub fn collapse(&mut self, h: u32, p: [f64; 3]) -> u32 {
        let t = twin(h);
        let (a, b) = (self.from(h), self.to[h as usize]);
        let ring_a = self.outgoing(a);
        for &x in &ring_a {
            self.to[twin(x) as usize] = b;
        }
        let mut touched = vec![b];
        // Half-edges that leave `b` after the collapse (for `out[b]`).
        let mut from_b: Vec<u32> = Vec::with_capacity(4);
        for (x, side_first) in [(h, true), (t, false)] {
            if self.face[x as usize] == NONE {
                let (xp, xn) = (self.prev[x as usize], self.next[x as usize]);
                self.link(xp, xn);
                from_b.push(xn);
                continue;
            }
            // Face (x, x1, x2). For h: x1 = b→c (kept), x2 = c→a (dropped with its twin o2).
            // For t: x1 = a→d (dropped with its twin), x2 = d→b (kept).
            let (x1, x2) = (self.next[x as usize], self.prev[x as usize]);
            let (keep, drop) = if side_first { (x1, x2) } else { (x2, x1) };
            from_b.push(if side_first { keep } else { twin(keep) });
            let o = twin(drop);
            // `keep` takes over `o`'s place in its face or boundary loop.
            let (op, on, of) = (
                self.prev[o as usize],
                self.next[o as usize],
                self.face[o as usize],
            );
            self.link(op, keep);
            self.link(keep, on);
            self.face[keep as usize] = of;
            if of != NONE && self.face_he[of as usize] == o {
                self.face_he[of as usize] = keep;
            }
            let f = self.feature[keep as usize] || self.feature[o as usize];
            self.feature[keep as usize] = f;
            self.feature[twin(keep) as usize] = f;
            let fx = self.face[x as usize];
            self.face_he[fx as usize] = NONE;
            let c = self.to[x1 as usize];
            for v in [self.from(keep), self.to[keep as usize], c] {
                if self.out[v as usize] == drop || self.out[v as usize] == o {
                    self.out[v as usize] = if self.from(keep) == v {
                        keep
                    } else {
                        twin(keep)
                    };
                }
                touched.push(v);
            }
            for dead in [drop, o] {
                self.he_dead[dead as usize] = true;
            }
        }
        for x in [h, t] {
            self.he_dead[x as usize] = true;
        }
        if self.he_dead[self.out[b as usize] as usize] || self.from(self.out[b as usize]) != b {
            let alive = from_b
                .iter()
                .chain(&ring_a)
                .copied()
                .find(|&x| !self.he_dead[x as usize] && self.from(x) == b);
            self.out[b as usize] = alive.unwrap_or(NONE);
        }
        self.out[a as usize] = NONE;
        self.pos[b as usize] = p;
        for v in touched {
            if self.alive(v) {
                self.fix_out(v);
            }
        }
        b
    }

    /// Whether the edge of `h` may be flipped topologically: interior, not a feature, the new
    /// diagonal not already an edge, and both end vertices keep valence ≥ 3.
    pub fn flip_ok(&self, h: u32) -> bool {
        if self.is_boundary_edge(h) || self.feature[h as usize] {
            return false;
        }
        let t = twin(h);
        let (a, b) = (self.from(h), self.to[h as usize]);
        let c = self.to[self.next[h as usize] as usize];
        let d = self.to[self.next[t as usize] as usize];
        if c == d || self.valence(a) <= 3 || self.valence(b) <= 3 {
            return false;
        }
        !self.outgoing(c).iter().any(|&x| self.to[x as usize] == d)
    }

    /// Flips the edge of `h`: faces (a, b, c), (b, a, d) become (a, d, c), (d, b, c).
    pub fn flip(&mut self, h: u32) {
        let t = twin(h);
        let (a, b) = (self.from(h), self.to[h as usize]);
        let (h1, h2) = (self.next[h as usize], self.prev[h as usize]);
        let (t1, t2) = (self.next[t as usize], self.prev[t as usize]);
        let c = self.to[h1 as usize];
        let d = self.to[t1 as usize];
        let (f0, f1) = (self.face[h as usize], self.face[t as usize]);
        self.to[h as usize] = c; // d→c
        self.to[t as usize] = d; // c→d
        self.set_face(f0, [h2, t1, h]);
        self.set_face(f1, [t2, h1, t]);
        if self.out[a as usize] == h {
            self.out[a as usize] = t1;
        }
        if self.out[b as usize] == t {
            self.out[b as usize] = h1;
        }
    }

    /// Checks the structure's invariants (twins, next/prev, faces of three, `out` pointers,
    /// boundary `out`, no duplicate edges); the first violation found.
    ///
    /// # Errors
    /// A description of the violation.
    pub fn validate(&self) -> Result<(), String> {
        let mut seen = std::collections::HashSet::new();
        for h in 0..self.to.len() as u32 {
            if self.he_dead[h as usize] {
                continue;
            }
            let hu = h as usize;
            if self.he_dead[twin(h) as usize] {
                return Err(format!("half-edge {h} alive, twin dead"));
            }
            let (n, p) = (self.next[hu], self.prev[hu]);
            if self.he_dead[n as usize] || self.he_dead[p as usize] {
                return Err(format!("half-edge {h}: next/prev dead"));
            }
            if self.prev[n as usize] != h || self.next[p as usize] != h {
                return Err(format!("half-edge {h}: next/prev not inverse"));
            }
            if self.from(n) != self.to[hu] {
                return Err(format!("half-edge {h}: next does not start at its end"));
            }
            if self.face[n as usize] != self.face[hu] {
                return Err(format!("half-edge {h}: next in another face"));
            }
            let f = self.face[hu];
            if f != NONE {
                if self.face_he[f as usize] == NONE {
                    return Err(format!("half-edge {h} in deleted face {f}"));
                }
                if self.next[self.next[n as usize] as usize] != h {
                    return Err(format!("face {f} is not a triangle"));
                }
            }
            if !seen.insert((self.from(h), self.to[hu])) {
                return Err(format!("duplicate edge {} → {}", self.from(h), self.to[hu]));
            }
            if !self.alive(self.to[hu]) {
                return Err(format!("half-edge {h} points to deleted vertex"));
            }
        }
        for v in 0..self.pos.len() as u32 {
            let o = self.out[v as usize];
            if o == NONE {
                continue;
            }
            if self.he_dead[o as usize] || self.from(o) != v {
                return Err(format!("vertex {v}: bad out {o}"));
            }
            let ring = self.outgoing(v);
            if ring.len() > self.to.len() {
                return Err(format!("vertex {v}: ring does not close"));
            }
            let boundary = ring
                .iter()
                .filter(|&&h| self.face[h as usize] == NONE)
                .count();
            if boundary > 1 {
                return Err(format!("vertex {v}: {boundary} boundary fans"));
            }
            if boundary == 1 && self.face[o as usize] != NONE {
                return Err(format!("vertex {v}: out is not its boundary half-edge"));
            }
        }
        Ok(())
    }

    /// The three vertices of face `f`.
    pub fn face_vertices(&self, f: u32) -> [u32; 3] {
        let h = self.face_he[f as usize];
        let n = self.next[h as usize];
        [self.from(h), self.to[h as usize], self.to[n as usize]]
    }

    /// The live faces.
    pub fn faces(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.face_he.len() as u32).filter(|&f| self.face_he[f as usize] != NONE)
    }

    /// One half-edge per live edge (the lower of each pair).
    pub fn edges(&self) -> Vec<u32> {
        (0..self.to.len() as u32)
            .step_by(2)
            .filter(|&h| !self.he_dead[h as usize])
            .collect()
    }

    /// Compacts into a [`Surface`] (live vertices with faces, live faces), with the old index
    /// of each new vertex.
    pub fn to_surface(&self) -> (Surface, Vec<u32>) {
        let mut map = vec![NONE; self.pos.len()];
        let mut old = Vec::new();
        let mut positions = Vec::new();
        let mut faces = Vec::new();
        for f in self.faces() {
            let vs = self.face_vertices(f).map(|v| {
                if map[v as usize] == NONE {
                    map[v as usize] = positions.len() as u32;
                    positions.push(self.pos[v as usize].map(|x| x as f32));
                    old.push(v);
                }
                map[v as usize]
            });
            faces.push(vs);
        }
        (Surface::from_triangles(positions, faces), old)
    }
}
