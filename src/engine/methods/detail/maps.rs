//! The per-texel values of `detail`'s two maps (see [`super::outputs`]): the displacement and
//! the tangent-space normal of the finest target level at a texel's point, refined by the
//! texture-space residual (§3.3.2, [`Refinement`]) where it applies.
//!
//! Both maps come from one sample per texel ([`MapFields`], a
//! [`crate::engine::methods::output::SurfaceFields`] with two outputs, baked by the shared
//! writer's [`crate::engine::methods::output::write_fields`]): the texel's point is located on
//! the finest level once and the refinement's residual (value and gradient: about two source
//! reads) is computed once, then written into both. Baking the maps as two single fields cost
//! the closest point and the residual twice per texel (7.3 s of a 14.4 s job at 2048²); caching
//! the residual per texel between the passes would have held about 160 MB at 2048². The
//! values are the same as the two single fields gave: the same point, face and residual, the
//! same arithmetic.
//!
//! - Displacement (output [`DISPLACEMENT`]): the finest level's interpolated displacement plus
//!   the residual, as `(d − offset) / scale` for the 16-bit texture.
//! - Normal (output [`NORMAL`]): the texel's own shading normal `N` tilted by the displacement's
//!   surface gradient, `n = normalize(N − ∇d)` (first order in `d`; the gradient per finest
//!   vertex is the area-weighted mean of its faces' constant gradients, interpolated, plus the
//!   residual's), expressed in the texel's frame: with `T`, `B = w · N × T`, `N` interpolated
//!   from the primitive's vertices as written (world space, as a viewer builds them), the stored
//!   `c` is `[T B N]⁻¹ n` normalised and mapped to `0.5 c + 0.5`. A primitive without frames
//!   has no normal value (its texels are padded), but still a displacement.

use super::refine::Refinement;
use crate::engine::math::{add, cross, dot, normalize, scale, sub, to_f64};
use crate::engine::mesh::Surface;
use crate::engine::methods::output::{SurfaceFields, SurfaceSample};
use crate::engine::spatial::Bvh;

/// Output index of the normal map in [`MapFields`].
pub(super) const NORMAL: usize = 0;
/// Output index of the displacement texture in [`MapFields`].
pub(super) const DISPLACEMENT: usize = 1;

/// The finest level, located by closest point.
pub(super) struct Finest<'a> {
    surface: &'a Surface,
    bvh: Bvh,
    displacement: &'a [f64],
    /// Surface gradient of the displacement per vertex (area-weighted mean of the faces'
    /// constant gradients), world units per world unit.
    gradients: Vec<[f64; 3]>,
}

impl<'a> Finest<'a> {
    /// The finest level with its displacement per vertex.
    pub(super) fn new(surface: &'a Surface, displacement: &'a [f64]) -> Self {
        Finest {
            surface,
            bvh: Bvh::build(&surface.positions, &surface.faces),
            displacement,
            gradients: vertex_gradients(surface, displacement),
        }
    }

    /// Face and barycentric coordinates of the closest point to `p`.
    fn locate(&self, p: [f32; 3], hint: Option<u32>) -> Option<(usize, [f64; 3])> {
        let mut bound = f32::INFINITY;
        if let Some(h) = hint {
            bound = self.surface.hint_bound(h as usize, p);
        }
        let hit = self.bvh.closest_point(p, bound)?;
        Some((hit.face as usize, hit.bary.map(|b| b as f64)))
    }

    fn displacement_at(&self, f: usize, b: [f64; 3]) -> f64 {
        let face = self.surface.faces[f];
        (0..3)
            .map(|k| b[k] * self.displacement[face[k] as usize])
            .sum()
    }

    fn gradient_at(&self, f: usize, b: [f64; 3]) -> [f64; 3] {
        let face = self.surface.faces[f];
        (0..3).fold([0.0; 3], |acc, k| {
            add(acc, scale(self.gradients[face[k] as usize], b[k]))
        })
    }

    /// The unit normal of the surface displaced by the displacement, at a point whose undisplaced
    /// unit normal is `n`: `n − ∇d` with the gradient's tangential part (first order in `d`).
    /// `extra` is added to the interpolated gradient (the refinement's residual).
    fn displaced_normal(&self, f: usize, b: [f64; 3], n: [f64; 3], extra: [f64; 3]) -> [f64; 3] {
        let g = add(self.gradient_at(f, b), extra);
        let tangential = sub(g, scale(n, dot(g, n)));
        normalize(sub(n, tangential))
    }
}

/// Per vertex, the area-weighted mean of the constant surface gradients of the piecewise-linear
/// `values` over the incident faces.
pub(super) fn vertex_gradients(s: &Surface, values: &[f64]) -> Vec<[f64; 3]> {
    let mut sum = vec![[0.0; 3]; s.vertex_count()];
    let mut area = vec![0.0; s.vertex_count()];
    for f in &s.faces {
        let p = f.map(|v| to_f64(s.positions[v as usize]));
        let n2 = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        let a2 = dot(n2, n2);
        if a2 <= 0.0 {
            continue;
        }
        // ∇φ_i = (n × e_i) / (2A) with e_i the edge opposite corner i; here n2 = 2A n.
        let mut g = [0.0; 3];
        for i in 0..3 {
            let e = sub(p[(i + 2) % 3], p[(i + 1) % 3]);
            g = add(g, scale(cross(n2, e), values[f[i] as usize] / a2));
        }
        let w = a2.sqrt();
        for &v in f {
            sum[v as usize] = add(sum[v as usize], scale(g, w));
            area[v as usize] += w;
        }
    }
    sum.iter()
        .zip(&area)
        .map(|(g, a)| {
            if *a > 0.0 {
                scale(*g, 1.0 / a)
            } else {
                [0.0; 3]
            }
        })
        .collect()
}

/// World-space vertex frames of one primitive as written (its own, or its atlas copy's):
/// unit normal and tangent with handedness, and the triangles over those vertices.
pub(super) struct Frames {
    pub(super) normals: Vec<[f64; 3]>,
    pub(super) tangents: Vec<[f64; 4]>,
    pub(super) triangles: Vec<[u32; 3]>,
}

/// Solves `[t b n] c = x` (columns) by Cramer's rule; `None` when singular.
fn solve3(t: [f64; 3], b: [f64; 3], n: [f64; 3], x: [f64; 3]) -> Option<[f64; 3]> {
    let det = dot(t, cross(b, n));
    if det.abs() < 1e-12 {
        return None;
    }
    Some([
        dot(x, cross(b, n)) / det,
        dot(t, cross(x, n)) / det,
        dot(t, cross(b, x)) / det,
    ])
}

/// Both maps' values per texel (see the module doc).
pub(super) struct MapFields<'a> {
    pub(super) finest: &'a Finest<'a>,
    pub(super) refinement: Option<&'a Refinement<'a>>,
    /// Per primitive: its frames when it receives the normal map.
    pub(super) frames: Vec<Option<Frames>>,
    /// The displacement texture's `d = offset + scale · value`.
    pub(super) offset: f64,
    /// See `offset`.
    pub(super) scale: f64,
}

impl MapFields<'_> {
    /// The encoded tangent-space normal at `at`, located at `bary` in finest face `f`, with the
    /// refinement's gradient `extra`; `None` when the primitive has no frames.
    fn normal(
        &self,
        at: &SurfaceSample,
        f: usize,
        bary: [f64; 3],
        extra: [f64; 3],
    ) -> Option<[f32; 4]> {
        let frames = self.frames.get(at.primitive)?.as_ref()?;
        let tri = *frames.triangles.get(at.triangle)?;
        let w = at.barycentric.map(|x| x as f64);
        let mut n = [0.0; 3];
        let mut t = [0.0; 3];
        for k in 0..3 {
            n = add(n, scale(frames.normals[tri[k] as usize], w[k]));
            let tk = frames.tangents[tri[k] as usize];
            t = add(t, scale([tk[0], tk[1], tk[2]], w[k]));
        }
        let handedness = frames.tangents[tri[0] as usize][3];
        let b = scale(cross(n, t), handedness);
        let target = self.finest.displaced_normal(f, bary, normalize(n), extra);
        let c = normalize(solve3(t, b, n, target).unwrap_or([0.0, 0.0, 1.0]));
        let mut out = [0.0f32; 4];
        for k in 0..3 {
            out[k] = (0.5 * c[k] + 0.5) as f32;
        }
        Some(out)
    }
}

impl SurfaceFields for MapFields<'_> {
    fn sample(
        &self,
        at: &SurfaceSample,
        hint: Option<u32>,
        out: &mut [Option<[f32; 4]>],
    ) -> Option<u32> {
        let (f, b) = self.finest.locate(at.position, hint)?;
        let residual = self.refinement.and_then(|r| r.at(f, b));
        out[NORMAL] = self.normal(at, f, b, residual.map_or([0.0; 3], |r| r.1));
        let mut d = self.finest.displacement_at(f, b);
        if let Some((r, _)) = residual {
            d += r;
        }
        out[DISPLACEMENT] = Some([((d - self.offset) / self.scale) as f32, 0.0, 0.0, 0.0]);
        Some(f as u32)
    }
}
