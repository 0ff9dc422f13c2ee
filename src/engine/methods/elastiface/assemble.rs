//! The output (Zell & Botsch 2013, "ElastiFace", §4-5): the fitted positions are taken back to
//! the target's world frame, morphed with the template when asked (§5: the linear morph of
//! [`super::blend`], or the part-based one, [`super::poisson`] on the weights of
//! [`super::region`]) and written into the source asset ([`super::writeback`]); the target's
//! colour is then re-laid into the source's UV layout (§4, [`super::texture`]), or blended in the
//! gradient domain over the region ([`super::region_texture`], [`super::region_colors`]).

use super::poisson::MeshPoisson;
use super::prepare::Prepared;
use super::system::{self, LapRows};
use super::{
    blend, refs, region_colors, region_texture, texture, writeback, Call, MethodError, OutputMode,
};
use crate::engine::asset::edits::Edit;
use crate::engine::methods::output::{TextureReport, VertexColorReport};
use crate::engine::texture::sample::MaterialSampler;

/// The placed geometry.
pub struct Geometry<'a> {
    /// The fitted welded source positions in the target's world frame (w = 1).
    pub world: Vec<[f64; 3]>,
    /// The part-based morph's factorised Poisson system and per-vertex weights `w · r`.
    pub region_solve: Option<(MeshPoisson<'a>, Vec<f64>)>,
}

/// Places the fitted positions (`fitted`, solve frame): the morph of §5 when asked, written
/// back through the source's node transforms or as a morph target. `lap_s` is the source's
/// Laplacian (the part-based morph's Poisson system). Returns the placed geometry and the
/// geometry edits of the source asset.
///
/// # Errors
/// [`MethodError::Cancelled`], [`MethodError::Internal`] for a failed solve,
/// [`MethodError::UnusableInput`] from the writeback.
pub fn geometry<'a>(
    call: &Call<'_>,
    p: &'a Prepared,
    lap_s: &'a LapRows,
    fitted: &[[f64; 3]],
) -> Result<(Geometry<'a>, Vec<Edit>), MethodError> {
    let (params, frame) = (call.params, &p.frame);
    let world: Vec<[f64; 3]> = fitted.iter().map(|q| frame.solve_to_target(*q)).collect();
    let morph = params.output == OutputMode::MorphTarget;
    let blend_weight = params.blend_weight();
    let region_solve = match &p.region_weights {
        Some(r) => {
            call.control.stage("region_geometry", 0)?;
            let areas = system::voronoi_areas(&p.src_world, &p.src.faces)?;
            let w = params.blend.as_ref().map_or(1.0, |b| b.weight);
            let omega: Vec<f64> = r.iter().map(|x| w * x).collect();
            Some((MeshPoisson::new(lap_s, &p.src.faces, r, areas)?, omega))
        }
        None => None,
    };
    let placed = match (&region_solve, &p.region_weights) {
        (Some((solver, omega)), Some(r)) => {
            // In the template's placement; a morph target holds the w = 1 blend (the solution
            // is affine in w) and glTF applies w.
            let back: Vec<[f64; 3]> = world.iter().map(|q| frame.target_to_source(*q)).collect();
            let full: Vec<f64>;
            let om = if morph {
                full = r.clone();
                &full
            } else {
                omega
            };
            let x = solver.blend(&coords(&p.src_world), &coords(&back), om)?;
            (0..p.src_world.len())
                .map(|v| [x[0][v], x[1][v], x[2][v]])
                .collect()
        }
        _ => match blend_weight {
            Some(w) if !morph => blend::blend_positions(&p.src_world, &world, w),
            _ => world.clone(),
        },
    };
    let same = |q: [f64; 3]| q;
    let back = |q: [f64; 3]| frame.target_to_source(q);
    let to_source: &dyn Fn([f64; 3]) -> [f64; 3] =
        if region_solve.is_some() { &same } else { &back };
    let follow = |q: [f64; 3]| match p.src_bvh.closest_point(q.map(|c| c as f32), f32::INFINITY) {
        Some(h) => refs::RefRow::face(p.src.faces[h.face as usize], h.bary).eval(&placed),
        None => frame.similarity.apply(q),
    };
    let edits = writeback::geometry_edits(
        call.source,
        &writeback::Placement {
            fitted: &placed,
            faces: &p.src.faces,
            welded: &p.welded,
            to_source_frame: to_source,
            follow_surface: &follow,
            morph,
            morph_weight: params.blend.as_ref().map_or(0.0, |b| b.weight as f32),
        },
    )?;
    Ok((
        Geometry {
            world,
            region_solve,
        },
        edits,
    ))
}

/// The baked colour: texture reports and COLOR_0 reports.
#[derive(Default)]
pub struct Colors {
    /// Baked textures.
    pub textures: Vec<TextureReport>,
    /// Primitives that received COLOR_0 through the shared vertex path.
    pub vertex_colors: Vec<VertexColorReport>,
}

/// Re-lays the target's colour into the source at the placed geometry `g`, appending the edits
/// to `edits` and any warnings to `warnings`.
///
/// # Errors
/// [`MethodError::Cancelled`], [`MethodError::Internal`] for a failed solve.
pub fn colors(
    call: &Call<'_>,
    p: &Prepared,
    g: &Geometry<'_>,
    edits: &mut Vec<Edit>,
    warnings: &mut Vec<String>,
) -> Result<Colors, MethodError> {
    let (source, target, constraints, params, control) = (
        call.source,
        call.target,
        call.constraints,
        call.params,
        call.control,
    );
    let mut out = Colors::default();
    if !texture::target_has_color(target) {
        warnings.push(
            "the target has no base color texture and no COLOR_0: the source keeps its own texture"
                .into(),
        );
        return Ok(out);
    }
    let world32: Vec<[f32; 3]> = g.world.iter().map(|q| q.map(|c| c as f32)).collect();
    let field = texture::RelaidColor {
        source,
        welded: &p.welded,
        fitted: &world32,
        target,
        target_surface: &p.tgt,
        target_bvh: &p.tgt_bvh,
        sampler: MaterialSampler::new(target),
        blend: params
            .blend_weight()
            .map(|w| blend::TemplateColor::new(source, w)),
    };
    if let (Some((solver, omega)), Some(r)) = (&g.region_solve, &p.region_weights) {
        let all = constraints.output.all_vertex_colors();
        if !all {
            let rt = region_texture::RegionTexture {
                relaid: &field,
                template: MaterialSampler::new(source),
                weights: r,
                w: params.blend.as_ref().map_or(1.0, |b| b.weight),
                max_texels: params.blend.as_ref().map_or(1, |b| b.max_region_texels),
            };
            let (tex_edits, reports) = region_texture::region_textures(&rt, constraints, control)?;
            edits.extend(tex_edits);
            out.textures = reports;
        }
        edits.extend(region_colors::region_vertex_colors(
            &field, solver, omega, all, control,
        )?);
    } else {
        let (tex_edits, relaid) = texture::relay_texture(&field, constraints, control)?;
        edits.extend(tex_edits);
        out.textures = relaid.textures;
        out.vertex_colors = relaid.vertex_colors;
        warnings.extend(relaid.warnings);
    }
    Ok(out)
}

/// Positions as three coordinate vectors.
fn coords(x: &[[f64; 3]]) -> Vec<Vec<f64>> {
    (0..3).map(|k| x.iter().map(|p| p[k]).collect()).collect()
}
