//! Blending of a synthesis pass (Berkiten et al. 2017, §3.3.1, eqs. 5-7):
//!
//! ```text
//!   w_disp ← w_disp + w_loc · w_val                      (5)
//!   w_loc  = f(‖x_c − x_i‖ / (n/√2))                      (6)
//!   w_val  = f(‖d_curr − d_new‖ / d_max),  d_max = 1      (7)
//!   f(x)   = 2x³ − 3x² + 1   (Turk 2001)
//! ```
//!
//! on displacements normalised to `[0, 1]`. The value shown at a vertex is the `w`-weighted mean
//! of the contributions it received in the current pass. Stated choices (the paper leaves them
//! open):
//! - `f` is clamped to `x ∈ [0, 1]`: the cubic rises again past 1 (`f(1.5) = 1`), which would
//!   give the corners of a patch and large disagreements full weight.
//! - `d_curr` for `w_val` is the mean of the contributions of the *current pass*; a vertex that
//!   has none yet has no synthesised value to disagree with, so its first contribution gets
//!   `w_val = 1`.
//! - Before its first contribution a vertex shows its *base* value (the up-sampled coarser level,
//!   or the previous pass of the same level), which the patch matching may use as context with
//!   a confidence given per pass (see [`Blend::context_weight`]).

/// Weight above which a vertex is skipped as a patch centre (Algorithm 2).
pub const SKIP_WEIGHT: f64 = 0.5;

/// `f(x) = 2x³ − 3x² + 1` for `x` clamped to `[0, 1]`: 1 at 0, 0 at 1, decreasing.
pub fn falloff(x: f64) -> f64 {
    let x = if x.is_nan() { 1.0 } else { x.clamp(0.0, 1.0) };
    2.0 * x * x * x - 3.0 * x * x + 1.0
}

/// Eq. 6: `f(‖x_c − x_i‖ / (n/√2))`, the distance in grid steps, `n` the patch side in steps
/// (0 at the patch's corners).
pub fn location_weight(distance: f64, patch_size: usize) -> f64 {
    falloff(distance / (patch_size.max(1) as f64 / std::f64::consts::SQRT_2))
}

/// Eq. 7: `f(|d_curr − d_new| / d_max)`.
pub fn value_weight(current: f64, new: f64, d_max: f64) -> f64 {
    falloff((current - new).abs() / d_max)
}

/// Per-vertex accumulators of one pass.
#[derive(Clone, Debug)]
pub struct Blend {
    sum: Vec<f64>,
    weight: Vec<f64>,
    base: Vec<f64>,
    base_confidence: f64,
}

impl Blend {
    /// A pass starting from `base` (one value per vertex), trusted as matching context with
    /// `base_confidence ∈ [0, 1]`.
    pub fn new(base: Vec<f64>, base_confidence: f64) -> Blend {
        Blend {
            sum: vec![0.0; base.len()],
            weight: vec![0.0; base.len()],
            base,
            base_confidence: base_confidence.clamp(0.0, 1.0),
        }
    }

    /// Vertex count.
    pub fn len(&self) -> usize {
        self.base.len()
    }

    /// Whether there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.base.is_empty()
    }

    /// `w_disp` of vertex `v` in this pass.
    pub fn weight(&self, v: usize) -> f64 {
        self.weight[v]
    }

    /// Whether `v` is skipped as a patch centre (`w_disp > 0.5`).
    pub fn skip(&self, v: usize) -> bool {
        self.weight[v] > SKIP_WEIGHT
    }

    /// The value shown at `v`: the weighted mean of this pass's contributions, else the base.
    pub fn current(&self, v: usize) -> f64 {
        if self.weight[v] > 0.0 {
            self.sum[v] / self.weight[v]
        } else {
            self.base[v]
        }
    }

    /// How much the patch matching trusts [`Blend::current`] at `v`: `w + (1 − w)·c` with
    /// `w = min(w_disp, 1)` and `c` the base confidence (what is synthesised in this pass
    /// counts fully once its weight reaches 1).
    pub fn context_weight(&self, v: usize) -> f64 {
        let w = self.weight[v].min(1.0);
        w + (1.0 - w) * self.base_confidence
    }

    /// Blends `new` into `v` with location weight `w_loc` (eqs. 5-7); returns the weight added.
    pub fn add(&mut self, v: usize, new: f64, w_loc: f64) -> f64 {
        let w_val = if self.weight[v] > 0.0 {
            value_weight(self.current(v), new, 1.0)
        } else {
            1.0
        };
        let w = w_loc * w_val;
        if w > 0.0 {
            self.sum[v] += w * new;
            self.weight[v] += w;
        }
        w
    }

    /// The shown values of all vertices.
    pub fn values(&self) -> Vec<f64> {
        (0..self.len()).map(|v| self.current(v)).collect()
    }

    /// The `w_disp` of all vertices.
    pub fn weights(&self) -> &[f64] {
        &self.weight
    }
}
