//! The part-based morph (§5) of the colour of source primitives without UVs (or of every
//! primitive with `output.vertex_colors`): COLOR_0 on the source's own vertices.
//!
//! Without a texel grid, the gradient-domain blend of Pérez et al. 2003 is done on the mesh, with
//! the same Poisson system as the geometry ([`super::poisson`]; cotan Laplacian, vertices of
//! weight 0 fixed): per welded vertex the template's own colour `a` (material factor × COLOR_0,
//! the mean over the primitive vertices welded into it; white without COLOR_0) and the re-laid
//! target colour `b` at the fitted vertex (§4; `a` where the target has none) are blended in
//! their Laplacians with ω = w·r and solved for, 4 channels. Welded vertices that belong only to
//! textured primitives take the re-laid colour for both (they only border the solve).

use crate::engine::asset::edits::{AttributeData, Edit};
use crate::engine::control::Control;

use super::blend::vertex_base_color;
use super::poisson::MeshPoisson;
use super::texture::{has_uvs, RelaidColor};
use super::MethodError;

/// COLOR_0 edits of the primitives without UVs (all of them when `all` is set).
///
/// # Errors
/// [`MethodError::Cancelled`], [`MethodError::Internal`] for a failed solve.
pub fn region_vertex_colors(
    field: &RelaidColor<'_>,
    poisson: &MeshPoisson<'_>,
    omega: &[f64],
    all: bool,
    control: &Control,
) -> Result<Vec<Edit>, MethodError> {
    let source = field.source;
    let prims: Vec<usize> = (0..source.primitives.len())
        .filter(|&p| (all || !has_uvs(source, p)) && !field.welded[p].is_empty())
        .collect();
    if prims.is_empty() {
        return Ok(Vec::new());
    }
    let stage = control.stage("region_vertex_colors", 1)?;
    let n = omega.len();
    let relaid: Vec<[f32; 4]> = (0..n)
        .map(|w| {
            field
                .fitted
                .get(w)
                .and_then(|&q| field.color_near(q, None))
                .map_or([1.0; 4], |c| c.0)
        })
        .collect();
    let mut own_sum = vec![[0.0f64; 4]; n];
    let mut own_count = vec![0u32; n];
    let own = |p: usize, v: usize| vertex_base_color(source, p, v);
    for &p in &prims {
        for (v, &w) in field.welded[p].iter().enumerate() {
            if w != u32::MAX {
                let c = own(p, v);
                for k in 0..4 {
                    own_sum[w as usize][k] += f64::from(c[k]);
                }
                own_count[w as usize] += 1;
            }
        }
    }
    let a: Vec<Vec<f64>> = (0..4)
        .map(|k| {
            (0..n)
                .map(|w| match own_count[w] {
                    0 => f64::from(relaid[w][k]),
                    c => own_sum[w][k] / f64::from(c),
                })
                .collect()
        })
        .collect();
    let b: Vec<Vec<f64>> = (0..4)
        .map(|k| (0..n).map(|w| f64::from(relaid[w][k])).collect())
        .collect();
    let x = poisson.blend(&a, &b, omega)?;
    let mut edits = Vec::new();
    for &p in &prims {
        let colors: Vec<[f32; 4]> = field.welded[p]
            .iter()
            .enumerate()
            .map(|(v, &w)| match w {
                u32::MAX => own(p, v),
                w => std::array::from_fn(|k| x[k][w as usize] as f32),
            })
            .collect();
        edits.push(Edit::SetAttribute {
            primitive: p,
            name: "COLOR_0".into(),
            data: AttributeData::Vec4(colors),
        });
    }
    stage.tick(1)?;
    Ok(edits)
}
