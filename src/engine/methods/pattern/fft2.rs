//! Two-dimensional real FFTs on a fixed `width × height` grid, for the correlations of the
//! pattern method's best fit (Soler, Cani & Angelidis 2002, §4.2: "the correlation of two
//! functions can be computed in O(N log N) by moving to Fourier space").
//!
//! Rows are transformed with a real-to-complex FFT (`realfft`), then each of the `width / 2 + 1`
//! frequency columns with a complex FFT of length `height` (`rustfft`). The spectrum is stored
//! column-major: bin `(kx, ky)` at `kx · height + ky`. The inverse undoes both passes and divides
//! by `width · height`, so `inverse(forward(f)) = f`. Rows that are all zero are skipped in the
//! forward pass (a mask is small next to the pattern grid it is splatted into; [`Fft2::forward_rows`]
//! takes the occupied rows from the caller instead of scanning for them). Both passes move data
//! between the row-major image and the column-major spectrum in 16 × 16 tiles, so that neither
//! side is written or read with a stride of a whole row or column per element (a profile of a
//! 512² pattern put a fifth of the fit's time in the untiled copies).

use std::sync::Arc;

use realfft::num_complex::Complex32;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

/// Rows moved per tile between the row-major image and the column-major spectrum.
const TILE: usize = 16;

/// Frequency columns transformed together by [`Fft2::correlate_box`] (8 complex f32 = one
/// 64-byte cache line per row).
const GROUP: usize = 8;

/// Planned forward and inverse 2-D real FFTs of one grid size.
#[derive(Clone)]
pub struct Fft2 {
    width: usize,
    height: usize,
    rows_forward: Arc<dyn RealToComplex<f32>>,
    rows_inverse: Arc<dyn ComplexToReal<f32>>,
    columns_forward: Arc<dyn Fft<f32>>,
    columns_inverse: Arc<dyn Fft<f32>>,
}

impl std::fmt::Debug for Fft2 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fft2({}x{})", self.width, self.height)
    }
}

impl Fft2 {
    /// Plans the transforms of a `width × height` grid (both ≥ 1).
    pub fn new(width: usize, height: usize) -> Self {
        let mut real = RealFftPlanner::<f32>::new();
        let mut complex = FftPlanner::<f32>::new();
        Self {
            width,
            height,
            rows_forward: real.plan_fft_forward(width),
            rows_inverse: real.plan_fft_inverse(width),
            columns_forward: complex.plan_fft_forward(height),
            columns_inverse: complex.plan_fft_inverse(height),
        }
    }

    /// The grid's width.
    pub fn width(&self) -> usize {
        self.width
    }

    /// The grid's height.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of frequency columns, `width / 2 + 1`.
    pub fn columns(&self) -> usize {
        self.width / 2 + 1
    }

    /// Length of a spectrum, `(width / 2 + 1) · height`.
    pub fn spectrum_len(&self) -> usize {
        self.columns() * self.height
    }

    /// The spectrum of a row-major `width × height` real image.
    pub fn forward(&self, image: &[f32]) -> Vec<Complex32> {
        debug_assert_eq!(image.len(), self.width * self.height);
        let w = self.width;
        let occupied: Vec<bool> = image
            .chunks_exact(w.max(1))
            .map(|row| row.iter().any(|&v| v != 0.0))
            .collect();
        self.forward_rows(image, &occupied)
    }

    /// [`forward`](Self::forward) of an image whose rows `y` with `occupied[y] == false` are all
    /// zero (they are skipped without being read).
    pub fn forward_rows(&self, image: &[f32], occupied: &[bool]) -> Vec<Complex32> {
        debug_assert_eq!(image.len(), self.width * self.height);
        debug_assert_eq!(occupied.len(), self.height);
        let (w, h, cols) = (self.width, self.height, self.columns());
        let mut spectrum = vec![Complex32::new(0.0, 0.0); cols * h];
        let mut row = vec![0.0f32; w];
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.rows_forward.get_scratch_len()];
        // Row spectra of a tile of rows, row-major (`TILE × cols`), copied into the column-major
        // spectrum column by column.
        let mut block = vec![Complex32::new(0.0, 0.0); TILE * cols];
        for y0 in (0..h).step_by(TILE) {
            let rows = TILE.min(h - y0);
            if !occupied[y0..y0 + rows].iter().any(|&o| o) {
                continue;
            }
            for r in 0..rows {
                let out = &mut block[r * cols..(r + 1) * cols];
                if !occupied[y0 + r] {
                    out.fill(Complex32::new(0.0, 0.0));
                    continue;
                }
                row.copy_from_slice(&image[(y0 + r) * w..(y0 + r + 1) * w]);
                // Lengths are right by construction, so the only error (wrong length) cannot occur.
                let _ = self
                    .rows_forward
                    .process_with_scratch(&mut row, out, &mut scratch);
            }
            for kx in 0..cols {
                let column = &mut spectrum[kx * h + y0..kx * h + y0 + rows];
                for (r, value) in column.iter_mut().enumerate() {
                    *value = block[r * cols + kx];
                }
            }
        }
        let mut scratch =
            vec![Complex32::new(0.0, 0.0); self.columns_forward.get_inplace_scratch_len()];
        for column in spectrum.chunks_exact_mut(h) {
            self.columns_forward
                .process_with_scratch(column, &mut scratch);
        }
        spectrum
    }

    /// `Σ_c factors[c] · (g_c ⋆ t_c)` on the whole grid, `(g ⋆ t)(d) = Σ_x g(x) t(x + d)`
    /// (circular), handed to `row_out(y, row)` one output row at a time for the rows `y` with
    /// `wanted(y)` (the others are not transformed back; rows in order, each of `width` values,
    /// already divided by `width · height`). Each `g_c` is zero outside a box of
    /// `size = [bw, bh]` cells (`bw ≤ width`, `bh ≤ height`) whose first cell is grid cell
    /// `origin` (the box wraps around the grid): `boxes` holds the box row-major (`bw · bh`), the
    /// `C` channels of a cell together (the splat writes them with one access).
    /// `spectra[c]` is the [`forward`](Self::forward) spectrum of `t_c`.
    ///
    /// The same sums as `inverse(Σ_c factors[c] · conj(forward(g_c)) · spectra[c])`, without
    /// the full-size images: a channel whose factor is 0 is skipped (its `spectra` entry is not
    /// read), only the box's rows go through the row FFTs, and each frequency
    /// column is transformed forward, combined and transformed back while it is in cache (a
    /// profile of a 512² pattern put most of a fit's time in the copies of full-size images and
    /// spectra, not in the FFT kernels).
    #[allow(clippy::too_many_arguments)]
    pub fn correlate_box<const C: usize>(
        &self,
        origin: [usize; 2],
        size: [usize; 2],
        boxes: &[[f32; C]],
        factors: &[f32; C],
        spectra: &[Vec<Complex32>],
        wanted: impl Fn(usize) -> bool,
        mut row_out: impl FnMut(usize, &[f32]),
    ) {
        let (w, h, cols) = (self.width, self.height, self.columns());
        let [bw, bh] = size;
        debug_assert!(bw <= w && bh <= h && origin[0] < w && origin[1] < h);
        debug_assert!(boxes.len() == bw * bh && spectra.len() == C);
        let zero = Complex32::new(0.0, 0.0);
        // Row spectra of the box's rows, per channel row-major (`bh × cols`).
        let mut row = vec![0.0f32; w];
        let mut scratch = vec![zero; self.rows_forward.get_scratch_len()];
        let row_spectra: Vec<Vec<Complex32>> = (0..C)
            .map(|c| {
                if factors[c] == 0.0 {
                    return Vec::new();
                }
                let mut out = vec![zero; bh * cols];
                // The box's row in the grid's row: one run, or two where it wraps.
                let first = bw.min(w - origin[0]);
                for r in 0..bh {
                    row.fill(0.0);
                    let cells = &boxes[r * bw..(r + 1) * bw];
                    for (x, v) in row[origin[0]..origin[0] + first].iter_mut().zip(cells) {
                        *x = v[c];
                    }
                    for (x, v) in row.iter_mut().zip(&cells[first..]) {
                        *x = v[c];
                    }
                    let _ = self.rows_forward.process_with_scratch(
                        &mut row,
                        &mut out[r * cols..(r + 1) * cols],
                        &mut scratch,
                    );
                }
                out
            })
            .collect();
        let forward_len = self.columns_forward.get_inplace_scratch_len();
        let inverse_len = self.columns_inverse.get_inplace_scratch_len();
        let mut scratch = vec![zero; forward_len.max(inverse_len)];
        // GROUP frequency columns at a time: gathered from the row spectra (GROUP contiguous
        // values per row), transformed, combined, transformed back, and written row-major
        // (GROUP contiguous values per frequency row), so that no pass walks memory with the
        // stride of a whole row or column per element.
        let mut columns = vec![zero; GROUP * h];
        let mut combined = vec![zero; GROUP * h];
        // The combined spectrum, row-major (`h × cols`), column passes already inverted.
        let mut spectrum = vec![zero; h * cols];
        for kx0 in (0..cols).step_by(GROUP) {
            let group = GROUP.min(cols - kx0);
            combined[..group * h].fill(zero);
            for ((rs, spec), &factor) in row_spectra.iter().zip(spectra).zip(factors) {
                if factor == 0.0 {
                    continue;
                }
                columns[..group * h].fill(zero);
                for r in 0..bh {
                    let y = origin[1] + r;
                    let y = if y < h { y } else { y - h };
                    for (j, v) in rs[r * cols + kx0..r * cols + kx0 + group]
                        .iter()
                        .enumerate()
                    {
                        columns[j * h + y] = *v;
                    }
                }
                for j in 0..group {
                    let column = &mut columns[j * h..(j + 1) * h];
                    self.columns_forward
                        .process_with_scratch(column, &mut scratch[..forward_len]);
                    let kx = kx0 + j;
                    for ((out, gv), tv) in combined[j * h..(j + 1) * h]
                        .iter_mut()
                        .zip(column.iter())
                        .zip(&spec[kx * h..(kx + 1) * h])
                    {
                        *out += gv.conj() * tv * factor;
                    }
                }
            }
            for j in 0..group {
                self.columns_inverse.process_with_scratch(
                    &mut combined[j * h..(j + 1) * h],
                    &mut scratch[..inverse_len],
                );
            }
            for ky in (0..h).filter(|&ky| wanted(ky)) {
                let out = &mut spectrum[ky * cols + kx0..ky * cols + kx0 + group];
                for (j, o) in out.iter_mut().enumerate() {
                    *o = combined[j * h + ky];
                }
            }
        }
        let scale = 1.0 / (w * h) as f32;
        let mut row = vec![0.0f32; w];
        let mut scratch = vec![zero; self.rows_inverse.get_scratch_len()];
        for (y, row_in) in spectrum.chunks_exact_mut(cols).enumerate() {
            if !wanted(y) {
                continue;
            }
            // A Hermitian spectrum has real DC (and Nyquist) bins; drop the round-off.
            row_in[0].im = 0.0;
            if w % 2 == 0 {
                row_in[cols - 1].im = 0.0;
            }
            let _ = self
                .rows_inverse
                .process_with_scratch(row_in, &mut row, &mut scratch);
            for v in row.iter_mut() {
                *v *= scale;
            }
            row_out(y, &row);
        }
    }

    /// The real image of a spectrum (consumed as scratch), divided by `width · height`.
    pub fn inverse(&self, spectrum: &mut [Complex32]) -> Vec<f32> {
        debug_assert_eq!(spectrum.len(), self.spectrum_len());
        let (w, h) = (self.width, self.height);
        let mut scratch =
            vec![Complex32::new(0.0, 0.0); self.columns_inverse.get_inplace_scratch_len()];
        for column in spectrum.chunks_exact_mut(h) {
            self.columns_inverse
                .process_with_scratch(column, &mut scratch);
        }
        let mut image = vec![0.0f32; w * h];
        self.inverse_rows(spectrum, |y, row| {
            image[y * w..(y + 1) * w].copy_from_slice(row);
        });
        image
    }

    /// The row pass of the inverse: a spectrum whose columns are already transformed back, to
    /// real rows divided by `width · height`, handed to `row_out(y, row)` in order.
    fn inverse_rows(&self, spectrum: &[Complex32], mut row_out: impl FnMut(usize, &[f32])) {
        let (w, h, cols) = (self.width, self.height, self.columns());
        let scale = 1.0 / (w * h) as f32;
        let mut block = vec![Complex32::new(0.0, 0.0); TILE * cols];
        let mut row = vec![0.0f32; w];
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.rows_inverse.get_scratch_len()];
        for y0 in (0..h).step_by(TILE) {
            let rows = TILE.min(h - y0);
            for kx in 0..cols {
                let column = &spectrum[kx * h + y0..kx * h + y0 + rows];
                for (r, value) in column.iter().enumerate() {
                    block[r * cols + kx] = *value;
                }
            }
            for r in 0..rows {
                let row_in = &mut block[r * cols..(r + 1) * cols];
                // A Hermitian spectrum has real DC (and Nyquist) bins; drop the round-off.
                row_in[0].im = 0.0;
                if w % 2 == 0 {
                    row_in[cols - 1].im = 0.0;
                }
                let _ = self
                    .rows_inverse
                    .process_with_scratch(row_in, &mut row, &mut scratch);
                for v in row.iter_mut() {
                    *v *= scale;
                }
                row_out(y0 + r, &row);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_circular_correlation() {
        for (w, h) in [(8, 6), (7, 5), (16, 16), (1, 3)] {
            let fft = Fft2::new(w, h);
            let a: Vec<f32> = (0..w * h).map(|i| ((i * 37 % 11) as f32) - 5.0).collect();
            let b: Vec<f32> = (0..w * h).map(|i| ((i * 13 % 7) as f32) * 0.5).collect();
            let mut spec_a = fft.forward(&a);
            let back = fft.inverse(&mut spec_a.clone());
            for (x, y) in a.iter().zip(&back) {
                assert!((x - y).abs() < 1e-4, "{w}x{h}: {x} vs {y}");
            }
            // (a ⋆ b)(d) = Σ_g a(g) b(g + d) = F⁻¹(conj(F a) · F b).
            let spec_b = fft.forward(&b);
            for (x, y) in spec_a.iter_mut().zip(&spec_b) {
                *x = x.conj() * y;
            }
            let corr = fft.inverse(&mut spec_a);
            for dy in 0..h {
                for dx in 0..w {
                    let mut direct = 0.0;
                    for gy in 0..h {
                        for gx in 0..w {
                            let (sx, sy) = ((gx + dx) % w, (gy + dy) % h);
                            direct += a[gy * w + gx] * b[sy * w + sx];
                        }
                    }
                    let got = corr[dy * w + dx];
                    assert!((got - direct).abs() < 1e-3 * (1.0 + direct.abs()));
                }
            }
        }
    }
    #[test]
    fn box_correlation_equals_full_grid_correlation() {
        // Boxes inside the grid, wrapping around its corner, and as wide as the grid.
        for (w, h, origin, size) in [
            (16, 12, [3, 2], [5, 4]),
            (16, 12, [13, 10], [6, 5]),
            (9, 8, [0, 6], [9, 3]),
        ] {
            let fft = Fft2::new(w, h);
            let t: Vec<Vec<f32>> = (0..2)
                .map(|c| {
                    (0..w * h)
                        .map(|i| ((i * (7 + c) % 13) as f32) * 0.3 - 1.0)
                        .collect()
                })
                .collect();
            let spectra: Vec<Vec<Complex32>> = t.iter().map(|t| fft.forward(t)).collect();
            let [bw, bh] = size;
            let boxes: Vec<[f32; 2]> = (0..bw * bh)
                .map(|i| [0, 1].map(|c| ((i * (3 + c) % 5) as f32) - 2.0))
                .collect();
            let factors = [-2.0, 1.0];
            let mut got = vec![f32::NAN; w * h];
            fft.correlate_box(
                origin,
                size,
                &boxes,
                &factors,
                &spectra,
                |_| true,
                |y, row| {
                    got[y * w..(y + 1) * w].copy_from_slice(row);
                },
            );
            for dy in 0..h {
                for dx in 0..w {
                    let mut direct = 0.0;
                    for c in 0..2 {
                        for r in 0..bh {
                            for i in 0..bw {
                                let (x, y) = ((origin[0] + i) % w, (origin[1] + r) % h);
                                let (sx, sy) = ((x + dx) % w, (y + dy) % h);
                                direct += factors[c] * boxes[r * bw + i][c] * t[c][sy * w + sx];
                            }
                        }
                    }
                    let v = got[dy * w + dx];
                    assert!(
                        (v - direct).abs() < 1e-3 * (1.0 + direct.abs()),
                        "{v} vs {direct}"
                    );
                }
            }
        }
    }
}
