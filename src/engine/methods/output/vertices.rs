//! The vertex path of [`super::write_field`] and [`super::write_fields`]: primitives without a
//! UV layout (or all of them, when `output.vertex_colors` is set) get the field as a vertex
//! attribute (COLOR_0 for colour),
//! on a refined copy with about `vertex_samples` vertices in all, or on their own vertices when
//! vertex colours were requested or the primitive is skinned or morphed (a refined copy would
//! drop its joints and targets).

use rayon::prelude::*;

use super::fields::OutputOf;
use super::texels::Layout;
use super::{
    cross, dot, normal_of, sub, to_f32, FieldOutput, OutputReport, SurfaceSample, VertexColorReport,
};
use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::{AttributeData, Edit, PrimitiveGeometry, TextureSlot};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};
use crate::engine::multires::{edge_length_for_vertex_count, refine, FacePoint, RefineParams};

/// Geometry of one primitive on the vertex path, in local space.
struct VertexGeometry {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    /// Each vertex's point on the primitive's own triangles.
    sources: Vec<FacePoint>,
}

/// The primitive's own vertices, each placed on the first triangle that uses it.
fn own_vertices(asset: &Asset, p: usize) -> VertexGeometry {
    let prim = &asset.primitives[p];
    let mut sources = vec![FacePoint::NONE; prim.positions.len()];
    for (ti, t) in prim.triangles.iter().enumerate() {
        for (k, &v) in t.iter().enumerate() {
            let s = &mut sources[v as usize];
            if s.face == u32::MAX {
                let mut bary = [0.0; 3];
                bary[k] = 1.0;
                *s = FacePoint {
                    face: ti as u32,
                    bary,
                };
            }
        }
    }
    VertexGeometry {
        positions: prim.positions.clone(),
        triangles: prim.triangles.clone(),
        normals: None,
        sources,
    }
}

/// A refined copy of the primitive with edges under `max_edge` (local units).
fn refined_vertices(asset: &Asset, p: usize, max_edge: f32) -> VertexGeometry {
    let prim = &asset.primitives[p];
    let r = refine(
        &prim.positions,
        &prim.triangles,
        &RefineParams {
            max_edge_length: max_edge,
            ..Default::default()
        },
    );
    let normals = prim.normals.as_ref().map(|n| {
        r.interpolate(n)
            .into_iter()
            .map(|v| {
                let l = dot(v, v).sqrt();
                if l > 0.0 {
                    [v[0] / l, v[1] / l, v[2] / l]
                } else {
                    [0.0, 0.0, 1.0]
                }
            })
            .collect()
    });
    VertexGeometry {
        positions: r.positions,
        triangles: r.triangles,
        normals,
        sources: r.sources,
    }
}

/// Evaluates one output of the fields at every vertex of `g` (placed by instance `ii`), in
/// chunks that each check for cancellation first.
fn sample_vertices(
    asset: &Asset,
    p: usize,
    ii: usize,
    g: &VertexGeometry,
    field: OutputOf<'_>,
    control: &Control,
) -> Result<Vec<Option<[f32; 4]>>, Cancelled> {
    let inst = &asset.instances[ii];
    let world: Vec<[f32; 3]> = g
        .positions
        .iter()
        .map(|q| to_f32(inst.transform_point(*q)))
        .collect();
    let mut vnormals = vec![[0.0f32; 3]; world.len()];
    for t in &g.triangles {
        let n = normal_of(
            world[t[0] as usize],
            world[t[1] as usize],
            world[t[2] as usize],
        );
        let n = if inst.mirrors() { n.map(|x| -x) } else { n };
        for &v in t {
            for k in 0..3 {
                vnormals[v as usize][k] += n[k];
            }
        }
    }
    let found: Vec<Vec<Option<[f32; 4]>>> = world
        .par_chunks(4096)
        .zip(vnormals.par_chunks(4096))
        .zip(g.sources.par_chunks(4096))
        .map(|((qs, ns), ss)| {
            control.check()?;
            let mut scratch = Vec::new();
            Ok(qs
                .iter()
                .zip(ns)
                .zip(ss)
                .map(|((q, n), s)| {
                    let l = dot(*n, *n).sqrt().max(1e-20);
                    let on_face = s.face != u32::MAX;
                    let at = SurfaceSample {
                        primitive: p,
                        triangle: if on_face { s.face as usize } else { 0 },
                        barycentric: if on_face { s.bary } else { [1.0, 0.0, 0.0] },
                        position: *q,
                        normal: n.map(|x| x / l),
                    };
                    field.sample(&at, &mut scratch)
                })
                .collect())
        })
        .collect::<Result<_, Cancelled>>()?;
    Ok(found.into_iter().flatten().collect())
}

/// The vertex path: evaluates one output of the fields at the (refined) vertices of every
/// collected primitive.
pub(super) fn write_vertex_values(
    asset: &Asset,
    constraints: &Constraints,
    layout: &Layout,
    output: &FieldOutput,
    field: OutputOf<'_>,
    control: &Control,
    report: &mut OutputReport,
) -> Result<VertexEdits, Cancelled> {
    let mut edits = VertexEdits::default();
    let vertex_path = &layout.vertex_path;
    if vertex_path.is_empty() {
        return Ok(edits);
    }
    let Some(attribute) = output.vertex_attribute else {
        report.warnings.push(format!(
            "{} primitive(s) have no UVs: they received no {} texture",
            vertex_path.len(),
            output.slot.key()
        ));
        return Ok(edits);
    };
    let stage = control.stage("vertex_colors", vertex_path.len() as u64)?;
    let refine_it: Vec<bool> = vertex_path
        .iter()
        .map(|&(p, _)| {
            let prim = &asset.primitives[p];
            let prim_json = &asset.json["meshes"][prim.mesh]["primitives"][prim.primitive];
            let skinned_or_morphed = prim_json.get("targets").is_some()
                || prim_json["attributes"].get("JOINTS_0").is_some();
            if !constraints.output.all_vertex_colors() && skinned_or_morphed {
                report.warnings.push(format!(
                    "mesh {} primitive {} has skin or morph data; COLOR_0 was written on its own vertices instead of a refined copy",
                    prim.mesh, prim.primitive
                ));
            }
            !constraints.output.all_vertex_colors() && !skinned_or_morphed
        })
        .collect();
    let geometries = budgeted_geometries(asset, vertex_path, &refine_it, output, control)?;
    for ((&(p, ii), g), refine_it) in vertex_path.iter().zip(geometries).zip(refine_it) {
        let prim = &asset.primitives[p];
        let found = sample_vertices(asset, p, ii, &g, field, control)?;
        let unmatched = found.iter().filter(|c| c.is_none()).count();
        let values = fill_from_neighbours(found, &g.triangles);
        report.vertex_colors.push(VertexColorReport {
            mesh: prim.mesh,
            primitive: prim.primitive,
            refined: refine_it,
            vertices: g.positions.len(),
            unmatched,
        });
        if refine_it {
            edits.refined.push(Edit::ReplacePrimitive {
                primitive: p,
                geometry: PrimitiveGeometry {
                    positions: g.positions,
                    normals: g.normals,
                    colors: Some(values),
                    triangles: g.triangles,
                    ..Default::default()
                },
            });
        } else {
            edits.vertex_values.push(Edit::SetAttribute {
                primitive: p,
                name: attribute.into(),
                data: AttributeData::Vec4(values),
            });
        }
        if let Some(m) = prim.material {
            let clears = output.slot == TextureSlot::BaseColor;
            if clears && !layout.groups.contains_key(&Some(m)) && !edits.cleared.contains(&m) {
                edits.cleared.push(m);
            }
        }
        stage.tick(1)?;
    }
    edits.cleared.sort_unstable();
    if !constraints.output.all_vertex_colors() {
        report.warnings.push(format!(
            "{} primitive(s) have no UVs for a base color texture: the color was written as COLOR_0 on a refined copy",
            vertex_path.len()
        ));
    }
    Ok(edits)
}

/// Largest overshoot of the vertex budget accepted.
const BUDGET_TOLERANCE: f64 = 1.1;

/// Most refinements tried while searching the edge bound that fits the vertex budget.
const BUDGET_SEARCH_STEPS: usize = 10;

/// A best count under the budget below this fraction of it is "far"...
const BUDGET_FAR_UNDER: f64 = 0.7;

/// ...and then a count over the budget by at most this factor is taken instead (uniform meshes;
/// measured on the cat at 100k: 28k under or 112k over).
const BUDGET_FAR_TOLERANCE: f64 = 1.25;

/// The geometry of every primitive on the vertex path: refined copies (where `refine_it`) whose
/// vertices add up to at most about `output.vertex_samples` (within [`BUDGET_TOLERANCE`]), and
/// own vertices elsewhere.
///
/// The first edge bound assumes equilateral triangles of that length; longest-edge bisection
/// leaves edges between half the bound and the bound, so it overshoots (1.85× on the remeshed
/// Spot), and since bisection is discrete the count jumps when the bound crosses a split level.
/// So the bound is searched: lengthened by the square root of the overshoot until the count fits,
/// then bisected between the last bound over budget and the best one under it (at most
/// [`BUDGET_SEARCH_STEPS`] refinements in all), keeping the largest count that fits, unless that
/// is far under the budget and a count a little over it was seen ([`BUDGET_FAR_UNDER`],
/// [`BUDGET_FAR_TOLERANCE`]). Inputs that already have more vertices than the budget are not
/// refined and cannot be reduced.
fn budgeted_geometries(
    asset: &Asset,
    vertex_path: &[(usize, usize)],
    refine_it: &[bool],
    output: &FieldOutput,
    control: &Control,
) -> Result<Vec<VertexGeometry>, Cancelled> {
    let budget = output.vertex_samples.max(1) as f64 * BUDGET_TOLERANCE;
    let area: f64 = vertex_path
        .iter()
        .zip(refine_it)
        .filter(|(_, r)| **r)
        .map(|(&(p, ii), _)| primitive_world_area(asset, p, ii))
        .sum();
    let build = |max_edge: f32| -> Result<(Vec<VertexGeometry>, usize), Cancelled> {
        let geometries: Vec<VertexGeometry> = vertex_path
            .iter()
            .zip(refine_it)
            .map(|(&(p, ii), &refine)| {
                if refine {
                    let scale = instance_scale(&asset.instances[ii].world);
                    refined_vertices(asset, p, max_edge / scale)
                } else {
                    own_vertices(asset, p)
                }
            })
            .collect();
        control.check()?;
        let total = geometries.iter().map(|g| g.positions.len()).sum();
        Ok((geometries, total))
    };
    // Refinement only adds vertices: below this count nothing can go.
    let floor: usize = vertex_path
        .iter()
        .map(|&(p, _)| asset.primitives[p].positions.len())
        .sum();
    let mut edge = edge_length_for_vertex_count(area, output.vertex_samples);
    if floor as f64 > budget || !edge.is_finite() {
        // The inputs alone are over the budget (or there is nothing to refine): no refinement.
        return Ok(build(f32::INFINITY)?.0);
    }
    let (first, total) = build(edge)?;
    if total as f64 <= budget {
        return Ok(first);
    }
    // The last bound over budget and the smallest count over it seen (with its geometry), and
    // the best (bound, geometry, count) under it.
    let mut over = edge;
    let mut over_count = total;
    let mut closest_over = (total, first);
    let mut under: Option<(f32, Vec<VertexGeometry>, usize)> = None;
    // While no bound under budget is known, the bound is lengthened by the square root of the
    // overshoot (at least 5%), and by half again for every step that did not lower the count
    // (bisection levels are discrete).
    let mut boost = 1.0f64;
    for _ in 1..BUDGET_SEARCH_STEPS {
        edge = match &under {
            None => over * ((over_count as f64 / budget).sqrt().max(1.05) * boost) as f32,
            Some((u, _, _)) => 0.5 * (over + u),
        };
        let (g, total) = build(edge)?;
        if total as f64 <= budget {
            if under.as_ref().is_none_or(|(_, _, best)| total >= *best) {
                under = Some((edge, g, total));
            }
        } else {
            if total >= over_count {
                boost *= 1.5;
            }
            over = edge;
            over_count = total;
            if total < closest_over.0 {
                closest_over = (total, g);
            }
        }
        if under
            .as_ref()
            .is_some_and(|(_, _, best)| *best as f64 >= 0.85 * budget)
        {
            break;
        }
    }
    // On a very uniform mesh the count jumps about 4× between bisection levels, so the best
    // count under the budget can be far below it: then a count at most
    // [`BUDGET_FAR_TOLERANCE`] over the budget is the closer answer.
    let samples = output.vertex_samples.max(1) as f64;
    let far_under = under
        .as_ref()
        .is_none_or(|(_, _, n)| (*n as f64) < BUDGET_FAR_UNDER * samples);
    if far_under && closest_over.0 as f64 <= BUDGET_FAR_TOLERANCE * samples {
        return Ok(closest_over.1);
    }
    match under {
        Some((_, g, _)) => Ok(g),
        // Never under budget within the steps: the unrefined inputs fit (floor <= budget).
        None => Ok(build(f32::INFINITY)?.0),
    }
}

/// The vertex path's edits, kept by kind so they are exported in a fixed order: materials
/// that lose their base-colour texture, attributes on original vertices, refined copies.
#[derive(Default)]
pub(super) struct VertexEdits {
    cleared: Vec<usize>,
    vertex_values: Vec<Edit>,
    refined: Vec<Edit>,
}

impl VertexEdits {
    pub(super) fn into_edits(self) -> impl Iterator<Item = Edit> {
        self.cleared
            .into_iter()
            .map(|material| Edit::ClearTexture {
                material,
                slot: TextureSlot::BaseColor,
            })
            .chain(self.vertex_values)
            .chain(self.refined)
    }
}

/// Cube root of |det| of the upper 3x3: the mean linear scale of an instance transform.
fn instance_scale(m: &[[f64; 4]; 4]) -> f32 {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[2][1] * m[1][2])
        - m[1][0] * (m[0][1] * m[2][2] - m[2][1] * m[0][2])
        + m[2][0] * (m[0][1] * m[1][2] - m[1][1] * m[0][2]);
    let s = det.abs().cbrt() as f32;
    if s > 0.0 && s.is_finite() {
        s
    } else {
        1.0
    }
}

/// Surface area of primitive `p` placed by instance `instance`, world units.
fn primitive_world_area(asset: &Asset, p: usize, instance: usize) -> f64 {
    let prim = &asset.primitives[p];
    let inst = &asset.instances[instance];
    prim.triangles
        .iter()
        .map(|t| {
            let w = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
            let n = cross(sub(w[1], w[0]), sub(w[2], w[0]));
            0.5 * (dot(n, n) as f64).sqrt()
        })
        .sum()
}

/// Vertices without a value take the mean of their valued neighbours, repeatedly; any left
/// (an island with no valid source point at all) take the mean of all valued vertices, or grey.
fn fill_from_neighbours(
    mut colors: Vec<Option<[f32; 4]>>,
    triangles: &[[u32; 3]],
) -> Vec<[f32; 4]> {
    for _ in 0..64 {
        if colors.iter().all(Option::is_some) {
            break;
        }
        let mut sum = vec![([0.0f32; 4], 0u32); colors.len()];
        for t in triangles {
            for a in 0..3 {
                for b in 0..3 {
                    let (va, vb) = (t[a] as usize, t[b] as usize);
                    if a != b && colors[va].is_none() {
                        if let Some(c) = colors[vb] {
                            for k in 0..4 {
                                sum[va].0[k] += c[k];
                            }
                            sum[va].1 += 1;
                        }
                    }
                }
            }
        }
        let mut changed = false;
        for (c, (s, n)) in colors.iter_mut().zip(sum) {
            if c.is_none() && n > 0 {
                *c = Some(s.map(|x| x / n as f32));
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let known: Vec<[f32; 4]> = colors.iter().flatten().copied().collect();
    let mean = if known.is_empty() {
        [0.5, 0.5, 0.5, 1.0]
    } else {
        let mut m = [0.0f32; 4];
        for c in &known {
            for k in 0..4 {
                m[k] += c[k] / known.len() as f32;
            }
        }
        m
    };
    colors.into_iter().map(|c| c.unwrap_or(mean)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unmatched_vertices_take_their_neighbours_mean() {
        let tris = [[0, 1, 2], [1, 2, 3]];
        let red = [1.0, 0.0, 0.0, 1.0];
        let blue = [0.0, 0.0, 1.0, 1.0];
        let out = fill_from_neighbours(vec![Some(red), Some(blue), None, None], &tris);
        // Vertex 2 sees red once and blue twice (edge 1-2 is in both triangles).
        let want = [1.0 / 3.0, 0.0, 2.0 / 3.0, 1.0];
        assert!(
            (0..4).all(|k| (out[2][k] - want[k]).abs() < 1e-6),
            "{:?}",
            out[2]
        );
        // Vertex 3 sees only blue: vertex 2 was still unknown in that pass.
        assert_eq!(out[3], blue);
        let grey = fill_from_neighbours(vec![None, None, None], &[[0, 1, 2]]);
        assert!(grey.iter().all(|c| *c == [0.5, 0.5, 0.5, 1.0]));
    }

    #[test]
    fn instance_scale_is_the_cube_root_of_the_determinant() {
        let mut m = [[0.0f64; 4]; 4];
        m[0][0] = 2.0;
        m[1][1] = -2.0;
        m[2][2] = 2.0;
        m[3][3] = 1.0;
        assert!((instance_scale(&m) - 2.0).abs() < 1e-6);
        assert_eq!(instance_scale(&[[0.0; 4]; 4]), 1.0);
    }
}
