//! Best similarity transform (scale, rotation, translation) between corresponding point sets,
//! used to align a source to its target from user correspondences before projection.
//!
//! Rotation by Horn's closed form with unit quaternions (Horn 1987, "Closed-form solution of
//! absolute orientation using unit quaternions", section 4): the optimal rotation is the
//! eigenvector of the largest eigenvalue of a symmetric 4x4 matrix built from the cross-covariance.
//! The eigenvector is found with cyclic Jacobi rotations (a 4x4 symmetric matrix needs no library).
//! Scale is Umeyama's least-squares scale (Umeyama 1991, eq. 42): s = Σ b'·R a' / Σ |a'|², so the
//! transform minimizes Σ |s R a + t − b|². Computed in f64.
//!
//! With one pair the result is a translation; with two pairs the rotation about the line through
//! them is not determined and the one nearest to the identity-free solution Jacobi finds is used.

use crate::engine::math::dist2;

/// A similarity transform p ↦ s R p + t.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Similarity {
    /// Uniform scale (> 0).
    pub scale: f64,
    /// Rotation matrix, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Translation.
    pub translation: [f64; 3],
}

impl Default for Similarity {
    fn default() -> Self {
        Self {
            scale: 1.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        }
    }
}

impl Similarity {
    /// Applies the transform to a point.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        let mut out = [0.0; 3];
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.scale * (r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2])
                + self.translation[i];
        }
        out
    }

    /// Root-mean-square residual over the pairs.
    pub fn rms_error(&self, from: &[[f64; 3]], to: &[[f64; 3]]) -> f64 {
        if from.is_empty() {
            return 0.0;
        }
        let sum: f64 = from
            .iter()
            .zip(to)
            .map(|(a, b)| dist2(self.apply(*a), *b))
            .sum();
        (sum / from.len() as f64).sqrt()
    }
}

fn centroid(points: &[[f64; 3]]) -> [f64; 3] {
    let mut c = [0.0; 3];
    for p in points {
        for k in 0..3 {
            c[k] += p[k];
        }
    }
    c.map(|x| x / points.len() as f64)
}

/// The similarity transform that best maps `from[i]` onto `to[i]` in the least-squares sense.
/// Returns the identity for empty input. `from` and `to` must have equal length (extra entries of
/// the longer one are ignored).
pub fn best_similarity(from: &[[f64; 3]], to: &[[f64; 3]]) -> Similarity {
    let n = from.len().min(to.len());
    let (from, to) = (&from[..n], &to[..n]);
    if n == 0 {
        return Similarity::default();
    }
    let ca = centroid(from);
    let cb = centroid(to);
    if n == 1 {
        return Similarity {
            translation: [cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]],
            ..Similarity::default()
        };
    }
    // Cross-covariance S[i][j] = Σ a'_i b'_j.
    let mut s = [[0.0f64; 3]; 3];
    let mut norm_a = 0.0;
    for (a, b) in from.iter().zip(to) {
        let a = [a[0] - ca[0], a[1] - ca[1], a[2] - ca[2]];
        let b = [b[0] - cb[0], b[1] - cb[1], b[2] - cb[2]];
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
        }
        norm_a += a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
    }
    if norm_a <= f64::MIN_POSITIVE {
        return Similarity {
            translation: [cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]],
            ..Similarity::default()
        };
    }
    let (sxx, sxy, sxz) = (s[0][0], s[0][1], s[0][2]);
    let (syx, syy, syz) = (s[1][0], s[1][1], s[1][2]);
    let (szx, szy, szz) = (s[2][0], s[2][1], s[2][2]);
    let nmat = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let q = largest_eigenvector(nmat);
    let rotation = quaternion_to_matrix(q);
    // Umeyama scale: Σ b'·(R a') / Σ|a'|² = trace(R S^T... ) computed directly.
    let mut num = 0.0;
    for (a, b) in from.iter().zip(to) {
        let a = [a[0] - ca[0], a[1] - ca[1], a[2] - ca[2]];
        let b = [b[0] - cb[0], b[1] - cb[1], b[2] - cb[2]];
        for i in 0..3 {
            num += b[i] * (rotation[i][0] * a[0] + rotation[i][1] * a[1] + rotation[i][2] * a[2]);
        }
    }
    let scale = if num > 0.0 { num / norm_a } else { 1.0 };
    let mut translation = [0.0; 3];
    for i in 0..3 {
        let rc = rotation[i][0] * ca[0] + rotation[i][1] * ca[1] + rotation[i][2] * ca[2];
        translation[i] = cb[i] - scale * rc;
    }
    Similarity {
        scale,
        rotation,
        translation,
    }
}

/// Eigenvector of the largest eigenvalue of a symmetric 4x4 matrix (cyclic Jacobi).
fn largest_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..64 {
        let off: f64 = (0..4)
            .flat_map(|i| ((i + 1)..4).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..4 {
            for q in (p + 1)..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..4 {
                    let akp = a[k][p];
                    let akq = a[k][q];
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..4 {
                    let apk = a[p][k];
                    let aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let vp = row[p];
                    let vq = row[q];
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4).fold(0, |b, i| if a[i][i] > a[b][b] { i } else { b });
    let mut q = [v[0][best], v[1][best], v[2][best], v[3][best]];
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    q.iter_mut().for_each(|x| *x /= n);
    if q[0] < 0.0 {
        q.iter_mut().for_each(|x| *x = -*x);
    }
    q
}

/// Rotation matrix (row-major) of a unit quaternion (w, x, y, z).
fn quaternion_to_matrix(q: [f64; 4]) -> [[f64; 3]; 3] {
    let [w, x, y, z] = q;
    [
        [
            w * w + x * x - y * y - z * z,
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            w * w - x * x + y * y - z * z,
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            w * w - x * x - y * y + z * z,
        ],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rot_axis_angle(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
        let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
        let (x, y, z) = (axis[0] / n, axis[1] / n, axis[2] / n);
        let h = angle / 2.0;
        quaternion_to_matrix([h.cos(), x * h.sin(), y * h.sin(), z * h.sin()])
    }

    #[test]
    fn recovers_a_known_similarity_from_four_points() {
        let truth = Similarity {
            scale: 2.5,
            rotation: rot_axis_angle([0.3, -1.0, 0.4], 2.1),
            translation: [10.0, -3.0, 0.5],
        };
        let from = [
            [0.0, 0.0, 0.0],
            [1.0, 0.2, 0.0],
            [0.1, 1.0, 0.3],
            [0.2, -0.4, 1.0],
        ];
        let to: Vec<[f64; 3]> = from.iter().map(|p| truth.apply(*p)).collect();
        let est = best_similarity(&from, &to);
        assert!((est.scale - 2.5).abs() < 1e-9, "{est:?}");
        for i in 0..3 {
            for j in 0..3 {
                assert!(
                    (est.rotation[i][j] - truth.rotation[i][j]).abs() < 1e-9,
                    "{est:?}"
                );
            }
        }
        assert!(est.rms_error(&from, &to) < 1e-9);
    }

    #[test]
    fn handles_a_half_turn_and_noise() {
        let truth = Similarity {
            scale: 0.5,
            rotation: rot_axis_angle([0.0, 1.0, 0.0], std::f64::consts::PI),
            translation: [1.0, 2.0, 3.0],
        };
        let from: Vec<[f64; 3]> = (0..20)
            .map(|i| {
                let t = i as f64;
                [t.sin() * 3.0, (t * 0.7).cos(), t * 0.1]
            })
            .collect();
        let to: Vec<[f64; 3]> = from
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let q = truth.apply(*p);
                [q[0] + 1e-3 * (i as f64).sin(), q[1], q[2]]
            })
            .collect();
        let est = best_similarity(&from, &to);
        assert!((est.scale - 0.5).abs() < 1e-3);
        assert!(est.rms_error(&from, &to) < 2e-3);
    }

    #[test]
    fn degenerate_inputs_do_not_fail() {
        assert_eq!(best_similarity(&[], &[]), Similarity::default());
        let one = best_similarity(&[[1.0, 1.0, 1.0]], &[[2.0, 3.0, 4.0]]);
        assert_eq!(one.apply([1.0, 1.0, 1.0]), [2.0, 3.0, 4.0]);
        let same = best_similarity(&[[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], &[[0.0; 3], [0.0; 3]]);
        assert!(same.scale.is_finite());
        let two = best_similarity(&[[0.0; 3], [1.0, 0.0, 0.0]], &[[0.0; 3], [0.0, 2.0, 0.0]]);
        assert!(two.rms_error(&[[0.0; 3], [1.0, 0.0, 0.0]], &[[0.0; 3], [0.0, 2.0, 0.0]]) < 1e-9);
    }
}
