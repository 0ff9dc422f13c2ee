//! Reference points (§3.1, eq. 1): every correspondence becomes a pair of barycentric
//! combinations of welded surface vertices, one on the source and one on the target.
//!
//! Checks (model-free ones also run at submission, [`check_correspondences`]): at least 3
//! correspondences (`correspondences`), exactly one target place each (ElastiFace needs a
//! one-to-one map, `correspondences[i].target`), places within the snap tolerance of their
//! surface (the shared resolver names the JSON path), and neither end's point set degenerate
//! (all points within `1e-3 ×` their extent of one line): a similarity is not determined by
//! collinear points.

use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::math::{cross, length, sub};

use super::super::correspondence::ResolvedCorrespondence;

/// A point as a barycentric combination of (up to) three welded vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefRow {
    /// Vertex indices (repeated with weight 0 when fewer than three are used).
    pub idx: [u32; 3],
    /// Weights, summing to 1.
    pub w: [f64; 3],
}

impl RefRow {
    /// The point of a face with barycentric coordinates.
    pub fn face(face: [u32; 3], bary: [f32; 3]) -> Self {
        let s: f64 = bary.iter().map(|&b| b as f64).sum();
        Self {
            idx: face,
            w: bary.map(|b| b as f64 / s),
        }
    }

    /// A point on the segment `a → b` at fraction `u`.
    pub fn segment(a: u32, b: u32, u: f64) -> Self {
        Self {
            idx: [a, b, a],
            w: [1.0 - u, u, 0.0],
        }
    }

    /// The position of the point.
    pub fn eval(&self, x: &[[f64; 3]]) -> [f64; 3] {
        let mut out = [0.0; 3];
        for k in 0..3 {
            let p = x[self.idx[k] as usize];
            for c in 0..3 {
                out[c] += self.w[k] * p[c];
            }
        }
        out
    }

    /// `(index + offset, weight)` pairs with nonzero weight, merged by index.
    pub fn entries(&self, offset: usize) -> Vec<(usize, f64)> {
        let mut out: Vec<(usize, f64)> = Vec::with_capacity(3);
        for k in 0..3 {
            if self.w[k] == 0.0 {
                continue;
            }
            let i = self.idx[k] as usize + offset;
            match out.iter_mut().find(|e| e.0 == i) {
                Some(e) => e.1 += self.w[k],
                None => out.push((i, self.w[k])),
            }
        }
        out
    }
}

/// A source/target reference pair with its weight in the point terms.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefPair {
    /// On the source surface.
    pub source: RefRow,
    /// On the target surface.
    pub target: RefRow,
    /// 1 for a hand-placed pair; derived boundary pairs weigh less (see `boundary`).
    pub weight: f64,
    /// The correspondence index for a hand-placed pair, `None` for a derived one.
    pub correspondence: Option<usize>,
}

/// The least number of correspondences ElastiFace accepts.
pub const MIN_CORRESPONDENCES: usize = 3;

/// The checks that need no model: count and one target each.
///
/// # Errors
/// A [`ConstraintsError`] at `correspondences` or `correspondences[i].target`.
pub fn check_correspondences(c: &Constraints) -> Result<(), ConstraintsError> {
    if c.correspondences.len() < MIN_CORRESPONDENCES {
        return Err(ConstraintsError::new(
            "correspondences",
            format!(
                "elastiface needs at least {MIN_CORRESPONDENCES} correspondences, got {}",
                c.correspondences.len()
            ),
        ));
    }
    for (i, corr) in c.correspondences.iter().enumerate() {
        if corr.target.as_slice().len() != 1 {
            return Err(ConstraintsError::new(
                format!("correspondences[{i}].target"),
                format!(
                    "elastiface needs exactly one target place per correspondence (a one-to-one \
                     map), got {}",
                    corr.target.as_slice().len()
                ),
            ));
        }
    }
    Ok(())
}

/// The hand-placed pairs from resolved correspondences on the welded surfaces.
pub fn hand_pairs(
    resolved: &[ResolvedCorrespondence],
    source_faces: &[[u32; 3]],
    target_faces: &[[u32; 3]],
) -> Vec<RefPair> {
    resolved
        .iter()
        .enumerate()
        .map(|(i, r)| RefPair {
            source: RefRow::face(source_faces[r.source.face as usize], r.source.bary),
            target: RefRow::face(target_faces[r.targets[0].face as usize], r.targets[0].bary),
            weight: 1.0,
            correspondence: Some(i),
        })
        .collect()
}

/// Fails when the points lie within `1e-3 ×` their extent of one line (or coincide).
///
/// # Errors
/// A [`ConstraintsError`] at `correspondences` naming the side.
pub fn check_not_collinear(points: &[[f64; 3]], side: &str) -> Result<(), ConstraintsError> {
    let mut far = (0, 0, 0.0);
    for i in 0..points.len() {
        for j in i + 1..points.len() {
            let d = length(sub(points[i], points[j]));
            if d > far.2 {
                far = (i, j, d);
            }
        }
    }
    let (a, b, extent) = far;
    let spread = if extent > 0.0 {
        let axis = sub(points[b], points[a]);
        points
            .iter()
            .map(|p| length(cross(axis, sub(*p, points[a]))) / extent)
            .fold(0.0, f64::max)
    } else {
        0.0
    };
    if extent == 0.0 || spread <= 1e-3 * extent {
        return Err(ConstraintsError::new(
            "correspondences",
            format!(
                "the {side} points of the correspondences are collinear (or coincide): they do \
                 not determine an alignment; place at least 3 points not on one line"
            ),
        ));
    }
    Ok(())
}
