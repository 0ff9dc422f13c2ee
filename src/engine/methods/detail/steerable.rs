//! Detail features (Berkiten et al. 2017, §3.2.1): the standard deviations of the sub-bands of a
//! steerable pyramid (Simoncelli & Freeman 1995) of a square grid of displacements, 4 orientations
//! × 4 scales, plus the high-pass residual: 17 numbers per patch.
//!
//! Built in the frequency domain on `rustfft` (as Portilla & Simoncelli's implementation), with
//! radius `ρ` normalised to the Nyquist frequency (ρ = 1) and the raised-cosine masks in `log2 ρ`:
//! `H(x) = cos(π/2 · clamp(−x, 0, 1))`, `L(x) = sin(π/2 · clamp(−x, 0, 1))` (`H² + L² = 1`).
//! - High-pass residual: `H(log2 ρ)` (passes `ρ ∈ [½, 1]` and beyond, the corners).
//! - Band at scale `s` (0 finest … 3): `L(log2 ρ) · Π_{j<s} L(log2 ρ + j + 1) · H(log2 ρ + s + 1)`,
//!   peaking at `ρ = 2^−(s+1)`; orientation `k` (angle `πk/4`): `α |cos(θ − πk/4)|³`,
//!   `α² = 0.8` so that the four orientations' squares sum to 1 (the two-sided form keeps every
//!   band real, which is all the standard deviations need).
//! - The low-pass residual is not a feature (the paper's 17-D count leaves it out).
//!
//! **Deviation:** the pyramid is undecimated (every band at full grid resolution, no
//! down-sampling between scales): the masks and their tiling are the same, the band images are
//! just not subsampled, so the standard deviations do not depend on where the grid starts.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

/// Scales.
pub const SCALES: usize = 4;
/// Orientations.
pub const ORIENTATIONS: usize = 4;
/// Features per patch: `SCALES × ORIENTATIONS` band deviations, then the high-pass residual's.
pub const FEATURES: usize = SCALES * ORIENTATIONS + 1;

/// Errors of [`band_deviations`].
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SteerableError {
    /// The grid is not `n × n` with `n ≥ 8`.
    #[error("the grid must be n × n with n ≥ 8 (got {got} values for n = {n})")]
    Shape {
        /// Side given.
        n: usize,
        /// Values given.
        got: usize,
    },
    /// A value is NaN or infinite.
    #[error("grid value {0} is not finite")]
    NonFinite(usize),
}

fn high(x: f64) -> f64 {
    (std::f64::consts::FRAC_PI_2 * (-x).clamp(0.0, 1.0)).cos()
}

fn low(x: f64) -> f64 {
    (std::f64::consts::FRAC_PI_2 * (-x).clamp(0.0, 1.0)).sin()
}

/// Signed frequency of FFT index `i` on an `n`-grid, normalised to Nyquist = 1.
fn freq(i: usize, n: usize) -> f64 {
    let f = if i <= n / 2 {
        i as f64
    } else {
        i as f64 - n as f64
    };
    f / (n as f64 / 2.0)
}

/// A reusable pyramid for `n × n` grids (FFT plans and masks computed once).
pub struct SteerablePyramid {
    n: usize,
    fft: std::sync::Arc<dyn rustfft::Fft<f64>>,
    ifft: std::sync::Arc<dyn rustfft::Fft<f64>>,
    /// Per feature, the real mask over the `n × n` spectrum (row-major).
    masks: Vec<Vec<f64>>,
}

impl std::fmt::Debug for SteerablePyramid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SteerablePyramid")
            .field("n", &self.n)
            .finish()
    }
}

impl SteerablePyramid {
    /// The pyramid for `n × n` grids.
    ///
    /// # Errors
    /// [`SteerableError::Shape`] for `n < 8`.
    pub fn new(n: usize) -> Result<Self, SteerableError> {
        if n < 8 {
            return Err(SteerableError::Shape { n, got: n * n });
        }
        let mut planner = FftPlanner::new();
        let (fft, ifft) = (planner.plan_fft_forward(n), planner.plan_fft_inverse(n));
        let alpha = 0.8f64.sqrt();
        let mut masks = vec![vec![0.0; n * n]; FEATURES];
        for iy in 0..n {
            for ix in 0..n {
                let (fx, fy) = (freq(ix, n), freq(iy, n));
                let rho = (fx * fx + fy * fy).sqrt();
                let i = iy * n + ix;
                if rho == 0.0 {
                    continue; // DC belongs to the low-pass residual
                }
                let x = rho.log2();
                let theta = fy.atan2(fx);
                masks[FEATURES - 1][i] = high(x);
                let mut radial_low = low(x);
                for s in 0..SCALES {
                    let radial = radial_low * high(x + s as f64 + 1.0);
                    for k in 0..ORIENTATIONS {
                        let a = std::f64::consts::PI * k as f64 / ORIENTATIONS as f64;
                        let ang = alpha * (theta - a).cos().abs().powi(3);
                        masks[s * ORIENTATIONS + k][i] = radial * ang;
                    }
                    radial_low *= low(x + s as f64 + 1.0);
                }
            }
        }
        Ok(Self {
            n,
            fft,
            ifft,
            masks,
        })
    }

    /// Grid side.
    pub fn size(&self) -> usize {
        self.n
    }

    fn fft2(&self, data: &mut [Complex<f64>], inverse: bool) {
        let n = self.n;
        let plan = if inverse { &self.ifft } else { &self.fft };
        for row in data.chunks_exact_mut(n) {
            plan.process(row);
        }
        let mut col = vec![Complex::new(0.0, 0.0); n];
        for x in 0..n {
            for y in 0..n {
                col[y] = data[y * n + x];
            }
            plan.process(&mut col);
            for y in 0..n {
                data[y * n + x] = col[y];
            }
        }
    }

    /// The band images (row-major `n × n`, real), in feature order.
    ///
    /// # Errors
    /// [`SteerableError`] for a wrong length or non-finite values.
    pub fn bands(&self, grid: &[f64]) -> Result<Vec<Vec<f64>>, SteerableError> {
        let n = self.n;
        if grid.len() != n * n {
            return Err(SteerableError::Shape { n, got: grid.len() });
        }
        if let Some(i) = grid.iter().position(|x| !x.is_finite()) {
            return Err(SteerableError::NonFinite(i));
        }
        let mut spectrum: Vec<Complex<f64>> = grid.iter().map(|&x| Complex::new(x, 0.0)).collect();
        self.fft2(&mut spectrum, false);
        let norm = 1.0 / (n * n) as f64;
        Ok(self
            .masks
            .iter()
            .map(|mask| {
                let mut b: Vec<Complex<f64>> =
                    spectrum.iter().zip(mask).map(|(c, m)| *c * *m).collect();
                self.fft2(&mut b, true);
                b.iter().map(|c| c.re * norm).collect()
            })
            .collect())
    }

    /// The 17 standard deviations (see the module doc).
    ///
    /// # Errors
    /// As [`SteerablePyramid::bands`].
    pub fn band_deviations(&self, grid: &[f64]) -> Result<[f64; FEATURES], SteerableError> {
        let bands = self.bands(grid)?;
        let mut out = [0.0; FEATURES];
        for (o, b) in out.iter_mut().zip(&bands) {
            let m = b.iter().sum::<f64>() / b.len() as f64;
            *o = (b.iter().map(|x| (x - m).powi(2)).sum::<f64>() / b.len() as f64).sqrt();
        }
        Ok(out)
    }
}
