//! Sampling: the synthesis meshes of MeshMatch (Chen et al. 2012, §4: the texture is "stored on
//! vertices"), always at the requested vertex count, so the output resolution and the memory do
//! not depend on how the asset was tessellated (DESIGN.md, "dense resampling"):
//! - an input with fewer vertices than requested is refined by longest-edge bisection
//!   ([`resample`]); refinement never moves the geometry and every synthesis vertex knows its
//!   (face, barycentric) point on the input surface;
//! - an input with more vertices is decimated by the MeshMatch hierarchy's own shortest-edge-first
//!   midpoint collapse ([`build_hierarchy`]; manifold-preserving, see `multires::collapse`), not by
//!   quadric error metrics: its levels' ratio is set so the coarsest level lands on the requested
//!   count (`k = ⌈log₅(n / samples)⌉` levels of ratio `(samples / n)^(1/k)`, at most 0.8), in
//!   passes until the count is within `samples / 0.9` (a level may stop short where collapses are
//!   blocked; up to four passes, each must remove 5%). An input within `samples / 0.9` is kept. Collapsed
//!   vertices sit at edge midpoints, slightly off the input; every synthesis vertex records its
//!   closest point on the input (face, barycentric) and every synthesis face the input face
//!   closest to its centroid, and colours are read at closest input points. Where collapses are
//!   blocked (non-manifold or locked regions) the count may stay above `samples`; above
//!   [`super::MAX_SAMPLES`] that is an error (the memory bound).
//!
//! The source's color per synthesis vertex is its base color (factor × texture × COLOR_0, linear)
//! box-filtered over about the vertex's own area: the mean of the point sample at the vertex
//! (weight 2) and one sample halfway to the centroid of each incident synthesis triangle
//! (weight 1 each). A bare point sample would alias a 1024² texture read by 64K vertices.

use rayon::prelude::*;

use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::math::{dot, sub};
use crate::engine::mesh::{topology, Surface};
use crate::engine::multires::{
    build_hierarchy, resample, FacePoint, HierarchyParams, ResampleParams,
};
use crate::engine::spatial::Bvh;
use crate::engine::texture::sample::MaterialSampler;

use super::MeshMatchError;

/// Largest ratio of one decimation level: the hierarchy stops after a level that removed less than
/// a quarter of its vertices, so one level of ratio up to 0.8 is the most a single step can do.
const MAX_LEVEL_RATIO: f64 = 0.8;
/// Decimation passes at most (a pass that removes less than 5% of the vertices ends them).
const MAX_PASSES: usize = 4;

/// A synthesis mesh: resampled surface plus its links to the input surface.
#[derive(Clone, Debug)]
pub struct SynthesisMesh {
    /// The resampled surface (positions and faces only).
    pub surface: Surface,
    /// For every face of `surface`: the input face it lies in (refined), or the input face
    /// closest to its centroid (decimated).
    pub input_face: Vec<u32>,
    /// For every vertex of `surface`: its point on the input surface (refined: where it lies;
    /// decimated: the closest point).
    pub vertex_link: Vec<FacePoint>,
    /// Whether the input was decimated (its vertices are then near, not on, the input surface).
    pub decimated: bool,
}

/// Builds the synthesis mesh of `input` at `samples` vertices (see the module docs).
///
/// # Errors
/// [`MeshMatchError`] for a bad surface, a surface that cannot be decimated below
/// [`super::MAX_SAMPLES`], or cancellation.
pub fn synthesis_mesh(
    input: &Surface,
    samples: usize,
    control: &Control,
) -> Result<SynthesisMesh, MeshMatchError> {
    let mut used = vec![false; input.vertex_count()];
    for f in &input.faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    let n = used.iter().filter(|&&u| u).count();
    if n > samples {
        return decimated(input, &used, samples, control);
    }
    let r = resample(
        &input.positions,
        &input.faces,
        &ResampleParams {
            max_vertices: samples,
            ..Default::default()
        },
        control,
    )?;
    Ok(SynthesisMesh {
        surface: Surface::from_triangles(r.positions, r.triangles),
        input_face: r.triangle_faces,
        vertex_link: r.sources,
        decimated: false,
    })
}

/// The decimated synthesis mesh of an input with more used vertices than `samples`.
fn decimated(
    input: &Surface,
    used: &[bool],
    samples: usize,
    control: &Control,
) -> Result<SynthesisMesh, MeshMatchError> {
    // The hierarchy wants every vertex used: compact.
    let mut index = vec![u32::MAX; used.len()];
    let mut positions = Vec::new();
    for (v, &u) in used.iter().enumerate() {
        if u {
            index[v] = positions.len() as u32;
            positions.push(input.positions[v]);
        }
    }
    let faces: Vec<[u32; 3]> = input
        .faces
        .iter()
        .map(|f| f.map(|v| index[v as usize]))
        .collect();
    drop(index);
    let mut surface = Surface::from_triangles(positions, faces);
    // Levels may stop short of their target where collapses are blocked; a further pass from
    // the result usually gets the rest (each pass starts its candidate queue afresh). Within
    // `samples / 0.9` a pass (ratio at most 0.8) would not get closer: stop.
    for _ in 0..MAX_PASSES {
        let n = surface.vertex_count();
        if (n as f64) <= samples as f64 / 0.9 {
            break;
        }
        let next = decimate_towards(&surface, samples, control)?;
        let progress = next.vertex_count() < n - n / 20;
        surface = next;
        if !progress {
            break;
        }
    }
    if surface.vertex_count() > super::MAX_SAMPLES {
        return Err(MeshMatchError::Param {
            name: "samples",
            message: format!(
                "the surface cannot be decimated to {samples} vertices: {} are left where edges cannot collapse (non-manifold or locked regions), above the limit {}",
                surface.vertex_count(),
                super::MAX_SAMPLES
            ),
        });
    }
    control.check()?;
    let bvh = Bvh::build(&input.positions, &input.faces);
    let closest = |p: [f32; 3]| -> FacePoint {
        match bvh.closest_point(p, f32::INFINITY) {
            Some(h) => FacePoint {
                face: h.face,
                bary: h.bary,
            },
            None => FacePoint::NONE,
        }
    };
    let vertex_link: Vec<FacePoint> = surface.positions.par_iter().map(|&p| closest(p)).collect();
    let input_face: Vec<u32> = (0..surface.face_count())
        .into_par_iter()
        .map(|f| {
            let t = surface.face_positions(f);
            let c: [f32; 3] = std::array::from_fn(|k| (t[0][k] + t[1][k] + t[2][k]) / 3.0);
            closest(c).face
        })
        .collect();
    if input_face.contains(&u32::MAX) {
        return Err(MeshMatchError::Param {
            name: "samples",
            message: "the decimated surface lost its link to the input".into(),
        });
    }
    Ok(SynthesisMesh {
        surface,
        input_face,
        vertex_link,
        decimated: true,
    })
}

/// One decimation pass: the coarsest level of a hierarchy of `surface` whose ratio and size are
/// set so that it lands on `samples` vertices (see the module docs).
fn decimate_towards(
    surface: &Surface,
    samples: usize,
    control: &Control,
) -> Result<Surface, MeshMatchError> {
    let n = surface.vertex_count() as f64;
    let wanted = samples as f64;
    let levels = ((n / wanted).ln() / 5f64.ln()).ceil().max(1.0);
    let ratio = (wanted / n).powf(1.0 / levels).clamp(0.2, MAX_LEVEL_RATIO);
    // A further level is built while its target is at least 0.75 · min_vertices: put that
    // threshold between `samples · ratio` and `samples`, so the last level built is the one
    // that reaches `samples`.
    let min_vertices = ((wanted * (1.0 + ratio) / 1.5).ceil() as usize).clamp(4, 1_000_000);
    let hierarchy = build_hierarchy(
        surface,
        &HierarchyParams {
            target_ratio: ratio as f32,
            min_vertices,
            ..Default::default()
        },
        control,
    )?;
    let coarsest = &hierarchy.level(hierarchy.level_count() - 1).surface;
    Ok(Surface::from_triangles(
        coarsest.positions.clone(),
        coarsest.faces.clone(),
    ))
}

/// Barycentric coordinates of `p` in the triangle `t` (least squares in the triangle's plane;
/// clamped to the triangle and renormalized).
pub fn barycentric_in(t: [[f32; 3]; 3], p: [f32; 3]) -> [f32; 3] {
    let (e0, e1, d) = (sub(t[1], t[0]), sub(t[2], t[0]), sub(p, t[0]));
    let (a, b, c) = (dot(e0, e0), dot(e0, e1), dot(e1, e1));
    let (r0, r1) = (dot(d, e0), dot(d, e1));
    let det = a * c - b * b;
    if det.abs() <= f32::EPSILON * a * c || det == 0.0 {
        return [1.0 / 3.0; 3];
    }
    let v = ((c * r0 - b * r1) / det).max(0.0);
    let w = ((a * r1 - b * r0) / det).max(0.0);
    let u = (1.0 - v - w).max(0.0);
    let s = u + v + w;
    [u / s, v / s, w / s]
}

/// Base color (linear RGBA) of the input surface at a point of its face `face`.
pub fn input_color(
    asset: &Asset,
    input: &Surface,
    sampler: &MaterialSampler<'_>,
    face: usize,
    bary: [f32; 3],
) -> [f32; 4] {
    match input.primitive_point(asset, face, bary) {
        Some((primitive, triangle, b)) => sampler.base_color(primitive, triangle, b),
        None => [1.0; 4],
    }
}

/// Box-filtered base color of every synthesis vertex (see the module docs), linear RGB.
pub fn synthesis_colors(asset: &Asset, input: &Surface, mesh: &SynthesisMesh) -> Vec<[f32; 3]> {
    let sampler = MaterialSampler::new(asset);
    let s = &mesh.surface;
    let nv = s.vertex_count();
    let topo = topology(s);
    // A decimated mesh lies near, not on, the input: read the closest input point.
    let bvh = mesh
        .decimated
        .then(|| Bvh::build(&input.positions, &input.faces));
    let color_at = |face: usize, p: [f32; 3]| -> [f32; 4] {
        if let Some(hit) = bvh.as_ref().and_then(|b| b.closest_point(p, f32::INFINITY)) {
            return input_color(asset, input, &sampler, hit.face as usize, hit.bary);
        }
        let input_face = mesh.input_face[face] as usize;
        let b = barycentric_in(input.face_positions(input_face), p);
        input_color(asset, input, &sampler, input_face, b)
    };
    (0..nv)
        .into_par_iter()
        .map(|v| {
            let faces = topo.vertex_faces(v);
            let p = s.positions[v];
            let mut sum = [0.0f32; 3];
            let mut weight = 0.0f32;
            if let Some(&f0) = faces.first() {
                let c = color_at(f0 as usize, p);
                for k in 0..3 {
                    sum[k] += 2.0 * c[k];
                }
                weight += 2.0;
            }
            for &f in faces {
                let t = s.face_positions(f as usize);
                let q: [f32; 3] =
                    std::array::from_fn(|k| 0.5 * p[k] + (t[0][k] + t[1][k] + t[2][k]) / 6.0);
                let c = color_at(f as usize, q);
                for k in 0..3 {
                    sum[k] += c[k];
                }
                weight += 1.0;
            }
            if weight == 0.0 {
                return [1.0; 3];
            }
            sum.map(|x| x / weight)
        })
        .collect()
}
