//! The pattern image T as the best fit sees it (Soler, Cani & Angelidis 2002, §4.2): texels in
//! an HSV-derived colour space, bilinear sampling, and the FFTs of T and T² computed once per
//! texturing of an object.
//!
//! **Colour space.** The paper works "in hsv color space" and says it beats rgb and grey levels,
//! but a squared difference of raw hue is wrong: hue is an angle, so hue 0.99 and 0.01 are
//! neighbours, and the hue of a grey texel is undefined. Each texel is therefore the point of the
//! HSV cone `(S·cos 2πH, S·sin 2πH, V)` (H, S, V in `[0, 1]` from the sRGB-encoded bytes, no
//! linearisation, as a colour picker shows them): a hue difference counts in proportion to the
//! saturation and wraps around, and V stays a separate axis. Alpha is ignored. The channels lie in
//! `[-1, 1] × [-1, 1] × [0, 1]`.
//!
//! **Orientations (deviation from the paper).** The paper stores the FFTs of 19 rotated copies of
//! T and T² and draws the mask once. Here T and T² are transformed once, unrotated, and the *mask*
//! is rotated per orientation instead (`fit.rs` splats it into the pattern's grid at each angle).
//! The correlations are the same (`Σ I(x) T(R x + t)`), but: (1) a toroidal pattern is sampled
//! exactly, on its own period: a rotated copy of a periodic image is not periodic on the pixel
//! grid, so the paper's copies need padding and anti-aliasing, while a rotated mask that is larger
//! than the pattern just wraps around the torus (exact, because T is periodic); (2) memory is one
//! set of spectra instead of 19 padded ones; (3) the FFT work per fit is about the same (paper:
//! 4 forward FFTs of a padded grid ≈ (1.4 W + mask)² plus 19 inverse ones; here 19 × 5 FFTs of
//! W × H with the mask's empty rows skipped). `orientations` is kept here so every fit of an
//! object uses the same set.
//!
//! **Coarse copy.** A pattern whose sides divide by 2 or 4 and stay at or above
//! [`COARSE_MIN_SIDE`] (64) once divided also keeps a box-filtered copy (`s × s` means of the
//! colour-space texels, the largest such `s` ≤ 4) with its own spectra, for the coarse orientation
//! search of `fit.rs`, provided that copy keeps at least [`COARSE_KEPT_VARIANCE`] (80%) of the
//! pattern's colour variance (else the factor is halved, down to no copy): a pattern whose
//! contrast is mostly texel-scale detail (a 512² wood grain) ranks orientations badly once
//! reduced (a planted placement's orientation came 8th of 19 at factor 4). A pattern of at least
//! 256 px a side ([`ALWAYS_HALVED_SIDE`] once halved) that fails that test keeps a 2× copy all
//! the same: its full-resolution search costs four times the 2× one, and with the 3 + margin
//! orientations refined at full resolution the 2× ranking lost little (512² SheenChair fabric
//! onto Spot, 77% of the variance kept at 2×, 46% at 4×: seam error 0.297 against 0.295 when
//! searched at full resolution, 0.314 with the 4× copy; the planted placements on the wood and
//! fabric textures of `tests/engine/pattern_fit.rs` are still found). Other patterns are searched
//! at full resolution only.
//!
//! **Unused colour channels.** A channel that is zero on every texel (the two hue channels of a
//! grey pattern, whose saturation is 0) has a zero correlation with any mask: its weight in
//! [`PatternTexture::factors`] is 0 and the correlations skip it, so a grey pattern's fit makes
//! two correlations per orientation instead of four. The sums are the same bit for bit (the
//! skipped terms were exact zeros): the 512² SheenChair fabric (grey) onto Spot gave the same
//! output file, in 20.4 s instead of 26.3 s.
//!
//! **Memory.** About 28 bytes per texel (12 for the colours, 16 for the four half spectra of
//! `T_0, T_1, T_2, |T|²` in complex f32), a quarter or a sixteenth of that again for the
//! reduced copy, plus, during a fit, about 8 bytes per texel per orientation in flight (the
//! combined spectrum and the error image; the mask is splatted into its own bounding box only,
//! see `fft2.rs`). Patterns above [`MAX_PATTERN_PIXELS`] (2048², ≈ 117 MB resident) are
//! refused: the per-fit FFT cost grows with the texel count, and the paper's patterns are
//! 128²–256².

use realfft::num_complex::Complex32;

use super::fft2::Fft2;
use super::orient::FACTORS;
use crate::engine::asset::DecodedImage;
use crate::engine::methods::MethodError;

/// The largest pattern accepted, in texels (2048 × 2048).
pub const MAX_PATTERN_PIXELS: usize = 2048 * 2048;

/// The largest number of orientations accepted.
pub const MAX_ORIENTATIONS: usize = 360;

/// A pattern image in the fitting colour space with the spectra of T and |T|².
#[derive(Clone, Debug)]
pub struct PatternTexture {
    width: u32,
    height: u32,
    toroidal: bool,
    orientations: usize,
    /// Row-major colour-space texels.
    colour: Vec<[f32; 3]>,
    /// Row-major `|T|² = Σ_c T_c²`.
    norm_sq: Vec<f32>,
    fft: Fft2,
    /// Spectra of `T_0, T_1, T_2` and `|T|²` (layout of [`Fft2`]).
    spectra: [Vec<Complex32>; 4],
    /// The correlations' weights per channel ([`FACTORS`]), 0 for a colour channel that is zero
    /// on every texel (module doc).
    factors: [f32; 4],
    /// The box-filtered copy for the coarse orientation search and its factor (module doc).
    coarse: Option<(Box<PatternTexture>, usize)>,
}

/// The coarse search grid's smallest side: a pattern is reduced by 2 or 4 only while both sides
/// stay at or above this (256² → 64², 128² → 64², 64² is searched at full resolution).
pub const COARSE_MIN_SIDE: usize = 64;

/// The largest reduction factor of the coarse search.
pub const MAX_COARSE_FACTOR: usize = 4;

/// The share of the pattern's colour variance the reduced copy must keep to be searched first
/// (module doc).
pub const COARSE_KEPT_VARIANCE: f32 = 0.8;

/// A pattern whose halved sides are at least this (256² and up) always keeps its 2× copy, whatever
/// share of its variance the copy keeps (module doc).
pub const ALWAYS_HALVED_SIDE: usize = 128;

/// The reduction factor of the coarse search for a `w × h` pattern: the largest of 4, 2 that
/// divides both sides and keeps them at or above [`COARSE_MIN_SIDE`], else 1 (no coarse search).
pub fn coarse_factor(w: usize, h: usize) -> usize {
    let mut s = MAX_COARSE_FACTOR;
    while s > 1 {
        if w.is_multiple_of(s)
            && h.is_multiple_of(s)
            && w / s >= COARSE_MIN_SIDE
            && h / s >= COARSE_MIN_SIDE
        {
            return s;
        }
        s /= 2;
    }
    1
}

/// The colour-space point `(S cos 2πH, S sin 2πH, V)` of an sRGB-encoded texel.
pub fn colour_of(rgba: [u8; 4]) -> [f32; 3] {
    let [r, g, b] = [rgba[0], rgba[1], rgba[2]].map(|c| c as f32 / 255.0);
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let chroma = max - min;
    if chroma <= 0.0 {
        return [0.0, 0.0, max];
    }
    let saturation = chroma / max;
    // Hue in sixths of a turn.
    let sixths = if max == r {
        ((g - b) / chroma).rem_euclid(6.0)
    } else if max == g {
        (b - r) / chroma + 2.0
    } else {
        (r - g) / chroma + 4.0
    };
    let angle = sixths / 6.0 * std::f32::consts::TAU;
    [saturation * angle.cos(), saturation * angle.sin(), max]
}

impl PatternTexture {
    /// Converts the sRGB texels into the fitting colour space (see the module doc) and computes
    /// the FFTs of T (per channel) and of `|T|²` once. The `orientations` (θ_k = 2πk/orientations)
    /// are applied by rotating the mask in `fit.rs` (module doc: deviation from the paper).
    ///
    /// # Errors
    /// [`MethodError::UnusableInput`] (field `pattern`) for an empty image, one above
    /// [`MAX_PATTERN_PIXELS`], a pixel buffer of the wrong length, or `orientations` outside
    /// `1..=MAX_ORIENTATIONS`.
    pub fn new(
        image: &DecodedImage,
        toroidal: bool,
        orientations: usize,
    ) -> Result<Self, MethodError> {
        let unusable = |message: String| MethodError::UnusableInput {
            field: Some("pattern".into()),
            kind: "unusable-pattern",
            message,
        };
        let (w, h) = (image.width as usize, image.height as usize);
        if w == 0 || h == 0 {
            return Err(unusable("the pattern image is empty".into()));
        }
        if w.saturating_mul(h) > MAX_PATTERN_PIXELS {
            return Err(unusable(format!(
                "the pattern image is {w}x{h} texels; the best fit accepts at most {MAX_PATTERN_PIXELS} (2048x2048)"
            )));
        }
        if image.pixels.len() != w * h {
            return Err(unusable(format!(
                "the pattern image has {} pixels for {w}x{h}",
                image.pixels.len()
            )));
        }
        if orientations == 0 || orientations > MAX_ORIENTATIONS {
            return Err(unusable(format!(
                "orientations must be in 1..={MAX_ORIENTATIONS}, got {orientations}"
            )));
        }
        let colour: Vec<[f32; 3]> = image.pixels.iter().map(|&p| colour_of(p)).collect();
        let mut texture = Self::from_colour(w, h, toroidal, orientations, colour);
        let mut s = coarse_factor(w, h);
        while s > 1 {
            let coarse = downsample(&texture.colour, w, h, s);
            let always = s == 2 && w / 2 >= ALWAYS_HALVED_SIDE && h / 2 >= ALWAYS_HALVED_SIDE;
            if always || kept_variance(&texture.colour, &coarse) >= COARSE_KEPT_VARIANCE {
                let coarse = Self::from_colour(w / s, h / s, toroidal, orientations, coarse);
                texture.coarse = Some((Box::new(coarse), s));
                break;
            }
            s /= 2;
        }
        Ok(texture)
    }

    /// The texture of colour-space texels (sizes checked by the caller), its spectra computed.
    fn from_colour(
        w: usize,
        h: usize,
        toroidal: bool,
        orientations: usize,
        colour: Vec<[f32; 3]>,
    ) -> Self {
        let norm_sq: Vec<f32> = colour
            .iter()
            .map(|c| c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
            .collect();
        let fft = Fft2::new(w, h);
        let channel = |c: usize| -> Vec<f32> { colour.iter().map(|t| t[c]).collect() };
        let spectra = [
            fft.forward(&channel(0)),
            fft.forward(&channel(1)),
            fft.forward(&channel(2)),
            fft.forward(&norm_sq),
        ];
        let mut factors = FACTORS;
        for (c, factor) in factors.iter_mut().take(3).enumerate() {
            if colour.iter().all(|t| t[c] == 0.0) {
                *factor = 0.0;
            }
        }
        Self {
            width: w as u32,
            height: h as u32,
            toroidal,
            orientations,
            colour,
            norm_sq,
            fft,
            spectra,
            factors,
            coarse: None,
        }
    }

    /// The reduced copy searched first by the best fit and its reduction factor, if any.
    pub fn coarse(&self) -> Option<(&PatternTexture, usize)> {
        self.coarse.as_ref().map(|(t, s)| (&**t, *s))
    }

    /// Width in texels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Whether the pattern tiles (sampling wraps; every offset is a candidate).
    pub fn toroidal(&self) -> bool {
        self.toroidal
    }

    /// The number of fitted orientations.
    pub fn orientations(&self) -> usize {
        self.orientations
    }

    /// The colour-space value at a pattern pixel position (bilinear between texel centres at
    /// `i + 0.5`; wrapped if toroidal, clamped otherwise). Non-finite positions read texel (0, 0).
    pub fn sample(&self, px: [f32; 2]) -> [f32; 3] {
        let (i, f) = self.bilinear(px);
        let mut out = [0.0f32; 3];
        for (k, &index) in i.iter().enumerate() {
            let c = self.colour[index];
            for ch in 0..3 {
                out[ch] += f[k] * c[ch];
            }
        }
        out
    }

    /// The bilinear interpolation of `|T|²` at a pattern pixel position (same rules as
    /// [`sample`](Self::sample)); this, not the square of `sample`, is what the FFT's `J ⋆ T²`
    /// term sums, so a brute-force check of `fit.rs` uses it.
    pub fn sample_norm_sq(&self, px: [f32; 2]) -> f32 {
        let (i, f) = self.bilinear(px);
        (0..4).map(|k| f[k] * self.norm_sq[i[k]]).sum()
    }

    /// The four texel indices and weights of a bilinear read.
    fn bilinear(&self, px: [f32; 2]) -> ([usize; 4], [f32; 4]) {
        let (w, h) = (self.width as i64, self.height as i64);
        let axis = |p: f32, n: i64| -> (i64, i64, f32) {
            let p = if p.is_finite() { p - 0.5 } else { 0.0 };
            let base = p.floor();
            let frac = p - base;
            let base = base as i64;
            if (0..n - 1).contains(&base) {
                // Inside the image: no wrap or clamp (and no integer division) needed.
                (base, base + 1, frac)
            } else if self.toroidal {
                (base.rem_euclid(n), (base + 1).rem_euclid(n), frac)
            } else {
                (base.clamp(0, n - 1), (base + 1).clamp(0, n - 1), frac)
            }
        };
        let (x0, x1, fx) = axis(px[0], w);
        let (y0, y1, fy) = axis(px[1], h);
        let at = |x: i64, y: i64| (y * w + x) as usize;
        (
            [at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1)],
            [
                (1.0 - fx) * (1.0 - fy),
                fx * (1.0 - fy),
                (1.0 - fx) * fy,
                fx * fy,
            ],
        )
    }

    /// The planned FFTs of the pattern grid.
    pub(crate) fn fft(&self) -> &Fft2 {
        &self.fft
    }

    /// The texel at row-major `index`: its colour-space value and `|T|²`.
    pub(crate) fn texel(&self, index: usize) -> ([f32; 3], f32) {
        (self.colour[index], self.norm_sq[index])
    }

    /// Spectra of `T_0, T_1, T_2` and `|T|²`.
    pub(crate) fn spectra(&self) -> &[Vec<Complex32>; 4] {
        &self.spectra
    }

    /// The weights of the four correlations `−2 Σ_c (G_Ic ⋆ T_c) + (G_J ⋆ |T|²)`: [`FACTORS`],
    /// with 0 for a colour channel that is zero on every texel (its correlation is zero, and
    /// [`Fft2::correlate_box`] skips a channel weighted 0).
    pub(crate) fn factors(&self) -> &[f32; 4] {
        &self.factors
    }
}

/// The variance (about the mean, summed over the channels) of the `s`-reduced grid over that of
/// the full one: the share of the pattern's contrast that is not texel-scale detail.
fn kept_variance(full: &[[f32; 3]], coarse: &[[f32; 3]]) -> f32 {
    let variance = |g: &[[f32; 3]]| -> f64 {
        let n = g.len().max(1) as f64;
        let mean = [0, 1, 2].map(|c| g.iter().map(|t| f64::from(t[c])).sum::<f64>() / n);
        g.iter()
            .map(|t| {
                (0..3)
                    .map(|c| (f64::from(t[c]) - mean[c]).powi(2))
                    .sum::<f64>()
            })
            .sum::<f64>()
            / n
    };
    let total = variance(full);
    if total <= 0.0 {
        return 1.0;
    }
    (variance(coarse) / total) as f32
}

/// The `s × s` box means of a `w × h` colour grid (both sides divisible by `s`).
fn downsample(colour: &[[f32; 3]], w: usize, h: usize, s: usize) -> Vec<[f32; 3]> {
    let (cw, ch) = (w / s, h / s);
    let mut out = vec![[0.0f32; 3]; cw * ch];
    for y in 0..h {
        for x in 0..w {
            let o = &mut out[(y / s) * cw + x / s];
            for (a, b) in o.iter_mut().zip(&colour[y * w + x]) {
                *a += b;
            }
        }
    }
    let inv = 1.0 / (s * s) as f32;
    for o in &mut out {
        for a in o {
            *a *= inv;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hue_is_circular_and_grey_has_no_hue() {
        let red_a = colour_of([255, 0, 2, 255]); // hue just below 1
        let red_b = colour_of([255, 2, 0, 255]); // hue just above 0
        let d: f32 = (0..3).map(|c| (red_a[c] - red_b[c]).powi(2)).sum();
        assert!(d < 1e-3, "{red_a:?} {red_b:?}");
        let cyan = colour_of([0, 255, 255, 255]);
        let far: f32 = (0..3).map(|c| (red_a[c] - cyan[c]).powi(2)).sum();
        assert!(far > 3.9);
        assert_eq!(colour_of([128, 128, 128, 255])[..2], [0.0, 0.0]);
    }

    #[test]
    fn sampling_wraps_or_clamps() {
        let pixels = (0..12)
            .map(|i| [(i * 20) as u8, 0, 0, 255])
            .collect::<Vec<_>>();
        let image = DecodedImage {
            width: 4,
            height: 3,
            pixels,
        };
        let tor = PatternTexture::new(&image, true, 19).unwrap();
        let clamp = PatternTexture::new(&image, false, 19).unwrap();
        // Texel centre reads the texel.
        assert_eq!(tor.sample([1.5, 1.5]), colour_of([100, 0, 0, 255]));
        // Half way between the last and the first column: the mean when toroidal.
        let v = tor.sample([4.0, 0.5])[2];
        assert!((v - (60.0 + 0.0) / 2.0 / 255.0).abs() < 1e-6);
        assert_eq!(clamp.sample([4.0, 0.5])[2], 60.0 / 255.0);
        assert_eq!(clamp.sample([f32::NAN, 0.5]), clamp.sample([0.5, 0.5]));
        assert!(PatternTexture::new(&image, true, 0).is_err());
        let empty = DecodedImage {
            width: 0,
            height: 0,
            pixels: vec![],
        };
        assert!(PatternTexture::new(&empty, true, 19).is_err());
    }
}
