//! Resampling by longest-edge bisection: repeatedly split the longest edge of the mesh at its
//! midpoint (each face on it becomes two, so the mesh stays conforming and the geometry does not
//! change) until the mesh has the requested number of vertices or no edge is longer than the
//! requested length. Splitting the longest edge first keeps triangles well shaped (Rivara 1984,
//! longest-edge bisection) and, unlike the pass-based [`super::refine`], reaches a sample count
//! exactly (DESIGN.md: "refine edges until a requested sample count or texel size").
//!
//! The result is a [`Refined`]: every new vertex records its two parents (for
//! [`Refined::interpolate`]) and its (face, barycentric) on the input mesh (for baking fields back),
//! every triangle its input face. Edges shared by more than [`MAX_EDGE_FACES`] faces are never
//! split. Ties in length go to the lower (vertex, vertex) pair, so the result is deterministic.
//! Progress and cancellation go through a [`Control`].

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};

use super::refine::{input_sources, midpoint_source, Refined};
use crate::engine::control::{Cancelled, Control};
use crate::engine::math::dist2;

/// Most faces an edge may have and still be split.
pub const MAX_EDGE_FACES: usize = 4;
/// Splits between progress ticks.
const TICK: u64 = 4096;

/// Parameters of [`resample`]. At least one bound must be finite.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ResampleParams {
    /// Stop once the mesh has this many vertices. Default: `usize::MAX` (no count bound).
    /// Range: ≥ 1.
    pub max_vertices: usize,
    /// Stop once no edge is longer than this, in the mesh's units. Default: infinity (no length
    /// bound). Range: > 0.
    pub max_edge_length: f32,
}

impl Default for ResampleParams {
    fn default() -> Self {
        Self {
            max_vertices: usize::MAX,
            max_edge_length: f32::INFINITY,
        }
    }
}

/// Errors of [`resample`].
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum ResampleError {
    /// Neither bound is set, or one is out of range.
    #[error("resample needs max_vertices ≥ 1 or a positive finite max_edge_length (got {max_vertices}, {max_edge_length})")]
    NoBound {
        /// The given vertex bound.
        max_vertices: usize,
        /// The given length bound.
        max_edge_length: f32,
    },
    /// A face refers past the vertex array.
    #[error("face {face} refers to vertex {vertex} of {count}")]
    VertexOutOfRange {
        /// Face index.
        face: usize,
        /// The offending vertex.
        vertex: u32,
        /// Vertex count.
        count: usize,
    },
    /// Cancelled through the [`Control`].
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for ResampleError {
    fn from(_: Cancelled) -> Self {
        ResampleError::Cancelled
    }
}

/// Faces using an edge (at most [`MAX_EDGE_FACES`]; `len` counts all, so `len > MAX_EDGE_FACES`
/// marks an edge that is never split).
#[derive(Clone, Copy, Debug, Default)]
struct EdgeFaces {
    faces: [u32; MAX_EDGE_FACES],
    len: u8,
}

impl EdgeFaces {
    fn add(&mut self, f: u32) {
        if (self.len as usize) < MAX_EDGE_FACES {
            self.faces[self.len as usize] = f;
        }
        self.len = self.len.saturating_add(1);
    }
    fn replace(&mut self, from: u32, to: u32) {
        let n = (self.len as usize).min(MAX_EDGE_FACES);
        for f in &mut self.faces[..n] {
            if *f == from {
                *f = to;
            }
        }
    }
}

fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

fn len2(p: &[[f32; 3]], a: u32, b: u32) -> f32 {
    dist2(p[a as usize], p[b as usize])
}

/// Splits longest edges first until `params.max_vertices` vertices or no edge longer than
/// `params.max_edge_length`. See the module docs.
///
/// # Errors
/// [`ResampleError::NoBound`] without a usable bound, [`ResampleError::VertexOutOfRange`] for a
/// bad face, [`ResampleError::Cancelled`] when cancelled.
pub fn resample(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    params: &ResampleParams,
    control: &Control,
) -> Result<Refined, ResampleError> {
    let limit = params.max_edge_length;
    let length_bound = limit.is_finite() && limit > 0.0;
    let count_bound = params.max_vertices >= 1 && params.max_vertices != usize::MAX;
    if !(length_bound || count_bound) || limit.is_nan() || limit <= 0.0 || params.max_vertices == 0
    {
        return Err(ResampleError::NoBound {
            max_vertices: params.max_vertices,
            max_edge_length: limit,
        });
    }
    let n = positions.len();
    for (f, t) in triangles.iter().enumerate() {
        if let Some(&v) = t.iter().find(|&&v| v as usize >= n) {
            return Err(ResampleError::VertexOutOfRange {
                face: f,
                vertex: v,
                count: n,
            });
        }
    }
    let limit2 = if length_bound { limit * limit } else { 0.0 };
    let mut out = Refined {
        positions: positions.to_vec(),
        triangles: triangles.to_vec(),
        parents: Vec::new(),
        input_count: n,
        sources: input_sources(n, triangles),
        triangle_faces: (0..triangles.len() as u32).collect(),
    };
    let planned = params
        .max_vertices
        .saturating_sub(n)
        .min(64 * triangles.len() + 1);
    let stage = control.stage("resample", planned as u64)?;

    let mut edges: HashMap<(u32, u32), EdgeFaces> = HashMap::with_capacity(triangles.len() * 2);
    for (f, t) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a != b {
                edges.entry(key(a, b)).or_default().add(f as u32);
            }
        }
    }
    // Heap of (squared length bits, Reverse(low), Reverse(high)): longest first, ties to the
    // lowest pair. Entries of edges already split are skipped on pop.
    let mut heap: BinaryHeap<(u32, Reverse<u32>, Reverse<u32>)> = edges
        .iter()
        .filter(|(_, e)| (e.len as usize) <= MAX_EDGE_FACES)
        .map(|(&(a, b), _)| (len2(&out.positions, a, b).to_bits(), Reverse(a), Reverse(b)))
        .collect();
    let mut since_tick = 0u64;
    while out.positions.len() < params.max_vertices {
        let Some((bits, Reverse(a), Reverse(b))) = heap.pop() else {
            break;
        };
        let l2 = f32::from_bits(bits);
        if l2 <= limit2 {
            break;
        }
        let Some(ef) = edges.remove(&(a, b)) else {
            continue;
        };
        if ef.len as usize > MAX_EDGE_FACES {
            edges.insert((a, b), ef);
            continue;
        }
        let m = out.positions.len() as u32;
        let (pa, pb) = (out.positions[a as usize], out.positions[b as usize]);
        out.positions
            .push(std::array::from_fn(|k| 0.5 * (pa[k] + pb[k])));
        out.parents.push([a, b]);
        let first = ef.faces[0];
        out.sources.push(midpoint_source(
            triangles,
            out.triangle_faces[first as usize],
            out.sources[a as usize],
            out.sources[b as usize],
        ));
        for &f in &ef.faces[..ef.len as usize] {
            let t = out.triangles[f as usize];
            // Rotate so the split edge is corners 0 → 1 (either direction).
            let k = (0..3)
                .find(|&k| key(t[k], t[(k + 1) % 3]) == (a, b))
                .expect("edge table matches the faces");
            let (u, v, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let g = out.triangles.len() as u32;
            // f becomes (u, m, c); the new face g is (m, v, c).
            out.triangles[f as usize] = [u, m, c];
            out.triangles.push([m, v, c]);
            out.triangle_faces.push(out.triangle_faces[f as usize]);
            if let Some(e) = edges.get_mut(&key(v, c)) {
                e.replace(f, g);
            }
            edges.entry(key(u, m)).or_default().add(f);
            edges.entry(key(m, v)).or_default().add(g);
            let mc = edges.entry(key(m, c)).or_default();
            mc.add(f);
            mc.add(g);
            heap.push((
                len2(&out.positions, m, c).to_bits(),
                Reverse(m.min(c)),
                Reverse(m.max(c)),
            ));
        }
        let half = len2(&out.positions, a, m).to_bits();
        heap.push((half, Reverse(a.min(m)), Reverse(a.max(m))));
        let half = len2(&out.positions, m, b).to_bits();
        heap.push((half, Reverse(m.min(b)), Reverse(m.max(b))));
        since_tick += 1;
        if since_tick == TICK {
            stage.tick(since_tick)?;
            since_tick = 0;
        }
    }
    stage.tick(since_tick)?;
    Ok(out)
}
