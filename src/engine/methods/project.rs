//! The `project` method: closest-point transfer of the source's base color onto the target.
//!
//! This is the texture-matching step of ElastiFace (Zell & Botsch 2013, section 4: after the
//! source is fitted to the target, every target texel takes the color of the closest source
//! point) and what every baker does. For every covered texel of the target's UV layout (and for
//! every vertex of primitives without UVs) the target surface point is found, the closest point on
//! the source is computed exactly (point–triangle distance through a BVH, not nearest vertex), and
//! the source's base color is sampled there (factor × texture × COLOR_0, in linear space).
//!
//! Options: `max_distance` and `max_normal_angle` gate the search (texels with no valid source
//! point are counted as `unmatched` and filled by padding); with two or more correspondences the
//! source is first moved onto the target by the best similarity transform (Horn/Umeyama, see
//! [`super::align`]). Parallel over texel rows with rayon; every texel is independent, so the
//! output does not depend on the thread count.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::align::{best_similarity, Similarity};
use super::correspondence::{resolve, Side};
use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::asset::export::{Edits, MaterialTexture, RefinedPrimitive, VertexColors};
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::{build_surface, MeshError, Surface, WeldParams};
use crate::engine::multires::{edge_length_for_vertex_count, refine, RefineParams};
use crate::engine::spatial::triangle::point_triangle_distance_squared;
use crate::engine::spatial::Bvh;
use crate::engine::texture::bake::rasterize_uv_layout;
use crate::engine::texture::encode::encode_png_srgb;
use crate::engine::texture::pad::pad;
use crate::engine::texture::sample::MaterialSampler;

/// Parameters of the `project` method (the `params` object of the constraints).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProjectParams {
    /// Largest source–target distance accepted, as a fraction of the target's bounding-box
    /// diagonal. Default: none (unbounded). Range (0, 10].
    pub max_distance: Option<f32>,
    /// Largest angle between the target face normal and the source face normal, in degrees.
    /// Default: none (no gating). Range (0, 180].
    pub max_normal_angle: Option<f32>,
    /// Align the source to the target from the correspondences (needs at least 2). Default true.
    pub align: bool,
    /// Vertex count of the refined copy written for target primitives without UVs (COLOR_0).
    /// Default 100,000. Range 1..=4,000,000.
    pub vertex_color_samples: usize,
    /// Largest distance from a correspondence point to its surface, as a fraction of that
    /// surface's bounding-box diagonal. Default 0.02. Range (0, 1].
    pub snap_tolerance: f32,
    /// Relative weld tolerance of both surfaces (see [`WeldParams`]). Default 1e-6.
    pub weld_tolerance: f32,
}

impl Default for ProjectParams {
    fn default() -> Self {
        Self {
            max_distance: None,
            max_normal_angle: None,
            align: true,
            vertex_color_samples: 100_000,
            snap_tolerance: 0.02,
            weld_tolerance: WeldParams::default().relative_tolerance,
        }
    }
}

impl ProjectParams {
    /// Reads and range-checks the parameters from the constraints' `params`.
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        let p: ProjectParams = c.method_params()?;
        let bad =
            |field: &str, msg: String| Err(ConstraintsError::new(format!("params.{field}"), msg));
        if let Some(d) = p.max_distance {
            if !(d > 0.0 && d <= 10.0) {
                return bad("max_distance", format!("{d} is outside the range (0, 10]"));
            }
        }
        if let Some(a) = p.max_normal_angle {
            if !(a > 0.0 && a <= 180.0) {
                return bad(
                    "max_normal_angle",
                    format!("{a} is outside the range (0, 180]"),
                );
            }
        }
        if !(1..=4_000_000).contains(&p.vertex_color_samples) {
            return bad(
                "vertex_color_samples",
                format!(
                    "{} is outside the range 1..=4000000",
                    p.vertex_color_samples
                ),
            );
        }
        if !(p.snap_tolerance > 0.0 && p.snap_tolerance <= 1.0) {
            return bad(
                "snap_tolerance",
                format!("{} is outside the range (0, 1]", p.snap_tolerance),
            );
        }
        if !(0.0..=1e-2).contains(&p.weld_tolerance) {
            return bad(
                "weld_tolerance",
                format!("{} is outside the range [0, 0.01]", p.weld_tolerance),
            );
        }
        Ok(p)
    }
}

/// Failures of the method.
#[derive(Debug, thiserror::Error)]
pub enum ProjectError {
    /// A surface could not be built.
    #[error("{side} surface: {source}")]
    Mesh {
        /// "source" or "target".
        side: &'static str,
        /// The cause.
        source: MeshError,
    },
    /// A correspondence or parameter is invalid.
    #[error(transparent)]
    Constraints(#[from] ConstraintsError),
    /// Cancelled through the Control.
    #[error("cancelled")]
    Cancelled(#[from] Cancelled),
}

/// The alignment that was applied.
#[derive(Clone, Debug, Serialize)]
pub struct AlignmentReport {
    /// The transform applied to the source.
    pub transform: Similarity,
    /// Correspondence pairs used.
    pub pairs: usize,
    /// Residual after alignment, world units of the target.
    pub rms_error: f64,
}

/// Figures of one baked texture.
#[derive(Clone, Debug, Serialize)]
pub struct TextureReport {
    /// Target material (`None`: a new material for primitives without one).
    pub material: Option<usize>,
    /// Texture width = height.
    pub size: u32,
    /// UV set baked into.
    pub tex_coord: u32,
    /// Triangles rasterized.
    pub triangles: usize,
    /// Texels inside some triangle.
    pub covered: u64,
    /// Covered texels claimed by more than one triangle (resolved to the lowest index).
    pub overlapped: u64,
    /// Covered texels with no valid source point (distance or normal gating); padded instead.
    pub unmatched: u64,
    /// Texels filled by dilation padding.
    pub padded: u64,
    /// Remaining texels filled by pull-push.
    pub filled: u64,
}

/// Figures of one primitive that received COLOR_0.
#[derive(Clone, Debug, Serialize)]
pub struct VertexColorReport {
    /// glTF mesh index.
    pub mesh: usize,
    /// Primitive index within the mesh.
    pub primitive: usize,
    /// Whether a refined copy replaced the primitive.
    pub refined: bool,
    /// Vertices written.
    pub vertices: usize,
    /// Vertices with no valid source point (filled from neighbours).
    pub unmatched: usize,
}

/// Counts of a welded surface.
#[derive(Clone, Debug, Serialize)]
pub struct SurfaceReport {
    /// Welded vertices.
    pub vertices: usize,
    /// Faces.
    pub faces: usize,
    /// Degenerate triangles removed.
    pub degenerate_removed: usize,
}

impl SurfaceReport {
    fn of(s: &Surface) -> Self {
        Self {
            vertices: s.vertex_count(),
            faces: s.face_count(),
            degenerate_removed: s.degenerate_removed,
        }
    }
}

/// What the method reports.
#[derive(Clone, Debug, Serialize)]
pub struct ProjectReport {
    /// The welded source surface.
    pub source_surface: SurfaceReport,
    /// The welded target surface.
    pub target_surface: SurfaceReport,
    /// The alignment, when one was applied.
    pub alignment: Option<AlignmentReport>,
    /// One entry per baked texture.
    pub textures: Vec<TextureReport>,
    /// One entry per primitive that received COLOR_0.
    pub vertex_colors: Vec<VertexColorReport>,
    /// Things the user should know (lowercase sentences).
    pub warnings: Vec<String>,
    /// Wall-clock milliseconds per stage (surface, align, bake, pad, vertex_colors).
    pub timings_ms: Vec<(String, f64)>,
}

/// The source, placed in the target's frame, ready to answer "what color is closest to p".
struct SourceField<'a> {
    asset: &'a Asset,
    surface: Surface,
    bvh: Bvh,
    sampler: MaterialSampler<'a>,
    normals: Vec<[f32; 3]>,
    max_distance: f32,
    min_cos: Option<f32>,
}

impl SourceField<'_> {
    /// Base color of the closest valid source point to `p` (target normal `n` for gating), and
    /// the source face it lies on. `hint` is a face that was closest for a nearby point: its
    /// distance bounds the search (a warm start that prunes most of the BVH); the result does not
    /// depend on it, because the bound includes the true closest point and ties still go to the
    /// lowest face index.
    fn color_at(&self, p: [f32; 3], n: [f32; 3], hint: Option<u32>) -> Option<([f32; 4], u32)> {
        let accept = |f: u32| {
            self.min_cos
                .is_none_or(|c| dot(self.normals[f as usize], n) >= c)
        };
        let mut bound = self.max_distance;
        if let Some(h) = hint.filter(|h| accept(*h)) {
            let [a, b, c] = self.surface.face_positions(h as usize);
            let (d2, _, _) = point_triangle_distance_squared(p, a, b, c);
            bound = bound.min(d2.sqrt() * (1.0 + 1e-4) + 1e-12);
        }
        let hit = match self.min_cos {
            None => self.bvh.closest_point(p, bound),
            Some(_) => self.bvh.closest_point_filtered(p, bound, accept),
        }?;
        let f = hit.face as usize;
        let o = self.surface.origins[f];
        let corners = &self.surface.corners[f];
        let tri = self.asset.primitives[o.primitive as usize].triangles[o.triangle as usize];
        // Map the face's barycentrics (corner order may be flipped for mirrored instances) onto
        // the primitive triangle's vertex order.
        let mut bary = [0.0f32; 3];
        for k in 0..3 {
            if let Some(j) = tri.iter().position(|v| *v == corners[k].vertex) {
                bary[j] += hit.bary[k];
            }
        }
        let color = self
            .sampler
            .base_color(o.primitive as usize, o.triangle as usize, bary);
        Some((color, hit.face))
    }
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn normal_of(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> [f32; 3] {
    let (u, v) = (sub(b, a), sub(c, a));
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let l = dot(n, n).sqrt();
    if l > 0.0 {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    }
}

fn to_f32(p: [f64; 3]) -> [f32; 3] {
    [p[0] as f32, p[1] as f32, p[2] as f32]
}

/// A target triangle placed in the world, with its UVs.
struct PlacedTriangle {
    primitive: usize,
    world: [[f32; 3]; 3],
    normal: [f32; 3],
    uv: [[f32; 2]; 3],
}

/// Runs `project`: returns the edits to write into the target and the report.
pub fn run(
    source: &Asset,
    target: &Asset,
    constraints: &Constraints,
    params: &ProjectParams,
    control: &Control,
) -> Result<(Edits, ProjectReport), ProjectError> {
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    let mut timings_ms: Vec<(String, f64)> = Vec::new();
    let mut clock = std::time::Instant::now();
    let mut lap = |name: &str, timings: &mut Vec<(String, f64)>| {
        let now = std::time::Instant::now();
        timings.push((name.to_string(), (now - clock).as_secs_f64() * 1e3));
        clock = now;
    };
    control.stage("surface", 2)?;
    let mut src_surface = build_surface(source, &weld).map_err(|source| ProjectError::Mesh {
        side: "source",
        source,
    })?;
    let tgt_surface = build_surface(target, &weld).map_err(|source| ProjectError::Mesh {
        side: "target",
        source,
    })?;
    let mut src_bvh = Bvh::build(&src_surface.positions, &src_surface.faces);
    let tgt_bvh = Bvh::build(&tgt_surface.positions, &tgt_surface.faces);
    let mut warnings = Vec::new();

    lap("surface", &mut timings_ms);
    control.stage("align", 1)?;
    let resolved = resolve(
        &constraints.correspondences,
        &Side {
            asset: source,
            bvh: &src_bvh,
            tolerance: params.snap_tolerance * src_surface.diagonal(),
        },
        &Side {
            asset: target,
            bvh: &tgt_bvh,
            tolerance: params.snap_tolerance * tgt_surface.diagonal(),
        },
    )?;
    let mut from = Vec::new();
    let mut to = Vec::new();
    for r in &resolved {
        for t in &r.targets {
            from.push(r.source.position.map(f64::from));
            to.push(t.position.map(f64::from));
        }
    }
    let alignment = if params.align && from.len() >= 2 {
        let transform = best_similarity(&from, &to);
        for p in src_surface.positions.iter_mut() {
            *p = to_f32(transform.apply(p.map(f64::from)));
        }
        src_bvh = Bvh::build(&src_surface.positions, &src_surface.faces);
        Some(AlignmentReport {
            rms_error: transform.rms_error(&from, &to),
            pairs: from.len(),
            transform,
        })
    } else {
        if from.len() == 1 && params.align {
            warnings.push(
                "one correspondence pair cannot define an alignment; the source was not moved"
                    .into(),
            );
        }
        None
    };

    let diag = tgt_surface.diagonal();
    let normals = (0..src_surface.face_count())
        .map(|f| src_surface.face_normal(f))
        .collect();
    let field = SourceField {
        asset: source,
        bvh: src_bvh,
        sampler: MaterialSampler::new(source),
        normals,
        max_distance: params.max_distance.map_or(f32::INFINITY, |d| d * diag),
        min_cos: params.max_normal_angle.map(|a| a.to_radians().cos()),
        surface: src_surface,
    };
    let src_report = SurfaceReport::of(&field.surface);

    // Group target triangles by material (UV path) or by primitive (COLOR_0 path).
    let uv_set_of = |p: usize| {
        target.primitives[p]
            .material
            .and_then(|m| target.materials.get(m))
            .and_then(|m| m.base_color_texture)
            .map_or(0, |t| t.tex_coord)
    };
    let mut groups: std::collections::BTreeMap<Option<usize>, Vec<PlacedTriangle>> =
        Default::default();
    let mut vertex_path: Vec<(usize, usize)> = Vec::new(); // (primitive, instance)
    for (ii, inst) in target.instances.iter().enumerate() {
        for p in target.primitives_of_mesh(inst.mesh) {
            let prim = &target.primitives[p];
            let set = uv_set_of(p) as usize;
            if constraints.output.vertex_colors || prim.tex_coords.len() <= set {
                if !vertex_path.iter().any(|(q, _)| *q == p) {
                    vertex_path.push((p, ii));
                } else {
                    warnings.push(format!(
                        "mesh {} is instanced more than once; its vertex colors follow its first instance",
                        prim.mesh
                    ));
                }
                continue;
            }
            let mirrored = inst.mirrors();
            let group = groups.entry(prim.material).or_default();
            for t in &prim.triangles {
                let w = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
                let mut normal = normal_of(w[0], w[1], w[2]);
                if mirrored {
                    normal = normal.map(|x| -x);
                }
                group.push(PlacedTriangle {
                    primitive: p,
                    world: w,
                    normal,
                    uv: t.map(|v| prim.tex_coords[set][v as usize]),
                });
            }
        }
    }
    warnings.dedup();

    let size = constraints.output.texture_size;
    let total_texels = groups.len() as u64 * size as u64 * size as u64;
    lap("align", &mut timings_ms);
    let stage = control.stage("bake", total_texels)?;
    let mut baked = Vec::new();
    for (material, tris) in &groups {
        let uvs: Vec<[[f32; 2]; 3]> = tris.iter().map(|t| t.uv).collect();
        let map = rasterize_uv_layout(&uvs, size, size);
        let mut pixels = vec![[0.0f32; 4]; (size * size) as usize];
        let mut valid = vec![false; pixels.len()];
        let row = size as usize;
        pixels
            .par_chunks_mut(row * 16)
            .zip(valid.par_chunks_mut(row * 16))
            .enumerate()
            .try_for_each(|(chunk, (px, ok))| {
                let base = chunk * row * 16;
                let mut hint = None;
                for i in 0..px.len() {
                    if let Some(hit) = map.hits[base + i] {
                        let t = &tris[hit.triangle as usize];
                        let b = hit.bary;
                        let mut p = [0.0f32; 3];
                        for (k, pk) in p.iter_mut().enumerate() {
                            *pk =
                                b[0] * t.world[0][k] + b[1] * t.world[1][k] + b[2] * t.world[2][k];
                        }
                        if let Some((c, face)) = field.color_at(p, t.normal, hint) {
                            px[i] = c;
                            ok[i] = true;
                            hint = Some(face);
                        }
                    }
                }
                stage.tick(px.len() as u64)
            })?;
        let covered = map.covered();
        let unmatched = covered - valid.iter().filter(|v| **v).count() as u64;
        baked.push((
            *material,
            tris,
            pixels,
            valid,
            TextureReport {
                material: *material,
                size,
                tex_coord: tris.first().map_or(0, |t| uv_set_of(t.primitive)),
                triangles: tris.len(),
                covered,
                overlapped: map.overlapped,
                unmatched,
                padded: 0,
                filled: 0,
            },
        ));
    }

    lap("bake", &mut timings_ms);
    let pad_stage = control.stage("pad", baked.len() as u64)?;
    let padding = constraints.output.padding;
    // Groups are independent: pad and encode them in parallel (order kept by the collect).
    let finished: Vec<(MaterialTexture, TextureReport)> = baked
        .into_par_iter()
        .map(|(material, tris, mut pixels, valid, mut report)| {
            let pr = pad(&mut pixels, &valid, size, size, padding);
            report.padded = pr.padded;
            report.filled = pr.filled;
            let mut prims: Vec<usize> = tris.iter().map(|t| t.primitive).collect();
            prims.sort_unstable();
            prims.dedup();
            let name = match material {
                Some(m) => format!("retex_basecolor_material{m}"),
                None => "retex_basecolor_default".to_string(),
            };
            let png = encode_png_srgb(&pixels, size, size);
            pad_stage.tick(1)?;
            Ok((
                MaterialTexture {
                    material,
                    primitives: prims,
                    png,
                    tex_coord: report.tex_coord,
                    name,
                },
                report,
            ))
        })
        .collect::<Result<_, Cancelled>>()?;
    let mut edits = Edits::default();
    let mut textures = Vec::new();
    for (texture, report) in finished {
        edits.textures.push(texture);
        textures.push(report);
    }

    lap("pad", &mut timings_ms);
    let mut vertex_colors = Vec::new();
    let area: f64 = vertex_path
        .iter()
        .map(|&(p, ii)| primitive_world_area(target, p, ii))
        .sum();
    let max_edge = edge_length_for_vertex_count(area, params.vertex_color_samples);
    for &(p, ii) in &vertex_path {
        let prim = &target.primitives[p];
        let inst = &target.instances[ii];
        let prim_json = &target.json["meshes"][prim.mesh]["primitives"][prim.primitive];
        let skinned_or_morphed =
            prim_json.get("targets").is_some() || prim_json["attributes"].get("JOINTS_0").is_some();
        let refine_it = !constraints.output.vertex_colors && !skinned_or_morphed;
        if !constraints.output.vertex_colors && skinned_or_morphed {
            warnings.push(format!(
                "mesh {} primitive {} has skin or morph data; COLOR_0 was written on its own vertices instead of a refined copy",
                prim.mesh, prim.primitive
            ));
        }
        let (positions, triangles, normals) = if refine_it {
            let scale = instance_scale(&inst.world);
            let r = refine(
                &prim.positions,
                &prim.triangles,
                &RefineParams {
                    max_edge_length: max_edge / scale,
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
            (r.positions, r.triangles, normals)
        } else {
            (prim.positions.clone(), prim.triangles.clone(), None)
        };
        let world: Vec<[f32; 3]> = positions
            .iter()
            .map(|q| to_f32(inst.transform_point(*q)))
            .collect();
        let mut vnormals = vec![[0.0f32; 3]; world.len()];
        for t in &triangles {
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
        let found: Vec<Option<[f32; 4]>> = world
            .par_iter()
            .zip(vnormals.par_iter())
            .map(|(q, n)| {
                let l = dot(*n, *n).sqrt().max(1e-20);
                field.color_at(*q, n.map(|x| x / l), None).map(|(c, _)| c)
            })
            .collect();
        let unmatched = found.iter().filter(|c| c.is_none()).count();
        let colors = fill_from_neighbours(found, &triangles);
        vertex_colors.push(VertexColorReport {
            mesh: prim.mesh,
            primitive: prim.primitive,
            refined: refine_it,
            vertices: positions.len(),
            unmatched,
        });
        if refine_it {
            edits.refined.push(RefinedPrimitive {
                primitive: p,
                positions,
                normals,
                colors,
                triangles,
            });
        } else {
            edits.vertex_colors.push(VertexColors {
                primitive: p,
                colors,
            });
        }
        if let Some(m) = prim.material {
            if !groups.contains_key(&Some(m)) && !edits.untextured_materials.contains(&m) {
                edits.untextured_materials.push(m);
            }
        }
        control.check()?;
    }
    edits.untextured_materials.sort_unstable();
    if !vertex_path.is_empty() && !constraints.output.vertex_colors {
        warnings.push(format!(
            "{} primitive(s) have no UVs for a base color texture: the color was written as COLOR_0 on a refined copy",
            vertex_path.len()
        ));
    }

    lap("vertex_colors", &mut timings_ms);
    let report = ProjectReport {
        source_surface: src_report,
        target_surface: SurfaceReport::of(&tgt_surface),
        alignment,
        textures,
        vertex_colors,
        warnings,
        timings_ms,
    };
    Ok((edits, report))
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

fn primitive_world_area(asset: &Asset, p: usize, instance: usize) -> f64 {
    let prim = &asset.primitives[p];
    let inst = &asset.instances[instance];
    prim.triangles
        .iter()
        .map(|t| {
            let w = t.map(|v| to_f32(inst.transform_point(prim.positions[v as usize])));
            let (u, v) = (sub(w[1], w[0]), sub(w[2], w[0]));
            let n = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            0.5 * (dot(n, n) as f64).sqrt()
        })
        .sum()
}

/// Vertices without a color take the mean of their colored neighbours, repeatedly; any left
/// (an island with no valid source point at all) take the mean of all colored vertices, or grey.
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
