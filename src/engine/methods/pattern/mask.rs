//! The mask I and its support J of a face-cluster about to be textured (Soler, Cani & Angelidis
//! 2002, §4.1 last paragraph, §4.2): the union of the bands of its already textured neighbours,
//! drawn in the current cluster's frame with the colours the neighbours' placements give them.
//!
//! The paper renders the bands off-screen (I from the colour buffer, J from the depth buffer).
//! Here each band triangle is scanned over the frame-pixel grid: a cell whose centre lies inside
//! the triangle (barycentric test) takes the pattern colour at the barycentric interpolation of
//! the corners' pattern positions ([`PatternTexture::sample`], the same colour space as the fit)
//! and the interpolated corner weight as support. Where bands overlap, colours are averaged with
//! their weights and the support is the largest weight.
//!
//! **Grid.** One cell per frame pixel; cell `(i, j)` (row-major, `j` down) covers
//! `origin + [i, i + 1) × [j, j + 1)` and its centre is `origin + (i + 0.5, j + 0.5)`. `colour` is
//! the sampled colour itself (not premultiplied by the support); cells outside every triangle have
//! colour 0 and support 0. The grid is not padded for the FFT: `fit.rs` splats the mask into the
//! pattern's own FFT grid at each orientation, so the mask's size does not set an FFT size.
//! A mask whose bounding box is wider or taller than [`MAX_MASK_SIDE`] frame pixels keeps the
//! centred window of that size (a limit the paper does not need, since it renders into a
//! fixed-size buffer); corners that are not finite drop their triangle. Bands of
//! [`BAND_ROWS`] rows are rasterised in parallel, each over every triangle in order, so every
//! cell gets the same sums as in one pass (the driver waits for the mask with a core idle).

use rayon::prelude::*;

use super::texture::PatternTexture;

/// Rows per band of the parallel rasterisation.
const BAND_ROWS: usize = 32;

/// The largest mask side, in frame pixels (4096: 16 M cells, 256 MB, at most).
pub const MAX_MASK_SIDE: usize = 4096;

/// A triangle of a textured neighbour in the band: its corners in the current cluster's frame
/// (pixels) and where the neighbour's placement put them in the pattern (pixels). `weight` per
/// corner (1 inside the band; the caller may fade it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaskTriangle {
    /// Corners in the current cluster's frame, in pattern pixels (`frame · px_per_world`).
    pub frame_px: [[f32; 2]; 3],
    /// Corners where the neighbour's placement maps them in the pattern, in pixels.
    pub pattern_px: [[f32; 2]; 3],
    /// Support weight per corner, in `[0, 1]` (values outside are clamped).
    pub weight: [f32; 3],
}

/// The mask I (colours) and its support J on a grid of frame pixels; `origin` = frame px of the
/// corner of cell (0, 0) (its centre is `origin + (0.5, 0.5)`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mask {
    /// Frame-pixel position of the top-left corner of cell (0, 0).
    pub origin: [f32; 2],
    /// Cells per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major colour-space values (not premultiplied by `support`).
    pub colour: Vec<[f32; 3]>,
    /// Row-major support J in `[0, 1]`.
    pub support: Vec<f32>,
}

impl Mask {
    /// The frame-pixel centre of cell `(i, j)`.
    pub fn cell_centre(&self, i: usize, j: usize) -> [f32; 2] {
        [
            self.origin[0] + i as f32 + 0.5,
            self.origin[1] + j as f32 + 0.5,
        ]
    }

    /// `Σ J`, the mask size the fitting error is normalised by.
    pub fn support_sum(&self) -> f32 {
        self.support.iter().sum()
    }
}

/// Rasterises the band triangles into a mask (module doc); no triangles (or none finite) give an
/// empty mask (width and height 0).
pub fn rasterise_mask(texture: &PatternTexture, triangles: &[MaskTriangle]) -> Mask {
    let finite = |t: &&MaskTriangle| {
        t.frame_px
            .iter()
            .chain(t.pattern_px.iter())
            .all(|p| p[0].is_finite() && p[1].is_finite())
            && t.weight.iter().all(|w| w.is_finite())
    };
    let usable: Vec<&MaskTriangle> = triangles.iter().filter(finite).collect();
    if usable.is_empty() {
        return Mask::default();
    }
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for t in &usable {
        for p in &t.frame_px {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    let mut origin = [lo[0].floor(), lo[1].floor()];
    let mut size = [0usize; 2];
    for a in 0..2 {
        let span = ((hi[a].ceil() - origin[a]) as f64).max(1.0);
        if span > MAX_MASK_SIDE as f64 {
            let centre = 0.5 * (lo[a] + hi[a]);
            origin[a] = (centre - MAX_MASK_SIDE as f32 / 2.0).floor();
            size[a] = MAX_MASK_SIDE;
        } else {
            size[a] = span as usize;
        }
    }
    let (w, h) = (size[0], size[1]);
    // Bands of rows rasterised in parallel, each over every triangle in order: the same sums
    // per cell as one pass (the driver waits for the mask, with the other core idle).
    let bands: Vec<(Vec<[f32; 3]>, Vec<f32>)> = (0..h.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|b| {
            let rows = [b * BAND_ROWS, h.min((b + 1) * BAND_ROWS)];
            let n = w * (rows[1] - rows[0]);
            let mut weight_sum = vec![0.0f32; n];
            let mut colour_sum = vec![[0.0f32; 3]; n];
            let mut support = vec![0.0f32; n];
            for t in &usable {
                scan_triangle(texture, t, origin, [w, h], rows, |cell, colour, weight| {
                    weight_sum[cell] += weight;
                    for c in 0..3 {
                        colour_sum[cell][c] += weight * colour[c];
                    }
                    support[cell] = support[cell].max(weight);
                });
            }
            let colour = colour_sum
                .iter()
                .zip(&weight_sum)
                .map(|(c, &s)| {
                    if s > 0.0 {
                        [c[0] / s, c[1] / s, c[2] / s]
                    } else {
                        [0.0; 3]
                    }
                })
                .collect();
            (colour, support)
        })
        .collect();
    let mut colour = Vec::with_capacity(w * h);
    let mut support = Vec::with_capacity(w * h);
    for (c, s) in bands {
        colour.extend(c);
        support.extend(s);
    }
    Mask {
        origin,
        width: w,
        height: h,
        colour,
        support,
    }
}

/// Calls `emit(cell, colour, weight)` for every grid cell of rows `rows[0]..rows[1]` whose centre
/// lies inside `t` (with a small tolerance so shared edges leave no gap) and gets a positive
/// weight; `cell` counts from the first of those rows.
fn scan_triangle(
    texture: &PatternTexture,
    t: &MaskTriangle,
    origin: [f32; 2],
    size: [usize; 2],
    rows: [usize; 2],
    mut emit: impl FnMut(usize, [f32; 3], f32),
) {
    let [a, b, c] = t.frame_px.map(|p| [p[0] - origin[0], p[1] - origin[1]]);
    let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if det.abs() < 1e-9 {
        return;
    }
    let range = |axis: usize, n: usize| -> (usize, usize) {
        let lo = a[axis].min(b[axis]).min(c[axis]);
        let hi = a[axis].max(b[axis]).max(c[axis]);
        let first = (lo - 0.5).ceil().max(0.0) as usize;
        let last = ((hi - 0.5).floor() + 1.0).clamp(0.0, n as f32) as usize;
        (first, last)
    };
    let (x0, x1) = range(0, size[0]);
    let (y0, y1) = range(1, size[1]);
    let (y0, y1) = (y0.max(rows[0]), y1.min(rows[1]));
    const TOLERANCE: f32 = -1e-5;
    for j in y0..y1 {
        let py = j as f32 + 0.5;
        for i in x0..x1 {
            let px = i as f32 + 0.5;
            let l1 = ((px - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (py - a[1])) / det;
            let l2 = ((b[0] - a[0]) * (py - a[1]) - (px - a[0]) * (b[1] - a[1])) / det;
            let l0 = 1.0 - l1 - l2;
            if l0 < TOLERANCE || l1 < TOLERANCE || l2 < TOLERANCE {
                continue;
            }
            let weight = (l0 * t.weight[0] + l1 * t.weight[1] + l2 * t.weight[2]).clamp(0.0, 1.0);
            if weight <= 0.0 {
                continue;
            }
            let p = [0, 1].map(|k| {
                l0 * t.pattern_px[0][k] + l1 * t.pattern_px[1][k] + l2 * t.pattern_px[2][k]
            });
            emit((j - rows[0]) * size[0] + i, texture.sample(p), weight);
        }
    }
}
