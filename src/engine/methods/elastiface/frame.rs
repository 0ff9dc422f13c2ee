//! The frames of the solve: the initial similarity (§3.1, last paragraph: Horn / Umeyama from
//! the hand-placed reference points) and the scale normalisation.
//!
//! **Why normalise.** The smoothness terms scale as 1/length² relative to the point terms, so
//! the published λ and μ only mean what they mean at one model size. Both aligned meshes are
//! translated so that the target's bounding-box centre is the origin and scaled so that its
//! diagonal is `reference_diagonal` (default 50: a prototype of this pipeline behaved as
//! published with the diagonal at about 40-100 units, collapsed at 4.5 and stopped unfolding
//! above 45 with λ1 = 0.1; 50 is inside the working range for the default weights). The result
//! is scaled back, so scaling both inputs by any factor scales the output by the same factor.

use crate::engine::methods::align::Similarity;

/// Source world → target world (similarity) and target world ↔ solve frame (normalisation).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// The initial similarity.
    pub similarity: Similarity,
    /// The target's bounding-box centre.
    pub centre: [f64; 3],
    /// Solve units per world unit.
    pub scale: f64,
}

impl Frame {
    /// The frame for a target bounding box and the reference diagonal.
    pub fn new(similarity: Similarity, lo: [f64; 3], hi: [f64; 3], reference: f64) -> Self {
        let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
        Self {
            similarity,
            centre: std::array::from_fn(|k| 0.5 * (lo[k] + hi[k])),
            scale: if diag > 0.0 { reference / diag } else { 1.0 },
        }
    }

    /// A target world point in the solve frame.
    pub fn target_to_solve(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| (p[k] - self.centre[k]) * self.scale)
    }

    /// A source world point in the solve frame (aligned, then normalised).
    pub fn source_to_solve(&self, p: [f64; 3]) -> [f64; 3] {
        self.target_to_solve(self.similarity.apply(p))
    }

    /// A solve-frame point in the target's world frame.
    pub fn solve_to_target(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|k| p[k] / self.scale + self.centre[k])
    }

    /// A target-frame point back in the source's world frame (the inverse similarity).
    pub fn target_to_source(&self, q: [f64; 3]) -> [f64; 3] {
        let s = &self.similarity;
        let d: [f64; 3] = std::array::from_fn(|k| q[k] - s.translation[k]);
        std::array::from_fn(|c| (0..3).map(|r| s.rotation[r][c] * d[r]).sum::<f64>() / s.scale)
    }
}
