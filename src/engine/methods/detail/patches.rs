//! Detail features per vertex (Berkiten et al. 2017, §3.2.1): a square patch of the tangent
//! plane at every vertex, mapped onto the surface by the discrete exponential map
//! ([`crate::engine::geometry::expmap`]), sampled into an `n × n` grid of displacements, then the
//! 17 steerable-pyramid sub-band deviations of that grid ([`super::steerable`]).
//!
//! **Frame** (§3.1, "Tangent Frame"): `u` = the constant `(1, 0, 0)` projected onto the tangent
//! plane; where that projection is shorter than 0.1 (the normal within ~84° of the x axis) the
//! toolkit's fallback (the projected edge to the vertex's first one-ring neighbour) is used;
//! `v = n × u`. Grid column `ix` runs along `u`, row `iy` along `v`.
//!
//! **Sampling.** Grid point `(ix, iy)` sits at the chart position
//! `((ix + ½ − n/2)·s, (iy + ½ − n/2)·s)`, `s = 2h/n`. The chart is cut at radius `h√2 + 2ē`
//! (`ē` the mean edge length) so its triangles cover the whole square away from mesh
//! boundaries. Every face whose three corners are in the chart is mapped to the plane by their
//! chart positions and rasterised: a grid point inside it gets the barycentric interpolation of
//! the three per-vertex displacements (the scalar field's value at that surface location).
//! Where the exponential map folds (two mapped faces overlap), the face reached first in chart
//! order (nearest the centre) wins. **Fill** (stated; the paper does not say): a grid point
//! outside every mapped face (past a mesh boundary, or a chart hole) takes the displacement of
//! the nearest chart vertex in the plane, which continues the patch without the artificial edge
//! a constant fill would add to the pyramid's high bands.
//!
//! **Constants the paper does not publish:** `n = 32` (a power of two for the FFT; the four
//! pyramid scales then peak at wavelengths of 4, 8, 16 and 32 grid steps) and half-width
//! `h = 8 ē`, so a grid step is half a mean edge: the finest band (4 steps = 2 edges) sits at the
//! mesh's own Nyquist wavelength and the coarsest spans the whole patch (16 edges).

use rayon::prelude::*;

use super::steerable::{SteerableError, SteerablePyramid, FEATURES};
use crate::engine::control::{Cancelled, Control};
use crate::engine::geometry::expmap::{
    local_frames, mean_edge_length, world_radius, ChartBuilder, Connection, ExpMapParams,
    FrameParams, RadiusUnit,
};
use crate::engine::mesh::{topology, Surface};

/// Parameters of [`detail_features`] and [`sample_patches`].
#[derive(Clone, Debug, PartialEq)]
pub struct PatchParams {
    /// Grid side `n`. Default: 32. Range: 8..=256.
    pub size: usize,
    /// Half the side of the square patch, in `unit`. Default: 8 mean edge lengths.
    pub half_width: f32,
    /// Unit of `half_width`. Default: mean edge lengths.
    pub unit: RadiusUnit,
    /// Global direction projected to give `u`. Default: `(1, 0, 0)` (the paper's).
    pub up: [f32; 3],
}

impl Default for PatchParams {
    fn default() -> Self {
        Self {
            size: 32,
            half_width: 8.0,
            unit: RadiusUnit::MeanEdge,
            up: [1.0, 0.0, 0.0],
        }
    }
}

/// Errors of this module.
#[derive(Debug, thiserror::Error)]
pub enum PatchError {
    /// A parameter is out of range.
    #[error("invalid patch parameter: {0}")]
    Param(String),
    /// The displacement does not have one value per vertex.
    #[error("{got} displacement values for {expected} vertices")]
    Length {
        /// Vertices.
        expected: usize,
        /// Values.
        got: usize,
    },
    /// A displacement value is NaN or infinite.
    #[error("displacement value {0} is not finite")]
    NonFinite(usize),
    /// The surface has no faces.
    #[error("the surface has no faces")]
    Empty,
    /// Pyramid failure (cannot happen for valid sizes).
    #[error("steerable pyramid: {0}")]
    Steerable(#[from] SteerableError),
    /// Cancelled through the control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for PatchError {
    fn from(_: Cancelled) -> Self {
        PatchError::Cancelled
    }
}

/// Everything the per-vertex sampling shares.
struct Sampler<'a> {
    surface: &'a Surface,
    values: &'a [f64],
    connection: Connection,
    /// Vertex → incident faces (CSR).
    offsets: Vec<u32>,
    faces: Vec<u32>,
    n: usize,
    half: f32,
    radius: f32,
    chart: ExpMapParams,
}

/// Scratch of one worker.
struct Scratch {
    builder: ChartBuilder,
    /// Mesh vertex → chart slot (u32::MAX when not in the current chart).
    slot: Vec<u32>,
    grid: Vec<f64>,
    covered: Vec<bool>,
}

fn validate(surface: &Surface, values: &[f64], p: &PatchParams) -> Result<(), PatchError> {
    if surface.faces.is_empty() {
        return Err(PatchError::Empty);
    }
    if values.len() != surface.vertex_count() {
        return Err(PatchError::Length {
            expected: surface.vertex_count(),
            got: values.len(),
        });
    }
    if let Some(i) = values.iter().position(|x| !x.is_finite()) {
        return Err(PatchError::NonFinite(i));
    }
    if !(8..=256).contains(&p.size) {
        return Err(PatchError::Param(format!("size {} not in 8..=256", p.size)));
    }
    if !(p.half_width.is_finite() && p.half_width > 0.0) {
        return Err(PatchError::Param(format!(
            "half_width {} must be finite and > 0",
            p.half_width
        )));
    }
    let up = p.up;
    if !(up.iter().all(|x| x.is_finite()) && up.iter().any(|x| *x != 0.0)) {
        return Err(PatchError::Param(format!(
            "up {up:?} must be finite, non-zero"
        )));
    }
    Ok(())
}

impl<'a> Sampler<'a> {
    fn new(surface: &'a Surface, values: &'a [f64], p: &PatchParams) -> Result<Self, PatchError> {
        validate(surface, values, p)?;
        let frames = local_frames(
            surface,
            &FrameParams {
                up: Some(p.up),
                min_up_projection: 0.1,
            },
        );
        let half = world_radius(surface, p.half_width, p.unit);
        let radius = half * std::f32::consts::SQRT_2 + 2.0 * mean_edge_length(surface);
        if !(half > 0.0 && radius.is_finite()) {
            return Err(PatchError::Param(format!(
                "patch half-width {half} world units"
            )));
        }
        let topo = topology(surface);
        let nv = surface.vertex_count();
        let mut offsets = Vec::with_capacity(nv + 1);
        let mut faces = Vec::new();
        offsets.push(0);
        for v in 0..nv {
            faces.extend_from_slice(topo.vertex_faces(v));
            offsets.push(faces.len() as u32);
        }
        Ok(Sampler {
            surface,
            values,
            connection: Connection::new(surface, &frames),
            offsets,
            faces,
            n: p.size,
            half,
            radius,
            chart: ExpMapParams {
                radius,
                radius_unit: RadiusUnit::World,
                ..ExpMapParams::default()
            },
        })
    }

    fn scratch(&self) -> Scratch {
        let nv = self.surface.vertex_count();
        Scratch {
            builder: ChartBuilder::new(nv),
            slot: vec![u32::MAX; nv],
            grid: vec![0.0; self.n * self.n],
            covered: vec![false; self.n * self.n],
        }
    }

    /// Samples the patch of `source` into `scratch.grid` (row-major, `iy · n + ix`).
    fn sample(&self, source: usize, scratch: &mut Scratch) {
        let n = self.n;
        let step = 2.0 * self.half as f64 / n as f64;
        let Scratch {
            builder,
            slot,
            grid,
            covered,
        } = scratch;
        grid.iter_mut().for_each(|g| *g = 0.0);
        covered.iter_mut().for_each(|c| *c = false);
        let chart = builder.build(&self.connection, source, self.radius, &self.chart);
        for (i, &v) in chart.vertex.iter().enumerate() {
            slot[v as usize] = i as u32;
        }
        // Grid coordinates of a chart position: index space where point k sits at k.
        let to_grid = |c: [f32; 2]| {
            [
                c[0] as f64 / step + n as f64 / 2.0 - 0.5,
                c[1] as f64 / step + n as f64 / 2.0 - 0.5,
            ]
        };
        for (i, &v) in chart.vertex.iter().enumerate() {
            let (a, b) = (self.offsets[v as usize], self.offsets[v as usize + 1]);
            for &f in &self.faces[a as usize..b as usize] {
                let corners = self.surface.faces[f as usize];
                let slots = corners.map(|c| slot[c as usize]);
                // Each face once: from its corner with the lowest chart slot.
                if slots.contains(&u32::MAX) || slots.iter().min() != Some(&(i as u32)) {
                    continue;
                }
                let pts = slots.map(|s| to_grid(chart.coords[s as usize]));
                let vals = corners.map(|c| self.values[c as usize]);
                // The first face to reach a grid point keeps it.
                rasterise_triangle(pts, n, |k, [wa, wb, wc]| {
                    if !covered[k] {
                        grid[k] = wa * vals[0] + wb * vals[1] + wc * vals[2];
                        covered[k] = true;
                    }
                });
            }
        }
        if covered.iter().any(|c| !c) {
            for iy in 0..n {
                for ix in 0..n {
                    if covered[iy * n + ix] {
                        continue;
                    }
                    let (gx, gy) = (ix as f64, iy as f64);
                    let nearest = (0..chart.vertex.len()).min_by(|&p, &q| {
                        let d = |s: usize| {
                            let g = to_grid(chart.coords[s]);
                            (g[0] - gx).powi(2) + (g[1] - gy).powi(2)
                        };
                        d(p).total_cmp(&d(q))
                    });
                    if let Some(s) = nearest {
                        grid[iy * n + ix] = self.values[chart.vertex[s] as usize];
                    }
                }
            }
        }
        for &v in chart.vertex.iter() {
            slot[v as usize] = u32::MAX;
        }
    }
}

/// Calls `visit(k, [wa, wb, wc])` for every point `(ix, iy)` of an `n × n` grid (`k = iy · n +
/// ix`; the point sits at `(ix, iy)` in grid index coordinates) inside the triangle `pts` (same
/// coordinates), with its barycentric weights of the three corners; points on an edge count
/// (tolerance 1e-9). Rows in increasing `iy`, each in increasing `ix`. Nothing for a degenerate
/// triangle (`|2 · area| < 1e-12`) or a non-finite area. Used by [`Sampler::sample`] here and by
/// [`super::patch_match`]'s rasterised charts; the caller decides what a covered point keeps.
pub(super) fn rasterise_triangle(
    pts: [[f64; 2]; 3],
    n: usize,
    mut visit: impl FnMut(usize, [f64; 3]),
) {
    let [a, b, c] = pts;
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let lo = |k: usize| pts.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
    let hi = |k: usize| pts.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max);
    let top = n as f64 - 1.0;
    if hi(0) < 0.0 || hi(1) < 0.0 || lo(0) > top || lo(1) > top {
        return;
    }
    let clamp = |x: f64| x.clamp(0.0, top) as usize;
    let eps = 1e-9;
    for iy in clamp(lo(1).ceil())..=clamp(hi(1).floor()) {
        for ix in clamp(lo(0).ceil())..=clamp(hi(0).floor()) {
            let (x, y) = (ix as f64, iy as f64);
            let wa = ((b[0] - x) * (c[1] - y) - (c[0] - x) * (b[1] - y)) / area;
            let wb = ((c[0] - x) * (a[1] - y) - (a[0] - x) * (c[1] - y)) / area;
            let wc = 1.0 - wa - wb;
            if wa >= -eps && wb >= -eps && wc >= -eps {
                visit(iy * n + ix, [wa, wb, wc]);
            }
        }
    }
}

/// The `n × n` displacement grid of each of `vertices` (row-major, `iy · n + ix`, `ix` along
/// `u`), for inspection and tests.
///
/// # Errors
/// [`PatchError`] for bad input or parameters.
pub fn sample_patches(
    surface: &Surface,
    displacement: &[f64],
    vertices: &[usize],
    params: &PatchParams,
) -> Result<Vec<Vec<f64>>, PatchError> {
    let sampler = Sampler::new(surface, displacement, params)?;
    if let Some(&v) = vertices.iter().find(|&&v| v >= surface.vertex_count()) {
        return Err(PatchError::Param(format!("vertex {v} out of range")));
    }
    let mut scratch = sampler.scratch();
    Ok(vertices
        .iter()
        .map(|&v| {
            sampler.sample(v, &mut scratch);
            scratch.grid.clone()
        })
        .collect())
}

/// The 17-D detail feature of every vertex (vertex-major: `out[v · 17 + j]`, bands in
/// [`super::steerable`] order). One Control stage "detail features", parallel over vertices,
/// deterministic.
///
/// # Errors
/// [`PatchError`] for bad input, parameters, or cancellation.
pub fn detail_features(
    surface: &Surface,
    displacement: &[f64],
    params: &PatchParams,
    control: &Control,
) -> Result<Vec<f64>, PatchError> {
    let all: Vec<usize> = (0..surface.vertex_count()).collect();
    detail_features_at(surface, displacement, &all, params, control)
}

/// The 17-D detail feature of `vertices` only (row `i` for `vertices[i]`, as
/// [`detail_features`] gives for all): the metric is learned on a sample of the finest level.
///
/// # Errors
/// [`PatchError`] for bad input, a vertex out of range, or cancellation.
pub fn detail_features_at(
    surface: &Surface,
    displacement: &[f64],
    vertices: &[usize],
    params: &PatchParams,
    control: &Control,
) -> Result<Vec<f64>, PatchError> {
    let sampler = Sampler::new(surface, displacement, params)?;
    if let Some(&v) = vertices.iter().find(|&&v| v >= surface.vertex_count()) {
        return Err(PatchError::Param(format!("vertex {v} out of range")));
    }
    let pyramid = SteerablePyramid::new(params.size)?;
    let stage = control.stage("detail features", vertices.len() as u64)?;
    let mut out = vec![0.0; vertices.len() * FEATURES];
    out.par_chunks_mut(FEATURES * 64)
        .zip(vertices.par_chunks(64))
        .try_for_each_init(
            || sampler.scratch(),
            |scratch, (block, vs)| -> Result<(), PatchError> {
                for (row, &v) in block.chunks_mut(FEATURES).zip(vs) {
                    sampler.sample(v, scratch);
                    row.copy_from_slice(&pyramid.band_deviations(&scratch.grid)?);
                }
                stage.tick(vs.len() as u64)?;
                Ok(())
            },
        )?;
    Ok(out)
}
