//! Sampling: the synthesis meshes of MeshMatch (Chen et al. 2012, §4: the texture is "stored on
//! vertices"): the welded input surface resampled by longest-edge bisection to a requested vertex
//! count, so the output resolution does not depend on how the asset was tessellated (DESIGN.md,
//! "dense resampling"). Resampling never moves the geometry; every synthesis vertex knows its
//! (face, barycentric) point on the input surface.
//!
//! The source's color per synthesis vertex is its base color (factor × texture × COLOR_0, linear)
//! box-filtered over about the vertex's own area: the mean of the point sample at the vertex
//! (weight 2) and one sample halfway to the centroid of each incident synthesis triangle
//! (weight 1 each). A bare point sample would alias a 1024² texture read by 64K vertices.
//!
//! An input with at least as many vertices as requested is used as it is.

use rayon::prelude::*;

use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::math::{dot, sub};
use crate::engine::mesh::{topology, Surface};
use crate::engine::multires::{resample, ResampleError, ResampleParams};
use crate::engine::texture::sample::MaterialSampler;

/// A synthesis mesh: resampled surface plus the link of each vertex to the input surface.
#[derive(Clone, Debug)]
pub struct SynthesisMesh {
    /// The resampled surface (positions and faces only).
    pub surface: Surface,
    /// For every face of `surface`: the input face it lies in.
    pub input_face: Vec<u32>,
}

/// Resamples `input` to `samples` vertices (or keeps it when it already has as many).
///
/// # Errors
/// [`ResampleError`] for a bad surface or cancellation.
pub fn synthesis_mesh(
    input: &Surface,
    samples: usize,
    control: &Control,
) -> Result<SynthesisMesh, ResampleError> {
    if input.vertex_count() >= samples {
        return Ok(SynthesisMesh {
            surface: Surface::from_triangles(input.positions.clone(), input.faces.clone()),
            input_face: (0..input.face_count() as u32).collect(),
        });
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
    })
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
    let color_at = |face: usize, p: [f32; 3]| -> [f32; 4] {
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
