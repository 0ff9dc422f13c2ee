//! The quality figures of the report: Hausdorff distance between the fitted source and the
//! target on area samples, flipped triangles, and correspondence residuals. Distances are
//! relative to the target's bounding-box diagonal.
//!
//! - **Samples**: every vertex, plus four points per face (the centroid and the three points with
//!   barycentric coordinates (2/3, 1/6, 1/6) and permutations), so a long triangle that bridges a
//!   gap is seen although its corners lie on the surface.
//! - **Flipped**: a fitted source triangle whose normal points against the target's face normal
//!   at the closest point to its centroid (negative dot product); count and area fraction.
//!
//! The closest-point searches reuse the stages' hierarchies and run in runs of [`RUN`] samples
//! (consecutive samples lie close together), each search bounded by the distance to the
//! previous sample's face: the exact answers, found with less traversal.

use rayon::prelude::*;

use crate::engine::math::{cross, dot, length, sub};
use crate::engine::spatial::{Bvh, ClosestHit};

use super::refs::RefPair;
use super::register::near_bound;

/// One direction of the Hausdorff distance.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Directed {
    /// Largest sample distance / target diagonal.
    pub max: f64,
    /// Mean sample distance / target diagonal.
    pub mean: f64,
    /// Samples measured.
    pub samples: usize,
}

/// The Hausdorff distance both ways.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Hausdorff {
    /// From the fitted source to the target (what matters when the target covers more).
    pub source_to_target: Directed,
    /// From the target to the fitted source.
    pub target_to_source: Directed,
    /// The larger of the two maxima.
    pub max: f64,
}

/// Flipped triangles of the fitted source.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Flipped {
    /// Triangles.
    pub count: usize,
    /// Their area over the fitted source's area.
    pub area_fraction: f64,
}

/// Correspondence residuals of the hand-placed pairs.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Residuals {
    /// RMS `|r^s − r^t|` / target diagonal.
    pub rms: f64,
    /// Largest.
    pub max: f64,
}

/// A mesh in the metric's frame.
pub struct MeshRef<'a> {
    /// Positions.
    pub x: &'a [[f64; 3]],
    /// Faces.
    pub faces: &'a [[u32; 3]],
    /// Hierarchy over `x` (as f32) and `faces` (the one the stages already built, when they did).
    pub bvh: &'a Bvh,
}

/// Samples per warm-started run of closest-point searches (each run in one task).
const RUN: usize = 256;

impl MeshRef<'_> {
    /// The closest point to `q`, the search bounded by the distance to `near` (a face of this
    /// mesh close to `q`, e.g. the previous sample's hit): the same answer as the unbounded
    /// search (see [`near_bound`]).
    fn closest(&self, q: [f32; 3], near: Option<u32>) -> Option<ClosestHit> {
        let bound = near
            .and_then(|f| self.faces.get(f as usize))
            .map_or(f32::INFINITY, |f| {
                near_bound(q, f.map(|v| self.x[v as usize].map(|c| c as f32)))
            });
        self.bvh
            .closest_point(q, bound)
            .or_else(|| self.bvh.closest_point(q, f32::INFINITY))
    }

    fn samples(&self) -> Vec<[f64; 3]> {
        let mut out = self.x.to_vec();
        const B: [[f64; 3]; 4] = [
            [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0],
            [2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0],
            [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
            [1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
        ];
        for f in self.faces {
            let p = f.map(|v| self.x[v as usize]);
            for b in B {
                out.push(std::array::from_fn(|d| {
                    b[0] * p[0][d] + b[1] * p[1][d] + b[2] * p[2][d]
                }));
            }
        }
        out
    }

    fn normal(&self, f: usize) -> [f64; 3] {
        let p = self.faces[f].map(|v| self.x[v as usize]);
        cross(sub(p[1], p[0]), sub(p[2], p[0]))
    }
}

fn directed(from: &MeshRef<'_>, to: &MeshRef<'_>, diagonal: f64) -> Directed {
    let samples = from.samples();
    let d: Vec<f64> = samples
        .par_chunks(RUN)
        .flat_map_iter(|run| {
            let mut near = None;
            run.iter().map(move |p| {
                let hit = to.closest(p.map(|c| c as f32), near);
                near = hit.map(|h| h.face);
                hit.map_or(f64::INFINITY, |h| (h.distance_squared as f64).sqrt())
            })
        })
        .collect();
    Directed {
        max: d.iter().copied().fold(0.0, f64::max) / diagonal,
        mean: d.iter().sum::<f64>() / d.len().max(1) as f64 / diagonal,
        samples: d.len(),
    }
}

/// The Hausdorff distance between `fitted` and `target`, relative to `diagonal`.
pub fn hausdorff(fitted: &MeshRef<'_>, target: &MeshRef<'_>, diagonal: f64) -> Hausdorff {
    let s2t = directed(fitted, target, diagonal);
    let t2s = directed(target, fitted, diagonal);
    Hausdorff {
        source_to_target: s2t,
        target_to_source: t2s,
        max: s2t.max.max(t2s.max),
    }
}

/// Flipped triangles of `fitted` against `target` (see the module docs).
pub fn flipped(fitted: &MeshRef<'_>, target: &MeshRef<'_>) -> Flipped {
    let faces: Vec<usize> = (0..fitted.faces.len()).collect();
    let per_face: Vec<(bool, f64)> = faces
        .par_chunks(RUN)
        .flat_map_iter(|run| {
            let mut near = None;
            run.iter().map(move |&f| {
                let n = fitted.normal(f);
                let area = 0.5 * length(n);
                let p = fitted.faces[f].map(|v| fitted.x[v as usize]);
                let c: [f64; 3] = std::array::from_fn(|d| (p[0][d] + p[1][d] + p[2][d]) / 3.0);
                let hit = target.closest(c.map(|x| x as f32), near);
                near = hit.map(|h| h.face);
                let flip = hit.is_some_and(|h| dot(n, target.normal(h.face as usize)) < 0.0);
                (flip, area)
            })
        })
        .collect();
    let total: f64 = per_face.iter().map(|x| x.1).sum();
    let bad: f64 = per_face.iter().filter(|x| x.0).map(|x| x.1).sum();
    Flipped {
        count: per_face.iter().filter(|x| x.0).count(),
        area_fraction: if total > 0.0 { bad / total } else { 0.0 },
    }
}

/// Residuals of the hand-placed pairs between the fitted source and the target.
pub fn residuals(
    pairs: &[RefPair],
    fitted: &[[f64; 3]],
    target: &[[f64; 3]],
    diagonal: f64,
) -> Residuals {
    let d: Vec<f64> = pairs
        .iter()
        .filter(|p| p.correspondence.is_some())
        .map(|p| length(sub(p.source.eval(fitted), p.target.eval(target))) / diagonal)
        .collect();
    Residuals {
        rms: (d.iter().map(|x| x * x).sum::<f64>() / d.len().max(1) as f64).sqrt(),
        max: d.iter().copied().fold(0.0, f64::max),
    }
}
