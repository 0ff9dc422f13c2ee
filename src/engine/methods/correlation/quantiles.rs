//! Weighted 1-D distributions kept as inverse CDFs, and exact quantile transfer (Mertens et al.
//! 2006, §4 and §5.2; Heeger & Bergen 1995 "match-histogram"; Pitié et al. 2005 per-axis step).
//!
//! A [`Quantiles`] is a set of knots `(u_i, v_i)`: the sorted values `v_i` and the midpoints `u_i`
//! of their cumulative weight intervals, divided by the total weight (so `u_i` is in (0, 1)). The
//! inverse CDF is piecewise linear between knots and constant outside the first and last knot.
//! With equal weights and the same sample size, [`match_to`] therefore maps the `i`-th smallest
//! value exactly onto the target's `i`-th smallest value.
//!
//! Deviations from the papers: H&B match histograms with 256 bins; here the distributions are
//! kept exact (every sample is a knot), which is cheaper than binning at the sample counts used
//! and has no bin-width parameter. [`Quantiles::blend`] (the interpolation of histograms between
//! clusters of §5.2, "blending inverse CDFs") evaluates the parts on the union of their knots;
//! when that union exceeds [`BLEND_KNOTS`] it uses that many evenly spaced `u` instead (a choice of
//! retex: 4096 knots keep the inverse CDF's error below 1/4096 of its range per unit slope, far
//! below the 8-bit output's resolution).
//!
//! Conventions: non-finite values and zero (or negative, or non-finite) weights are ignored; an
//! empty distribution has the value 0 everywhere.

/// Most knots a blended distribution keeps (see the module docs).
pub const BLEND_KNOTS: usize = 4096;

/// A weighted 1-D distribution kept as an inverse CDF (sorted values with cumulative weights).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Quantiles {
    /// Knot positions in (0, 1), non-decreasing.
    u: Vec<f32>,
    /// Knot values, non-decreasing.
    v: Vec<f32>,
}

/// A usable weight: finite and positive.
fn usable(w: f32) -> bool {
    w.is_finite() && w > 0.0
}

/// The bits of `x` as an unsigned key with the order of [`f32::total_cmp`].
fn order_key(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Indices of the samples that count, sorted by value (ties by index: stable). The sort runs on
/// packed `(value key, index)` integers, so it compares in cache instead of through the indices.
fn sorted_indices(values: &[f32], weights: Option<&[f32]>) -> Vec<u32> {
    let mut keys: Vec<u64> = (0..values.len() as u32)
        .filter(|&i| {
            values[i as usize].is_finite() && weights.is_none_or(|w| usable(w[i as usize]))
        })
        .map(|i| (u64::from(order_key(values[i as usize])) << 32) | u64::from(i))
        .collect();
    keys.sort_unstable();
    keys.into_iter().map(|k| k as u32).collect()
}

/// Midpoint cumulative weight (in (0, 1)) of each index of `idx`, in `idx` order.
fn midpoints(idx: &[u32], weights: Option<&[f32]>) -> Vec<f32> {
    let w = |i: u32| weights.map_or(1.0, |w| w[i as usize] as f64);
    let total: f64 = idx.iter().map(|&i| w(i)).sum();
    let mut acc = 0.0f64;
    idx.iter()
        .map(|&i| {
            let wi = w(i);
            let u = (acc + 0.5 * wi) / total;
            acc += wi;
            u as f32
        })
        .collect()
}

impl Quantiles {
    /// The distribution of `values` with `weights` (one per value, ≥ 0; `None` = equal).
    ///
    /// # Panics
    /// If `weights` has a different length than `values`.
    pub fn new(values: &[f32], weights: Option<&[f32]>) -> Quantiles {
        if let Some(w) = weights {
            assert_eq!(w.len(), values.len(), "one weight per value");
        }
        let idx = sorted_indices(values, weights);
        let u = midpoints(&idx, weights);
        let v = idx.iter().map(|&i| values[i as usize]).collect();
        Quantiles { u, v }
    }

    /// Number of knots (0 for an empty distribution).
    pub fn len(&self) -> usize {
        self.v.len()
    }

    /// True when no sample counted.
    pub fn is_empty(&self) -> bool {
        self.v.is_empty()
    }

    /// The inverse CDF at `u` (clamped to [0, 1]): linear between knots, the first / last value
    /// outside them; 0 for an empty distribution.
    pub fn value_at(&self, u: f32) -> f32 {
        let n = self.v.len();
        if n == 0 {
            return 0.0;
        }
        let u = if u.is_nan() { 0.5 } else { u.clamp(0.0, 1.0) };
        // First knot with position > u.
        self.between(self.u.partition_point(|&x| x <= u), u)
    }

    /// The inverse CDF at `u` given `j`, the first knot with position > `u` (non-empty).
    fn between(&self, j: usize, u: f32) -> f32 {
        let n = self.v.len();
        if j == 0 {
            return self.v[0];
        }
        if j == n {
            return self.v[n - 1];
        }
        let (u0, u1) = (self.u[j - 1], self.u[j]);
        let (v0, v1) = (self.v[j - 1], self.v[j]);
        if u1 <= u0 {
            return v1;
        }
        let t = (u - u0) / (u1 - u0);
        v0 + t * (v1 - v0)
    }

    /// The mean of the distribution as kept: the integral of the inverse CDF over [0, 1].
    pub fn mean(&self) -> f32 {
        let n = self.v.len();
        if n == 0 {
            return 0.0;
        }
        let mut s = self.u[0] as f64 * self.v[0] as f64;
        for k in 1..n {
            s += 0.5 * (self.u[k] - self.u[k - 1]) as f64 * (self.v[k] + self.v[k - 1]) as f64;
        }
        s += (1.0 - self.u[n - 1] as f64) * self.v[n - 1] as f64;
        s as f32
    }

    /// The weighted mean of the parts' inverse CDFs (§5.2: interpolating a target cluster's
    /// histograms from the nearest source clusters). Parts with a non-positive weight or empty
    /// distributions are skipped; the result is empty when none is left.
    pub fn blend(parts: &[(&Quantiles, f32)]) -> Quantiles {
        let kept: Vec<(&Quantiles, f64)> = parts
            .iter()
            .filter(|(q, w)| usable(*w) && !q.is_empty())
            .map(|(q, w)| (*q, *w as f64))
            .collect();
        let total: f64 = kept.iter().map(|(_, w)| w).sum();
        if kept.is_empty() || total <= 0.0 {
            return Quantiles::default();
        }
        if kept.len() == 1 {
            return kept[0].0.clone();
        }
        let knots: usize = kept.iter().map(|(q, _)| q.len()).sum();
        let u: Vec<f32> = if knots <= BLEND_KNOTS {
            let mut u: Vec<f32> = kept.iter().flat_map(|(q, _)| q.u.iter().copied()).collect();
            u.sort_by(f32::total_cmp);
            u.dedup();
            u
        } else {
            (0..BLEND_KNOTS)
                .map(|k| ((k as f64 + 0.5) / BLEND_KNOTS as f64) as f32)
                .collect()
        };
        let v = u
            .iter()
            .map(|&x| {
                let s: f64 = kept.iter().map(|(q, w)| w * q.value_at(x) as f64).sum();
                (s / total) as f32
            })
            .collect();
        Quantiles { u, v }
    }
}

/// Exact quantile transfer: replaces `values` (weighted by `weights`) by the target distribution's
/// values at their own weighted ranks (ties broken stably), so the result's distribution equals
/// `target`'s. Non-finite values and values with an unusable weight are set to the target's
/// median (they have no rank). An empty target leaves `values` unchanged.
///
/// # Panics
/// If `weights` has a different length than `values`.
pub fn match_to(values: &mut [f32], weights: Option<&[f32]>, target: &Quantiles) {
    if let Some(w) = weights {
        assert_eq!(w.len(), values.len(), "one weight per value");
    }
    if target.is_empty() {
        return;
    }
    let idx = sorted_indices(values, weights);
    let u = midpoints(&idx, weights);
    let mut ranked = vec![false; values.len()];
    // `u` is non-decreasing: one forward walk over the target's knots replaces a binary search
    // per value (the same piecewise-linear inverse CDF as [`Quantiles::value_at`]).
    let mut j = 0usize;
    let n = target.v.len();
    for (&i, &ui) in idx.iter().zip(&u) {
        while j < n && target.u[j] <= ui {
            j += 1;
        }
        values[i as usize] = target.between(j, ui);
        ranked[i as usize] = true;
    }
    let median = target.value_at(0.5);
    for (x, r) in values.iter_mut().zip(&ranked) {
        if !r {
            *x = median;
        }
    }
}
