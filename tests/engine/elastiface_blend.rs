//! The morphing of §5 (`params.blend = {"weight": w}`, issue 10 item 8): positions
//! `(1 − w)·template + w·fitted` and base colour `(1 − w)·template + w·re-laid`, per texel in
//! linear colour; w = 1 is the unblended output byte for byte; w = 0 gives the template back;
//! with `output = "morph_target"` w is the morph target's default weight; a bad weight and a
//! malformed region are refused naming the field (regions: `elastiface_region`).
//!
//! The pair: a UV sphere template onto a turned, finer sphere stretched by `diag(s)` (as in
//! `elastiface_inputs`). The template's own colour is `tcolor(u, v)`, either as a texture or as
//! COLOR_0 without a texture (and, without UVs, COLOR_0 blended per vertex); the target's is a smooth function of the unit-sphere point. Sweep:
//! w ∈ {0, 0.3, 0.7} × two stretches × both template colour kinds (README "elastiface"). Set
//! `RETEX_ELASTIFACE_OUT` to a folder to keep the blended GLBs for `retex preview`.

use retex::engine::asset::Asset;
use retex::engine::asset::DecodedImage;
use retex::engine::texture::bake::rasterize_uv_layout;
use serde_json::{json, Value};

use crate::common::assert_validator_clean;
use crate::elastiface_common::*;

const STRETCHES: [[f64; 3]; 2] = [[1.4, 1.0, 0.8], [0.8, 1.2, 1.5]];
const WEIGHTS: [f64; 3] = [0.0, 0.3, 0.7];

/// The template's own linear colour at UV (u, v): linear in (u, v), so that bilinear sampling
/// and barycentric COLOR_0 interpolation both reproduce it.
fn tcolor(u: f64, v: f64) -> [f64; 3] {
    [0.8, 0.1 + 0.5 * u, 0.7 - 0.5 * v]
}

/// The first nine sphere landmarks mapped by `stretch`, with `params`.
fn constraints(stretch: [f64; 3], params: Value) -> Value {
    let mut c = sphere_constraints(stretch, 9);
    c["params"] = params;
    c
}

fn target_glb(stretch: [f64; 3]) -> Vec<u8> {
    let (tgt, _) = stretched_sphere(stretch);
    let png = texture_png(256, 128, |u, v| sphere_color(turn(sphere_point(u, v))));
    mesh_glb(&tgt, Some(&png), 1.0)
}

/// The template: textured (`textured`) or with its colour as COLOR_0 and no texture.
fn template_glb(source: &MeshData, textured: bool) -> Vec<u8> {
    if textured {
        return mesh_glb(source, Some(&texture_png(256, 128, tcolor)), 1.0);
    }
    let colors: Vec<f32> = source
        .uvs
        .as_ref()
        .unwrap()
        .iter()
        .flat_map(|uv| {
            let c = tcolor(uv[0] as f64, uv[1] as f64);
            [c[0] as f32, c[1] as f32, c[2] as f32, 1.0]
        })
        .collect();
    mesh_glb_with(source, None, 1.0, &[("COLOR_0", 4, colors)])
}

fn base_image(asset: &Asset) -> DecodedImage {
    let tex = asset.materials[0]
        .base_color_texture
        .expect("baked texture");
    let image = asset.textures[tex.texture].image.expect("image");
    (*asset.images[image].decoded.clone().expect("decoded")).clone()
}

/// Per covered texel of the template's UV layout: its UV and its sRGB 8-bit RGB.
fn covered_texels(source: &MeshData, img: &DecodedImage) -> Vec<([f64; 2], [u8; 3])> {
    let uvs = source.uvs.as_ref().unwrap();
    let tris: Vec<[[f32; 2]; 3]> = source
        .indices
        .chunks(3)
        .map(|t| [0, 1, 2].map(|k| uvs[t[k] as usize]))
        .collect();
    let map = rasterize_uv_layout(&tris, img.width, img.height);
    let mut out = Vec::new();
    for y in 0..img.height {
        for x in 0..img.width {
            let Some(hit) = map.hit(x, y) else { continue };
            let t = tris[hit.triangle as usize];
            let uv = [0, 1].map(|d| (0..3).map(|k| hit.bary[k] as f64 * t[k][d] as f64).sum());
            let px = img.pixels[(y * img.width + x) as usize];
            out.push((uv, [px[0], px[1], px[2]]));
        }
    }
    out
}

fn diagonal(p: &[[f32; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for q in p {
        for k in 0..3 {
            lo[k] = lo[k].min(q[k] as f64);
            hi[k] = hi[k].max(q[k] as f64);
        }
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn elastiface_blend_weight_one_is_the_unblended_output_byte_for_byte() {
    let source = uv_sphere(48, 24, |p| p);
    let stretch = STRETCHES[0];
    let (s, t) = (template_glb(&source, true), target_glb(stretch));
    let plain = run_glbs(&s, &t, constraints(stretch, json!({}))).expect("no blend");
    let one = run_glbs(
        &s,
        &t,
        constraints(stretch, json!({"blend": {"weight": 1.0}})),
    )
    .expect("w = 1");
    assert_validator_clean(&one.model, "elastiface_blend_w1.glb");
    assert!(plain.model == one.model, "w = 1 differs from no blend");
}

/// Positions and texels of a blend at `w` against the formula, from the w = 1 output.
fn check_blend(source: &MeshData, fitted: &Asset, out: &Asset, w: f64, label: &str) {
    let diag = diagonal(&source.positions);
    let got = &out.primitives[0].positions;
    let fit = &fitted.primitives[0].positions;
    assert_eq!(got.len(), source.positions.len());
    let mut pos_err = 0.0f64;
    let mut moved = 0.0f64;
    for v in 0..got.len() {
        let want: [f64; 3] = std::array::from_fn(|k| {
            (1.0 - w) * source.positions[v][k] as f64 + w * fit[v][k] as f64
        });
        let e = (0..3)
            .map(|k| (got[v][k] as f64 - want[k]).powi(2))
            .sum::<f64>();
        let m = (0..3)
            .map(|k| (got[v][k] as f64 - fit[v][k] as f64).powi(2))
            .sum::<f64>();
        pos_err = pos_err.max(e.sqrt() / diag);
        moved = moved.max(m.sqrt() / diag);
    }
    let (img, img1) = (base_image(out), base_image(fitted));
    let texels = covered_texels(source, &img);
    let relaid = covered_texels(source, &img1);
    let (mut err, mut far, mut vs_relaid) = (0.0f64, 0usize, 0.0f64);
    for ((uv, px), (_, px1)) in texels.iter().zip(&relaid) {
        let own = tcolor(uv[0], uv[1]);
        for d in 0..3 {
            let want = srgb8((1.0 - w) * own[d] + w * linear(px1[d])) as f64;
            let e = (px[d] as f64 - want).abs();
            err += e;
            far += usize::from(e > 2.0);
            vs_relaid += (px[d] as f64 - px1[d] as f64).abs();
        }
    }
    let n = (3 * texels.len()) as f64;
    let (err, far, vs_relaid) = (err / n, far as f64 / n, vs_relaid / n);
    eprintln!(
        "blend {label} w {w}: max position error {pos_err:.2e} of the diagonal (max distance to \
         the fitted shape {moved:.3}), texel error {err:.2} levels (mean), {:.2}% over 2 levels, \
         the unblended texture is {vs_relaid:.1} levels off",
        100.0 * far
    );
    let tol = if w == 0.0 { 1e-6 } else { 1e-5 };
    assert!(pos_err < tol, "{label} w {w}: position error {pos_err}");
    assert!(
        moved > 0.02,
        "{label} w {w}: the blend did not move off the fit"
    );
    assert!(
        err < 0.75 && far < 0.01,
        "{label} w {w}: texel error {err}, far {far}"
    );
    assert!(vs_relaid > 5.0 * err.max(0.5), "{label} w {w}: not a blend");
}

#[test]
fn elastiface_blend_is_linear_in_positions_and_texels() {
    let source = uv_sphere(48, 24, |p| p);
    for stretch in STRETCHES {
        let t = target_glb(stretch);
        for textured in [true, false] {
            let s = template_glb(&source, textured);
            let label = format!(
                "{} template, stretch {stretch:?}",
                if textured { "textured" } else { "COLOR_0" }
            );
            let fitted =
                output_asset(&run_glbs(&s, &t, constraints(stretch, json!({}))).expect("fitted"));
            for w in WEIGHTS {
                let out = run_glbs(
                    &s,
                    &t,
                    constraints(stretch, json!({"blend": {"weight": w}})),
                )
                .expect("blend");
                assert_validator_clean(&out.model, "elastiface_blend.glb");
                if let Ok(dir) = std::env::var("RETEX_ELASTIFACE_OUT") {
                    let name = format!("blend_{}_{w}_{}.glb", u8::from(textured), stretch[0]);
                    std::fs::write(std::path::Path::new(&dir).join(name), &out.model).unwrap();
                }
                assert_eq!(out.report.method_report["blend_weight"], json!(w));
                check_blend(&source, &fitted, &output_asset(&out), w, &label);
            }
        }
    }
}

#[test]
fn elastiface_blend_with_morph_target_sets_the_default_weight() {
    let source = uv_sphere(48, 24, |p| p);
    let stretch = STRETCHES[1];
    let (s, t) = (template_glb(&source, true), target_glb(stretch));
    let params = json!({"output": "morph_target", "blend": {"weight": 0.4}});
    let out = run_glbs(&s, &t, constraints(stretch, params)).expect("morph blend");
    assert_validator_clean(&out.model, "elastiface_blend_morph.glb");
    let asset = output_asset(&out);
    assert_eq!(asset.json["meshes"][0]["weights"], json!([0.4f32 as f64]));
    assert_eq!(
        asset.json["meshes"][0]["extras"]["targetNames"],
        json!(["elastiface"])
    );
    assert_eq!(asset.primitives[0].positions, source.positions);
}

#[test]
fn elastiface_blend_refuses_bad_weights_and_the_region() {
    let source = uv_sphere(16, 8, |p| p);
    let stretch = STRETCHES[0];
    let (s, t) = (template_glb(&source, true), target_glb(stretch));
    for (blend, field, words) in [
        (json!({"weight": 1.5}), "params.blend.weight", "range"),
        (json!({"weight": -0.1}), "params.blend.weight", "range"),
        (json!({}), "params.blend", "weight"),
        (
            json!({"weight": 0.5, "region": "r"}),
            "params.blend.region",
            "",
        ),
    ] {
        let err = run_glbs(&s, &t, constraints(stretch, json!({"blend": blend})))
            .expect_err("refused")
            .to_string();
        assert!(err.contains(field) && err.contains(words), "{blend}: {err}");
    }
}

#[test]
fn elastiface_blend_of_a_uvless_template_mixes_its_own_color0() {
    let source = MeshData {
        uvs: None,
        ..uv_sphere(48, 24, |p| p)
    };
    let own: Vec<[f64; 3]> = source
        .positions
        .iter()
        .map(|p| tcolor(0.5 + 0.5 * p[0] as f64, 0.5 + 0.5 * p[1] as f64))
        .collect();
    let flat: Vec<f32> = own
        .iter()
        .flat_map(|c| [c[0] as f32, c[1] as f32, c[2] as f32, 1.0])
        .collect();
    let s = mesh_glb_with(&source, None, 1.0, &[("COLOR_0", 4, flat)]);
    for stretch in STRETCHES {
        let t = target_glb(stretch);
        let full = output_asset(&run_glbs(&s, &t, constraints(stretch, json!({}))).expect("w = 1"));
        let relaid = full.primitives[0].colors.clone().expect("COLOR_0");
        for w in WEIGHTS {
            let out = run_glbs(
                &s,
                &t,
                constraints(stretch, json!({"blend": {"weight": w}})),
            )
            .expect("blend");
            assert_validator_clean(&out.model, "elastiface_blend_uvless.glb");
            let got = output_asset(&out).primitives[0]
                .colors
                .clone()
                .expect("COLOR_0");
            assert_eq!(got.len(), source.positions.len());
            let (mut err, mut off) = (0.0f64, 0.0f64);
            for v in 0..got.len() {
                for d in 0..3 {
                    let want = (1.0 - w) * own[v][d] + w * relaid[v][d] as f64;
                    err = err.max((got[v][d] as f64 - want).abs());
                    off += (got[v][d] as f64 - relaid[v][d] as f64).abs() / (3 * got.len()) as f64;
                }
            }
            eprintln!(
                "blend UV-less template, stretch {stretch:?} w {w}: max COLOR_0 error {err:.1e}, \
                 unblended colours {off:.3} away (mean)"
            );
            assert!(err < 1e-3, "w {w}: COLOR_0 error {err}");
            assert!(off > 0.03, "w {w}: not a blend ({off})");
        }
    }
}
