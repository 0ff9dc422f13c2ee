//! The best placement of a mask over the pattern by FFT (Soler, Cani & Angelidis 2002, §4.2,
//! eq. 2).
//!
//! For a placement `P(f) = R(α) f + t` (frame pixels → pattern pixels) the error of the mask is
//! `E = Σ J (I − T(P f))² = Σ J I² − 2 Σ J I · T(P f) + Σ J T²(P f)`, summed over the colour
//! channels. For a fixed rotation the two last sums are correlations over `t`, computed for every
//! integer offset at once by FFT. With `(f ⋆ g)(d) = Σ_x f(x) g(x + d)` the correlation is
//! `F⁻¹(conj(F f) · F g)`: the conjugate goes on the *mask's* transform. The formula as printed in
//! the paper conjugates the pattern's, which returns the match at `−d` (a planted-offset test in
//! `tests/engine/pattern_fit.rs` pins the sign).
//!
//! **Rotations.** The orientations are `α_k = 2πk/n + φ`, `n` = [`PatternTexture::orientations`].
//! The paper draws the mask at a random rotation `φ` so that the fit does not return the trivial
//! continuation of a single textured neighbour; `best_fit` has no RNG argument, so `φ ∈ [0, 2π/n)`
//! is drawn from a hash of the mask's contents (deterministic for a given input).
//! [`best_fit_with_rotation`] takes `φ` explicitly. Per orientation the mask cells `f` are rotated
//! to `q = R(α_k) f` and *splatted* bilinearly into a grid of the pattern's size (wrapping
//! around the torus for a toroidal pattern; this replaces the paper's rotated copies of T, see
//! `texture.rs`). Bilinear splatting is the adjoint of bilinear sampling, so the FFT evaluates
//! exactly `Σ J (I² − 2 I · T̃(q + t) + T²̃(q + t))` with `~` a bilinear read (`T²̃` interpolates
//! `|T|²`, which differs from `|T̃|²` only between texels).
//!
//! **Offsets.** Integer `t` per orientation; the minimum is refined to sub-pixel precision by a
//! parabola through its two neighbours on each axis (clamped to ±0.5 px, only where both
//! neighbours are valid). Non-toroidal patterns: an offset is valid only if every splatted mask
//! cell and every corner of the rotated patch bounding box stays inside the image; an orientation
//! with no valid offset is skipped, and no valid offset at all gives `None`.
//!
//! **Coarse-to-fine search (not in the paper).** The paper searches all 19 orientations at full
//! resolution (its text describes no multiresolution fit; its coarse-to-fine order is the
//! cluster hierarchy's). Here, when the pattern has a reduced copy
//! ([`PatternTexture::coarse`]: 2× or 4× box means, at least 64 px a side), every orientation is
//! first searched on it, with the mask merged per `s × s` block (summed support, weighted mean
//! colour, weighted centroid); the [`REFINED_ORIENTATIONS`] (3) orientations with the lowest
//! coarse minimum, and any other whose coarse minimum lies below `best + COARSE_MARGIN · (median
//! − best)` ([`COARSE_MARGIN`] = 0.25: with the 3 alone a planted placement on a 512² wood
//! texture with texel-scale grain, trial 3 of `planted_placements_are_recovered_on_shared_textures`,
//! was missed), are then searched at full resolution, and the best of those is the fit (if none
//! of them has a valid full-resolution offset, all orientations are). The full-resolution search
//! of a refined orientation is restricted to windows of `±2s` px around `s ·` the translations
//! of its [`COARSE_MINIMA`] (4) lowest coarse local minima (kept at least [`MINIMA_SEPARATION`]
//! coarse px apart while the coarse image is scanned): the same sums as the full search at those
//! offsets, by small FFTs (`fit_window.rs`); an orientation whose best windowed value lies on its
//! window's border, or whose windows would cost more than the full search (a large mask), is
//! searched over all offsets as before. One window around the single coarse minimum was not
//! enough: on a regular weave (the toy-car fabric, 512²) the 2× image has several near-equal
//! minima, and a planted placement was found 163 px off. Per fit on
//! a 256² pattern that is 19 FFT passes of 64² plus 3 of 256² instead of 19 of 256²: the
//! skull benchmark went from 9.8 s to 2.7 s with the same fits and seam errors within 0.001 on
//! two smooth 256² patterns; on a pattern with 4-px detail the seam error rose by about 3% (README).
//!
//! **Cost per orientation.** The splats are made in the bounding box of the rotated mask, not
//! in pattern-sized grids, and the four correlations are summed per frequency column while it is
//! in cache ([`super::fft2::Fft2::correlate_box`]); the error image is filled, and its minimum
//! found, one row at a time. Same sums as four full-size forward FFTs and one inverse (the
//! output files of the 512² fabric onto Spot were identical); CPU per fit on that case fell from
//! about 89 to 46 ms (load average 3-4, both measured). The coarse ranking keeps no error image
//! (only its few lowest local minima), the splat writes the four channels of a cell together,
//! and its floors are taken without a libm call (a profile put 10-15% of the fit in the splat).
//!
//! **Normalisation.** `Fit::error` is `E / Σ J` (the mean squared colour-space error per mask
//! pixel), so thresholds do not depend on the mask's size.

use rayon::prelude::*;

use super::fit_window;
use super::mask::Mask;
use super::orient::{orient, splat, Oriented, Splat};
use super::texture::PatternTexture;
use crate::engine::rng;

/// Orientations refined at full resolution after the coarse search (module doc).
pub const REFINED_ORIENTATIONS: usize = 3;

/// ... plus every orientation whose coarse minimum is below `best + COARSE_MARGIN · (median −
/// best)` (module doc).
pub const COARSE_MARGIN: f32 = 0.25;

/// Local minima of each refined orientation's coarse error image whose neighbourhoods are
/// searched at full resolution (module doc).
pub const COARSE_MINIMA: usize = 4;

/// Two coarse minima closer than this (reduced pixels, on each axis) are one.
pub const MINIMA_SEPARATION: i64 = 3;

/// A rigid map of frame pixels into pattern pixels: `pattern_px = R(rotation) · frame_px + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Counter-clockwise in the pixel axes (x right, y down), radians.
    pub rotation: f32,
    /// Translation in pattern pixels.
    pub translation_px: [f32; 2],
}

impl Placement {
    /// `R(rotation) · frame_px + translation_px`.
    pub fn apply(&self, frame_px: [f32; 2]) -> [f32; 2] {
        let [x, y] = rotate(self.rotation, frame_px);
        [x + self.translation_px[0], y + self.translation_px[1]]
    }
}

/// The result of [`best_fit`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    /// The best placement found.
    pub placement: Placement,
    /// `E / Σ J` (mean squared colour error per mask pixel) at the best integer offset.
    pub error: f32,
    /// `k` of the orientation `α_k = 2πk/n + φ` the placement uses.
    pub orientation_index: usize,
}

/// The error of every integer offset for one rotation.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorImage {
    /// The rotation of the mask.
    pub rotation: f32,
    /// Grid size (the pattern's).
    pub width: usize,
    /// Grid size (the pattern's).
    pub height: usize,
    /// Cell `d` of the grid is the placement with translation `d − shift`.
    pub shift: [i64; 2],
    /// Row-major `E / Σ J`; `f32::INFINITY` where the offset is not valid.
    pub values: Vec<f32>,
}

impl ErrorImage {
    /// The placement of grid cell `(dx, dy)`.
    pub fn placement(&self, dx: usize, dy: usize) -> Placement {
        Placement {
            rotation: self.rotation,
            translation_px: [
                (dx as i64 - self.shift[0]) as f32,
                (dy as i64 - self.shift[1]) as f32,
            ],
        }
    }
}

/// `R(angle) · p` in pixel axes.
pub fn rotate(angle: f32, p: [f32; 2]) -> [f32; 2] {
    let (s, c) = angle.sin_cos();
    [c * p[0] - s * p[1], s * p[0] + c * p[1]]
}

/// Best placement of the mask over all orientations and offsets (eq. 2 by FFT), the mask drawn
/// at a rotation `φ` hashed from its contents (module doc). `patch_bbox_px` = the current
/// cluster's frame-pixel bounding box `[min, max]`: for a non-toroidal pattern, the patch plus
/// mask must stay inside the image (`None` if they cannot). A mask with no support → `None` (the
/// caller places the patch like the first one).
pub fn best_fit(
    texture: &PatternTexture,
    mask: &Mask,
    patch_bbox_px: [[f32; 2]; 2],
) -> Option<Fit> {
    let step = std::f32::consts::TAU / texture.orientations() as f32;
    let phi = rng::hash_unit(mask_hash(mask), 0) as f32 * step;
    best_fit_with_rotation(texture, mask, patch_bbox_px, phi)
}

/// [`best_fit`] with the mask rotation `φ` given (orientations `α_k = 2πk/n + φ`).
pub fn best_fit_with_rotation(
    texture: &PatternTexture,
    mask: &Mask,
    patch_bbox_px: [[f32; 2]; 2],
    phi: f32,
) -> Option<Fit> {
    if !phi.is_finite() {
        return None;
    }
    let n = texture.orientations();
    let alpha = |k: usize| std::f32::consts::TAU * k as f32 / n as f32 + phi;
    let all: Vec<(usize, Vec<[f32; 2]>)> = (0..n).map(|k| (k, Vec::new())).collect();
    // The full-resolution cells are gathered while the coarse ranking runs (it reads the mask
    // merged per block, not them).
    let (cells, (candidates, s)) = rayon::join(
        || support_cells(mask),
        || match texture.coarse() {
            Some((coarse, s)) => (coarse_candidates(coarse, s, mask, patch_bbox_px, &alpha), s),
            None => (all.clone(), 1),
        },
    );
    if cells.is_empty() {
        return None;
    }
    let radius = fit_window::WINDOW_RADIUS_PER_FACTOR * s as i64;
    let refine = |k: usize, coarse: &[[f32; 2]]| -> Option<(f32, Placement)> {
        let o = orient(texture, &cells, patch_bbox_px, alpha(k))?;
        let sp = splat(texture, &cells, &o.rotated, o.shift);
        let centres: Vec<[i64; 2]> = coarse
            .iter()
            .map(|t| [0, 1].map(|a| (t[a] * s as f32).round() as i64 + o.shift[a]))
            .collect();
        fit_window::windows_minimum(texture, &o, &sp, &centres, radius).or_else(|| {
            let (image, argmin) = oriented_error_image(texture, &o, &sp);
            minimum(&image, argmin?, texture.toroidal())
        })
    };
    let fine = |ks: &[(usize, Vec<[f32; 2]>)]| -> Option<Fit> {
        let results: Vec<(usize, Option<(f32, Placement)>)> = ks
            .par_iter()
            .map(|(k, coarse)| (*k, refine(*k, coarse)))
            .collect();
        let mut best: Option<Fit> = None;
        for (k, result) in results {
            if let Some((error, placement)) = result {
                if best.is_none_or(|b| error < b.error) {
                    best = Some(Fit {
                        placement,
                        error,
                        orientation_index: k,
                    });
                }
            }
        }
        best
    };
    // Candidates the coarse grid allowed but the full one does not (a non-toroidal border case)
    // fall back to the full search.
    fine(&candidates).or_else(|| (candidates.len() < n).then(|| fine(&all)).flatten())
}

/// The orientations refined at full resolution: the [`REFINED_ORIENTATIONS`] with the lowest
/// coarse minimum, and every other one whose coarse minimum is within [`COARSE_MARGIN`] of the
/// spread between the lowest and the median (all of them when none has a valid coarse offset).
fn coarse_candidates(
    coarse: &PatternTexture,
    s: usize,
    mask: &Mask,
    patch_bbox_px: [[f32; 2]; 2],
    alpha: &(dyn Fn(usize) -> f32 + Sync),
) -> Vec<(usize, Vec<[f32; 2]>)> {
    let n = coarse.orientations();
    let scored = coarse_scores(coarse, s, mask, patch_bbox_px, alpha);
    if scored.is_empty() {
        return (0..n).map(|k| (k, Vec::new())).collect();
    }
    let best = scored[0].0;
    let median = scored[scored.len() / 2].0;
    let cut = best + COARSE_MARGIN * (median - best);
    scored
        .into_iter()
        .enumerate()
        .filter(|(i, (v, _, _))| *i < REFINED_ORIENTATIONS || *v <= cut)
        .map(|(_, (_, k, t))| (k, t))
        .collect()
}

/// `(coarse minimum, k, the translations of its [`COARSE_MINIMA`] best local minima in reduced
/// pixels)` per orientation with a valid coarse offset, lowest first, for the pattern's reduced
/// copy `coarse` (factor `s`) and orientations `alpha(k)`.
fn coarse_scores(
    coarse: &PatternTexture,
    s: usize,
    mask: &Mask,
    patch_bbox_px: [[f32; 2]; 2],
    alpha: &(dyn Fn(usize) -> f32 + Sync),
) -> Vec<(f32, usize, Vec<[f32; 2]>)> {
    let n = coarse.orientations();
    let cells = reduced_cells(mask, s);
    let inv = 1.0 / s as f32;
    let bbox = patch_bbox_px.map(|p| p.map(|v| v * inv));
    let mut scored: Vec<(f32, usize, Vec<[f32; 2]>)> = (0..n)
        .into_par_iter()
        .filter_map(|k| {
            let minima = smallest_errors(coarse, &cells, bbox, alpha(k));
            let best = minima.first()?.0;
            let t = minima.iter().map(|m| m.1).collect();
            best.is_finite().then_some((best, k, t))
        })
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    scored
}

/// The coarse ranking [`best_fit_with_rotation`] starts from: `(coarse minimum, k)` per
/// orientation `2πk/n + phi`, lowest first; empty when the pattern has no reduced copy.
pub fn coarse_ranking(
    texture: &PatternTexture,
    mask: &Mask,
    patch_bbox_px: [[f32; 2]; 2],
    phi: f32,
) -> Vec<(f32, usize)> {
    let n = texture.orientations();
    let alpha = |k: usize| std::f32::consts::TAU * k as f32 / n as f32 + phi;
    match texture.coarse() {
        Some((coarse, s)) => coarse_scores(coarse, s, mask, patch_bbox_px, &alpha)
            .into_iter()
            .map(|(v, k, _)| (v, k))
            .collect(),
        None => Vec::new(),
    }
}

/// The mask's support cells merged per `s × s` block of mask cells, in reduced pixels: weight =
/// the block's summed support, colour = the support-weighted mean, position = the
/// support-weighted centroid divided by `s`.
fn reduced_cells(mask: &Mask, s: usize) -> Vec<Cell> {
    let (bw, bh) = (mask.width.div_ceil(s), mask.height.div_ceil(s));
    // Per block: Σw, Σw·colour, Σw·position.
    let mut blocks = vec![(0.0f32, [0.0f32; 3], [0.0f32; 2]); bw * bh];
    for cell in support_cells_indexed(mask) {
        let (i, j, c) = cell;
        let b = &mut blocks[(j / s) * bw + i / s];
        b.0 += c.weight;
        for (sum, v) in b.1.iter_mut().zip(c.colour) {
            *sum += c.weight * v;
        }
        for (sum, v) in b.2.iter_mut().zip(c.frame) {
            *sum += c.weight * v;
        }
    }
    let inv_s = 1.0 / s as f32;
    blocks
        .into_iter()
        .filter(|b| b.0 > 0.0)
        .map(|(w, c, p)| Cell {
            frame: p.map(|v| v / w * inv_s),
            colour: c.map(|v| v / w),
            weight: w,
        })
        .collect()
}

/// `E / Σ J` for every integer offset at one rotation (`None` if the mask has no support or,
/// for a non-toroidal pattern, no offset is valid).
pub fn error_image(
    texture: &PatternTexture,
    mask: &Mask,
    patch_bbox_px: [[f32; 2]; 2],
    rotation: f32,
) -> Option<ErrorImage> {
    error_image_of(texture, &support_cells(mask), patch_bbox_px, rotation).map(|(image, _)| image)
}

/// The mean squared colour error `Σ J |I − T(P f)|² / Σ J` of a placement, by direct
/// evaluation with bilinear reads (`None` for a mask with no support).
pub fn placement_error(
    texture: &PatternTexture,
    mask: &Mask,
    placement: &Placement,
) -> Option<f32> {
    let cells = support_cells(mask);
    let total: f32 = cells.iter().map(|c| c.weight).sum();
    if total <= 0.0 {
        return None;
    }
    let e: f32 = cells
        .iter()
        .map(|c| {
            let t = texture.sample(placement.apply(c.frame));
            c.weight * (0..3).map(|ch| (c.colour[ch] - t[ch]).powi(2)).sum::<f32>()
        })
        .sum();
    Some(e / total)
}

/// A mask cell with positive support.
pub(super) struct Cell {
    pub frame: [f32; 2],
    pub colour: [f32; 3],
    pub weight: f32,
}

pub(super) fn support_cells(mask: &Mask) -> Vec<Cell> {
    support_cells_indexed(mask).map(|(_, _, c)| c).collect()
}

/// The support cells with their grid indices `(i, j)`.
fn support_cells_indexed(mask: &Mask) -> impl Iterator<Item = (usize, usize, Cell)> + '_ {
    let ok =
        mask.colour.len() == mask.width * mask.height && mask.support.len() == mask.colour.len();
    let n = if ok { mask.colour.len() } else { 0 };
    (0..n).filter_map(move |index| {
        let (i, j) = (index % mask.width, index / mask.width);
        let (w, c) = (mask.support[index], mask.colour[index]);
        (w > 0.0 && w.is_finite() && c.iter().all(|v| v.is_finite())).then(|| {
            (
                i,
                j,
                Cell {
                    frame: mask.cell_centre(i, j),
                    colour: c,
                    weight: w.min(1.0),
                },
            )
        })
    })
}

/// A deterministic hash of a mask's geometry and contents (the seed of its rotation φ).
fn mask_hash(mask: &Mask) -> u64 {
    let mut h = rng::mix(
        mask.width as u64,
        mask.height as u64,
        ((mask.origin[0].to_bits() as u64) << 32) | mask.origin[1].to_bits() as u64,
    );
    for (i, (c, s)) in mask.colour.iter().zip(&mask.support).enumerate() {
        if *s > 0.0 {
            let bits = (c[0].to_bits() as u64) ^ ((c[2].to_bits() as u64) << 32);
            h = rng::mix(h, i as u64, bits ^ s.to_bits() as u64);
        }
    }
    h
}

/// The [`COARSE_MINIMA`] smallest local minima of `E / Σ J` over the valid integer offsets at
/// one rotation, at least [`MINIMA_SEPARATION`] px apart on each axis (a streaming suppression:
/// a value enters when it beats the worst kept and every kept one near it), lowest first, with
/// their integer translations. The first is the image's smallest value. The image itself is not
/// kept (the coarse ranking needs no more).
fn smallest_errors(
    texture: &PatternTexture,
    cells: &[Cell],
    patch_bbox_px: [[f32; 2]; 2],
    alpha: f32,
) -> Vec<(f32, [f32; 2])> {
    let Some(o) = orient(texture, cells, patch_bbox_px, alpha) else {
        return Vec::new();
    };
    let n = [texture.width() as i64, texture.height() as i64];
    let near = |a: [i64; 2], b: [i64; 2]| {
        (0..2).all(|i| {
            let d = (a[i] - b[i]).abs();
            let d = if texture.toroidal() {
                d.min(n[i] - d)
            } else {
                d
            };
            d <= MINIMA_SEPARATION
        })
    };
    let mut kept: Vec<(f32, [i64; 2])> = Vec::with_capacity(COARSE_MINIMA + 1);
    let mut worst = f32::INFINITY;
    let sp = splat(texture, cells, &o.rotated, o.shift);
    correlate_valid(texture, &o, &sp, |dy, xlo, correlation| {
        for (i, c) in correlation.iter().enumerate() {
            let v = o.error(*c);
            if v >= worst {
                continue;
            }
            let d = [(xlo + i) as i64, dy as i64];
            if kept.iter().any(|(kv, kd)| *kv <= v && near(*kd, d)) {
                continue;
            }
            kept.retain(|(_, kd)| !near(*kd, d));
            let at = kept.partition_point(|(kv, _)| *kv <= v);
            kept.insert(at, (v, d));
            kept.truncate(COARSE_MINIMA);
            worst = if kept.len() == COARSE_MINIMA {
                kept[COARSE_MINIMA - 1].0
            } else {
                f32::INFINITY
            };
        }
    });
    kept.into_iter()
        .map(|(v, d)| (v, [0, 1].map(|a| (d[a] - o.shift[a]) as f32)))
        .collect()
}

pub(super) fn error_image_of(
    texture: &PatternTexture,
    cells: &[Cell],
    patch_bbox_px: [[f32; 2]; 2],
    alpha: f32,
) -> Option<(ErrorImage, Option<usize>)> {
    let o = orient(texture, cells, patch_bbox_px, alpha)?;
    let sp = splat(texture, cells, &o.rotated, o.shift);
    Some(oriented_error_image(texture, &o, &sp))
}

/// [`error_image_of`] for an orientation and its splat already made.
fn oriented_error_image(
    texture: &PatternTexture,
    o: &Oriented,
    sp: &Splat,
) -> (ErrorImage, Option<usize>) {
    let (w, h) = (texture.width() as usize, texture.height() as usize);
    let mut values = vec![f32::INFINITY; w * h];
    let (mut argmin, mut min) = (None, f32::INFINITY);
    correlate_valid(texture, o, sp, |dy, xlo, correlation| {
        let out = &mut values[dy * w + xlo..dy * w + xlo + correlation.len()];
        for (value, c) in out.iter_mut().zip(correlation) {
            *value = o.error(*c);
        }
        // `max` maps NaN to 0, so the first value equal to the row's minimum is its first
        // smallest (the order of a plain scan).
        let row_min = out.iter().copied().fold(f32::INFINITY, f32::min);
        if row_min < min {
            let i = out.iter().position(|&v| v == row_min).unwrap_or(0);
            (argmin, min) = (Some(dy * w + xlo + i), row_min);
        }
    });
    let image = ErrorImage {
        rotation: o.alpha,
        width: w,
        height: h,
        shift: o.shift,
        values,
    };
    (image, argmin)
}

/// The correlations of orientation `o` (splat `sp`) over the pattern's whole grid, handed to
/// `row(dy, xlo, values)` for each row of valid offsets: `values[i]` belongs to `dx = xlo + i`.
fn correlate_valid(
    texture: &PatternTexture,
    o: &Oriented,
    sp: &Splat,
    mut row: impl FnMut(usize, usize, &[f32]),
) {
    let [(xlo, xhi), (ylo, yhi)] = o.ranges.map(|(lo, hi)| (lo as usize, hi as usize));
    texture.fft().correlate_box(
        sp.origin,
        sp.size,
        &sp.boxes,
        texture.factors(),
        texture.spectra(),
        |dy| (ylo..=yhi).contains(&dy),
        |dy, correlation| row(dy, xlo, &correlation[xlo..=xhi]),
    );
}

/// The smallest valid value, refined by parabolas; `(E / Σ J, placement)`.
/// `index` = the first smallest value's, row-major (found while the image was filled).
pub(super) fn minimum(
    image: &ErrorImage,
    index: usize,
    toroidal: bool,
) -> Option<(f32, Placement)> {
    let (w, h) = (image.width, image.height);
    let value = image.values[index];
    let (dx, dy) = (index % w, index / w);
    let at = |x: i64, y: i64| -> f32 {
        if toroidal {
            image.values[(y.rem_euclid(h as i64) as usize) * w + x.rem_euclid(w as i64) as usize]
        } else if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            f32::INFINITY
        } else {
            image.values[y as usize * w + x as usize]
        }
    };
    let (x, y) = (dx as i64, dy as i64);
    let refine = |minus: f32, plus: f32| -> f32 {
        let curvature = minus - 2.0 * value + plus;
        if minus.is_finite() && plus.is_finite() && curvature > 0.0 {
            (0.5 * (minus - plus) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let sub = [
        refine(at(x - 1, y), at(x + 1, y)),
        refine(at(x, y - 1), at(x, y + 1)),
    ];
    let mut placement = image.placement(dx, dy);
    placement.translation_px[0] += sub[0];
    placement.translation_px[1] += sub[1];
    placement.rotation = placement.rotation.rem_euclid(std::f32::consts::TAU);
    Some((value, placement))
}
