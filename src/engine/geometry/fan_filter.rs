//! The sample filter of the geodesic fans ([`super::fans`]; Zelinka & Garland 2004, as used by
//! MeshMatch, Chen et al. 2012 §4.1) as *linear weights*: every fan sample is a weighted sum of
//! the field at a few chart vertices, and the weights depend on the charts only, not on the field.
//!
//! **Weights.** For the sample at chart position `s` and the chart vertices `q` within the
//! filter's reach, with Gaussian weights `w_q = a_q · exp(−|U(q) − s|²/2σ²)` (`a_q` the lumped
//! vertex area):
//! - [`FanFilter::Gaussian`]: `c_q = w_q / Σ w`;
//! - [`FanFilter::LocalLinear`]: `c_q = w_q · (c0 + c1 x_q + c2 y_q) / det`, where
//!   `(x_q, y_q) = (U(q) − s)/σ` and `(c0, c1, c2)/det` is the first row of the inverse of the
//!   weighted moment matrix `[[Σw Σwx Σwy][Σwx Σwxx Σwxy][Σwy Σwxy Σwyy]]`: the constant term of
//!   the weighted least-squares plane, written as a weight per neighbour. When the moment matrix
//!   is ill conditioned the Gaussian weights are used;
//! - no neighbour in reach (past a boundary): weight 1 on the nearest chart vertex.
//!
//! **Cache.** [`FanWeights`] keeps the weights of every sample of every fan, so a surface whose
//! field changes (MeshMatch's target colours, re-sampled at every EM iteration) pays the
//! exponentials, moments and inverses once per level; each later sampling is a gather of
//! about 8 weighted values per sample (measured on the module's MeshMatch use: see the README).
//! It costs 8 bytes per weight (vertex index and `f32` weight). The same weights, applied in the
//! same order, give the uncached fans, so both paths agree bit for bit.
//!
//! Written by hand: no crate does this.

use super::super::control::{Cancelled, Control};
use super::expmap::{ExpMap, CHUNK};
use super::fans::{FanFilter, FanShape, FieldRef};
use rayon::prelude::*;

/// The Gaussian and its reach, in chart units.
pub(super) struct Kernel {
    pub inv_two_sigma2: f32,
    pub inv_sigma: f32,
    pub reach2: f32,
    pub filter: FanFilter,
}

/// What every fan of one surface shares: layout, sample positions, vertex areas.
pub(super) struct Layout<'a> {
    pub shape: FanShape,
    pub radius: f32,
    pub reach: f32,
    pub samples: &'a [[f32; 2]],
    pub area: &'a [f32],
}

/// Per-thread scratch: the chart vertices of one ring's band (structure of arrays) and the
/// weights of the current sample.
pub(super) struct Scratch {
    x: Vec<f32>,
    y: Vec<f32>,
    vertex: Vec<u32>,
    area: Vec<f32>,
    d2: Vec<f32>,
    /// Indices (into the band) of the vertices within reach of the current sample.
    near: Vec<u32>,
    /// The current sample's weights: field vertices and their weights.
    pub weight_vertex: Vec<u32>,
    pub weight: Vec<f32>,
}

impl Scratch {
    pub fn new() -> Self {
        Scratch {
            x: Vec::new(),
            y: Vec::new(),
            vertex: Vec::new(),
            area: Vec::new(),
            d2: Vec::new(),
            near: Vec::new(),
            weight_vertex: Vec::new(),
            weight: Vec::new(),
        }
    }

    /// Keeps the chart vertices whose radius is within `reach` of `rho`.
    fn band(&mut self, vertex: &[u32], coords: &[[f32; 2]], area: &[f32], rho: f32, reach: f32) {
        self.x.clear();
        self.y.clear();
        self.vertex.clear();
        self.area.clear();
        let (lo, hi) = ((rho - reach).max(0.0), rho + reach);
        let (lo2, hi2) = (lo * lo, hi * hi);
        for (&v, u) in vertex.iter().zip(coords) {
            let r2 = u[0] * u[0] + u[1] * u[1];
            if r2 >= lo2 && r2 <= hi2 {
                self.x.push(u[0]);
                self.y.push(u[1]);
                self.vertex.push(v);
                self.area.push(area[v as usize]);
            }
        }
        self.d2.resize(self.x.len(), 0.0);
        self.near.resize(self.x.len() + 1, 0);
    }
}

impl Layout<'_> {
    /// Calls `each(sample, vertices, weights)` for every sample of the fan of the chart
    /// `(vertex, coords)`, in `[ring][spoke]` order.
    pub fn weigh(
        &self,
        vertex: &[u32],
        coords: &[[f32; 2]],
        kernel: &Kernel,
        scratch: &mut Scratch,
        mut each: impl FnMut(usize, &[u32], &[f32]),
    ) {
        let shape = self.shape;
        for ring in 0..shape.rings {
            // Only chart vertices with | |U| − ρ | <= reach can be within reach of a sample on
            // ring ρ.
            let rho = (ring + 1) as f32 * self.radius / shape.rings as f32;
            scratch.band(vertex, coords, self.area, rho, self.reach);
            for spoke in 0..shape.spokes {
                let sample = ring * shape.spokes + spoke;
                let s = self.samples[sample];
                if !kernel.weights(s, scratch) {
                    scratch.weight_vertex.clear();
                    scratch.weight.clear();
                    scratch
                        .weight_vertex
                        .push(nearest_vertex(s, vertex, coords));
                    scratch.weight.push(1.0);
                }
                each(sample, &scratch.weight_vertex, &scratch.weight);
            }
        }
    }

    /// Fills one fan (`rings × spokes × dim` floats) from the chart `(vertex, coords)`.
    pub fn fill(
        &self,
        vertex: &[u32],
        coords: &[[f32; 2]],
        kernel: &Kernel,
        field: FieldRef<'_>,
        scratch: &mut Scratch,
        fan: &mut [f32],
    ) {
        let dim = field.dim;
        self.weigh(vertex, coords, kernel, scratch, |sample, v, w| {
            apply(v, w, field, &mut fan[sample * dim..(sample + 1) * dim]);
        });
    }
}

/// `value = Σ_k weight_k · field[vertex_k]` per channel, accumulated in `f64`.
fn apply(vertex: &[u32], weight: &[f32], field: FieldRef<'_>, value: &mut [f32]) {
    let dim = field.dim;
    if dim == 3 {
        let mut acc = [0.0f64; 3];
        for (&v, &w) in vertex.iter().zip(weight) {
            let f = &field.values[v as usize * 3..v as usize * 3 + 3];
            let w = w as f64;
            acc[0] += w * f[0] as f64;
            acc[1] += w * f[1] as f64;
            acc[2] += w * f[2] as f64;
        }
        for c in 0..3 {
            value[c] = acc[c] as f32;
        }
        return;
    }
    for (c, out) in value.iter_mut().enumerate() {
        let mut acc = 0.0f64;
        for (&v, &w) in vertex.iter().zip(weight) {
            acc += w as f64 * field.values[v as usize * dim + c] as f64;
        }
        *out = acc as f32;
    }
}

/// The chart vertex nearest to `s`.
fn nearest_vertex(s: [f32; 2], vertex: &[u32], coords: &[[f32; 2]]) -> u32 {
    let mut nearest = (f32::INFINITY, vertex[0]);
    for (&v, u) in vertex.iter().zip(coords) {
        let d2 = (u[0] - s[0]).powi(2) + (u[1] - s[1]).powi(2);
        if d2 < nearest.0 {
            nearest = (d2, v);
        }
    }
    nearest.1
}

impl Kernel {
    /// The kernel of Gaussian width `sigma` cut at `reach` (chart units).
    pub fn new(sigma: f32, reach: f32, filter: FanFilter) -> Kernel {
        Kernel {
            inv_two_sigma2: 1.0 / (2.0 * sigma * sigma),
            inv_sigma: 1.0 / sigma,
            reach2: reach * reach,
            filter,
        }
    }

    /// Writes the filter weights of the sample at chart position `s` over the band in `scratch`
    /// into `scratch.weight_vertex` / `scratch.weight`; false when no band vertex is in reach.
    fn weights(&self, s: [f32; 2], scratch: &mut Scratch) -> bool {
        // Pass 1 (vectorizes): squared chart distances to the sample.
        for ((d2, x), y) in scratch.d2.iter_mut().zip(&scratch.x).zip(&scratch.y) {
            let (dx, dy) = (x - s[0], y - s[1]);
            *d2 = dx * dx + dy * dy;
        }
        // Branch-free compaction of the band vertices within reach.
        let mut n = 0;
        for (k, &d2) in scratch.d2.iter().enumerate() {
            scratch.near[n] = k as u32;
            n += (d2 <= self.reach2) as usize;
        }
        // Pass 2: Gaussian weights (kept in `weight`) and their moments.
        scratch.weight_vertex.clear();
        scratch.weight.clear();
        let (mut s0, mut sx, mut sy, mut sxx, mut sxy, mut syy) = (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut gauss_sum = 0.0f32;
        for &k in &scratch.near[..n] {
            let k = k as usize;
            let g = (-scratch.d2[k] * self.inv_two_sigma2).exp();
            gauss_sum += g;
            let w = g * scratch.area[k];
            let wd = w as f64;
            let x = ((scratch.x[k] - s[0]) * self.inv_sigma) as f64;
            let y = ((scratch.y[k] - s[1]) * self.inv_sigma) as f64;
            s0 += wd;
            sx += wd * x;
            sy += wd * y;
            sxx += wd * x * x;
            sxy += wd * x * y;
            syy += wd * y * y;
            scratch.weight_vertex.push(scratch.vertex[k]);
            scratch.weight.push(w);
        }
        if gauss_sum < 1e-4 || s0 <= 0.0 {
            return false;
        }
        if self.filter == FanFilter::LocalLinear {
            let c0 = sxx * syy - sxy * sxy;
            let c1 = sxy * sy - sx * syy;
            let c2 = sx * sxy - sxx * sy;
            let det = s0 * c0 + sx * c1 + sy * c2;
            if det > 1e-3 * s0 * s0 * s0 {
                for (&k, w) in scratch.near[..n].iter().zip(scratch.weight.iter_mut()) {
                    let k = k as usize;
                    let x = ((scratch.x[k] - s[0]) * self.inv_sigma) as f64;
                    let y = ((scratch.y[k] - s[1]) * self.inv_sigma) as f64;
                    *w = (*w as f64 * (c0 + c1 * x + c2 * y) / det) as f32;
                }
                return true;
            }
        }
        for w in scratch.weight.iter_mut() {
            *w = (*w as f64 / s0) as f32;
        }
        true
    }
}

/// The filter weights of every sample of every fan of one surface, in chunks of [`CHUNK`]
/// vertices (so the offsets stay `u32` whatever the surface's size).
pub(super) struct FanWeights {
    chunks: Vec<WeightChunk>,
    samples_per_fan: usize,
}

struct WeightChunk {
    /// `fans × samples + 1` offsets into `vertex` / `weight`.
    offsets: Vec<u32>,
    vertex: Vec<u32>,
    weight: Vec<f32>,
}

impl FanWeights {
    /// The weights of every fan of the charts `charts` (parallel over chunks; one Control tick
    /// per vertex on the caller's stage).
    pub fn build(
        layout: &Layout<'_>,
        kernel: &Kernel,
        charts: &ExpMap,
        tick: &(dyn Fn(u64) -> Result<(), Cancelled> + Sync),
    ) -> Result<Self, Cancelled> {
        let nv = charts.offsets.len().saturating_sub(1);
        let samples_per_fan = layout.shape.rings * layout.shape.spokes;
        let chunks = (0..nv.div_ceil(CHUNK))
            .into_par_iter()
            .map_init(Scratch::new, |scratch, chunk| {
                let range = chunk * CHUNK..((chunk + 1) * CHUNK).min(nv);
                let fans = range.len();
                let mut out = WeightChunk {
                    offsets: Vec::with_capacity(fans * samples_per_fan + 1),
                    vertex: Vec::new(),
                    weight: Vec::new(),
                };
                out.offsets.push(0);
                for v in range {
                    let (vertex, coords) = charts.chart(v);
                    layout.weigh(vertex, coords, kernel, scratch, |_, vs, ws| {
                        out.vertex.extend_from_slice(vs);
                        out.weight.extend_from_slice(ws);
                        out.offsets.push(out.vertex.len() as u32);
                    });
                }
                out.vertex.shrink_to_fit();
                out.weight.shrink_to_fit();
                tick(fans as u64)?;
                Ok(out)
            })
            .collect::<Result<Vec<_>, Cancelled>>()?;
        Ok(Self {
            chunks,
            samples_per_fan,
        })
    }

    /// Weights kept.
    pub fn len(&self) -> usize {
        self.chunks.iter().map(|c| c.vertex.len()).sum()
    }

    /// Fans of `field`: `data` holds `fans × samples × dim` floats (parallel over chunks).
    pub fn sample(&self, field: FieldRef<'_>, data: &mut [f32], control: &Control) {
        let dim = field.dim;
        let per_fan = self.samples_per_fan * dim;
        data.par_chunks_mut(CHUNK * per_fan.max(1))
            .zip(self.chunks.par_iter())
            .for_each(|(out, chunk)| {
                if control.is_cancelled() {
                    return;
                }
                for (i, value) in out.chunks_exact_mut(dim).enumerate() {
                    let (a, b) = (chunk.offsets[i] as usize, chunk.offsets[i + 1] as usize);
                    apply(&chunk.vertex[a..b], &chunk.weight[a..b], field, value);
                }
            });
    }
}
