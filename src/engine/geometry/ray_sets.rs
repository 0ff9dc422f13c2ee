//! Deterministic ray sets and the shared machinery of the ray-cast shape features
//! ([solid-angle curvature](super::solid_angle), [directional occlusion](super::occlusion),
//! [shape diameter](super::sdf)), after Mertens et al., *Texture Transfer Using Geometry
//! Correlation* (EGSR 2006), §3.2, and Shapira, Shamir, Cohen-Or, *Consistent Mesh Partitioning
//! and Skeletonisation using the Shape Diameter Function* (2008).
//!
//! Directions: spherical Fibonacci sets (González, *Measurement of Areas on a Sphere Using
//! Fibonacci and Latitude–Longitude Lattices*, 2010). Point `i` of `n` on the cap `z ≥ z_min`
//! has `z_i = 1 - (i + ½)(1 - z_min)/n` and azimuth `i · 2π(1 - 1/φ)` (the golden angle), so the
//! points have equal solid-angle weights and are exactly stratified in `z`: any cap or band
//! bounded by planes `z = const` receives its share of the points to within one point. Every
//! feature orients its local set with the pole on the vertex normal, then turns it about the
//! normal by an azimuth drawn from a hash of `(seed, vertex index)` (SplitMix64), so neighbouring
//! vertices do not share aliasing patterns and the result does not depend on the thread count
//! or the order of evaluation.
//!
//! Frames: the branchless orthonormal basis of Duff et al., *Building an Orthonormal Basis,
//! Revisited* (JCGT 2017).
//!
//! Offsets: rays start a small distance off the vertex along its normal (inward for the solid
//! angle and the shape diameter, outward for occlusion), `offset × (mean length of the edges at
//! the vertex)`, so that the start side is known and the incident faces are not hit at `t ≈ 0`.
//!
//! Written by hand: these are a few dozen lines of well-known formulas.

use rayon::prelude::*;

use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::surface::Surface;
use crate::engine::rng::hash_unit;
use crate::engine::spatial::{Bvh, RayHit};

/// Errors of the ray-cast features.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RayFeatureError {
    /// The control was cancelled.
    #[error("cancelled")]
    Cancelled,
    /// A parameter is out of its documented range.
    #[error("parameter {name} = {value} is outside {range}")]
    InvalidParam {
        /// Field name.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// The valid range, in words.
        range: &'static str,
    },
    /// The normals given do not match the vertices.
    #[error("{got} vertex normals given for {expected} vertices")]
    NormalCount {
        /// Vertex count of the surface.
        expected: usize,
        /// Normals given.
        got: usize,
    },
}

impl From<Cancelled> for RayFeatureError {
    fn from(_: Cancelled) -> Self {
        RayFeatureError::Cancelled
    }
}

/// Fails with [`RayFeatureError::InvalidParam`] unless `ok`.
pub(crate) fn check_param(
    ok: bool,
    name: &'static str,
    value: f64,
    range: &'static str,
) -> Result<(), RayFeatureError> {
    if ok {
        Ok(())
    } else {
        Err(RayFeatureError::InvalidParam { name, value, range })
    }
}

/// The golden angle, `2π(1 - 1/φ)`, radians.
const GOLDEN_ANGLE: f64 = 2.399_963_229_728_653;

/// `n` spherical-Fibonacci unit directions on the cap `z ≥ z_min` (`z_min = -1`: the whole
/// sphere), each standing for an equal solid angle `2π(1 - z_min)/n`. See the module docs.
pub fn fibonacci_cap(n: usize, z_min: f32) -> Vec<[f32; 3]> {
    let z_min = z_min.clamp(-1.0, 1.0) as f64;
    (0..n)
        .map(|i| {
            let z = 1.0 - (i as f64 + 0.5) * (1.0 - z_min) / n as f64;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let phi = i as f64 * GOLDEN_ANGLE;
            [(s * phi.cos()) as f32, (s * phi.sin()) as f32, z as f32]
        })
        .collect()
}

/// `n` spherical-Fibonacci unit directions over the whole sphere (see [`fibonacci_cap`]).
pub fn fibonacci_sphere(n: usize) -> Vec<[f32; 3]> {
    fibonacci_cap(n, -1.0)
}

/// An orthonormal frame `(t, b, n)`; local `(x, y, z)` maps to `x t + y b + z n`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// First tangent.
    pub t: [f32; 3],
    /// Second tangent (`n × t`).
    pub b: [f32; 3],
    /// Pole (unit normal).
    pub n: [f32; 3],
}

impl Frame {
    /// The frame with pole `n` (unit length; a zero vector falls back to `+z`), turned about `n`
    /// by `azimuth` radians.
    pub fn new(n: [f32; 3], azimuth: f32) -> Frame {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let n = if len > 0.0 && len.is_finite() {
            n.map(|c| c / len)
        } else {
            [0.0, 0.0, 1.0]
        };
        let sign = 1.0f32.copysign(n[2]);
        let a = -1.0 / (sign + n[2]);
        let b = n[0] * n[1] * a;
        let t0 = [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]];
        let b0 = [b, sign + n[1] * n[1] * a, -n[1]];
        let (s, c) = azimuth.sin_cos();
        let t = std::array::from_fn(|k| c * t0[k] + s * b0[k]);
        let b = std::array::from_fn(|k| -s * t0[k] + c * b0[k]);
        Frame { t, b, n }
    }

    /// Local `(x, y, z)` to world.
    #[inline]
    pub fn to_world(&self, d: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|k| d[0] * self.t[k] + d[1] * self.b[k] + d[2] * self.n[k])
    }
}

/// The frame of vertex `v`: pole on its normal, turned by the hashed azimuth when `randomize`.
pub fn vertex_frame(normal: [f32; 3], seed: u64, v: usize, randomize: bool) -> Frame {
    let azimuth = if randomize {
        (hash_unit(seed, v as u64) * std::f64::consts::TAU) as f32
    } else {
        0.0
    };
    Frame::new(normal, azimuth)
}

/// What every ray feature needs: the BVH, outward vertex normals, unnormalized face normals
/// (for the side of a hit), the mean incident edge length per vertex and the bounding-box
/// diagonal. Build it once to compute several features of the same surface.
#[derive(Clone, Debug)]
pub struct RayContext<'a> {
    /// The surface.
    pub surface: &'a Surface,
    /// BVH over the surface's faces.
    pub bvh: Bvh,
    /// Unit outward vertex normals (`[0; 3]` for vertices without faces).
    pub normals: Vec<[f32; 3]>,
    /// `(b - a) × (c - a)` per face (outward for counter-clockwise winding).
    pub face_normals: Vec<[f32; 3]>,
    /// Mean length of the edges at each vertex, world units (0 for isolated vertices).
    pub edge_scale: Vec<f32>,
    /// Bounding-box diagonal, world units.
    pub diagonal: f32,
}

impl<'a> RayContext<'a> {
    /// Builds the context. `normals`: unit outward vertex normals, or `None` for the
    /// angle-weighted normals of [`Surface::vertex_normals`].
    ///
    /// # Errors
    /// [`RayFeatureError::NormalCount`] when `normals` does not have one entry per vertex.
    pub fn new(
        surface: &'a Surface,
        normals: Option<&[[f32; 3]]>,
    ) -> Result<RayContext<'a>, RayFeatureError> {
        let nv = surface.vertex_count();
        let normals = match normals {
            Some(n) if n.len() != nv => {
                return Err(RayFeatureError::NormalCount {
                    expected: nv,
                    got: n.len(),
                })
            }
            Some(n) => n.to_vec(),
            None => surface.vertex_normals(),
        };
        let bvh = Bvh::build(&surface.positions, &surface.faces);
        let face_normals = surface
            .faces
            .par_iter()
            .map(|f| {
                let [a, b, c] = f.map(|v| surface.positions[v as usize]);
                let e1: [f32; 3] = std::array::from_fn(|k| b[k] - a[k]);
                let e2: [f32; 3] = std::array::from_fn(|k| c[k] - a[k]);
                [
                    e1[1] * e2[2] - e1[2] * e2[1],
                    e1[2] * e2[0] - e1[0] * e2[2],
                    e1[0] * e2[1] - e1[1] * e2[0],
                ]
            })
            .collect();
        let mut sum = vec![0.0f64; nv];
        let mut count = vec![0u32; nv];
        for f in &surface.faces {
            for k in 0..3 {
                let (a, b) = (f[k] as usize, f[(k + 1) % 3] as usize);
                let pa = surface.positions[a];
                let pb = surface.positions[b];
                let len = (0..3)
                    .map(|j| ((pa[j] - pb[j]) as f64).powi(2))
                    .sum::<f64>()
                    .sqrt();
                for v in [a, b] {
                    sum[v] += len;
                    count[v] += 1;
                }
            }
        }
        let edge_scale = sum
            .iter()
            .zip(&count)
            .map(|(&s, &c)| if c > 0 { (s / c as f64) as f32 } else { 0.0 })
            .collect();
        Ok(RayContext {
            surface,
            bvh,
            normals,
            face_normals,
            edge_scale,
            diagonal: surface.diagonal(),
        })
    }

    /// Whether `hit` crosses its face from the back side to the front side (leaves the solid
    /// for outward winding) when travelling along `dir`.
    #[inline]
    pub fn is_exit(&self, hit: &RayHit, dir: [f32; 3]) -> bool {
        let n = self.face_normals[hit.face as usize];
        n[0] * dir[0] + n[1] * dir[1] + n[2] * dir[2] > 0.0
    }

    /// The ray origin for vertex `v`: its position moved by `side × offset × edge_scale[v]`
    /// along its normal (`side` = +1 outward, -1 inward).
    #[inline]
    pub fn origin(&self, v: usize, side: f32, offset: f32) -> [f32; 3] {
        let p = self.surface.positions[v];
        let n = self.normals[v];
        let d = side * offset * self.edge_scale[v];
        std::array::from_fn(|k| p[k] + d * n[k])
    }
}

/// Vertices per work item of [`per_vertex`] (one progress tick each).
const CHUNK: usize = 256;

/// Evaluates `f(v)` (returning `width` values) for every vertex in parallel, in chunks that
/// tick a progress stage named `stage` and stop on cancellation. The output is row-major,
/// `out[v * width + j]`, and independent of the thread count (each vertex is computed alone).
pub fn per_vertex(
    vertex_count: usize,
    width: usize,
    stage: &str,
    control: &Control,
    f: impl Fn(usize, &mut [f32]) + Sync,
) -> Result<Vec<f32>, RayFeatureError> {
    let progress = control.stage(stage, vertex_count as u64)?;
    let mut out = vec![0.0f32; vertex_count * width];
    if width == 0 {
        return Ok(out);
    }
    out.par_chunks_mut(CHUNK * width)
        .enumerate()
        .try_for_each(|(c, chunk)| {
            control.check()?;
            let first = c * CHUNK;
            for (i, row) in chunk.chunks_mut(width).enumerate() {
                f(first + i, row);
            }
            progress.tick((chunk.len() / width) as u64)
        })?;
    Ok(out)
}

/// First hits of rays from every point along every direction, in parallel:
/// `out[p * dirs.len() + d]` is the hit of `points[p] + t dirs[d]`, `t` in `(t_min, t_max]`.
pub fn cast_rays(
    bvh: &Bvh,
    points: &[[f32; 3]],
    dirs: &[[f32; 3]],
    t_min: f32,
    t_max: f32,
) -> Vec<Option<RayHit>> {
    let nd = dirs.len();
    let mut out = vec![None; points.len() * nd];
    if nd == 0 {
        return out;
    }
    out.par_chunks_mut(nd).enumerate().for_each(|(p, row)| {
        for (slot, d) in row.iter_mut().zip(dirs) {
            *slot = bvh.ray_cast(points[p], *d, t_min, t_max);
        }
    });
    out
}
