//! One orientation of a mask on the pattern's offset grid, and its bilinear splat: the shared
//! first step of every correlation of the best fit (Soler, Cani & Angelidis 2002, §4.2, eq. 2),
//! whether over all offsets (`fit.rs`) or a window of them (`fit_window.rs`).
//!
//! The mask cells `f` are rotated to `q = R(α) f`; grid offset `d` is the translation
//! `d − shift`, with `shift` making every cell's grid coordinate `u = q − 0.5 − shift` non-negative.
//! For a non-toroidal pattern an offset is valid only if every splatted cell and every corner of
//! the rotated patch bounding box stays inside the image. Each cell is splatted bilinearly (the
//! adjoint of a bilinear read) into the smallest box of grid cells that holds the mask, so that
//! the correlations evaluate `Σ J (I² − 2 I · T̃(q + t) + T²̃(q + t))` exactly (`fit.rs` module
//! doc). Written here: no crate splats points for an FFT correlation.

use super::fit::{rotate, Cell};
use super::texture::PatternTexture;

/// The valid integer range `[lo, hi]` of grid offsets `d` on one axis, or `None`.
pub(super) type Range = Option<(i64, i64)>;

/// One orientation of a mask on the pattern's offset grid: the rotated cells, the shift that
/// makes their grid coordinates non-negative, the valid offsets per axis, and the two sums that
/// normalise a correlation into `E / Σ J`.
pub(super) struct Oriented {
    pub alpha: f32,
    pub rotated: Vec<[f32; 2]>,
    /// Grid offset `d` is the translation `d − shift`.
    pub shift: [i64; 2],
    /// Valid grid offsets `[lo, hi]` per axis.
    pub ranges: [(i64, i64); 2],
    /// `Σ J`.
    pub total: f32,
    /// `Σ J |I|²`.
    pub sum_i2: f32,
}

impl Oriented {
    /// `E / Σ J` of a correlation value `−2 Σ J I·T + Σ J |T|²`.
    pub fn error(&self, correlation: f32) -> f32 {
        ((self.sum_i2 + correlation) / self.total).max(0.0)
    }
}

/// The mask's cells at rotation `alpha` ([`Oriented`]); `None` without cells or, for a
/// non-toroidal pattern, without a valid offset.
pub(super) fn orient(
    texture: &PatternTexture,
    cells: &[Cell],
    patch_bbox_px: [[f32; 2]; 2],
    alpha: f32,
) -> Option<Oriented> {
    if cells.is_empty() {
        return None;
    }
    let size = [texture.width() as usize, texture.height() as usize];
    let rotated: Vec<[f32; 2]> = cells.iter().map(|c| rotate(alpha, c.frame)).collect();
    // Grid coordinate of a rotated cell: u = q − 0.5 − shift, with shift making u ≥ 0.
    let mut shift = [0i64; 2];
    let mut max_cell = [0i64; 2];
    for a in 0..2 {
        let lo = rotated.iter().map(|q| q[a]).fold(f32::INFINITY, f32::min);
        let hi = rotated
            .iter()
            .map(|q| q[a])
            .fold(f32::NEG_INFINITY, f32::max);
        shift[a] = (lo - 0.5).floor() as i64;
        max_cell[a] = (hi - 0.5).floor() as i64 - shift[a] + 1;
    }
    let ranges: [Range; 2] = if texture.toroidal() {
        [Some((0, size[0] as i64 - 1)), Some((0, size[1] as i64 - 1))]
    } else {
        let corners = [
            patch_bbox_px[0],
            [patch_bbox_px[1][0], patch_bbox_px[0][1]],
            [patch_bbox_px[0][0], patch_bbox_px[1][1]],
            patch_bbox_px[1],
        ]
        .map(|c| rotate(alpha, c));
        [0, 1].map(|a| clamped_range(&corners, a, size[a], shift[a], max_cell[a]))
    };
    Some(Oriented {
        alpha,
        rotated,
        shift,
        ranges: [ranges[0]?, ranges[1]?],
        total: cells.iter().map(|c| c.weight).sum(),
        sum_i2: cells
            .iter()
            .map(|c| c.weight * c.colour.iter().map(|v| v * v).sum::<f32>())
            .sum(),
    })
}

/// Non-toroidal offsets `d` on one axis that keep the splatted mask (grid cells `0..=max_cell`)
/// and the rotated patch corners (at `corner + d − shift`) inside `[0, n]`.
fn clamped_range(
    corners: &[[f32; 2]; 4],
    axis: usize,
    n: usize,
    shift: i64,
    max_cell: i64,
) -> Range {
    let n_i = n as i64;
    let lo_c = corners
        .iter()
        .map(|c| c[axis])
        .fold(f32::INFINITY, f32::min);
    let hi_c = corners
        .iter()
        .map(|c| c[axis])
        .fold(f32::NEG_INFINITY, f32::max);
    if !lo_c.is_finite() || !hi_c.is_finite() {
        return None;
    }
    let lo = 0i64.max((shift as f32 - lo_c).ceil() as i64);
    let hi = (n_i - 1 - max_cell).min((n as f32 + shift as f32 - hi_c).floor() as i64);
    (lo <= hi).then_some((lo, hi))
}

/// The four correlations' weights: `−2 Σ_c (G_Ic ⋆ T_c) + (G_J ⋆ |T|²)`.
pub(super) const FACTORS: [f32; 4] = [-2.0, -2.0, -2.0, 1.0];

/// The bilinear splats `G` of `J·I_c` (three channels) and `J` at `u = q − 0.5 − shift`, in the
/// smallest box of grid cells that holds them (the whole grid on an axis where the mask is wider
/// than the pattern, wrapped onto it): the input of
/// [`super::fft2::Fft2::correlate_box`], whose sums with [`FACTORS`] are
/// `−2 Σ_c (G_Ic ⋆ T_c)(d) + (G_J ⋆ |T|²)(d)` for every grid offset `d`.
pub(super) struct Splat {
    /// The box's first grid cell (wrapped onto the grid).
    pub origin: [usize; 2],
    /// The box's size in cells.
    pub size: [usize; 2],
    /// Per axis: the box is the whole grid (the mask is wider than the pattern).
    pub wraps: [bool; 2],
    /// `J·I_0, J·I_1, J·I_2, J` per cell, row-major in the box.
    pub boxes: Vec<[f32; 4]>,
}

pub(super) fn splat(
    texture: &PatternTexture,
    cells: &[Cell],
    rotated: &[[f32; 2]],
    shift: [i64; 2],
) -> Splat {
    let n = [texture.width() as i64, texture.height() as i64];
    // Integer base cell and fractions of each splat.
    let taps: Vec<([i64; 2], [f32; 2])> = rotated
        .iter()
        .map(|q| {
            let u = [q[0] - 0.5 - shift[0] as f32, q[1] - 0.5 - shift[1] as f32];
            let base = u.map(floor_i64);
            (base, [u[0] - base[0] as f32, u[1] - base[1] as f32])
        })
        .collect();
    // Per axis: the box's first grid cell, its size, and the map of a cell to its box index.
    // Grid coordinates are ≥ 0 by the choice of `shift` (up to round-off); a box no larger than
    // the grid holds each cell once, so a cell's box index is its distance from the box's first.
    let axis = |a: usize| -> (i64, i64, bool) {
        let lo = taps.iter().map(|t| t.0[a]).min().unwrap_or(0);
        let hi = taps.iter().map(|t| t.0[a]).max().unwrap_or(0) + 1;
        if hi - lo < n[a] {
            (lo, hi - lo + 1, false)
        } else {
            (0, n[a], true)
        }
    };
    let boxes_axes = [axis(0), axis(1)];
    let local = |v: i64, a: usize| -> usize {
        let (lo, _, wraps) = boxes_axes[a];
        if wraps {
            v.rem_euclid(n[a]) as usize
        } else {
            (v - lo) as usize
        }
    };
    let (bw, bh) = (boxes_axes[0].1 as usize, boxes_axes[1].1 as usize);
    let mut boxes = vec![[0.0f32; 4]; bw * bh];
    for (cell, (base, frac)) in cells.iter().zip(&taps) {
        let values = [
            cell.weight * cell.colour[0],
            cell.weight * cell.colour[1],
            cell.weight * cell.colour[2],
            cell.weight,
        ];
        let (x0, x1) = (local(base[0], 0), local(base[0] + 1, 0));
        let (y0, y1) = (local(base[1], 1), local(base[1] + 1, 1));
        for (x, y, f) in [
            (x0, y0, (1.0 - frac[0]) * (1.0 - frac[1])),
            (x1, y0, frac[0] * (1.0 - frac[1])),
            (x0, y1, (1.0 - frac[0]) * frac[1]),
            (x1, y1, frac[0] * frac[1]),
        ] {
            let cell = &mut boxes[y * bw + x];
            for (sum, v) in cell.iter_mut().zip(values) {
                *sum += f * v;
            }
        }
    }
    Splat {
        origin: [0, 1].map(|a| boxes_axes[a].0.rem_euclid(n[a]) as usize),
        size: [bw, bh],
        wraps: [boxes_axes[0].2, boxes_axes[1].2],
        boxes,
    }
}

/// `⌊v⌋` as an integer without a call to `floorf` (the baseline x86-64 target has no SSE4.1
/// rounding instruction, and this runs for every splatted cell of every orientation).
fn floor_i64(v: f32) -> i64 {
    let t = v as i64;
    if (t as f32) > v {
        t - 1
    } else {
        t
    }
}
