//! The `correlation` method (Mertens, Kautz, Chen, Bekaert, Durand, *Texture Transfer Using
//! Geometry Correlation*, EGSR 2006): the source's colour is explained by local geometry
//! (curvature, occlusion, orientation, height), and the target gets colour synthesized from the
//! same relation on its own geometry: no correspondences, no shared shape.
//!
//! Pipeline, one module per step:
//! 1. [`pyramid`] (§3.1): dense even samples of both surfaces and their Gaussian / Laplacian
//!    pyramids; the source's linear colour per sample (the base colour box-filtered over about
//!    the sample's own area by MeshMatch's sampling, [`sample_colors`]); [`mask`]: training weights (masked samples get
//!    weight 0 in every statistic, and the training mean colour so that their colour does not
//!    bleed through the colour pyramid into the samples around them).
//! 2. [`features`] (§3.2): 12-D features per input vertex, interpolated to the samples.
//! 3. [`cca`] (§3.3): CCA (or PCA) guidance, fitted on the source, applied to both.
//! 4. [`histmatch`] (§4): the target's guidance matched to the source's (marginals or
//!    multiscale).
//! 5. [`parametric`] (§5.2): clustered histogram synthesis of the target's colour; or, with
//!    `synthesis = "nonparametric"`, [`nonparametric`] (§5.1): image analogies with Ashikhmin
//!    coherence over the surface pyramid, searched PatchMatch-style ([`guidance_index`] gives
//!    the guidance-nearest source sample per target sample).
//! 6. Output: the target's sample colours, interpolated over its level-0 mesh, baked through
//!    [`crate::engine::methods::color_output::write_color_field`].
//!
//! 7. [`debug`] (with `params.debug`): `guidance.glb` and `segmentation.glb`, the target's
//!    guidance as colours (Fig. 8 bottom) and its clusters (Fig. 9a), baked like the output.

pub mod cca;
pub mod cluster_stats;
pub mod debug;
pub mod feather;
pub mod features;
pub mod guidance_index;
pub mod histmatch;
pub mod kmeans;
pub mod mask;
pub mod nonparametric;
pub mod parametric;
pub mod params;
pub mod pyramid;
pub mod quantiles;
pub mod report;

use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::asset::edits::Edit;
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::mesh::{Surface, WeldParams};
use crate::engine::methods::color_output::{write_color_field, ColorField};
use crate::engine::methods::meshmatch::sampling::{synthesis_colors, SynthesisMesh};
use crate::engine::methods::{
    surface_of, InputSpec, Method, MethodError, MethodInput, MethodOutput,
};
use crate::engine::spatial::Bvh;

use debug::{debug_files, guidance_range, DebugFields};
use features::{sample_features, vertex_features, FeatureParams};
use nonparametric::{synthesize_nonparametric, NonparametricSettings};
use parametric::{synthesize, ParametricParams, SynthesisInput};
use params::{CorrelationParams, FeatureMatching, Reduction, SourceMask, Synthesis};
use pyramid::SurfacePyramid;
use report::{CorrelationReport, SideReport};

/// Working-set bytes per requested sample of one model (its sample mesh, pyramid levels and
/// hierarchy, guidance, colour, memberships and synthesis buffers). Measured with `retex
/// transfer` Spot → cat, peak resident set 87 MB at 32,768 samples and 157 MB at 131,072; `retex
/// bench` head → bust 485 MiB at 524,288: 360-425 bytes per sample of each model above the
/// loaded inputs. 1,024 leaves a margin for larger inputs and deeper pyramids.
pub const SAMPLE_BYTES: u64 = 1024;
/// Working-set bytes per input triangle: the 12-D features per input vertex and the ray-cast
/// features' BVH (the loaded surfaces are counted by the job's own budget).
pub const INPUT_TRIANGLE_BYTES: u64 = 256;
/// Extra working-set bytes per requested sample for `synthesis = "nonparametric"`: the source's
/// fans (16 samples × 6 floats) and centres, the target's fans, field and exponential-map charts
/// (about 40 vertices × 12 bytes per sample at the default 5-neighbourhood) on level 0.
/// Estimated from the layout, with a margin for larger neighbourhoods' charts.
pub const NONPARAMETRIC_SAMPLE_BYTES: u64 = 2048;

/// The `correlation` method (registry entry).
pub struct Correlation;

impl Method for Correlation {
    fn id(&self) -> MethodId {
        MethodId::Correlation
    }

    fn inputs(&self) -> InputSpec {
        InputSpec::SOURCE_AND_TARGET
    }

    fn params_schema(&self) -> serde_json::Value {
        crate::engine::methods::params::schema_of::<CorrelationParams>()
    }

    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError> {
        CorrelationParams::from_constraints(constraints).map(drop)
    }

    fn extra_images(&self, constraints: &Constraints) -> Vec<(&'static str, usize)> {
        match CorrelationParams::from_constraints(constraints).map(|p| p.mask) {
            Ok(Some(SourceMask::Image { index, .. })) => vec![("source", index)],
            _ => Vec::new(),
        }
    }

    /// Both models' samples and pyramids ([`SAMPLE_BYTES`] per requested sample, counted twice),
    /// the per-vertex features ([`INPUT_TRIANGLE_BYTES`]), one baked texture (three with the
    /// debug files) and the generated atlas ([`crate::engine::methods::atlas_working_set`]).
    fn working_set(
        &self,
        constraints: &Constraints,
        input_triangles: u64,
    ) -> Option<crate::engine::methods::WorkingSet> {
        let params = CorrelationParams::from_constraints(constraints).ok()?;
        let texture = crate::engine::methods::texture_working_set(constraints);
        let per_sample = 2 * SAMPLE_BYTES
            + match params.synthesis {
                Synthesis::Parametric => 0,
                Synthesis::Nonparametric => NONPARAMETRIC_SAMPLE_BYTES,
            };
        let samples = (params.samples as u64).saturating_mul(per_sample);
        let inputs = input_triangles.saturating_mul(INPUT_TRIANGLE_BYTES);
        let atlas = crate::engine::methods::atlas_working_set(constraints, input_triangles);
        let field = if atlas > inputs.max(samples).max(texture.bytes) {
            "output.uv"
        } else if inputs > samples.max(texture.bytes) {
            "inputs"
        } else if samples >= texture.bytes {
            "params.samples"
        } else {
            texture.field
        };
        // The debug files bake two more textures while the output's edits are held.
        let bakes = if params.debug { 3 } else { 1 };
        Some(crate::engine::methods::WorkingSet {
            bytes: samples
                .saturating_add(inputs)
                .saturating_add(atlas)
                .saturating_add(texture.bytes.saturating_mul(bakes)),
            field,
        })
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let params = CorrelationParams::from_constraints(input.constraints)?;
        let done = run(
            input.source()?,
            input.target,
            input.constraints,
            &params,
            control,
        )?;
        let mut out = MethodOutput::target(done.edits, &done.report);
        out.warnings = done.report.warnings;
        if let Some(fields) = &done.debug {
            out.files = debug_files(
                input.target,
                input.constraints,
                params.vertex_color_samples,
                fields,
                control,
            )?;
        }
        Ok(out)
    }
}

/// The target's sample colours as a field over its surface: the closest point on the level-0
/// mesh, colours interpolated barycentrically (or, with `nearest`, the colour of the triangle's
/// corner with the largest weight: labels that must not blend).
struct SampleField<'a> {
    mesh: &'a Surface,
    bvh: Bvh,
    colors: &'a [[f32; 3]],
    nearest: bool,
}

impl ColorField for SampleField<'_> {
    fn color_at(
        &self,
        p: [f32; 3],
        _normal: [f32; 3],
        hint: Option<u32>,
    ) -> Option<([f32; 4], u32)> {
        let bound = hint.map_or(f32::INFINITY, |h| self.mesh.hint_bound(h as usize, p));
        let hit = self.bvh.closest_point(p, bound)?;
        let f = self.mesh.faces[hit.face as usize];
        let mut c = [0.0f32, 0.0, 0.0, 1.0];
        if self.nearest {
            let k = (0..3)
                .max_by(|a, b| hit.bary[*a].total_cmp(&hit.bary[*b]))
                .unwrap_or(0);
            let v = self.colors[f[k] as usize];
            return Some(([v[0], v[1], v[2], 1.0].map(|x| x.clamp(0.0, 1.0)), hit.face));
        }
        for k in 0..3 {
            for ch in 0..3 {
                c[ch] += hit.bary[k] * self.colors[f[k] as usize][ch];
            }
        }
        Some((c.map(|x| x.clamp(0.0, 1.0)), hit.face))
    }
}

/// The source's linear base colour of each level-0 sample, box-filtered over about the sample's
/// own area by MeshMatch's sampling ([`synthesis_colors`]: the point sample at the sample (weight
/// 2) and one halfway to the centroid of each incident sample triangle), so a texture finer than
/// the sample spacing gives its local mean rather than aliasing.
pub fn sample_colors(asset: &Asset, input: &Surface, pyramid: &SurfacePyramid) -> Vec<[f32; 3]> {
    let mesh = pyramid.mesh(0);
    let synthesis = SynthesisMesh {
        surface: Surface::from_triangles(mesh.positions.clone(), mesh.faces.clone()),
        input_face: pyramid.input_face().to_vec(),
        vertex_link: pyramid.location().to_vec(),
        decimated: false,
    };
    synthesis_colors(asset, input, &synthesis)
}

/// Masked samples take the mean colour of the training samples: they carry no weight in any
/// statistic, but the source's colour pyramid smooths across the mask's edge, and a masked
/// colour kept there would bleed into the coarse levels of the samples around it.
fn fill_masked(mut colors: Vec<[f32; 3]>, weights: &[f32], area: &[f32]) -> Vec<[f32; 3]> {
    let mut sum = [0.0f64; 3];
    let mut total = 0.0f64;
    for ((c, w), a) in colors.iter().zip(weights).zip(area) {
        let w = f64::from(w * a);
        total += w;
        for k in 0..3 {
            sum[k] += w * f64::from(c[k]);
        }
    }
    if total > 0.0 {
        let mean = sum.map(|s| (s / total) as f32);
        for (c, w) in colors.iter_mut().zip(weights) {
            if *w == 0.0 {
                *c = mean;
            }
        }
    }
    colors
}

fn side_report(surface: &Surface, p: &SurfacePyramid) -> SideReport {
    SideReport {
        vertices: surface.vertex_count(),
        samples: p.len(0),
        level_samples: (0..p.level_count()).map(|l| p.len(l)).collect(),
    }
}

/// What [`run`] gives.
#[derive(Clone, Debug)]
pub struct Transferred {
    /// The edits of the target.
    pub edits: Vec<Edit>,
    /// The method's report.
    pub report: CorrelationReport,
    /// The fields of the debug files, with `params.debug`.
    pub debug: Option<DebugFields>,
}

/// Runs `correlation`: the edits of the target, the report and (with `params.debug`) the
/// fields of the debug files.
///
/// # Errors
/// [`MethodError`]: a bad surface, a mask that removes everything, cancellation.
pub fn run(
    source: &Asset,
    target: &Asset,
    constraints: &Constraints,
    params: &CorrelationParams,
    control: &Control,
) -> Result<Transferred, MethodError> {
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    let seed = constraints.seed;
    let span = control.span(0.0, 0.15);
    control.stage("surface", 0)?;
    let src = surface_of(source, &weld, "source")?;
    let tgt = surface_of(target, &weld, "target")?;
    let src_pyr = SurfacePyramid::build(&src, params.samples, params.pyramid_levels, control)?;
    let tgt_pyr = SurfacePyramid::build(&tgt, params.samples, params.pyramid_levels, control)?;
    control.stage("source_colour", 0)?;
    let colors = sample_colors(source, &src, &src_pyr);
    let weights = match &params.mask {
        Some(m) => mask::training_weights(m, source, &src, src_pyr.location())?,
        None => vec![1.0; colors.len()],
    };
    let masked_samples = weights.iter().filter(|w| **w == 0.0).count();
    let colors = fill_masked(colors, &weights, src_pyr.area(0));
    drop(span);

    let span = control.span(0.15, 0.5);
    let fp = FeatureParams {
        up: params.up_unit(),
        radii: params.curvature_radii,
        rays: params.feature_rays,
        seed,
    };
    let src_vf = vertex_features(&src, &fp, control)?;
    let tgt_vf = vertex_features(&tgt, &fp, control)?;
    let src_f = sample_features(&src, &src_vf, src_pyr.location());
    let tgt_f = sample_features(&tgt, &tgt_vf, tgt_pyr.location());
    drop((src_vf, tgt_vf));
    drop(span);

    let span = control.span(0.5, 0.55);
    control.stage("cca", 0)?;
    let train: Vec<f32> = src_pyr
        .area(0)
        .iter()
        .zip(&weights)
        .map(|(a, w)| a * w)
        .collect();
    let model = match params.reduction {
        Reduction::Cca => cca::fit_cca(&src_f, &colors, &train)?,
        Reduction::Pca => cca::fit_pca(&src_f, &colors, &train)?,
    };
    let src_g = model.apply(&src_f);
    let mut tgt_g = model.apply(&tgt_f);
    drop((src_f, tgt_f));
    drop(span);

    let span = control.span(0.55, 0.65);
    control.stage("feature_matching", 0)?;
    let matching = match params.feature_matching {
        FeatureMatching::Off => Default::default(),
        m => histmatch::match_guidance(
            &mut tgt_g,
            &tgt_pyr,
            &src_g,
            &src_pyr,
            &weights,
            model.dims,
            m == FeatureMatching::Multiscale,
            seed,
            control,
        )?,
    };
    drop(span);

    let span = control.span(0.65, 0.9);
    let input = SynthesisInput {
        source: &src_pyr,
        target: &tgt_pyr,
        source_guidance: &src_g,
        target_guidance: &tgt_g,
        guidance_dims: model.dims,
        source_color: &colors,
        source_weight: &weights,
    };
    let (out_colors, labels, synthesis, nonparametric) = match params.synthesis {
        Synthesis::Parametric => {
            let (c, labels, r) = synthesize(
                &input,
                &ParametricParams {
                    clusters: params.clusters,
                    nearest_clusters: params.nearest_clusters,
                    levels: params.pyramid_levels,
                    iterations: params.iterations,
                    noise: params.noise,
                    seed,
                },
                control,
            )?;
            (c, Some(labels), Some(r), None)
        }
        Synthesis::Nonparametric => {
            let np = &params.nonparametric;
            let (c, _matches, r) = synthesize_nonparametric(
                &input,
                &NonparametricSettings {
                    neighbourhood: np.neighbourhood,
                    coherence: np.coherence,
                    feature_weight: np.feature_weight,
                    passes: params.iterations.max(1),
                    up: params.up_unit(),
                    seed,
                },
                control,
            )?;
            (c, None, None, Some(r))
        }
    };
    drop(span);
    let debug = if params.debug {
        let labels = match labels {
            Some(l) => l,
            None => debug_labels(&tgt_g, &tgt_pyr, params, seed, control)?,
        };
        Some(DebugFields {
            mesh: tgt_pyr.mesh(0).clone(),
            guidance: tgt_g.clone(),
            dims: model.dims,
            range: guidance_range(&src_g, &train, model.dims),
            labels,
        })
    } else {
        None
    };

    let _span = control.span(0.9, 1.0);
    let mesh = tgt_pyr.mesh(0);
    let field = SampleField {
        mesh,
        bvh: Bvh::build(&mesh.positions, &mesh.faces),
        colors: &out_colors,
        nearest: false,
    };
    let (edits, output) = write_color_field(
        target,
        constraints,
        params.vertex_color_samples,
        &field,
        control,
    )?;
    let mut warnings = Vec::new();
    if model.kind == cca::Kind::Cca && model.correlations.first().copied().unwrap_or(0.0) < 0.2 {
        warnings.push(format!(
            "the source's colour hardly correlates with its geometry (first canonical correlation {:.2}): the transfer carries its colour statistics, not a placement",
            model.correlations.first().copied().unwrap_or(0.0)
        ));
    }
    warnings.extend(output.warnings.iter().cloned());
    let report = CorrelationReport {
        source: side_report(&src, &src_pyr),
        target: side_report(&tgt, &tgt_pyr),
        masked_samples,
        reduction: params.reduction,
        clusters: params.clusters,
        guidance: model,
        feature_matching: params.feature_matching,
        matching,
        synthesis,
        nonparametric,
        output,
        debug_guidance_range: debug.as_ref().map(|d| d.range),
        warnings: warnings.clone(),
    };
    Ok(Transferred {
        edits,
        report,
        debug,
    })
}

/// The target's k-means segmentation for the debug file when the synthesis made none (the
/// non-parametric one): the parametric synthesis's clustering of the target (`clusters`, its
/// seed) on the same guidance.
fn debug_labels(
    guidance: &[[f32; 3]],
    pyramid: &SurfacePyramid,
    params: &CorrelationParams,
    seed: u64,
    control: &Control,
) -> Result<Vec<u32>, MethodError> {
    control.stage("debug segmentation", 0)?;
    Ok(kmeans::kmeans(
        guidance,
        pyramid.area(0),
        params.clusters,
        seed ^ 0x0074_6774,
        control,
    )?
    .map(|k| k.labels)
    .unwrap_or_else(|| vec![0; guidance.len()]))
}
