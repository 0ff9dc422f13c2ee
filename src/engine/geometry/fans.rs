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
//! boundary) takes the value of the nearest chart vertex.
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
}

/// Sum of squared differences of two equally long slices, in 8 independent lanes (so it
/// vectorizes); the lane order is fixed, so the result is deterministic.
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
    let kernel = Kernel {
        inv_two_sigma2: 1.0 / (2.0 * sigma * sigma),
        inv_sigma: 1.0 / sigma,
        reach2: reach * reach,
        filter: params.filter,
    };
    data.par_chunks_mut(CHUNK * shape.len().max(1))
        .enumerate()
        .try_for_each_init(
            || (ChartBuilder::new(nv), Scratch::new(field.dim)),
            |(builder, scratch), (chunk, out)| {
                for (i, fan) in out.chunks_exact_mut(shape.len()).enumerate() {
                    let s = chunk * CHUNK + i;
                    let chart = builder.build(&connection, s, radius + reach, &chart_params);
                    let layout = Layout {
                        shape,
                        radius,
                        reach,
                        samples: &samples,
                        area: &area,
                    };
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

/// What every fan of one surface shares: layout, sample positions, vertex areas.
struct Layout<'a> {
    shape: FanShape,
    radius: f32,
    reach: f32,
    samples: &'a [[f32; 2]],
    area: &'a [f32],
}

impl Layout<'_> {
    /// Fills one fan from the chart `(vertex, coords)` of its centre.
    fn fill(
        &self,
        vertex: &[u32],
        coords: &[[f32; 2]],
        kernel: &Kernel,
        field: FieldRef<'_>,
        scratch: &mut Scratch,
        fan: &mut [f32],
    ) {
        let shape = self.shape;
        let ring_len = shape.spokes * shape.dim;
        for (ring, ring_out) in fan.chunks_exact_mut(ring_len).enumerate() {
            // Only chart vertices with | |U| − ρ | <= reach can be within reach of a sample on
            // ring ρ.
            let rho = (ring + 1) as f32 * self.radius / shape.rings as f32;
            scratch.band(vertex, coords, self.area, rho, self.reach);
            let ring_samples = &self.samples[ring * shape.spokes..(ring + 1) * shape.spokes];
            for (sample, value) in ring_samples
                .iter()
                .zip(ring_out.chunks_exact_mut(field.dim))
            {
                kernel.estimate(*sample, scratch, field, value);
                if scratch.fallback {
                    nearest_value(*sample, vertex, coords, field, value);
                }
            }
        }
    }
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
        })
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
        let kernel = Kernel {
            inv_two_sigma2: 1.0 / (2.0 * self.sigma * self.sigma),
            inv_sigma: 1.0 / self.sigma,
            reach2: self.reach * self.reach,
            filter: self.params.filter,
        };
        let layout = Layout {
            shape,
            radius: self.radius,
            reach: self.reach,
            samples: &self.samples,
            area: &self.area,
        };
        let stage = control.stage("geodesic fans", nv as u64)?;
        let mut data = vec![0.0f32; nv * shape.len()];
        data.par_chunks_mut(CHUNK * shape.len().max(1))
            .enumerate()
            .try_for_each_init(
                || Scratch::new(field.dim),
                |scratch, (chunk, out)| {
                    for (i, fan) in out.chunks_exact_mut(shape.len()).enumerate() {
                        let (vertex, coords) = self.charts.chart(chunk * CHUNK + i);
                        layout.fill(vertex, coords, &kernel, field, scratch, fan);
                    }
                    stage.tick((out.len() / shape.len().max(1)) as u64)
                },
            )?;
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

struct Kernel {
    inv_two_sigma2: f32,
    inv_sigma: f32,
    reach2: f32,
    filter: FanFilter,
}

/// Per-thread scratch: the chart vertices of one ring's band, structure-of-arrays.
struct Scratch {
    x: Vec<f32>,
    y: Vec<f32>,
    vertex: Vec<u32>,
    area: Vec<f32>,
    d2: Vec<f32>,
    /// Indices (into the band) of the vertices within reach of the current sample.
    near: Vec<u32>,
    /// `3 * dim` accumulators.
    acc: Vec<f64>,
    /// Set by [`Kernel::estimate`] when no neighbour was in reach.
    fallback: bool,
}

impl Scratch {
    fn new(dim: usize) -> Self {
        Scratch {
            x: Vec::new(),
            y: Vec::new(),
            vertex: Vec::new(),
            area: Vec::new(),
            d2: Vec::new(),
            near: Vec::new(),
            acc: vec![0.0; 3 * dim],
            fallback: false,
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

/// Writes the field value of the chart vertex nearest to `s` into `value`.
fn nearest_value(
    s: [f32; 2],
    vertex: &[u32],
    coords: &[[f32; 2]],
    field: FieldRef<'_>,
    value: &mut [f32],
) {
    let mut nearest = (f32::INFINITY, vertex[0] as usize);
    for (&v, u) in vertex.iter().zip(coords) {
        let d2 = (u[0] - s[0]).powi(2) + (u[1] - s[1]).powi(2);
        if d2 < nearest.0 {
            nearest = (d2, v as usize);
        }
    }
    let dim = field.dim;
    value.copy_from_slice(&field.values[nearest.1 * dim..(nearest.1 + 1) * dim]);
}

impl Kernel {
    /// Writes the filtered field at chart position `s` over the band in `scratch` into `value`
    /// (`dim` floats), or sets `scratch.fallback` when no band vertex is in reach.
    fn estimate(&self, s: [f32; 2], scratch: &mut Scratch, field: FieldRef<'_>, value: &mut [f32]) {
        let dim = field.dim;
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
        // Pass 2: weights and moments of the vertices in reach.
        let acc = &mut scratch.acc;
        acc.fill(0.0);
        let (mut s0, mut sx, mut sy, mut sxx, mut sxy, mut syy) = (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut gauss_sum = 0.0f32;
        for &k in &scratch.near[..n] {
            let k = k as usize;
            let d2 = scratch.d2[k];
            let g = (-d2 * self.inv_two_sigma2).exp();
            gauss_sum += g;
            let w = (g * scratch.area[k]) as f64;
            let x = ((scratch.x[k] - s[0]) * self.inv_sigma) as f64;
            let y = ((scratch.y[k] - s[1]) * self.inv_sigma) as f64;
            s0 += w;
            sx += w * x;
            sy += w * y;
            sxx += w * x * x;
            sxy += w * x * y;
            syy += w * y * y;
            let v = scratch.vertex[k] as usize;
            let f = &field.values[v * dim..(v + 1) * dim];
            for c in 0..dim {
                let wf = w * f[c] as f64;
                acc[c] += wf;
                acc[dim + c] += wf * x;
                acc[2 * dim + c] += wf * y;
            }
        }
        scratch.fallback = gauss_sum < 1e-4 || s0 <= 0.0;
        if scratch.fallback {
            return;
        }
        if self.filter == FanFilter::LocalLinear {
            // First row of the inverse of the moment matrix [[s0 sx sy][sx sxx sxy][sy sxy syy]].
            let c0 = sxx * syy - sxy * sxy;
            let c1 = sxy * sy - sx * syy;
            let c2 = sx * sxy - sxx * sy;
            let det = s0 * c0 + sx * c1 + sy * c2;
            if det > 1e-3 * s0 * s0 * s0 {
                for c in 0..dim {
                    value[c] =
                        ((c0 * acc[c] + c1 * acc[dim + c] + c2 * acc[2 * dim + c]) / det) as f32;
                }
                return;
            }
        }
        for c in 0..dim {
            value[c] = (acc[c] / s0) as f32;
        }
    }
}
