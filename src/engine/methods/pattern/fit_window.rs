//! The full-resolution step of the coarse-to-fine best fit (Soler, Cani & Angelidis 2002, §4.2,
//! eq. 2) restricted to a window of offsets around the coarse minimum (not in the paper; see
//! `fit.rs` for the coarse search it follows).
//!
//! After the orientations have been ranked on the pattern's reduced copy (factor `s`), the
//! paper's error `E(t) = Σ J |I − T(R f + t)|²` of a refined orientation is evaluated at full
//! resolution only for the integer translations within [`WINDOW_RADIUS_PER_FACTOR`]` · s` pixels
//! of `s ·` (its coarse minimum's translation), instead of at every offset of the pattern. The
//! values are the same sums as the full search's (same bilinear splat of the rotated mask, same
//! correlation), computed by FFT on a small grid: the pattern texels the window can read (the
//! mask's splat box plus the window, wrapped on a toroidal pattern) are cropped into an
//! `N₀ × N₁` grid with `N ≥` box + window − 1, so that the circular correlation on it has no
//! wrap-around for the window's offsets. All windows of an orientation share one crop size, so
//! the mask's spectra (its four channels at cell `(0, 0)` of the crop grid) are made once per
//! orientation; each window then correlates its pattern crop against them
//! ([`super::fft2::Fft2::correlate_box`] with the crop as the box: `Σ_y crop(y) mask(y + e)`
//! is the window's sum at `d = −e`), transforming back only the window's rows. That is
//! `4 + 5k` transforms of `N₀ N₁` for `k` windows against 5 of the pattern's size for the full
//! search; the windows are used when they cost less by that count (a median mask of the 512²
//! fabric onto Spot is about 100 px a side: `N` = 128 or 144 against 512). Colour channels the
//! pattern does not use (zero on every texel: the two hue channels of a grey pattern) are skipped
//! on both sides ([`PatternTexture::factors`]). Before the shared mask spectra (9 transforms per
//! window, used only below half the full search's count) 39% of the refined orientations of that case fell
//! back to the full search for cost.
//!
//! The window's smallest value is taken (and refined by the same parabolas) only where it is a
//! local minimum inside the window; a minimum on the window's border, windows that cost more than
//! the full search, or a mask as wide as the pattern return `None`, and the caller searches that
//! orientation over all offsets as before. The FFT plans of each crop size are made once per
//! thread and kept (planning costs more than one small transform). No crate offers a windowed
//! correlation; this is written here on top of [`super::fft2::Fft2`].

use std::cell::RefCell;
use std::collections::HashMap;

use realfft::num_complex::Complex32;

use super::fft2::Fft2;
use super::fit::{minimum, ErrorImage, Placement};
use super::orient::{Oriented, Splat};
use super::texture::PatternTexture;

/// The window's half-width in full-resolution pixels per unit of the coarse factor `s`: the
/// coarse minimum locates a translation to within one coarse pixel (`s` full-resolution
/// pixels) when the reduced copy keeps the pattern's structure; twice that leaves room for the
/// full-resolution minimum to move by one more coarse pixel and keep its parabola neighbours.
pub const WINDOW_RADIUS_PER_FACTOR: i64 = 2;

thread_local! {
    /// Planned transforms per crop size, kept for the thread's lifetime.
    static PLANS: RefCell<HashMap<(usize, usize), Fft2>> = RefCell::new(HashMap::new());
}

/// The smallest `2^a · 3^b ≥ n` with `a ≥ 1` (sizes rustfft and realfft transform fastest).
fn fast_size(n: usize) -> usize {
    let mut best = usize::MAX;
    let mut three = 1usize;
    while three < 2 * n.max(1) {
        let mut size = 2 * three;
        while size < n {
            size *= 2;
        }
        best = best.min(size);
        three *= 3;
    }
    best
}

/// Transforms of the crop grid per orientation (the mask's four channels), and per window (the
/// pattern crop's four channels and the inverse), against [`FULL_TRANSFORMS`] of the pattern's
/// grid for the full search.
const MASK_TRANSFORMS: usize = 4;
const WINDOW_TRANSFORMS: usize = 5;
const FULL_TRANSFORMS: usize = 5;

/// The smallest error of orientation `o` over the windows of grid offsets within `radius` of
/// each of `centres` (per axis, intersected with `o.ranges`), refined by parabolas: `(E / Σ J,
/// placement)`, or `None` when the windows do not apply or cost more than the full search
/// (module doc).
pub(super) fn windows_minimum(
    texture: &PatternTexture,
    o: &Oriented,
    sp: &Splat,
    centres: &[[i64; 2]],
    radius: i64,
) -> Option<(f32, Placement)> {
    if centres.is_empty() || sp.wraps.iter().any(|&w| w) {
        return None;
    }
    let span = 2 * radius.max(0) as usize + 1;
    let crop = [0, 1].map(|a| fast_size(sp.size[a] + span - 1));
    let n = texture.width() as usize * texture.height() as usize;
    let transforms = MASK_TRANSFORMS + WINDOW_TRANSFORMS * centres.len();
    if transforms * crop[0] * crop[1] > FULL_TRANSFORMS * n {
        return None;
    }
    let fft = PLANS.with(|plans| {
        plans
            .borrow_mut()
            .entry((crop[0], crop[1]))
            .or_insert_with(|| Fft2::new(crop[0], crop[1]))
            .clone()
    });
    let mask_spectra = mask_spectra(texture, &fft, sp, crop);
    let mut best: Option<Window> = None;
    for &centre in centres {
        if let Some(w) = window(texture, o, sp, (&fft, &mask_spectra), centre, radius) {
            if best.as_ref().is_none_or(|b| w.value < b.value) {
                best = Some(w);
            }
        }
    }
    let best = best?;
    best.interior.then_some(best.minimum).flatten()
}

/// The spectra of the splat's four channels, its box at cell `(0, 0)` of the `crop` grid.
fn mask_spectra(
    texture: &PatternTexture,
    fft: &Fft2,
    sp: &Splat,
    crop: [usize; 2],
) -> Vec<Vec<Complex32>> {
    let [bw, bh] = sp.size;
    let occupied: Vec<bool> = (0..crop[1]).map(|y| y < bh).collect();
    let factors = texture.factors();
    (0..4)
        .map(|c| {
            if factors[c] == 0.0 {
                return Vec::new();
            }
            let mut grid = vec![0.0f32; crop[0] * crop[1]];
            for (row, cells) in grid
                .chunks_exact_mut(crop[0])
                .zip(sp.boxes.chunks_exact(bw))
            {
                for (g, v) in row.iter_mut().zip(cells) {
                    *g = v[c];
                }
            }
            fft.forward_rows(&grid, &occupied)
        })
        .collect()
}

/// One window's smallest value, its refined minimum, and whether it is a local minimum inside
/// the window.
struct Window {
    value: f32,
    interior: bool,
    minimum: Option<(f32, Placement)>,
}

fn window(
    texture: &PatternTexture,
    o: &Oriented,
    sp: &Splat,
    (fft, mask_spectra): (&Fft2, &[Vec<Complex32>]),
    centre: [i64; 2],
    radius: i64,
) -> Option<Window> {
    let n = [texture.width() as usize, texture.height() as usize];
    let toroidal = texture.toroidal();
    // The window's first offset and size per axis.
    let mut lo = [0i64; 2];
    let mut count = [0usize; 2];
    for a in 0..2 {
        let (mut l, mut h) = (centre[a] - radius, centre[a] + radius);
        if !toroidal {
            l = l.max(o.ranges[a].0);
            h = h.min(o.ranges[a].1);
        }
        if l > h {
            return None;
        }
        lo[a] = l;
        count[a] = (h - l + 1) as usize;
    }
    let crop = [fft.width(), fft.height()];
    // crop(y) = T(origin + lo + y), wrapped (non-toroidal: only reads that stay inside the image
    // reach the window's offsets, by the valid ranges).
    let tx: Vec<usize> = (0..crop[0])
        .map(|x| (sp.origin[0] as i64 + lo[0] + x as i64).rem_euclid(n[0] as i64) as usize)
        .collect();
    let mut cells = vec![[0.0f32; 4]; crop[0] * crop[1]];
    for (y, row) in cells.chunks_exact_mut(crop[0]).enumerate() {
        let ty = (sp.origin[1] as i64 + lo[1] + y as i64).rem_euclid(n[1] as i64) as usize;
        for (cell, &tx) in row.iter_mut().zip(&tx) {
            let (colour, norm_sq) = texture.texel(ty * n[0] + tx);
            *cell = [colour[0], colour[1], colour[2], norm_sq];
        }
    }
    // Σ_y crop(y) · mask(y + e) = the window's sum at offset d = −e (mod the crop's size): the
    // mask's spectra are made once for all windows, the crop's inside the correlation.
    let back = |e: usize, len: usize| if e == 0 { 0 } else { len - e };
    let mut values = vec![f32::INFINITY; count[0] * count[1]];
    let (mut argmin, mut min) = (None, f32::INFINITY);
    fft.correlate_box(
        [0, 0],
        crop,
        &cells,
        texture.factors(),
        mask_spectra,
        |ey| back(ey, crop[1]) < count[1],
        |ey, correlation| {
            let dy = back(ey, crop[1]);
            let out = &mut values[dy * count[0]..(dy + 1) * count[0]];
            for (dx, v) in out.iter_mut().enumerate() {
                *v = o.error(correlation[back(dx, crop[0])]);
            }
            for (dx, &v) in out.iter().enumerate() {
                if v < min || v == min && argmin.is_some_and(|i| dy * count[0] + dx < i) {
                    (argmin, min) = (Some(dy * count[0] + dx), v);
                }
            }
        },
    );
    let index = argmin?;
    let (ex, ey) = (index % count[0], index / count[0]);
    // Only a minimum with a neighbour on each side inside the window is a local one.
    let inside = |e: usize, c: usize, a: usize| {
        (e > 0 || lo[a] == o.ranges[a].0 && !toroidal)
            && (e + 1 < c || lo[a] + c as i64 - 1 == o.ranges[a].1 && !toroidal)
    };
    let interior = inside(ex, count[0], 0) && inside(ey, count[1], 1);
    let image = ErrorImage {
        rotation: o.alpha,
        width: count[0],
        height: count[1],
        shift: [o.shift[0] - lo[0], o.shift[1] - lo[1]],
        values,
    };
    let minimum = minimum(&image, index, false).map(|(error, mut placement)| {
        if toroidal {
            // The translation of the same offset as the full search reports it (`d` in `0..n`).
            for a in 0..2 {
                let d = lo[a] + [ex, ey][a] as i64;
                placement.translation_px[a] += (d.rem_euclid(n[a] as i64) - d) as f32;
            }
        }
        (error, placement)
    });
    Some(Window {
        value: min,
        interior,
        minimum,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::asset::DecodedImage;
    use crate::engine::methods::pattern::fit::{error_image_of, support_cells};
    use crate::engine::methods::pattern::mask::Mask;
    use crate::engine::methods::pattern::orient::{orient, splat};
    use crate::engine::rng::SplitMix64;

    #[test]
    fn fast_sizes_are_the_smallest_even_3_smooth_sizes() {
        assert_eq!(fast_size(1), 2);
        assert_eq!(fast_size(7), 8);
        assert_eq!(fast_size(100), 108);
        assert_eq!(fast_size(129), 144);
        assert_eq!(fast_size(193), 216);
        for n in 1..600 {
            let s = fast_size(n);
            assert!(s >= n && s.is_multiple_of(2));
        }
    }

    /// A 96 × 80 texture of random texels (grey ones: two colour channels zero, skipped by the
    /// correlations) and a 14 × 11 mask with random colours and support.
    fn case(seed: u64, toroidal: bool, grey: bool) -> (PatternTexture, Mask) {
        let mut rng = SplitMix64::new(seed);
        let mut byte = || (rng.unit_f32() * 255.0) as u8;
        let pixels = (0..96 * 80)
            .map(|_| {
                let v = byte();
                if grey {
                    [v, v, v, 255]
                } else {
                    [v, byte(), byte(), 255]
                }
            })
            .collect();
        let image = DecodedImage {
            width: 96,
            height: 80,
            pixels,
        };
        let texture = PatternTexture::new(&image, toroidal, 19).unwrap();
        let mut rng = SplitMix64::new(seed + 100);
        let (w, h) = (14, 11);
        let mask = Mask {
            origin: [-7.0, -5.0],
            width: w,
            height: h,
            colour: (0..w * h)
                .map(|_| [0; 3].map(|_| rng.unit_f32() * 0.8 - 0.3))
                .collect(),
            support: (0..w * h)
                .map(|_| (rng.unit_f32() * 1.5 - 0.3).clamp(0.0, 1.0))
                .collect(),
        };
        (texture, mask)
    }

    /// Centred on the full search's minimum, the window returns that minimum (value and refined
    /// placement); centred elsewhere, it returns no smaller value than the full search's, and
    /// every value it finds is one of the full error image's.
    #[test]
    fn windows_reproduce_the_full_search() {
        for (seed, toroidal, grey) in [
            (1, true, false),
            (2, true, false),
            (3, false, false),
            (4, false, false),
            (5, true, true),
            (6, false, true),
        ] {
            let (texture, mask) = case(seed, toroidal, grey);
            assert_eq!(texture.factors()[0] == 0.0, grey);
            let cells = support_cells(&mask);
            let bbox = [[-6.0, -4.0], [6.0, 5.0]];
            for alpha in [0.0f32, 0.7, 2.9] {
                let (image, argmin) = error_image_of(&texture, &cells, bbox, alpha).unwrap();
                let argmin = argmin.unwrap();
                let (full_error, full) = minimum(&image, argmin, toroidal).unwrap();
                let o = orient(&texture, &cells, bbox, alpha).unwrap();
                let sp = splat(&texture, &cells, &o.rotated, o.shift);
                let at = [argmin % image.width, argmin / image.width].map(|v| v as i64);
                // Centres one and three pixels off the minimum, wrapped past the grid's edge
                // on a torus.
                for off in [[1i64, -1i64], [-3, 2]] {
                    let mut centre = [at[0] + off[0], at[1] + off[1]];
                    if toroidal {
                        centre[0] += 96;
                    }
                    let (error, placement) = windows_minimum(&texture, &o, &sp, &[centre], 4)
                        .unwrap_or_else(|| panic!("seed {seed} α {alpha}: no window minimum"));
                    assert!(
                        (error - full_error).abs() <= 1e-4 * (1.0 + full_error),
                        "seed {seed} α {alpha}: {error} vs {full_error}"
                    );
                    for a in 0..2 {
                        let d = placement.translation_px[a] - full.translation_px[a];
                        assert!(
                            d.abs() < 1e-3,
                            "seed {seed} α {alpha}: {placement:?} vs {full:?}"
                        );
                    }
                }
                // A window far from the minimum: a larger value, or none (minimum on its border).
                let far = [at[0] + 30, at[1] + 25];
                if let Some((error, _)) = windows_minimum(&texture, &o, &sp, &[far], 4) {
                    assert!(error >= full_error - 1e-5, "seed {seed} α {alpha}");
                    let exists = image
                        .values
                        .iter()
                        .any(|v| (v - error).abs() <= 1e-4 * (1.0 + error));
                    assert!(
                        exists,
                        "seed {seed} α {alpha}: {error} is no offset's error"
                    );
                }
            }
        }
    }
}
