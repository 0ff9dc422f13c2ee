//! Atlas orchestration (Lévy et al. 2002, §§4-5: segmentation, per-chart LSCM, packing): grow
//! charts ([`super::charts::grow`]), parameterise each ([`super::param::lscm`]), split every
//! chart that is not a disc, has a flipped triangle or exceeds the L2 stretch bound (Sander et
//! al. 2001; the splitting replaces Lévy's §4 feature-driven seams, see [`super::charts`]), then
//! turn each chart to its principal axes and pack ([`super::pack`]).
//!
//! Charts are parameterised in rounds, in parallel within a round (rayon); every result is
//! collected in order and charts are finally sorted by their first face, so the atlas does not
//! depend on the thread count. Single triangles flatten isometrically and are never split, so
//! the loop ends.

use rayon::prelude::*;

use super::charts::{adjacency, edge_key, grow, is_disc, split, Adjacency};
use super::pack::pack;
use super::param::{chart_vertices, flatten_chart, local_triangle, signed_area, triangle_stretch};
use super::report::{atlas_report, chart_report, AtlasReport, Totals, TriangleMeasure};
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::Surface;

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
}

impl Default for AtlasParams {
    /// 2048², 4-texel gutter, 60° and 1.2: see the README's atlas sweep for why.
    fn default() -> Self {
        Self {
            texture_size: 2048,
            gutter: 4,
            max_normal_deviation: 60.0,
            max_stretch: 1.2,
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
    /// Quality figures.
    pub report: AtlasReport,
}

impl Atlas {
    /// The UVs of a face's corners.
    pub fn face_uv(&self, surface: &Surface, face: usize) -> [[f32; 2]; 3] {
        let c = &self.charts[self.face_chart[face] as usize];
        surface.faces[face].map(|v| c.uv_of(v).unwrap_or([0.0; 2]))
    }
}

/// A chart flattened in world units (texture area = surface area).
struct Flat {
    faces: Vec<u32>,
    vertices: Vec<u32>,
    frame: Vec<[f64; 2]>,
}

/// Flattens a chart, or `None` when it must be split (see the module doc).
fn flatten(surface: &Surface, faces: &[u32], max_stretch: f64) -> Option<Flat> {
    if faces.len() > 1 && !is_disc(surface, faces) {
        return None;
    }
    let vertices = chart_vertices(surface, faces);
    let mut frame = flatten_chart(surface, faces, &vertices)?;
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
    let mut sum = 0.0;
    for f in faces {
        let (l2_sq, _, _) = triangle_stretch(surface.face_positions(*f as usize), tri(&frame, *f))?;
        sum += l2_sq * local_triangle(surface.face_positions(*f as usize)).1;
    }
    if faces.len() > 1 && (sum / a3.max(1e-300)).sqrt() > max_stretch {
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
) -> Result<Vec<Flat>, AtlasError> {
    let grown = grow(adj, params.max_normal_deviation);
    let mut pending: Vec<Vec<u32>> = Vec::new();
    for g in grown {
        pending.extend(super::charts::components(adj, &g));
    }
    let stage = control.stage("atlas_charts", surface.faces.len() as u64)?;
    let mut done = Vec::new();
    while !pending.is_empty() {
        control.check()?;
        let results: Vec<Result<Flat, Vec<Vec<u32>>>> = pending
            .par_iter()
            .map(|faces| match flatten(surface, faces, params.max_stretch) {
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
    let adj = adjacency(surface);
    let mut flats = flatten_all(surface, &adj, params, control)?;
    let stage = control.stage("atlas_pack", flats.len() as u64)?;
    let sizes: Vec<[f64; 2]> = flats.iter_mut().map(orient).collect();
    let (scale, places) =
        pack(&sizes, params.texture_size, params.gutter).ok_or(AtlasError::DoesNotFit {
            charts: flats.len(),
            size: params.texture_size,
            gutter: params.gutter,
        })?;
    let width = f64::from(params.texture_size);
    let mut face_chart = vec![0u32; surface.faces.len()];
    let mut charts = Vec::with_capacity(flats.len());
    let mut measures = vec![
        TriangleMeasure {
            area: 0.0,
            l2_sq: 0.0,
            big: 0.0,
            small: 0.0,
            density: 0.0
        };
        surface.faces.len()
    ];
    let mut chart_reports = Vec::with_capacity(flats.len());
    let mut uv_area = 0.0;
    for (ci, (flat, place)) in flats.iter().zip(&places).enumerate() {
        let uv: Vec<[f32; 2]> = flat
            .frame
            .iter()
            .map(|p| {
                // A 90° turn (x, y) → (h − y, x) keeps the orientation.
                let q = if place.rotated {
                    [sizes[ci][1] - p[1], p[0]]
                } else {
                    *p
                };
                [
                    ((place.offset[0] + q[0] * scale) / width) as f32,
                    ((place.offset[1] + q[1] * scale) / width) as f32,
                ]
            })
            .collect();
        let mut tris = Vec::with_capacity(flat.faces.len());
        for f in &flat.faces {
            face_chart[*f as usize] = ci as u32;
            let fv = surface.faces[*f as usize];
            let local = |v: u32| flat.vertices.binary_search(&v).unwrap_or(0);
            let p = surface.face_positions(*f as usize);
            let area = local_triangle(p).1;
            let world = fv.map(|v| flat.frame[local(v)]);
            let texel = fv.map(|v| uv[local(v)].map(|c| f64::from(c) * width));
            let texel_area = signed_area(texel);
            uv_area += texel_area / (width * width);
            let (l2_sq, big, small) =
                triangle_stretch(p, world).unwrap_or((f64::INFINITY, f64::INFINITY, 0.0));
            let m = TriangleMeasure {
                area,
                l2_sq,
                big,
                small,
                density: (texel_area.max(0.0) / area).sqrt(),
            };
            measures[*f as usize] = m;
            tris.push(m);
        }
        chart_reports.push(chart_report(&tris, scale));
        charts.push(Chart {
            faces: flat.faces.clone(),
            vertices: flat.vertices.clone(),
            uv,
        });
        stage.tick(1)?;
    }
    let seams = seam_length(surface, &face_chart);
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
    report.flipped = charts
        .iter()
        .flat_map(|c| c.faces.iter().map(move |f| (c, *f)))
        .filter(|(c, f)| {
            let q =
                surface.faces[*f as usize].map(|v| c.uv_of(v).unwrap_or([0.0; 2]).map(f64::from));
            signed_area(q) <= 0.0
        })
        .count();
    Ok(Atlas {
        charts,
        face_chart,
        report,
    })
}

/// Total world length and count of edges whose faces lie in different charts.
fn seam_length(surface: &Surface, face_chart: &[u32]) -> (f64, usize) {
    let mut edges: std::collections::HashMap<(u32, u32), (u32, bool)> =
        std::collections::HashMap::with_capacity(surface.faces.len() * 2);
    for (f, fv) in surface.faces.iter().enumerate() {
        for k in 0..3 {
            let e = edges
                .entry(edge_key(fv[k], fv[(k + 1) % 3]))
                .or_insert((face_chart[f], false));
            if e.0 != face_chart[f] {
                e.1 = true;
            }
        }
    }
    let mut keys: Vec<(u32, u32)> = edges.iter().filter(|(_, v)| v.1).map(|(k, _)| *k).collect();
    keys.sort_unstable();
    let length = keys
        .iter()
        .map(|(a, b)| {
            let p = surface.positions[*a as usize];
            let q = surface.positions[*b as usize];
            (0..3)
                .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum();
    (length, keys.len())
}
