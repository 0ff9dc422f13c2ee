//! Small fixed-size vector helpers on `[T; 3]`, for `T` = `f32` or `f64` (see [`Real`]), and
//! [`Affine`], a node transform as a 3x4 map.
//!
//! Every helper spells its arithmetic out component by component, in one fixed order (`dot` is
//! `a0·b0 + a1·b1 + a2·b2`, left to right), so a caller gets the same bits whichever module it is
//! in. Change that order and the engine's outputs change.

use std::ops::{Add, Div, Mul, Sub};

/// The scalar types the helpers work on: `f32` and `f64`.
pub trait Real:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
{
    /// `0`.
    const ZERO: Self;
    /// The square root.
    fn sqrt(self) -> Self;
    /// Neither infinite nor NaN.
    fn is_finite(self) -> bool;
    /// `self` to the integer power `n`.
    fn powi(self, n: i32) -> Self;
}

impl Real for f32 {
    const ZERO: f32 = 0.0;
    #[inline(always)]
    fn sqrt(self) -> f32 {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    #[inline(always)]
    fn powi(self, n: i32) -> f32 {
        f32::powi(self, n)
    }
}

impl Real for f64 {
    const ZERO: f64 = 0.0;
    #[inline(always)]
    fn sqrt(self) -> f64 {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    #[inline(always)]
    fn powi(self, n: i32) -> f64 {
        f64::powi(self, n)
    }
}

/// `a + b`.
#[inline(always)]
pub fn add<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a - b`.
#[inline(always)]
pub fn sub<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a · s`.
#[inline(always)]
pub fn scale<T: Real>(a: [T; 3], s: T) -> [T; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a · b`.
#[inline(always)]
pub fn dot<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`.
#[inline(always)]
pub fn cross<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `|a|`, as `sqrt(a · a)`.
#[inline(always)]
pub fn length<T: Real>(a: [T; 3]) -> T {
    dot(a, a).sqrt()
}

/// `|a - b|²`, as `(a0 - b0)² + (a1 - b1)² + (a2 - b2)²` with `powi(2)`.
#[inline(always)]
pub fn dist2<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// `a / |a|`; `[0, 0, 0]` where `|a|` is zero, infinite or NaN.
#[inline]
pub fn normalize<T: Real>(a: [T; 3]) -> [T; 3] {
    let l = length(a);
    if l > T::ZERO && l.is_finite() {
        [a[0] / l, a[1] / l, a[2] / l]
    } else {
        [T::ZERO; 3]
    }
}

/// The unit normal of triangle `(a, b, c)` from its winding, `(b - a) × (c - a)` normalized;
/// `[0, 0, 0]` for a triangle of zero area (see [`normalize`]).
#[inline]
pub fn normal_of<T: Real>(a: [T; 3], b: [T; 3], c: [T; 3]) -> [T; 3] {
    normalize(cross(sub(b, a), sub(c, a)))
}

/// `p` rounded to `f32`, component by component.
#[inline(always)]
pub fn to_f32(p: [f64; 3]) -> [f32; 3] {
    [p[0] as f32, p[1] as f32, p[2] as f32]
}

/// `p` widened to `f64`, component by component (exact).
#[inline(always)]
pub fn to_f64(p: [f32; 3]) -> [f64; 3] {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn helpers_on_both_widths() {
        assert_eq!(cross([1.0f32, 0.0, 0.0], [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]);
        assert_eq!(cross([1.0f64, 0.0, 0.0], [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]);
        assert_eq!(dot([1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]), 32.0);
        assert_eq!(length([3.0f64, 4.0, 0.0]), 5.0);
        assert_eq!(dist2([1.0f32, 1.0, 1.0], [2.0, 3.0, 4.0]), 14.0);
        assert_eq!(normalize([0.0f64, 0.0, 2.0]), [0.0, 0.0, 1.0]);
        assert_eq!(normalize([0.0f32; 3]), [0.0; 3]);
        assert_eq!(normalize([f64::INFINITY, 0.0, 0.0]), [0.0; 3]);
        let n = normal_of([0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(n, [0.0, 0.0, 1.0]);
        assert_eq!(normal_of([1.0f32; 3], [1.0; 3], [1.0; 3]), [0.0; 3]);
        assert_eq!(to_f64(to_f32([0.5, 1.5, -2.0])), [0.5, 1.5, -2.0]);
        assert_eq!(
            add(scale([1.0f32, 2.0, 3.0], 2.0), [1.0; 3]),
            [3.0, 5.0, 7.0]
        );
        assert_eq!(sub([1.0f64, 2.0, 3.0], [1.0; 3]), [0.0, 1.0, 2.0]);
    }
}

/// A 3x4 affine map stored row-major (`[linear | translation]`): a glTF node's local-to-world
/// transform and its inverse (ElastiFace's write-back, `detail`'s outputs).
#[derive(Clone, Copy, Debug)]
pub struct Affine {
    m: [[f64; 3]; 3],
    t: [f64; 3],
}

impl Affine {
    /// From a column-major 4x4 matrix (glTF `matrix`, [`crate::engine::asset::MeshInstance`]).
    pub fn of_column_major(w: &[[f64; 4]; 4]) -> Self {
        Self {
            m: std::array::from_fn(|r| std::array::from_fn(|c| w[c][r])),
            t: [w[3][0], w[3][1], w[3][2]],
        }
    }

    /// The inverse map, `None` when the linear part is singular.
    pub fn inverse(&self) -> Option<Self> {
        let a = &self.m;
        let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
        if det.abs() < 1e-300 || !det.is_finite() {
            return None;
        }
        let c = |r: usize, k: usize| {
            let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
            let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
            a[r1][k1] * a[r2][k2] - a[r1][k2] * a[r2][k1]
        };
        let m: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|k| c(k, r) / det));
        let t = std::array::from_fn(|r| -(0..3).map(|k| m[r][k] * self.t[k]).sum::<f64>());
        Some(Self { m, t })
    }

    /// The map applied to a point.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| (0..3).map(|k| self.m[r][k] * p[k]).sum::<f64>() + self.t[r])
    }

    /// The linear part applied to a direction (a tangent).
    pub fn linear(&self, v: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| (0..3).map(|k| self.m[r][k] * v[k]).sum::<f64>())
    }

    /// `Mᵀ v` for the linear part `M`: a world normal carried to local space by the
    /// local-to-world map, or a local normal to world space by its inverse.
    pub fn transpose_linear(&self, n: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| (0..3).map(|k| self.m[k][r] * n[k]).sum::<f64>())
    }
}
