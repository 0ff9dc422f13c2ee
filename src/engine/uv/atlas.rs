//! Atlas orchestration (Lévy et al. 2002, §§4-5: segmentation, per-chart LSCM, packing): grow
//! charts ([`super::charts::grow`]), parameterise each ([`super::param::lscm`],
//! optionally refined by ARAP, [`super::arap`]), split every
//! chart that is not a disc, has a flipped triangle or exceeds the L2 stretch bound (Sander et
//! al. 2001; the splitting replaces Lévy's §4 feature-driven seams, see [`super::charts`]), merge
//! neighbouring charts while the union still passes those tests ([`super::merge`]), then turn
//! each chart to its principal axes and pack ([`super::pack`]).
//!
//! Control stages: `atlas_charts` (adjacency, growth, the flattening rounds and the merge) and
//! `atlas_pack` (orientation, packing, and each chart laid out and measured, in parallel).
//!
//! Charts are parameterised in rounds, in parallel within a round (rayon); every result is
//! collected in order and charts are finally sorted by their first face, so the atlas does not
//! depend on the thread count. Single triangles flatten isometrically and are never split, so
//! the loop ends.

use rayon::prelude::*;

use super::arap::{self, Parameterization, MAX_ITERATIONS};
use super::charts::{adjacency, edge_key, grow, is_disc, split, Adjacency};
use super::merge::merge_charts;
use super::pack::{pack, Outline, Placement};
use super::param::{chart_vertices, flatten_chart, local_triangle, signed_area, triangle_stretch};
use super::report::{atlas_report, chart_report, AtlasReport, Totals, TriangleMeasure};
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::Surface;

/// Upper estimate of the atlas's working memory per input triangle, bytes: the adjacency and
/// sorted edge lists (~110 B), the charts' frames and corner UVs (~60 B), the per-triangle
/// measures (40 B) and the LSCM normal equations and Cholesky factors of the charts solved at
/// once (~1 KB for the largest charts). Measured: a transfer onto the 320k-triangle sphere
/// peaks 276 MB above the same transfer onto the 20k-triangle one (~920 B per triangle for the
/// atlas, the larger surface and its bake together).
pub const WORKING_SET_BYTES_PER_TRIANGLE: u64 = 1_500;

/// The atlas's estimated working memory for `triangles` input triangles (see
/// [`WORKING_SET_BYTES_PER_TRIANGLE`]).
pub fn working_set_bytes(triangles: u64) -> u64 {
    triangles.saturating_mul(WORKING_SET_BYTES_PER_TRIANGLE)
}

/// Parameters of the atlas.
#[derive(Clone, Debug, PartialEq)]
pub struct AtlasParams {
    /// Texture width = height the charts are packed for, texels.
    pub texture_size: u32,
    /// Texels between charts (room for padding and bilinear filtering).
    pub gutter: u32,
    /// Largest angle between a face normal and its chart's mean normal while growing, degrees.
    pub max_normal_deviation: f64,
    /// Largest L2 stretch of a chart (Sander et al. 2001, 1 = isometric); above it the chart is
    /// split.
    pub max_stretch: f64,
    /// How each chart is flattened: LSCM, or LSCM refined by ARAP ([`super::arap`]; kept per
    /// chart only when it has no flipped triangle and neither its L2 nor its L∞ stretch is above
    /// LSCM's; when LSCM flipped a triangle, whenever ARAP has none). The
    /// stretch bound, the splits and the merge all see the chart as finally flattened.
    pub parameterization: Parameterization,
    /// Largest union of two charts the merge tries, in faces ([`super::merge`]; 0 turns the
    /// merge off).
    pub merge_max_faces: usize,
    /// Most merge rounds ([`super::merge`]).
    pub merge_rounds: usize,
}

impl Default for AtlasParams {
    /// 2048², 4-texel gutter, 60° and 1.2: see the README's atlas sweep for why.
    fn default() -> Self {
        Self {
            texture_size: 2048,
            gutter: 4,
            max_normal_deviation: 60.0,
            max_stretch: 1.2,
            parameterization: Parameterization::default(),
            merge_max_faces: super::merge::MERGE_MAX_FACES,
            merge_rounds: super::merge::MERGE_ROUNDS,
        }
    }
}

/// Why no atlas could be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AtlasError {
    /// No faces.
    #[error("the surface has no faces")]
    Empty,
    /// A face has zero area or non-finite corners.
    #[error("face {face} is degenerate (zero area or non-finite position); weld the surface first, which drops such faces")]
    DegenerateFace {
        /// The face.
        face: usize,
    },
    /// The charts do not fit.
    #[error("{charts} charts do not fit a {size}² texture with a {gutter}-texel gutter")]
    DoesNotFit {
        /// Charts.
        charts: usize,
        /// Texture size.
        size: u32,
        /// Gutter.
        gutter: u32,
    },
    /// A parameter is out of range.
    #[error("atlas parameter {0}")]
    InvalidParam(&'static str),
    /// Cancelled.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for AtlasError {
    fn from(_: Cancelled) -> Self {
        AtlasError::Cancelled
    }
}

/// One chart.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    /// Faces (sorted surface indices).
    pub faces: Vec<u32>,
    /// Vertices (sorted surface indices).
    pub vertices: Vec<u32>,
    /// Texture coordinates per vertex, in [0, 1] (x right, y as the glTF `v`).
    pub uv: Vec<[f32; 2]>,
}

impl Chart {
    /// UV of a surface vertex of this chart.
    pub fn uv_of(&self, v: u32) -> Option<[f32; 2]> {
        self.vertices.binary_search(&v).ok().map(|i| self.uv[i])
    }
}

/// The atlas of a surface.
#[derive(Clone, Debug, PartialEq)]
pub struct Atlas {
    /// Charts, ordered by first face.
    pub charts: Vec<Chart>,
    /// Chart of each face.
    pub face_chart: Vec<u32>,
    /// UVs of each face's corners (in the face's corner order).
    pub corner_uv: Vec<[[f32; 2]; 3]>,
    /// Quality figures.
    pub report: AtlasReport,
}

impl Atlas {
    /// The UVs of a face's corners (`surface` is the surface the atlas was made for).
    pub fn face_uv(&self, _surface: &Surface, face: usize) -> [[f32; 2]; 3] {
        self.corner_uv[face]
    }
}

/// A chart flattened in world units (texture area = surface area).
pub(super) struct Flat {
    pub(super) faces: Vec<u32>,
    pub(super) vertices: Vec<u32>,
    pub(super) frame: Vec<[f64; 2]>,
}

/// A chart flattened by LSCM ([`flatten_chart`]) in world units: oriented counter-clockwise and
/// scaled so that its texture area equals its surface area. One position per entry of
/// `vertices` ([`chart_vertices`]); `None` when the solve fails.
pub fn world_frame(surface: &Surface, faces: &[u32], vertices: &[u32]) -> Option<Vec<[f64; 2]>> {
    let mut frame = flatten_chart(surface, faces, vertices)?;
    let local = |v: u32| vertices.binary_search(&v).unwrap_or(0);
    let tri = |frame: &[[f64; 2]], f: u32| surface.faces[f as usize].map(|v| frame[local(v)]);
    let a2: f64 = faces.iter().map(|f| signed_area(tri(&frame, *f))).sum();
    let a3: f64 = faces
        .iter()
        .map(|f| local_triangle(surface.face_positions(*f as usize)).1)
        .sum();
    if a2 < 0.0 {
        frame.iter_mut().for_each(|p| p[1] = -p[1]);
    }
    let s = (a3 / a2.abs().max(1e-300)).sqrt();
    frame.iter_mut().for_each(|p| *p = [p[0] * s, p[1] * s]);
    Some(frame)
}

/// Flattens a chart as `params.parameterization` says ([`world_frame`], then the ARAP refinement
/// with its guard), or `None` when it must be split (see the module doc).
pub(super) fn flatten(surface: &Surface, faces: &[u32], params: &AtlasParams) -> Option<Flat> {
    if faces.len() > 1 && !is_disc(surface, faces) {
        return None;
    }
    let vertices = chart_vertices(surface, faces);
    let mut frame = world_frame(surface, faces, &vertices)?;
    let mut stretch = arap::chart_stretch(surface, faces, &vertices, &frame);
    if let Parameterization::Arap { iterations } = params.parameterization {
        let refined = arap::refine(surface, faces, &vertices, &frame, iterations);
        if let Some(r) = refined {
            // Kept only without flips (`chart_stretch` is `None` then) and with neither L2 nor
            // L∞ above LSCM's (ARAP can pinch a triangle: on the skull a merged chart went from
            // L2 1.61 / L∞ 4.0 to 1.09 / 72).
            if let Some(s) = arap::chart_stretch(surface, faces, &vertices, &r) {
                if stretch.is_none_or(|l| s.0 <= l.0 && s.1 <= l.1) {
                    frame = r;
                    stretch = Some(s);
                }
            }
        }
    }
    let l2 = stretch?.0;
    if faces.len() > 1 && l2 > params.max_stretch {
        return None;
    }
    Some(Flat {
        faces: faces.to_vec(),
        vertices,
        frame,
    })
}

/// Turns a flat chart to its principal axes with its bounding box's corner at the origin;
/// returns the box size.
fn orient(flat: &mut Flat) -> [f64; 2] {
    let n = flat.frame.len() as f64;
    let c = flat
        .frame
        .iter()
        .fold([0.0; 2], |a, p| [a[0] + p[0], a[1] + p[1]]);
    let c = [c[0] / n, c[1] / n];
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in &flat.frame {
        let (x, y) = (p[0] - c[0], p[1] - c[1]);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
    }
    let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (sn, cs) = theta.sin_cos();
    let mut lo = [f64::MAX; 2];
    let mut hi = [f64::MIN; 2];
    for p in &mut flat.frame {
        let (x, y) = (p[0] - c[0], p[1] - c[1]);
        *p = [cs * x + sn * y, -sn * x + cs * y];
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    for p in &mut flat.frame {
        *p = [p[0] - lo[0], p[1] - lo[1]];
    }
    [hi[0] - lo[0], hi[1] - lo[1]]
}

fn check(surface: &Surface, params: &AtlasParams) -> Result<(), AtlasError> {
    if surface.faces.is_empty() {
        return Err(AtlasError::Empty);
    }
    if !(16..=16384).contains(&params.texture_size) {
        return Err(AtlasError::InvalidParam(
            "texture_size must be in 16..=16384",
        ));
    }
    if params.gutter > 256 {
        return Err(AtlasError::InvalidParam("gutter must be at most 256"));
    }
    let cone = params.max_normal_deviation;
    if cone.is_nan() || cone <= 0.0 || cone > 180.0 {
        return Err(AtlasError::InvalidParam(
            "max_normal_deviation must be in (0, 180]",
        ));
    }
    if !params.max_stretch.is_finite() || params.max_stretch < 1.0 {
        return Err(AtlasError::InvalidParam(
            "max_stretch must be finite and at least 1",
        ));
    }
    if let Parameterization::Arap { iterations } = params.parameterization {
        if !(1..=MAX_ITERATIONS).contains(&iterations) {
            return Err(AtlasError::InvalidParam(
                "parameterization: ARAP iterations must be in 1..=1000",
            ));
        }
    }
    for f in 0..surface.faces.len() {
        let p = surface.face_positions(f);
        let (_, area) = local_triangle(p);
        let finite = p.iter().flatten().all(|c| c.is_finite());
        if !finite || area.is_nan() || area <= 0.0 {
            return Err(AtlasError::DegenerateFace { face: f });
        }
    }
    Ok(())
}

/// Parameterises charts in rounds until none is split (see the module doc).
fn flatten_all(
    surface: &Surface,
    adj: &Adjacency,
    params: &AtlasParams,
    control: &Control,
    stage: &crate::engine::control::StageProgress<'_>,
) -> Result<Vec<Flat>, AtlasError> {
    let grown = grow(adj, params.max_normal_deviation);
    let mut pending = super::charts::components_of_charts(adj, &grown);
    let mut done = Vec::new();
    while !pending.is_empty() {
        control.check()?;
        let results: Vec<Result<Flat, Vec<Vec<u32>>>> = pending
            .par_iter()
            .map(|faces| match flatten(surface, faces, params) {
                Some(f) => Ok(f),
                None => Err(split(surface, adj, faces)),
            })
            .collect();
        pending = Vec::new();
        for r in results {
            match r {
                Ok(f) => {
                    stage.tick(f.faces.len() as u64)?;
                    done.push(f);
                }
                Err(parts) => pending.extend(parts),
            }
        }
    }
    done.sort_by_key(|f| f.faces[0]);
    Ok(done)
}

/// Builds the atlas of `surface` (see the module doc). Control stages `atlas_charts` and
/// `atlas_pack`.
///
/// # Errors
/// [`AtlasError`]: no faces, a degenerate face, charts that do not fit, a bad parameter, or
/// cancellation.
pub fn generate(
    surface: &Surface,
    params: &AtlasParams,
    control: &Control,
) -> Result<Atlas, AtlasError> {
    check(surface, params)?;
    let charts_stage = control.stage("atlas_charts", surface.faces.len() as u64)?;
    let adj = adjacency(surface);
    let flats = flatten_all(surface, &adj, params, control, &charts_stage)?;
    let mut flats = merge_charts(surface, &adj, flats, params, control)?;
    let stage = control.stage("atlas_pack", flats.len() as u64)?;
    let sizes: Vec<[f64; 2]> = flats.iter_mut().map(orient).collect();
    let outlines: Vec<Outline> = (flats.par_iter().zip(&sizes))
        .map(|(flat, size)| Outline {
            points: &flat.frame,
            triangles: (flat.faces.iter())
                .map(|f| {
                    let fv = surface.faces[*f as usize];
                    fv.map(|v| flat.vertices.binary_search(&v).unwrap_or(0) as u32)
                })
                .collect(),
            size: *size,
        })
        .collect();
    let (scale, places) =
        pack(&outlines, params.texture_size, params.gutter).ok_or(AtlasError::DoesNotFit {
            charts: flats.len(),
            size: params.texture_size,
            gutter: params.gutter,
        })?;
    drop(outlines);
    let width = f64::from(params.texture_size);
    // Each chart on its own (in parallel, collected in order).
    let laid: Vec<Laid> = flats
        .par_iter()
        .zip(&places)
        .map(|(flat, place)| lay_out(surface, flat, *place, scale, width))
        .collect();
    let nf = surface.faces.len();
    let mut face_chart = vec![0u32; nf];
    let mut corner_uv = vec![[[0.0f32; 2]; 3]; nf];
    let mut measures = vec![TriangleMeasure::default(); nf];
    let mut chart_reports = Vec::with_capacity(flats.len());
    let mut charts = Vec::with_capacity(flats.len());
    let (mut uv_area, mut flipped) = (0.0, 0);
    for (ci, (flat, l)) in flats.into_iter().zip(laid).enumerate() {
        for (k, f) in flat.faces.iter().enumerate() {
            face_chart[*f as usize] = ci as u32;
            corner_uv[*f as usize] = l.corners[k];
            measures[*f as usize] = l.tris[k];
        }
        uv_area += l.uv_area;
        flipped += l.flipped;
        chart_reports.push(chart_report(&l.tris, scale));
        charts.push(Chart {
            faces: flat.faces,
            vertices: flat.vertices,
            uv: l.uv,
        });
        stage.tick(1)?;
    }
    let seams = seam_length(surface, &adj, &face_chart);
    let mut report = atlas_report(
        &measures,
        Totals {
            charts: chart_reports,
            seams,
            packing_efficiency: uv_area,
            texels_per_unit: scale,
            texture: (params.texture_size, params.gutter),
        },
    );
    report.flipped = flipped;
    Ok(Atlas {
        charts,
        face_chart,
        corner_uv,
        report,
    })
}

/// One chart placed in the texture.
struct Laid {
    uv: Vec<[f32; 2]>,
    corners: Vec<[[f32; 2]; 3]>,
    tris: Vec<TriangleMeasure>,
    uv_area: f64,
    flipped: usize,
}

/// Places a flat chart (scaled by `scale` texels per unit, turned by quarter turns, which keep
/// the orientation, and moved, as `place` says) and measures its triangles.
fn lay_out(surface: &Surface, flat: &Flat, place: Placement, scale: f64, width: f64) -> Laid {
    let uv: Vec<[f32; 2]> = flat
        .frame
        .iter()
        .map(|p| place.apply(*p, scale).map(|t| (t / width) as f32))
        .collect();
    let mut out = Laid {
        corners: Vec::with_capacity(flat.faces.len()),
        tris: Vec::with_capacity(flat.faces.len()),
        uv_area: 0.0,
        flipped: 0,
        uv: Vec::new(),
    };
    for f in &flat.faces {
        let fv = surface.faces[*f as usize];
        let local = fv.map(|v| flat.vertices.binary_search(&v).unwrap_or(0));
        let p = surface.face_positions(*f as usize);
        let area = local_triangle(p).1;
        let world = local.map(|i| flat.frame[i]);
        let corners = local.map(|i| uv[i]);
        let texel = corners.map(|c| c.map(|x| f64::from(x) * width));
        let texel_area = signed_area(texel);
        out.uv_area += texel_area / (width * width);
        if signed_area(corners.map(|c| c.map(f64::from))) <= 0.0 {
            out.flipped += 1;
        }
        let (l2_sq, big, small) =
            triangle_stretch(p, world).unwrap_or((f64::INFINITY, f64::INFINITY, 0.0));
        out.tris.push(TriangleMeasure {
            area,
            l2_sq,
            big,
            small,
            density: (texel_area.max(0.0) / area).sqrt(),
        });
        out.corners.push(corners);
    }
    out.uv = uv;
    out
}

/// Total world length and count of edges whose faces lie in different charts: manifold edges
/// from the adjacency, edges with more than two faces (left unconnected there) from one sort.
fn seam_length(surface: &Surface, adj: &Adjacency, face_chart: &[u32]) -> (f64, usize) {
    let length = |a: u32, b: u32| {
        let p = surface.positions[a as usize];
        let q = surface.positions[b as usize];
        (0..3)
            .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let (mut total, mut count) = (0.0, 0);
    let mut open: Vec<((u32, u32), u32)> = Vec::new();
    for (f, fv) in surface.faces.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (fv[k], fv[(k + 1) % 3]);
            match adj.neighbors[f][k] {
                Some(g) if (g as usize) > f => {
                    if face_chart[g as usize] != face_chart[f] {
                        total += length(a, b);
                        count += 1;
                    }
                }
                Some(_) => {}
                None => open.push((edge_key(a, b), face_chart[f])),
            }
        }
    }
    // Edges without a manifold neighbour: boundary (one face) or non-manifold (three or more).
    open.sort_unstable();
    let mut start = 0;
    while start < open.len() {
        let mut end = start + 1;
        while end < open.len() && open[end].0 == open[start].0 {
            end += 1;
        }
        if open[start].1 != open[end - 1].1 {
            let (a, b) = open[start].0;
            total += length(a, b);
            count += 1;
        }
        start = end;
    }
    (total, count)
}
