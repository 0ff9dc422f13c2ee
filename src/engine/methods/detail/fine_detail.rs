//! Where the texture-space refinement (Berkiten et al. 2017, §3.3.2; [`super::refine`]) reads
//! the source's full-resolution detail: rays to a detailed mesh ([`RayDetail`]) or a
//! displacement map read at the closest source point ([`SampledDetail`]). Each gives the
//! displacement and its tangential surface gradient at a point of the source's base.
//!
//! Written by hand: ray and closest-point queries on the crate's BVH.

use super::displacement::area_weighted_normals;
use super::refine::{frame, FineDetail};
use crate::engine::math::{add, dot, normalize, scale, sub, to_f32};
use crate::engine::mesh::Surface;
use crate::engine::spatial::Bvh;

/// The detail of a detailed mesh: the signed distance along `n` to it (as
/// [`super::displacement::displacement`] measures the levels), the hit nearest to the predicted
/// value within a window.
pub struct RayDetail<'a> {
    detailed: &'a Surface,
    bvh: Bvh,
    normals: Vec<[f64; 3]>,
    max_distance: f64,
    edge: f64,
    window: f64,
}

impl<'a> RayDetail<'a> {
    /// Casts against `detailed` up to `max_distance` both ways, and only within `window` of the
    /// predicted value (the refinement bounds its residual by one finest edge: pass that edge).
    pub fn new(detailed: &'a Surface, max_distance: f64, window: f64) -> Self {
        Self {
            detailed,
            bvh: Bvh::build(&detailed.positions, &detailed.faces),
            normals: area_weighted_normals(detailed),
            max_distance,
            edge: super::hierarchy::mean_edge_length(detailed),
            window,
        }
    }
}

/// The barycentric interpolation of per-vertex unit vectors over face `f`, normalised.
fn interpolated(s: &Surface, values: &[[f64; 3]], f: usize, b: [f32; 3]) -> [f64; 3] {
    let corners = s.faces[f];
    normalize((0..3).fold([0.0; 3], |acc, k| {
        add(acc, scale(values[corners[k] as usize], b[k] as f64))
    }))
}

/// The tangential part of `g` for the unit normal `n`.
pub(super) fn tangential(g: [f64; 3], n: [f64; 3]) -> [f64; 3] {
    sub(g, scale(n, dot(g, n)))
}

impl FineDetail for RayDetail<'_> {
    fn at(&self, p: [f64; 3], n: [f64; 3], predicted: f64) -> Option<(f64, [f64; 3])> {
        let d_max = self.max_distance;
        // The segment [predicted − window, predicted + window] within [−d_max, d_max].
        let lo = (predicted - self.window).max(-d_max);
        let hi = (predicted + self.window).min(d_max);
        if lo >= hi {
            return None;
        }
        let origin = to_f32(add(p, scale(n, lo)));
        let mut best: Option<(f64, u32, [f32; 3])> = None;
        self.bvh
            .ray_for_each_hit(origin, to_f32(n), 0.0, (hi - lo) as f32, |hit| {
                let t = hit.t as f64 + lo;
                if best.is_none_or(|b| (t - predicted).abs() < (b.0 - predicted).abs()) {
                    best = Some((t, hit.face, hit.bary));
                }
            });
        let (t, face, bary) = best?;
        let nh = interpolated(self.detailed, &self.normals, face as usize, bary);
        let c = dot(nh, n);
        // n_h ∝ n − ∇d: ∇d = −(n_h − (n_h·n) n) / (n_h·n); a hit surface steeper than ~84°
        // gives no usable slope.
        let gradient = match c > 0.1 {
            true => scale(tangential(nh, n), -1.0 / c),
            false => [0.0; 3],
        };
        Some((t, gradient))
    }

    fn sampling(&self) -> f64 {
        self.edge
    }
}

/// The detail of a displacement map, read by `value` at the closest source point; the gradient by
/// central differences at `±step` along a tangent frame.
pub struct SampledDetail<F: Fn([f32; 3]) -> Option<f64> + Sync> {
    /// The displacement closest to a point.
    pub value: F,
    /// Difference step (world units).
    pub step: f64,
    /// World size of the map's texels.
    pub texel: f64,
}

impl<F: Fn([f32; 3]) -> Option<f64> + Sync> FineDetail for SampledDetail<F> {
    fn at(&self, p: [f64; 3], n: [f64; 3], _predicted: f64) -> Option<(f64, [f64; 3])> {
        let d = (self.value)(to_f32(p))?;
        let (u, v) = frame(n);
        let mut g = [0.0; 3];
        for e in [u, v] {
            let plus = (self.value)(to_f32(add(p, scale(e, self.step))));
            let minus = (self.value)(to_f32(sub(p, scale(e, self.step))));
            if let (Some(a), Some(b)) = (plus, minus) {
                g = add(g, scale(e, (a - b) / (2.0 * self.step)));
            }
        }
        Some((d, g))
    }

    fn sampling(&self) -> f64 {
        self.texel
    }
}
