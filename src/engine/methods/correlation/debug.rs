//! The optional debug files of the `correlation` method (issue 11, `params.debug`): the target's
//! guidance field as colours (Mertens et al. 2006, Fig. 8 bottom) and its segmentation into
//! k-means clusters (Fig. 9a), each baked onto a copy of the target through the same colour
//! writer as the output ([`write_color_field`]) and exported as GLB: `guidance.glb` and
//! `segmentation.glb`.
//!
//! **Guidance colours.** Guidance axis `k` (the paper shows the first three) maps to colour
//! channel `k` (R, G, B) by `(g − p₁)/(p₉₉ − p₁)` clamped to [0, 1], where p₁ and p₉₉ are the 1st
//! and 99th percentiles of the *source's* training samples on that axis (retex's choice: the
//! paper does not state its normalisation; using the source's range shows where the matched
//! target leaves it, and the percentiles keep a few outliers from washing out the rest). Axes
//! beyond the guidance's dimension (CCA of a grey source) are black. The colours are written as
//! linear values.
//!
//! **Segmentation.** Every target sample gets its cluster's colour from a fixed palette (golden-
//! ratio hue steps over three value/saturation rings, so that neighbouring indices differ), and
//! the field takes the *nearest* sample's colour instead of interpolating, so no blend of two
//! clusters' colours appears at a boundary. The parametric synthesis's own target clustering is
//! shown; the non-parametric synthesis has none, so the same k-means (`clusters`, the target's
//! seed) is run on its guidance for the file.

use crate::engine::asset::constraints::{Constraints, OutputFormat};
use crate::engine::asset::export::export;
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::mesh::Surface;
use crate::engine::methods::color_output::write_color_field;
use crate::engine::methods::{MethodError, ResultFile};
use crate::engine::spatial::Bvh;

use super::SampleField;

/// The target's fields the debug files show.
#[derive(Clone, Debug)]
pub struct DebugFields {
    /// The target's level-0 sample mesh (its vertices are the samples).
    pub mesh: Surface,
    /// Guidance per target sample after feature matching (unused axes 0).
    pub guidance: Vec<[f32; 3]>,
    /// Guidance axes in use.
    pub dims: usize,
    /// Per guidance axis: the source's 1st and 99th percentiles (the colour normalisation).
    pub range: [[f32; 2]; 3],
    /// Target cluster per sample.
    pub labels: Vec<u32>,
}

/// Weighted-by-count 1st and 99th percentiles of each axis over the training samples (`weight`
/// > 0); `[0, 1]` for an unused axis or when nothing trains.
pub fn guidance_range(guidance: &[[f32; 3]], weight: &[f32], dims: usize) -> [[f32; 2]; 3] {
    std::array::from_fn(|k| {
        if k >= dims {
            return [0.0, 1.0];
        }
        let mut v: Vec<f32> = guidance
            .iter()
            .zip(weight)
            .filter(|(g, w)| **w > 0.0 && g[k].is_finite())
            .map(|(g, _)| g[k])
            .collect();
        if v.is_empty() {
            return [0.0, 1.0];
        }
        v.sort_unstable_by(f32::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        let (lo, hi) = (at(0.01), at(0.99));
        if hi > lo {
            [lo, hi]
        } else {
            [lo - 0.5, lo + 0.5]
        }
    })
}

/// The guidance as linear RGB (see the module docs).
pub fn guidance_colors(guidance: &[[f32; 3]], dims: usize, range: &[[f32; 2]; 3]) -> Vec<[f32; 3]> {
    guidance
        .iter()
        .map(|g| {
            std::array::from_fn(|k| {
                if k >= dims {
                    return 0.0;
                }
                let [lo, hi] = range[k];
                ((g[k] - lo) / (hi - lo)).clamp(0.0, 1.0)
            })
        })
        .collect()
}

/// The palette colour of cluster `c` (linear RGB): hue `c · 0.618…` turns, value and saturation
/// cycling over three rings.
pub fn palette(c: u32) -> [f32; 3] {
    let h = (f64::from(c) * 0.618_033_988_749_895).fract() * 6.0;
    let (s, v) = [(0.85, 0.95), (0.6, 0.6), (1.0, 0.35)][(c % 3) as usize];
    let i = h.floor();
    let f = h - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    let rgb = match i as u32 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    };
    rgb.map(|x| x as f32)
}

fn baked(
    target: &Asset,
    constraints: &Constraints,
    vertex_color_samples: usize,
    field: &SampleField<'_>,
    name: &str,
    control: &Control,
) -> Result<ResultFile, MethodError> {
    let (edits, _) = write_color_field(target, constraints, vertex_color_samples, field, control)?;
    let bytes = export(target, &edits, OutputFormat::Glb)
        .map_err(|e| MethodError::Internal(format!("debug file {name}: {e}")))?;
    Ok(ResultFile {
        name: name.into(),
        media_type: "model/gltf-binary".into(),
        bytes,
    })
}

/// `guidance.glb` and `segmentation.glb` of `fields` on copies of `target`.
///
/// # Errors
/// [`MethodError::Cancelled`]; [`MethodError::Internal`] if the export fails.
pub fn debug_files(
    target: &Asset,
    constraints: &Constraints,
    vertex_color_samples: usize,
    fields: &DebugFields,
    control: &Control,
) -> Result<Vec<ResultFile>, MethodError> {
    control.stage("debug files", 0)?;
    let bvh = Bvh::build(&fields.mesh.positions, &fields.mesh.faces);
    let colors = guidance_colors(&fields.guidance, fields.dims, &fields.range);
    let guidance = SampleField {
        mesh: &fields.mesh,
        bvh,
        colors: &colors,
        nearest: false,
    };
    let g = baked(
        target,
        constraints,
        vertex_color_samples,
        &guidance,
        "guidance.glb",
        control,
    )?;
    let colors: Vec<[f32; 3]> = fields.labels.iter().map(|&c| palette(c)).collect();
    let segmentation = SampleField {
        colors: &colors,
        nearest: true,
        ..guidance
    };
    let s = baked(
        target,
        constraints,
        vertex_color_samples,
        &segmentation,
        "segmentation.glb",
        control,
    )?;
    Ok(vec![g, s])
}
