//! `detail` onto a target without UVs (issue 15, "Use it everywhere"; issue 13, "Interface"):
//! with `output.uv = "auto"` the target gets a generated atlas that its normal map and
//! displacement texture share, with MikkTSpace TANGENT on the new layout; with `keep` it is
//! replaced by the displaced finest level, as before.
//!
//! The case is `detail_method`'s sphere (bumps on the upper half of the source, onto a UV
//! ellipsoid), run twice: onto the ellipsoid with its own UVs and onto the same mesh without
//! them. The synthesis does not depend on the UVs, so both runs carry the same displacement: read
//! back at the target's vertices through each output's UVs, the two must agree. That compares
//! the atlas bake against a bake through hand-made UVs on a case where the answer is known.

use std::collections::HashMap;

use retex::engine::asset::Asset;
use retex::engine::pipeline::TransferOutput;
use serde_json::json;

use crate::common::{assert_validator_clean, load_bytes};
use crate::detail_method::{run, sphere_pair, std};
use crate::elastiface_common::{mesh_glb as uv_mesh_glb, uv_sphere};

/// Bumps of wavelength 0.25 on the upper half (as `detail_method`'s case).
fn bumps(p: [f64; 3]) -> f64 {
    let w = std::f64::consts::TAU / 0.25;
    let ramp = (p[1] / 0.2).clamp(0.0, 1.0);
    0.02 * ramp * (w * p[0]).sin() * (w * p[2]).sin()
}

fn constraints(uv: &str) -> serde_json::Value {
    json!({"version": 1, "method": "detail",
        "params": {"levels": 3, "finest_edge_length": 0.012},
        "output": {"texture_size": 512, "uv": uv}})
}

/// Bilinear read of an image's channels at glTF UV `uv` (clamped to the image).
fn read(img: &image::DynamicImage, uv: [f32; 2]) -> [f64; 3] {
    let rgb = img.to_rgb32f();
    let (w, h) = (img.width() as f64, img.height() as f64);
    let x = (uv[0] as f64 * w - 0.5).clamp(0.0, w - 1.0);
    let y = (uv[1] as f64 * h - 0.5).clamp(0.0, h - 1.0);
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(w as u32 - 1), (y0 + 1).min(h as u32 - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let px = |x, y| rgb.get_pixel(x, y).0.map(f64::from);
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let top = px(x0, y0)[k] * (1.0 - fx) + px(x1, y0)[k] * fx;
        let bottom = px(x0, y1)[k] * (1.0 - fx) + px(x1, y1)[k] * fx;
        *o = top * (1.0 - fy) + bottom * fy;
    }
    out
}

/// Per output vertex: (position, displacement, normal-map tilt), read through its TEXCOORD_0.
fn vertex_reads(out: &TransferOutput) -> Vec<([f32; 3], f64, f64)> {
    let asset = load_bytes(&out.model, "out.glb");
    let mat = &asset.json["materials"][asset.primitives[0].material.expect("a material")];
    let image_of = |index: u64| {
        let source = asset.json["textures"][index as usize]["source"]
            .as_u64()
            .unwrap();
        let name = asset.json["images"][source as usize]["name"]
            .as_str()
            .unwrap();
        let a = (out.artifacts.iter())
            .find(|a| a.name.starts_with(name))
            .unwrap_or_else(|| panic!("artifact {name}"));
        image::load_from_memory(&a.bytes).unwrap()
    };
    let extra = &mat["extras"]["retex_displacement"];
    let height = image_of(extra["index"].as_u64().expect("displacement texture"));
    let normal = image_of(mat["normalTexture"]["index"].as_u64().expect("normal map"));
    let (offset, scale) = (
        extra["offset"].as_f64().unwrap(),
        extra["scale"].as_f64().unwrap(),
    );
    let prim = &asset.primitives[0];
    let uvs = &prim.tex_coords[0];
    (prim.positions.iter().zip(uvs))
        .map(|(p, uv)| {
            let d = offset + scale * read(&height, *uv)[0];
            let c = read(&normal, *uv).map(|x| 2.0 * x - 1.0);
            let tilt = (c[0] * c[0] + c[1] * c[1]).sqrt() / c[2].max(1e-3);
            (*p, d, tilt)
        })
        .collect()
}

/// The GLB with its first material replaced by `material` (JSON chunk rewritten, the binary
/// chunk kept).
fn with_material(glb: &[u8], material: serde_json::Value) -> Vec<u8> {
    let word = |at: usize| u32::from_le_bytes(glb[at..at + 4].try_into().unwrap()) as usize;
    let json_len = word(12);
    let mut doc: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    doc["materials"][0] = material;
    let mut text = serde_json::to_vec(&doc).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let rest = &glb[20 + json_len..];
    let mut out = Vec::new();
    out.extend_from_slice(&glb[0..8]);
    out.extend_from_slice(&((20 + text.len() + rest.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(&glb[16..20]);
    out.extend_from_slice(&text);
    out.extend_from_slice(rest);
    out
}

fn key(p: [f32; 3]) -> [u32; 3] {
    p.map(f32::to_bits)
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    cov / (std(a) * std(b) * n)
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

#[test]
fn detail_onto_a_target_without_uvs_bakes_both_maps_through_one_generated_atlas() {
    let (source, base, with_uvs) = sphere_pair(32, bumps);
    let mut bare = uv_sphere(128, 64, |p| [1.1 * p[0], p[1], 0.9 * p[2]]);
    bare.uvs = None;
    let without_uvs = with_material(
        &uv_mesh_glb(&bare, None, 1.0),
        json!({"name": "clay", "doubleSided": true,
            "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.4, 0.2, 1.0], "roughnessFactor": 0.3}}),
    );

    let reference = run(&source, Some(&base), &with_uvs, constraints("auto"));
    let atlas = run(&source, Some(&base), &without_uvs, constraints("auto"));
    assert_validator_clean(&atlas.model, "detail_atlas.glb");
    let _ = std::fs::write(std::env::temp_dir().join("detail_atlas.glb"), &atlas.model);
    let _ = std::fs::write(
        std::env::temp_dir().join("detail_uvs.glb"),
        &reference.model,
    );
    let summary = &atlas.report.method_report["outputs"];
    println!(
        "atlas: {}",
        json!({"atlas_primitives": summary["atlas_primitives"],
            "replaced": summary["replaced_primitives"], "charts": summary["atlas"]["chart_count"],
            "l2": summary["atlas"]["l2_stretch"], "packing": summary["atlas"]["packing_efficiency"]})
    );
    assert_eq!(summary["atlas_primitives"], 1, "{summary}");
    assert_eq!(summary["replaced_primitives"], 0, "{summary}");

    // The atlas copy carries the new layout and the frames the normal map was baked in.
    let model = load_bytes(&atlas.model, "out.glb");
    let attrs = &model.json["meshes"][0]["primitives"][0]["attributes"];
    for a in ["TEXCOORD_0", "NORMAL", "TANGENT"] {
        assert!(attrs[a].is_u64(), "{a} missing: {attrs}");
    }
    assert!(
        model.primitives[0].positions.len() > bare.positions.len(),
        "the atlas splits vertices at its seams"
    );

    // The maps' new material is a copy of the primitive's own (factors, double-sidedness).
    let m = model.primitives[0].material.expect("a material");
    let mat = &model.json["materials"][m];
    assert!(m >= 1, "a new material, not the input's: {m}");
    assert_eq!(mat["doubleSided"], true, "{mat}");
    assert_eq!(mat["pbrMetallicRoughness"]["roughnessFactor"], 0.3, "{mat}");
    assert!(mat["normalTexture"]["index"].is_u64(), "{mat}");
    assert!(
        mat["extras"]["retex_displacement"]["index"].is_u64(),
        "{mat}"
    );

    // Both maps read back at the target's vertices agree with the bake through hand-made UVs.
    let by_position: HashMap<[u32; 3], (f64, f64)> = vertex_reads(&reference)
        .into_iter()
        .map(|(p, d, t)| (key(p), (d, t)))
        .collect();
    let (mut ours, mut theirs, mut tilt_ours, mut tilt_theirs) = (vec![], vec![], vec![], vec![]);
    let mut gaps: Vec<(f64, f32)> = Vec::new();
    let mut first: HashMap<[u32; 3], f64> = HashMap::new();
    for (p, d, t) in vertex_reads(&atlas) {
        let y = p[1] as f64;
        if let Some(&(d_ref, t_ref)) = by_position.get(&key(p)) {
            if y.abs() < 0.95 {
                ours.push(d);
                theirs.push(d_ref);
                if y > 0.3 {
                    tilt_ours.push(t);
                    tilt_theirs.push(t_ref);
                }
            }
        }
        // Vertices split at a chart seam: both charts' texels give the same value.
        match first.get(&key(p)) {
            Some(&d0) => gaps.push(((d - d0).abs(), p[1])),
            None => {
                first.insert(key(p), d);
            }
        }
    }
    let r = correlation(&ours, &theirs);
    let diff: Vec<f64> = ours.iter().zip(&theirs).map(|(a, b)| a - b).collect();
    let relative = rms(&diff) / std(&theirs);
    let (tilt_a, tilt_b) = (rms(&tilt_ours), rms(&tilt_theirs));
    gaps.sort_by(|a, b| a.0.total_cmp(&b.0));
    let seams = gaps.len();
    let seam_rms = rms(&gaps.iter().map(|g| g.0).collect::<Vec<_>>());
    let worst: Vec<(f64, f32)> = gaps.iter().rev().take(5).copied().collect();
    println!("seam gaps: rms {seam_rms:.5}, worst (gap, y) {worst:?}");
    println!(
        "vertices compared {}: displacement correlation {r:.4}, rms difference {relative:.3} of \
         the std; upper-half tilt rms atlas {tilt_a:.3} vs uvs {tilt_b:.3}; seam vertices \
         {seams}, rms gap {seam_rms:.5} (std {:.5})",
        ours.len(),
        std(&theirs)
    );
    assert!(ours.len() > 5000, "only {} vertices matched", ours.len());
    assert!(r > 0.95, "displacement correlation {r}");
    assert!(relative < 0.3, "rms difference {relative} of the std");
    assert!(
        (0.8..=1.25).contains(&(tilt_a / tilt_b)),
        "normal-map tilt {tilt_a} vs {tilt_b}"
    );
    assert!(seams > 0, "no seam vertices");
    assert!(
        seam_rms < 0.5 * std(&theirs),
        "seam gap rms {seam_rms} vs std {}",
        std(&theirs)
    );

    // `keep`: the target is replaced by the displaced finest level, no textures.
    let kept = run(&source, Some(&base), &without_uvs, constraints("keep"));
    let summary = &kept.report.method_report["outputs"];
    assert_eq!(summary["replaced_primitives"], 1, "{summary}");
    assert_eq!(summary["atlas_primitives"], 0, "{summary}");
    let model: Asset = load_bytes(&kept.model, "kept.glb");
    assert!(model.primitives[0].tex_coords.is_empty());
    assert!(model.json["materials"][0]["normalTexture"].is_null());
}
