//! Geodesic fans (Zelinka & Garland, *Similarity-Based Surface Modelling Using Geodesic Fans*,
//! SGP 2004), as used by MeshMatch (Chen, Funkhouser, Goldman & Shechtman 2012, §4.1): per
//! vertex, `R` rings × `A` spokes of filtered samples of a per-vertex field, laid out in the
//! vertex's exponential-map chart ([`super::expmap`]), and compared under cyclic rotation.
//!
//! **Samples.** Ring `i` (0-based) lies at chart radius `ρ_i = (i + 1) · radius / R`, spoke `j` at
//! angle `θ_j = 2πj / A` counter-clockwise from the vertex's tangent, so sample `(i, j)` sits at
//! `ρ_i (cos θ_j, sin θ_j)` in the chart. There is no centre sample (MeshMatch: 3 × 18 RGB
//! samples = 162 numbers per vertex).
//!
//! **Filter.** Each sample is a Gaussian-weighted estimate over the chart vertices `q` within
//! `cutoff · σ` of it, with weights `w_q = a_q · exp(−d²/2σ²)`, `d` the chart distance from the
//! sample to `U(q)` and `a_q` the lumped (barycentric, one third of the incident face areas)
//! vertex area, so irregular sampling is not over-counted. `σ = sigma · (radius / R)`: a fraction
//! of the ring spacing (default one half). [`FanFilter::Gaussian`] is the normalized weighted
//! mean. [`FanFilter::LocalLinear`] (default) is the Gaussian-weighted local linear fit
//! (the sample value is the constant term of the weighted least-squares plane through the
//! neighbours): it equals the Gaussian mean of a smooth field up to the bias of irregular or
//! one-sided support, and reproduces linear fields exactly. Its effective weights can be
//! negative, so values may overshoot the neighbours' range slightly. When the fit is ill
//! conditioned it falls back to the mean, and a sample with no neighbour in reach (past a mesh
//! boundary) takes the value of the nearest chart vertex. Both filters are linear in the field;
//! [`super::fan_filter`] computes them as weights per neighbour, which [`FanSampler`] can keep
//! ([`FanSampler::cache_weights`]) for surfaces sampled many times.
//!
//! **Layout.** `Fans::data` is row-major per vertex: `[vertex][ring][spoke][dim]`.
//!
//! **Rotation.** Rotating a field by `k · 360°/A` counter-clockwise about a vertex shifts its fan
//! by `k` spokes: [`FanShape::distance`]`(a, b, k)` compares spoke `j` of `a` with spoke
//! `j + k (mod A)` of `b`, which is zero when `b` is `a` rotated counter-clockwise by `k` spokes.
//! Written by hand: no crate does this.

use super::super::control::{Cancelled, Control};
use super::super::mesh::surface::Surface;
use super::expmap::{
    world_radius, ChartBuilder, Connection, ExpMapParams, LocalFrames, RadiusUnit, CHUNK,
};
use super::fan_filter::{FanWeights, Kernel, Layout, Scratch};
use rayon::prelude::*;

/// Errors of [`geodesic_fans`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FanError {
    /// The control was cancelled.
    #[error("cancelled")]
    Cancelled,
    /// A parameter is outside its documented range.
    #[error("parameter {name} = {value} is outside its valid range {range}")]
    InvalidParam {
        name: &'static str,
        value: f64,
        range: &'static str,
    },
    /// The field or the frames do not match the surface.
    #[error("{what} has {got} values, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
}

impl From<Cancelled> for FanError {
    fn from(_: Cancelled) -> Self {
        FanError::Cancelled
    }
}

/// The sample filter (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FanFilter {
    /// Normalized Gaussian-weighted mean.
    Gaussian,
    /// Gaussian-weighted local linear fit (exact on linear fields). Default.
    #[default]
    LocalLinear,
}

/// Parameters of [`geodesic_fans`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FanParams {
    /// Number of rings `R`. Default: 3. Range: 1..=64.
    pub rings: usize,
    /// Number of spokes `A`; a rotation step is 360°/A. Default: 18. Range: 1..=1024.
    pub spokes: usize,
    /// Radius of the outer ring, in `radius_unit`. Default: 3.0. Range: (0, ∞), finite.
    pub radius: f32,
    /// Unit of `radius`. Default: multiples of the mean edge length.
    pub radius_unit: RadiusUnit,
    /// Gaussian σ as a multiple of the ring spacing `radius / R`. Default: 0.5. Range: (0, ∞).
    pub sigma: f32,
    /// Neighbours farther than `cutoff · σ` from a sample are ignored. Default: 3.0 (weight
    /// e^−4.5 ≈ 1.1% at the cut). Range: (0, ∞).
    pub cutoff: f32,
    /// Sample filter. Default: [`FanFilter::LocalLinear`].
    pub filter: FanFilter,
    /// Upwind averaging in the exponential map ([`ExpMapParams::upwind_average`]). Default: false.
    pub upwind_average: bool,
    /// Most vertices per chart ([`ExpMapParams::max_vertices`]): where the mesh is much denser
    /// than the radius implies, samples beyond the closest vertices fall back to the nearest
    /// one. Default: unbounded. Range: ≥ 1.
    pub max_chart_vertices: usize,
}

impl Default for FanParams {
    fn default() -> Self {
        Self {
            rings: 3,
            spokes: 18,
            radius: 3.0,
            radius_unit: RadiusUnit::MeanEdge,
            sigma: 0.5,
            cutoff: 3.0,
            filter: FanFilter::LocalLinear,
            upwind_average: false,
            max_chart_vertices: usize::MAX,
        }
    }
}

/// A per-vertex field: `dim` floats per vertex, vertex-major (`values[v * dim + c]`).
#[derive(Clone, Copy, Debug)]
pub struct FieldRef<'a> {
    /// Floats per vertex (3 for RGB).
    pub dim: usize,
    /// `vertex_count * dim` values.
    pub values: &'a [f32],
}

/// The shape of one fan; compares fans.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FanShape {
    /// Rings `R`.
    pub rings: usize,
    /// Spokes `A`.
    pub spokes: usize,
    /// Floats per sample.
    pub dim: usize,
}

impl FanShape {
    /// Floats per fan: `rings * spokes * dim`.
    pub fn len(&self) -> usize {
        self.rings * self.spokes * self.dim
    }

    /// Whether a fan holds no floats.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Chart position of sample (`ring`, `spoke`) for an outer radius `radius`.
    pub fn sample_position(&self, radius: f32, ring: usize, spoke: usize) -> [f32; 2] {
        let rho = (ring + 1) as f32 * radius / self.rings as f32;
        let theta = std::f32::consts::TAU * spoke as f32 / self.spokes as f32;
        [rho * theta.cos(), rho * theta.sin()]
    }

    /// Sum of squared differences between spoke `j` of `a` and spoke `j + k (mod A)` of `b`,
    /// over all rings, spokes and channels. No allocation.
    ///
    /// # Panics
    /// If `a` or `b` does not hold [`FanShape::len`] floats.
    pub fn distance(&self, a: &[f32], b: &[f32], k: usize) -> f32 {
        self.distance_below(a, b, k, f32::INFINITY)
    }

    /// The rotation `k` in `0..A` minimizing [`FanShape::distance`]`(a, b, k)`, and that distance;
    /// the lowest `k` on ties. Rotations are abandoned ring by ring once they exceed the best so
    /// far. No allocation.
    ///
    /// # Panics
    /// If `a` or `b` does not hold [`FanShape::len`] floats.
    pub fn best_rotation(&self, a: &[f32], b: &[f32]) -> (usize, f32) {
        let mut best = (0, self.distance(a, b, 0));
        for k in 1..self.spokes {
            let d = self.distance_below(a, b, k, best.1);
            if d < best.1 {
                best = (k, d);
            }
        }
        best
    }

    /// [`FanShape::distance`], but may stop early (returning a partial sum `>= bound`) once
    /// the sum reaches `bound`.
    pub fn distance_below(&self, a: &[f32], b: &[f32], k: usize, bound: f32) -> f32 {
        assert!(
            a.len() == self.len() && b.len() == self.len(),
            "fan lengths {} and {} do not match the shape's {}",
            a.len(),
            b.len(),
            self.len()
        );
        let row = self.spokes * self.dim;
        let shift = (k % self.spokes.max(1)) * self.dim;
        let mut sum = 0.0f32;
        for (ar, br) in a.chunks_exact(row).zip(b.chunks_exact(row)) {
            sum += squared_difference(&ar[..row - shift], &br[shift..])
                + squared_difference(&ar[row - shift..], &br[..shift]);
            if sum >= bound {
                break;
            }
        }
        sum
    }

    /// Ring weights proportional to the surface area each ring's samples stand for: ring `i`
    /// (radius `(i + 1)·h`) covers an annulus sector of area ∝ `i + 1`; normalized to mean 1,
    /// `2(i + 1)/(R + 1)`.
    pub fn area_ring_weights(&self) -> Vec<f32> {
        let r = self.rings as f32;
        (0..self.rings)
            .map(|i| 2.0 * (i + 1) as f32 / (r + 1.0))
            .collect()
    }

    /// Floats of [`FanShape::ring_stats`] per fan: per ring, the mean sample and the norm of
    /// the samples minus that mean.
    pub fn stats_len(&self) -> usize {
        self.rings * (self.dim + 1)
    }

    /// Rotation-invariant statistics of every fan in `fans` ([`FanShape::len`] floats each), for
    /// [`FanShape::rotation_free_bound`]: per fan and ring, the `dim` channel means over the
    /// spokes, then the Euclidean norm of the ring's samples minus those means.
    pub fn ring_stats(&self, fans: &[f32]) -> Vec<f32> {
        let (n, row) = (self.len(), self.spokes * self.dim);
        if n == 0 {
            return Vec::new();
        }
        let mut out = vec![0.0f32; fans.len() / n * self.stats_len()];
        out.par_chunks_mut(self.dim + 1)
            .zip(fans.par_chunks_exact(row))
            .for_each(|(stats, ring)| {
                let (mean, norm) = stats.split_at_mut(self.dim);
                for sample in ring.chunks_exact(self.dim) {
                    for (m, x) in mean.iter_mut().zip(sample) {
                        *m += x;
                    }
                }
                mean.iter_mut().for_each(|m| *m /= self.spokes as f32);
                let mut sq = 0.0f32;
                for sample in ring.chunks_exact(self.dim) {
                    for (m, x) in mean.iter().zip(sample) {
                        sq += (x - m) * (x - m);
                    }
                }
                norm[0] = sq.sqrt();
            });
        out
    }

    /// A lower bound of [`FanShape::distance`]`(a, b, k)` for every rotation `k`, from the
    /// fans' [`FanShape::ring_stats`]: per ring, `A‖μ_a − μ_b‖² + (‖ã‖ − ‖b̃‖)²`, with `μ` the
    /// ring's mean sample and `ã` its samples minus the mean. Exact algebra: rotation permutes
    /// the spokes, so the means and residual norms do not change, the cross term of mean and
    /// residual is zero (residuals sum to zero), and `‖ã − R b̃‖ ≥ |‖ã‖ − ‖b̃‖|`.
    /// `ring_weights` as in [`FanShape::distance_below_doubled`].
    pub fn rotation_free_bound(&self, sa: &[f32], sb: &[f32], ring_weights: &[f32]) -> f32 {
        let mut sum = 0.0f32;
        for (ring, (ra, rb)) in sa
            .chunks_exact(self.dim + 1)
            .zip(sb.chunks_exact(self.dim + 1))
            .enumerate()
        {
            let mut mean = 0.0f32;
            for c in 0..self.dim {
                mean += (ra[c] - rb[c]) * (ra[c] - rb[c]);
            }
            let norm = ra[self.dim] - rb[self.dim];
            let d = self.spokes as f32 * mean + norm * norm;
            sum += ring_weights.get(ring).map_or(d, |w| w * d);
        }
        sum
    }

    /// Floats of a fan whose rings are written twice ([`FanShape::double_rings`]).
    pub fn doubled_len(&self) -> usize {
        2 * self.len()
    }

    /// Writes `b` into `out` with every ring twice in a row, so the ring rotated by any `k`
    /// spokes is one contiguous slice (for [`FanShape::distance_below_doubled`]).
    ///
    /// # Panics
    /// If `b` does not hold [`FanShape::len`] floats or `out` not [`FanShape::doubled_len`].
    pub fn double_rings(&self, b: &[f32], out: &mut [f32]) {
        assert!(b.len() == self.len() && out.len() == self.doubled_len());
        let row = self.spokes * self.dim;
        if row == 0 {
            return;
        }
        for (src, dst) in b.chunks_exact(row).zip(out.chunks_exact_mut(2 * row)) {
            dst[..row].copy_from_slice(src);
            dst[row..].copy_from_slice(src);
        }
    }

    /// [`FanShape::distance_below`] with `b` given by [`FanShape::double_rings`]: each ring is
    /// one contiguous comparison instead of two (the E-step's inner loop).
    ///
    /// `ring_weights`: one factor per ring on that ring's sum (empty: every ring 1).
    pub fn distance_below_doubled(
        &self,
        a: &[f32],
        b2: &[f32],
        k: usize,
        bound: f32,
        ring_weights: &[f32],
    ) -> f32 {
        assert!(
            a.len() == self.len() && b2.len() == self.doubled_len(),
            "fan lengths {} and {} do not match the shape's {} and {}",
            a.len(),
            b2.len(),
            self.len(),
            self.doubled_len()
        );
        let row = self.spokes * self.dim;
        if row == 0 {
            return 0.0;
        }
        let shift = (k % self.spokes.max(1)) * self.dim;
        let mut sum = 0.0f32;
        for (ring, (ar, br)) in a
            .chunks_exact(row)
            .zip(b2.chunks_exact(2 * row))
            .enumerate()
        {
            let d = squared_difference(ar, &br[shift..shift + row]);
            sum += ring_weights.get(ring).map_or(d, |w| w * d);
            if sum >= bound {
                break;
            }
        }
        sum
    }
}

/// Sum of squared differences of two equally long slices, in 8 independent lanes (so it
/// vectorizes); the lane order is fixed, so the result is deterministic.
#[inline]
fn squared_difference(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    let (ac, bc) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        for l in 0..8 {
            let d = x[l] - y[l];
            lanes[l] += d * d;
        }
    }
    let mut tail = 0.0f32;
    for (x, y) in ar.iter().zip(br) {
        tail += (x - y) * (x - y);
    }
    lanes.iter().sum::<f32>() + tail
}

/// Geodesic fans of every vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Fans {
    /// Rings `R`.
    pub rings: usize,
    /// Spokes `A`.
    pub spokes: usize,
    /// Floats per sample.
    pub dim: usize,
    /// Outer ring radius, world units.
    pub radius: f32,
    /// Gaussian σ, world units.
    pub sigma: f32,
    /// `[vertex][ring][spoke][dim]`, row-major.
    pub data: Vec<f32>,
}

impl Fans {
    /// The shape of each fan.
    pub fn shape(&self) -> FanShape {
        FanShape {
            rings: self.rings,
            spokes: self.spokes,
            dim: self.dim,
        }
    }

    /// Number of fans (vertices).
    pub fn len(&self) -> usize {
        self.data.len().checked_div(self.shape().len()).unwrap_or(0)
    }

    /// Whether there are no fans.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The fan of vertex `v`.
    pub fn fan(&self, v: usize) -> &[f32] {
        let n = self.shape().len();
        &self.data[v * n..(v + 1) * n]
    }
}

/// Samples `field` on a fan around every vertex (parallel over vertices; one Control stage
/// "geodesic fans" with one unit of work per vertex). Deterministic for any thread count.
///
/// # Errors
/// [`FanError::InvalidParam`], [`FanError::LengthMismatch`], [`FanError::Cancelled`].
pub fn geodesic_fans(
    surface: &Surface,
    frames: &LocalFrames,
    field: FieldRef<'_>,
    params: &FanParams,
    control: &Control,
) -> Result<Fans, FanError> {
    validate(surface, frames, field, params)?;
    let nv = surface.vertex_count();
    let shape = FanShape {
        rings: params.rings,
        spokes: params.spokes,
        dim: field.dim,
    };
    let Geometry {
        radius,
        sigma,
        reach,
        samples,
    } = geometry(surface, params)?;
    let chart_params = ExpMapParams {
        radius,
        radius_unit: RadiusUnit::World,
        upwind_average: params.upwind_average,
        max_vertices: params.max_chart_vertices,
    };
    let area = lumped_areas(surface);
    let connection = Connection::new(surface, frames);
    let stage = control.stage("geodesic fans", nv as u64)?;
    let mut data = vec![0.0f32; nv * shape.len()];
    let kernel = Kernel::new(sigma, reach, params.filter);
    let layout = Layout {
        shape,
        radius,
        reach,
        samples: &samples,
        area: &area,
    };
    data.par_chunks_mut(CHUNK * shape.len().max(1))
        .enumerate()
        .try_for_each_init(
            || (ChartBuilder::new(nv), Scratch::new()),
            |(builder, scratch), (chunk, out)| {
                for (i, fan) in out.chunks_exact_mut(shape.len()).enumerate() {
                    let s = chunk * CHUNK + i;
                    let chart = builder.build(&connection, s, radius + reach, &chart_params);
                    layout.fill(chart.vertex, chart.coords, &kernel, field, scratch, fan);
                    // Per source: a chart can be large when the radius is.
                    stage.tick(1)?;
                }
                Ok::<(), Cancelled>(())
            },
        )?;
    Ok(Fans {
        rings: shape.rings,
        spokes: shape.spokes,
        dim: shape.dim,
        radius,
        sigma,
        data,
    })
}

/// Fans of one surface for many fields (MeshMatch samples the target's changing colours once per
/// EM iteration): the exponential-map charts (radius + reach) are built once by [`FanSampler::new`]
/// and reused by every [`FanSampler::sample`], which gives exactly what [`geodesic_fans`] gives.
pub struct FanSampler {
    params: FanParams,
    radius: f32,
    sigma: f32,
    reach: f32,
    samples: Vec<[f32; 2]>,
    area: Vec<f32>,
    charts: super::expmap::ExpMap,
    /// The filter weights of every sample, once [`FanSampler::cache_weights`] ran.
    weights: Option<FanWeights>,
}

impl FanSampler {
    /// Builds the charts of every vertex of `surface`.
    ///
    /// # Errors
    /// As [`geodesic_fans`] (the field is checked later).
    pub fn new(
        surface: &Surface,
        frames: &LocalFrames,
        params: &FanParams,
        control: &Control,
    ) -> Result<Self, FanError> {
        let nv = surface.vertex_count();
        let probe = vec![0.0f32; nv];
        validate(
            surface,
            frames,
            FieldRef {
                dim: 1,
                values: &probe,
            },
            params,
        )?;
        let Geometry {
            radius,
            sigma,
            reach,
            samples,
        } = geometry(surface, params)?;
        let charts = super::expmap::exponential_map(
            surface,
            frames,
            &ExpMapParams {
                radius: radius + reach,
                radius_unit: RadiusUnit::World,
                upwind_average: params.upwind_average,
                max_vertices: params.max_chart_vertices,
            },
            control,
        )
        .map_err(|e| match e {
            super::expmap::ExpMapError::Cancelled => FanError::Cancelled,
            super::expmap::ExpMapError::InvalidParam { name, value, range } => {
                FanError::InvalidParam { name, value, range }
            }
            super::expmap::ExpMapError::FrameCount { expected, got } => FanError::LengthMismatch {
                what: "frames",
                expected,
                got,
            },
        })?;
        Ok(Self {
            params: params.clone(),
            radius,
            sigma,
            reach,
            samples,
            area: lumped_areas(surface),
            charts,
            weights: None,
        })
    }

    fn kernel(&self) -> Kernel {
        Kernel::new(self.sigma, self.reach, self.params.filter)
    }

    fn layout(&self) -> Layout<'_> {
        Layout {
            shape: FanShape {
                rings: self.params.rings,
                spokes: self.params.spokes,
                dim: 1,
            },
            radius: self.radius,
            reach: self.reach,
            samples: &self.samples,
            area: &self.area,
        }
    }

    /// Computes and keeps the filter weights of every fan sample (one Control stage "fan
    /// weights"), so every later [`FanSampler::sample`] is a gather: worth it when the same
    /// charts sample several fields. Costs 8 bytes per weight ([`FanSampler::cached_weights`];
    /// about 8 per sample with the default filter). The fans are the same, bit for bit.
    ///
    /// # Errors
    /// [`FanError::Cancelled`].
    pub fn cache_weights(&mut self, control: &Control) -> Result<(), FanError> {
        let nv = self.area.len();
        let stage = control.stage("fan weights", nv as u64)?;
        let weights = FanWeights::build(&self.layout(), &self.kernel(), &self.charts, &|n| {
            stage.tick(n)
        })?;
        self.weights = Some(weights);
        Ok(())
    }

    /// Weights kept by [`FanSampler::cache_weights`] (0 before).
    pub fn cached_weights(&self) -> usize {
        self.weights.as_ref().map_or(0, FanWeights::len)
    }

    /// The charts (radius = fan radius + filter reach), world units.
    pub fn charts(&self) -> &super::expmap::ExpMap {
        &self.charts
    }

    /// Outer ring radius, world units.
    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// Samples `field` on every fan (parallel; one Control tick per vertex).
    ///
    /// # Errors
    /// [`FanError::LengthMismatch`] when `field` does not fit the surface; [`FanError::Cancelled`].
    pub fn sample(&self, field: FieldRef<'_>, control: &Control) -> Result<Fans, FanError> {
        let nv = self.area.len();
        if field.dim == 0 {
            return Err(FanError::InvalidParam {
                name: "field.dim",
                value: 0.0,
                range: "1..",
            });
        }
        if field.values.len() != nv * field.dim {
            return Err(FanError::LengthMismatch {
                what: "field",
                expected: nv * field.dim,
                got: field.values.len(),
            });
        }
        let shape = FanShape {
            rings: self.params.rings,
            spokes: self.params.spokes,
            dim: field.dim,
        };
        let stage = control.stage("geodesic fans", nv as u64)?;
        let mut data = vec![0.0f32; nv * shape.len()];
        if let Some(weights) = &self.weights {
            weights.sample(field, &mut data, control);
            control.check()?;
            stage.tick(nv as u64)?;
        } else {
            let (kernel, layout) = (self.kernel(), self.layout());
            data.par_chunks_mut(CHUNK * shape.len().max(1))
                .enumerate()
                .try_for_each_init(Scratch::new, |scratch, (chunk, out)| {
                    for (i, fan) in out.chunks_exact_mut(shape.len()).enumerate() {
                        let (vertex, coords) = self.charts.chart(chunk * CHUNK + i);
                        layout.fill(vertex, coords, &kernel, field, scratch, fan);
                    }
                    stage.tick((out.len() / shape.len().max(1)) as u64)
                })?;
        }
        Ok(Fans {
            rings: shape.rings,
            spokes: shape.spokes,
            dim: shape.dim,
            radius: self.radius,
            sigma: self.sigma,
            data,
        })
    }
}

/// World radius, filter σ and reach, and the chart positions of the samples.
struct Geometry {
    radius: f32,
    sigma: f32,
    reach: f32,
    samples: Vec<[f32; 2]>,
}

fn geometry(surface: &Surface, params: &FanParams) -> Result<Geometry, FanError> {
    let radius = world_radius(surface, params.radius, params.radius_unit);
    if surface.vertex_count() > 0 && !(radius > 0.0 && radius.is_finite()) {
        // E.g. a radius in mean edge lengths on a surface without faces.
        return Err(FanError::InvalidParam {
            name: "radius (world units)",
            value: radius as f64,
            range: "(0, inf)",
        });
    }
    let sigma = params.sigma * radius / params.rings as f32;
    let shape = FanShape {
        rings: params.rings,
        spokes: params.spokes,
        dim: 1,
    };
    Ok(Geometry {
        radius,
        sigma,
        reach: params.cutoff * sigma,
        samples: (0..params.rings)
            .flat_map(|i| (0..params.spokes).map(move |j| shape.sample_position(radius, i, j)))
            .collect(),
    })
}

fn validate(
    surface: &Surface,
    frames: &LocalFrames,
    field: FieldRef<'_>,
    params: &FanParams,
) -> Result<(), FanError> {
    let bad = |name, value: f64, range| FanError::InvalidParam { name, value, range };
    if !(1..=64).contains(&params.rings) {
        return Err(bad("rings", params.rings as f64, "1..=64"));
    }
    if !(1..=1024).contains(&params.spokes) {
        return Err(bad("spokes", params.spokes as f64, "1..=1024"));
    }
    for (name, v) in [
        ("radius", params.radius),
        ("sigma", params.sigma),
        ("cutoff", params.cutoff),
    ] {
        if !(v > 0.0 && v.is_finite()) {
            return Err(bad(name, v as f64, "(0, inf)"));
        }
    }
    if field.dim == 0 {
        return Err(bad("field.dim", 0.0, "1.."));
    }
    let nv = surface.vertex_count();
    if field.values.len() != nv * field.dim {
        return Err(FanError::LengthMismatch {
            what: "field",
            expected: nv * field.dim,
            got: field.values.len(),
        });
    }
    if frames.len() != nv {
        return Err(FanError::LengthMismatch {
            what: "frames",
            expected: nv,
            got: frames.len(),
        });
    }
    Ok(())
}

/// One third of the incident face areas per vertex (barycentric lumped mass).
fn lumped_areas(surface: &Surface) -> Vec<f32> {
    let mut area = vec![0.0f32; surface.vertex_count()];
    for (f, face) in surface.faces.iter().enumerate() {
        let a = surface.face_area(f) / 3.0;
        for &v in face {
            area[v as usize] += a;
        }
    }
    area
}
