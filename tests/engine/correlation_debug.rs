//! The `correlation` method's debug files (issue 11, `params.debug`): `guidance.glb` (the target's
//! guidance as colours, the paper's Fig. 8 bottom) and `segmentation.glb` (its k-means clusters,
//! Fig. 9a), on the procedural weathering case. They are written only when asked, are
//! validator-clean, the guidance colours follow the guidance values (Pearson per used axis at the
//! output's points), a wrong axis does not, and the segmentation shows one colour per non-empty
//! cluster.

use std::collections::{BTreeSet, HashSet};

use retex::engine::asset::constraints::Constraints;
use retex::engine::control::Control;
use retex::engine::methods::correlation::debug::{debug_files, palette};
use retex::engine::methods::correlation::params::CorrelationParams;
use retex::engine::methods::correlation::run;
use serde_json::json;

use crate::common::{assert_validator_clean, load_bytes};
use crate::correlation_common::{at_points, case, pearson};
use crate::meshmatch_common::{colored_points, run_bytes};

/// The debug files' COLOR_0 is read back at its points, so the target keeps vertex colours
/// (`output.uv = "keep"`: a UV-less target is otherwise baked through a generated atlas).
fn constraints(params: serde_json::Value, seed: u64) -> Constraints {
    let c = json!({"version": 1, "method": "correlation", "seed": seed,
        "output": {"uv": "keep"}, "params": params});
    Constraints::from_json(c.to_string().as_bytes()).unwrap()
}

#[test]
fn debug_guidance_and_segmentation_show_the_fields() {
    let c = case(1);
    let (src, tgt) = (
        load_bytes(&c.source_glb, "s.glb"),
        load_bytes(&c.target_glb, "t.glb"),
    );
    for (synthesis, seed) in [
        ("parametric", 1u64),
        ("parametric", 2),
        ("nonparametric", 1),
    ] {
        let cons = constraints(
            json!({"samples": 16384, "vertex_color_samples": 20000, "debug": true,
                   "synthesis": synthesis}),
            seed,
        );
        let params = CorrelationParams::from_constraints(&cons).unwrap();
        let done = run(&src, &tgt, &cons, &params, &Control::new()).unwrap();
        let fields = done.debug.expect("debug fields with params.debug");
        assert!(done.report.debug_guidance_range.is_some());
        let files = debug_files(&tgt, &cons, 20000, &fields, &Control::new()).unwrap();
        let names: Vec<&str> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["guidance.glb", "segmentation.glb"]);
        for f in &files {
            assert_validator_clean(
                &f.bytes,
                &format!("correlation_debug_{synthesis}_{seed}_{}", f.name),
            );
        }
        if let Some(dir) = std::env::var_os("RETEX_CORRELATION_DUMP") {
            for f in &files {
                let p = std::path::Path::new(&dir).join(format!("{synthesis}_{seed}_{}", f.name));
                std::fs::write(p, &f.bytes).unwrap();
            }
        }

        // Guidance: each used axis's colour channel against the axis's value at the same
        // points (the same closest-point interpolation over the sample mesh); the other axes
        // are the baseline a channel must not follow as well.
        let pts = colored_points(&files[0].bytes);
        assert!(pts.len() > 10_000, "{} points", pts.len());
        let points: Vec<[f32; 3]> = pts.iter().map(|p| p.0).collect();
        let axis: Vec<Vec<f32>> = (0..3)
            .map(|k| {
                let v: Vec<f32> = fields.guidance.iter().map(|g| g[k]).collect();
                at_points(&fields.mesh, &v, &points)
            })
            .collect();
        assert_eq!(
            fields.dims, 3,
            "a coloured source gives three canonical axes"
        );
        for k in 0..fields.dims {
            let channel: Vec<f32> = pts.iter().map(|p| p.1[k]).collect();
            let r = pearson(&channel, &axis[k]);
            let others: Vec<f64> = (0..fields.dims)
                .filter(|j| *j != k)
                .map(|j| pearson(&channel, &axis[j]).abs())
                .collect();
            let mean = channel.iter().sum::<f32>() / channel.len() as f32;
            let spread = (channel.iter().map(|x| (x - mean).powi(2)).sum::<f32>()
                / channel.len() as f32)
                .sqrt();
            eprintln!(
                "{synthesis} seed {seed}: axis {k}: r {r:.4}, other axes |r| {others:.3?}, channel mean {mean:.3} spread {spread:.3}"
            );
            assert!(r > 0.95, "axis {k}: r {r:.3}");
            assert!(others.iter().all(|o| *o < r - 0.3), "axis {k}: {others:?}");
            assert!(spread > 0.1, "axis {k}: channel spread {spread:.3}");
        }

        // Segmentation: one colour per non-empty cluster (a cluster of a few samples may be
        // nobody's nearest sample on the output's vertices), never a blend.
        let clusters: BTreeSet<u32> = fields.labels.iter().copied().collect();
        let key = |c: [f32; 3]| c.map(|x| (x * 255.0).round() as i32);
        let colours: HashSet<[i32; 3]> = colored_points(&files[1].bytes)
            .iter()
            .map(|p| key(p.1))
            .collect();
        let palette_keys: HashSet<[i32; 3]> = clusters.iter().map(|c| key(palette(*c))).collect();
        eprintln!(
            "{synthesis} seed {seed}: {} non-empty clusters, {} palette colours, {} colours on the output",
            clusters.len(),
            palette_keys.len(),
            colours.len()
        );
        assert_eq!(
            palette_keys.len(),
            clusters.len(),
            "palette colours collide"
        );
        assert!(
            colours.is_subset(&palette_keys),
            "{} colours are no cluster's",
            colours.difference(&palette_keys).count()
        );
        assert!(
            colours.len() as f64 >= 0.9 * clusters.len() as f64,
            "{} colours for {} clusters",
            colours.len(),
            clusters.len()
        );
    }
}

#[test]
fn debug_files_are_artifacts_only_when_asked() {
    let c = case(1);
    for debug in [false, true] {
        let out = run_bytes(
            ("s.glb", c.source_glb.clone()),
            ("t.glb", c.target_glb.clone()),
            json!({"version": 1, "method": "correlation", "seed": 1,
                   "params": {"samples": 8192, "vertex_color_samples": 8000, "debug": debug}}),
        );
        let names: Vec<&str> = out.artifacts.iter().map(|a| a.name.as_str()).collect();
        let has = |n: &str| names.contains(&n);
        assert_eq!(has("guidance.glb"), debug, "{names:?}");
        assert_eq!(has("segmentation.glb"), debug, "{names:?}");
        assert!(has("report.json"));
        for a in &out.artifacts {
            if a.name.ends_with(".glb") {
                assert_eq!(a.media_type, "model/gltf-binary");
                assert_validator_clean(&a.bytes, &format!("correlation_artifact_{}", a.name));
            }
        }
        assert_eq!(
            out.report
                .method_report
                .get("debug_guidance_range")
                .is_some(),
            debug
        );
    }
}
