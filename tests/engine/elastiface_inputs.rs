//! Inputs `elastiface` must handle (issue 10, "Interface"): a target whose colour is only COLOR_0
//! (no texture), a source without UVs (COLOR_0 on its own vertices), a source with TANGENT (the
//! tangents recomputed with MikkTSpace on the fitted shape), and a multi-component target
//! (Suzanne, whose eyes are separate components, under the Lee Perry-Smith head template).
//!
//! The code-made pairs: a UV sphere template onto an independently tessellated (turned) sphere
//! stretched by `diag(s)`; the colour of a target point is `color(q)` of the unit-sphere point `q`
//! it came from, so a perfect fit shows `color(p/|p|)` at the template point `p`. Each case runs
//! over three stretches (the `STRETCHES` sweep; figures in README "elastiface"). The real-asset
//! tests use `tests/data/elastiface/head_to_suzanne.json` both ways; set `RETEX_ELASTIFACE_OUT`
//! to a folder to keep the head → Suzanne GLB for `retex preview`.

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput, TransferOutput};
use retex::engine::spatial::Bvh;
use retex::engine::texture::bake::rasterize_uv_layout;
use serde_json::{json, Value};

use crate::common::{assert_validator_clean, load_path, shared_asset};
use crate::elastiface_common::*;

const HEAD: &str = "src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf";
const SUZANNE: &str = "src_suzanne_khronos/glTF/Suzanne.gltf";

/// The stretch sweep: anisotropic, elongated, and mixed.
const STRETCHES: [[f64; 3]; 3] = [[1.4, 1.0, 0.8], [1.0, 1.3, 1.0], [0.8, 1.2, 1.5]];

fn faces(m: &MeshData) -> Vec<[u32; 3]> {
    m.indices.chunks(3).map(|t| [t[0], t[1], t[2]]).collect()
}

#[test]
fn elastiface_color0_only_target_is_relaid_into_the_texture() {
    let source = uv_sphere(48, 24, |p| p);
    let grey = texture_png(4, 4, |_, _| [0.2, 0.2, 0.2]);
    for stretch in STRETCHES {
        let (tgt, unit) = stretched_sphere(stretch);
        let colors: Vec<f32> = unit
            .iter()
            .flat_map(|q| {
                let c = sphere_color(*q);
                [c[0] as f32, c[1] as f32, c[2] as f32, 1.0]
            })
            .collect();
        let tgt_untextured = MeshData {
            uvs: None,
            ..tgt.clone()
        };
        let out = run_glbs(
            &mesh_glb(&source, Some(&grey), 1.0),
            &mesh_glb_with(&tgt_untextured, None, 1.0, &[("COLOR_0", 4, colors)]),
            sphere_constraints(stretch, 10),
        )
        .expect("COLOR_0-only target");
        assert_validator_clean(&out.model, "elastiface_color0_target.glb");
        let asset = output_asset(&out);
        let fitted = &asset.primitives[0].positions;
        let tex = asset.materials[0]
            .base_color_texture
            .expect("re-laid texture");
        let img = asset.images[asset.textures[tex.texture].image.unwrap()]
            .decoded
            .clone()
            .unwrap();
        let uvs = source.uvs.as_ref().unwrap();
        let tris: Vec<[[f32; 2]; 3]> = faces(&source)
            .iter()
            .map(|t| t.map(|v| uvs[v as usize]))
            .collect();
        let map = rasterize_uv_layout(&tris, img.width, img.height);
        let tf = faces(&tgt);
        let bvh = Bvh::build(&tgt.positions, &tf);
        let (mut got, mut at_fit, mut ideal) = (vec![], vec![], vec![]);
        for y in 0..img.height {
            for x in 0..img.width {
                let Some(hit) = map.hit(x, y) else { continue };
                let t = faces(&source)[hit.triangle as usize];
                let mut p = [0.0f64; 3];
                let mut f = [0.0f32; 3];
                for k in 0..3 {
                    for d in 0..3 {
                        p[d] += hit.bary[k] as f64 * source.positions[t[k] as usize][d] as f64;
                        f[d] += hit.bary[k] * fitted[t[k] as usize][d];
                    }
                }
                // The target's vertex colour at its closest point to the fitted texel point.
                let h = bvh.closest_point(f, f32::INFINITY).unwrap();
                let mut c = [0.0; 3];
                for k in 0..3 {
                    let q = sphere_color(unit[tf[h.face as usize][k] as usize]);
                    for d in 0..3 {
                        c[d] += h.bary[k] as f64 * q[d];
                    }
                }
                let px = img.pixels[(y * img.width + x) as usize];
                got.push([0, 1, 2].map(|d| linear(px[d])));
                at_fit.push(c);
                ideal.push(sphere_color(normalize(p)));
            }
        }
        let exact = psnr(&got, &at_fit);
        let vs_ideal = psnr(&got, &ideal);
        let base = psnr(&constant(&ideal), &ideal);
        eprintln!(
            "COLOR_0 target, stretch {stretch:?}: psnr vs target colour at the fitted points \
             {exact:.1} dB, vs the ideal map {vs_ideal:.1} dB, constant baseline {base:.1} dB, \
             hausdorff {}",
            out.report.method_report["hausdorff"]["max"]
        );
        assert!(exact > 40.0, "re-laid COLOR_0 psnr {exact}");
        assert!(
            vs_ideal > 24.0 && vs_ideal > base + 10.0,
            "psnr {vs_ideal} vs {base}"
        );
    }
}

#[test]
fn elastiface_uvless_source_gets_color0_on_its_own_vertices() {
    let source = MeshData {
        uvs: None,
        ..uv_sphere(48, 24, |p| p)
    };
    for stretch in STRETCHES {
        let (tgt, _) = stretched_sphere(stretch);
        // Target texel (u, v) shows the colour of the unit point it covers.
        let png = texture_png(256, 128, |u, v| sphere_color(turn(sphere_point(u, v))));
        let out = run_glbs(
            &mesh_glb(&source, None, 1.0),
            &mesh_glb(&tgt, Some(&png), 1.0),
            sphere_constraints(stretch, 10),
        )
        .expect("UV-less source");
        assert_validator_clean(&out.model, "elastiface_uvless_source.glb");
        let asset = output_asset(&out);
        let prim = &asset.primitives[0];
        assert_eq!(prim.positions.len(), source.positions.len());
        assert!(prim.tex_coords.is_empty());
        let colors = prim.colors.as_ref().expect("COLOR_0 on the source");
        let got: Vec<[f64; 3]> = colors
            .iter()
            .map(|c| [0, 1, 2].map(|d| c[d] as f64))
            .collect();
        let ideal: Vec<[f64; 3]> = source
            .positions
            .iter()
            .map(|p| sphere_color(normalize(p.map(f64::from))))
            .collect();
        let vs_ideal = psnr(&got, &ideal);
        let base = psnr(&constant(&ideal), &ideal);
        eprintln!(
            "UV-less source, stretch {stretch:?}: vertex colour psnr vs the ideal map \
             {vs_ideal:.1} dB, constant baseline {base:.1} dB"
        );
        assert!(
            vs_ideal > 24.0 && vs_ideal > base + 10.0,
            "psnr {vs_ideal} vs {base}"
        );
    }
}

/// Float values of a vertex attribute of the first primitive of a GLB (tightly packed floats).
fn attribute(glb: &[u8], name: &str, n: usize) -> Vec<Vec<f32>> {
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&glb[20..20 + len]).unwrap();
    let bin = &glb[20 + len + 8..];
    let i = doc["meshes"][0]["primitives"][0]["attributes"][name]
        .as_u64()
        .unwrap_or_else(|| panic!("no {name}")) as usize;
    let a = &doc["accessors"][i];
    assert_eq!(a["componentType"], 5126);
    let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let stride = v["byteStride"].as_u64().unwrap_or(4 * n as u64) as usize;
    let start = v["byteOffset"].as_u64().unwrap_or(0) as usize
        + a["byteOffset"].as_u64().unwrap_or(0) as usize;
    (0..a["count"].as_u64().unwrap() as usize)
        .map(|i| {
            (0..n)
                .map(|k| {
                    let o = start + stride * i + 4 * k;
                    f32::from_le_bytes(bin[o..o + 4].try_into().unwrap())
                })
                .collect()
        })
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Per vertex: the direction of increasing u on the mesh (dP/du per face, summed, projected
/// off the normal and normalised).
fn u_directions(
    pos: &[[f32; 3]],
    uv: &[[f32; 2]],
    tris: &[[u32; 3]],
    n: &[Vec<f32>],
) -> Vec<[f64; 3]> {
    let mut acc = vec![[0.0f64; 3]; pos.len()];
    for t in tris {
        let p = t.map(|v| pos[v as usize].map(f64::from));
        let w = t.map(|v| uv[v as usize].map(f64::from));
        let (e1, e2) = (
            [0, 1, 2].map(|d| p[1][d] - p[0][d]),
            [0, 1, 2].map(|d| p[2][d] - p[0][d]),
        );
        let (a, b) = (
            [w[1][0] - w[0][0], w[1][1] - w[0][1]],
            [w[2][0] - w[0][0], w[2][1] - w[0][1]],
        );
        let det = a[0] * b[1] - a[1] * b[0];
        if det.abs() < 1e-12 {
            continue;
        }
        // dP/du = (e1 b_v − e2 a_v) / det, with the sign of det (orientation of the UV face).
        let du = [0, 1, 2].map(|d| (e1[d] * b[1] - e2[d] * a[1]) / det);
        for &v in t {
            for d in 0..3 {
                acc[v as usize][d] += du[d] * det.abs();
            }
        }
    }
    acc.iter()
        .zip(n)
        .map(|(a, n)| {
            let n: Vec<f64> = n.iter().map(|c| *c as f64).collect();
            let k = dot(a, &n);
            let t = [0, 1, 2].map(|d| a[d] - k * n[d]);
            normalize(t)
        })
        .collect()
}

#[test]
fn elastiface_recomputes_tangents_on_the_fitted_source() {
    let source = uv_sphere(48, 24, |p| p);
    let normals: Vec<f32> = source
        .positions
        .iter()
        .flat_map(|p| normalize(p.map(f64::from)).map(|c| c as f32))
        .collect();
    // Unit, orthogonal to the sphere normal, along increasing longitude.
    let tangents: Vec<f32> = source
        .uvs
        .as_ref()
        .unwrap()
        .iter()
        .flat_map(|uv| {
            let a = 2.0 * std::f32::consts::PI * uv[0];
            [-a.sin(), 0.0, -a.cos(), 1.0]
        })
        .collect();
    let grey = texture_png(4, 4, |_, _| [0.2, 0.2, 0.2]);
    let src_glb = mesh_glb_with(
        &source,
        Some(&grey),
        1.0,
        &[("NORMAL", 3, normals), ("TANGENT", 4, tangents)],
    );
    for stretch in STRETCHES {
        let (tgt, _) = stretched_sphere(stretch);
        let png = texture_png(64, 32, |u, v| sphere_color(turn(sphere_point(u, v))));
        let out = run_glbs(
            &src_glb,
            &mesh_glb(&tgt, Some(&png), 1.0),
            sphere_constraints(stretch, 10),
        )
        .expect("source with TANGENT");
        assert_validator_clean(&out.model, "elastiface_tangents.glb");
        let t = attribute(&out.model, "TANGENT", 4);
        let n = attribute(&out.model, "NORMAL", 3);
        let pos = attribute(&out.model, "POSITION", 3);
        assert_eq!(t.len(), source.positions.len());
        let pos: Vec<[f32; 3]> = pos.iter().map(|p| [p[0], p[1], p[2]]).collect();
        let u_dir = u_directions(&pos, source.uvs.as_ref().unwrap(), &faces(&source), &n);
        let (mut worst_len, mut worst_dot, mut align, mut counted) = (0.0f64, 0.0f64, 0.0, 0);
        for ((t, n), u) in t.iter().zip(&n).zip(&u_dir) {
            let tv: Vec<f64> = t[..3].iter().map(|c| *c as f64).collect();
            let nv: Vec<f64> = n.iter().map(|c| *c as f64).collect();
            worst_len = worst_len.max((dot(&tv, &tv).sqrt() - 1.0).abs());
            worst_dot = worst_dot.max(dot(&tv, &nv).abs());
            assert!(t[3] == 1.0 || t[3] == -1.0, "tangent w {}", t[3]);
            if u.iter().all(|c| c.is_finite()) {
                align += dot(&tv, u);
                counted += 1;
            }
        }
        let align = align / counted as f64;
        eprintln!(
            "tangents, stretch {stretch:?}: max | |t| - 1 | {worst_len:.1e}, max |t·n| \
             {worst_dot:.1e}, mean cos(t, dP/du) {align:.4} over {counted} vertices"
        );
        assert!(
            worst_len < 1e-3 && worst_dot < 1e-3,
            "{worst_len} {worst_dot}"
        );
        // A random unit tangent in the normal plane averages 0; the input's would not follow
        // the stretch.
        assert!(align > 0.95, "tangents along dP/du: mean cos {align}");
    }
}

#[test]
#[ignore = "needs the shared assets (../shared/assets)"]
fn elastiface_head_onto_suzanne_with_separate_eye_components() {
    let c: Value = serde_json::from_slice(
        &std::fs::read(
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("tests/data/elastiface/head_to_suzanne.json"),
        )
        .expect("constraints file"),
    )
    .unwrap();
    let out = run_shared(HEAD, SUZANNE, &c);
    assert_validator_clean(&out.model, "elastiface_head_to_suzanne.glb");
    if let Ok(dir) = std::env::var("RETEX_ELASTIFACE_OUT") {
        std::fs::write(
            std::path::Path::new(&dir).join("head_to_suzanne.glb"),
            &out.model,
        )
        .unwrap();
    }
    let r = &out.report.method_report;
    eprintln!(
        "head onto Suzanne: warnings {:?}; target surface {}, unanchored components {}, fairing area ratio {}, \
         hausdorff {}, flipped {}, residuals {}, timings {}",
        out.report.warnings,
        r["target_surface"],
        r["fairing"]["unanchored_components"],
        r["fairing"]["area_ratio"],
        r["hausdorff"],
        r["flipped"],
        r["residuals"],
        stage_timings(&out.report.timings)
    );
    // Suzanne's two eyes carry no reference point: anchored weakly in place (fairing.rs).
    assert_eq!(r["fairing"]["unanchored_components"], json!([0, 2]));
    // Measured 2026-12-02: Hausdorff 4.8 % (fitted → Suzanne 3.2 %, mean 0.045 %), 5.1 % of
    // the area flipped, residual rms 0.26 %; the fairing's collapse guard fires (16 % of the
    // area). These bounds guard against regressions only (the 1 % is for faces).
    let h = r["hausdorff"]["max"].as_f64().unwrap();
    let mean = r["hausdorff"]["source_to_target"]["mean"].as_f64().unwrap();
    assert!(h < 0.08 && mean < 0.002, "hausdorff {h}, mean {mean}");
    let flipped = r["flipped"]["area_fraction"].as_f64().unwrap();
    assert!(flipped < 0.1, "flipped area {flipped}");
    assert!(r["residuals"]["rms"].as_f64().unwrap() < 0.01);
}

/// Runs `elastiface` between two shared assets with a constraints file of `tests/data`.
fn run_shared(source: &str, target: &str, constraints: &Value) -> TransferOutput {
    let (sm, sb) = BlobSet::from_path(&shared_asset(source)).expect("read source");
    let (tm, tb) = BlobSet::from_path(&shared_asset(target)).expect("read target");
    let c = Constraints::from_json(constraints.to_string().as_bytes()).expect("constraints");
    let input = TransferInput::pair(
        ModelInput {
            main: &sm,
            blobs: &sb,
        },
        ModelInput {
            main: &tm,
            blobs: &tb,
        },
        c,
    );
    transfer(&input, &Control::new()).expect("transfer")
}

#[test]
#[ignore = "needs the shared assets (../shared/assets)"]
fn elastiface_suzanne_template_keeps_valid_tangents() {
    // Suzanne as the template (TANGENT, UV seams, eyes as separate components) onto the head:
    // the head → Suzanne landmarks with the sides swapped.
    let mut c: Value = serde_json::from_slice(
        &std::fs::read(
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("tests/data/elastiface/head_to_suzanne.json"),
        )
        .expect("constraints file"),
    )
    .unwrap();
    for pair in c["correspondences"].as_array_mut().unwrap() {
        let s = pair["source"].take();
        pair["source"] = pair["target"].take();
        pair["target"] = s;
    }
    let out = run_shared(SUZANNE, HEAD, &c);
    assert_validator_clean(&out.model, "elastiface_suzanne_to_head.glb");
    let r = &out.report.method_report;
    let t = attribute(&out.model, "TANGENT", 4);
    let n = attribute(&out.model, "NORMAL", 3);
    let (mut worst_len, mut worst_dot) = (0.0f64, 0.0f64);
    for (t, n) in t.iter().zip(&n) {
        let tv: Vec<f64> = t[..3].iter().map(|c| *c as f64).collect();
        let nv: Vec<f64> = n.iter().map(|c| *c as f64).collect();
        worst_len = worst_len.max((dot(&tv, &tv).sqrt() - 1.0).abs());
        worst_dot = worst_dot.max(dot(&tv, &nv).abs());
        assert!(t[3] == 1.0 || t[3] == -1.0, "tangent w {}", t[3]);
    }
    eprintln!(
        "Suzanne onto the head: {} tangents, max | |t| - 1 | {worst_len:.1e}, max |t·n| \
         {worst_dot:.1e}; unanchored components {}, hausdorff {}, flipped {}",
        t.len(),
        r["fairing"]["unanchored_components"],
        r["hausdorff"]["max"],
        r["flipped"]["area_fraction"]
    );
    assert_eq!(
        t.len(),
        load_path(&shared_asset(SUZANNE)).primitives[0]
            .positions
            .len()
    );
    assert!(
        worst_len < 1e-3 && worst_dot < 1e-3,
        "{worst_len} {worst_dot}"
    );
    assert_eq!(r["fairing"]["unanchored_components"], json!([2, 0]));
}
