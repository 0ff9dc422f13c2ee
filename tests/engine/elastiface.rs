//! The `elastiface` method on analytic pairs with a known map `f` from the template to the
//! target: a sphere template onto an independently tessellated, rotated sphere that is stretched
//! anisotropically and carries a protruding bump (a "nose" the template lacks).

use retex::engine::methods::align::best_similarity;
use retex::engine::spatial::Bvh;
use retex::engine::texture::bake::rasterize_uv_layout;
use serde_json::{json, Value};

use crate::common::assert_validator_clean;
use crate::elastiface_common::*;

/// One analytic pair: bump height, stretch and the turn of the target's tessellation.
#[derive(Clone, Copy, Debug)]
struct Variant {
    bump: f64,
    stretch: [f64; 3],
    turn: f64,
}

/// The pair every test but the sweep uses.
const DEFAULT: Variant = Variant {
    bump: 0.8,
    stretch: [1.6, 1.0, 0.8],
    turn: 0.7,
};

thread_local! {
    /// The variant of this test thread (the sweep changes it on its own thread only).
    static VARIANT: std::cell::Cell<Variant> = const { std::cell::Cell::new(DEFAULT) };
}

/// Rotation of the target's tessellation (about (1, 1, 0)/√2 by the variant's turn, 0.7 rad).
fn rotate(p: [f64; 3]) -> [f64; 3] {
    let turn = VARIANT.with(|v| v.get().turn);
    let k = [
        std::f64::consts::FRAC_1_SQRT_2,
        std::f64::consts::FRAC_1_SQRT_2,
        0.0,
    ];
    let (s, c) = turn.sin_cos();
    let kxp = [
        k[1] * p[2] - k[2] * p[1],
        k[2] * p[0] - k[0] * p[2],
        k[0] * p[1] - k[1] * p[0],
    ];
    let kp = k[0] * p[0] + k[1] * p[1] + k[2] * p[2];
    std::array::from_fn(|i| p[i] * c + kxp[i] * s + k[i] * kp * (1.0 - c))
}

/// The known map: a Gaussian bump (height 0.8 by default) around +z, then a stretch
/// (diag(1.6, 1, 0.8) by default).
fn f(p: [f64; 3]) -> [f64; 3] {
    let v = VARIANT.with(|v| v.get());
    let d2 = p[0] * p[0] + p[1] * p[1] + (p[2] - 1.0).powi(2);
    let h = v.bump * (-d2 / 0.12).exp();
    [
        v.stretch[0] * p[0],
        v.stretch[1] * p[1],
        v.stretch[2] * (p[2] + h),
    ]
}

fn normalize(p: [f64; 3]) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    p.map(|c| c / l)
}

/// Linear colour as a function of the template's sphere point.
fn color(q: [f64; 3]) -> [f64; 3] {
    [
        0.5 + 0.4 * (2.5 * q[0] + 1.0).sin(),
        0.5 + 0.4 * (2.0 * q[1]).sin(),
        0.5 + 0.4 * (3.0 * q[2]).cos(),
    ]
}

/// Correspondence directions on the template sphere: spread over the sphere, dense on the bump.
fn landmarks() -> Vec<[f64; 3]> {
    let mut out = vec![
        [0.0, 0.0, 1.0],
        [0.3, 0.0, 0.95],
        [-0.3, 0.0, 0.95],
        [0.0, 0.3, 0.95],
        [0.0, -0.3, 0.95],
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.6, 0.6, 0.5],
        [-0.6, 0.6, 0.5],
        [0.6, -0.6, 0.5],
        [-0.6, -0.6, 0.5],
        [0.6, 0.6, -0.5],
        [-0.6, -0.6, -0.5],
    ];
    for p in &mut out {
        *p = normalize(*p);
    }
    out
}

struct Pair {
    source: MeshData,
    target: MeshData,
    source_glb: Vec<u8>,
    target_glb: Vec<u8>,
    diagonal: f64,
}

fn pair(scale: f64) -> Pair {
    let source = uv_sphere(96, 48, |p| p).mapped(|p| p.map(|c| c * scale));
    let target = uv_sphere(128, 64, rotate).mapped(|p| f(p).map(|c| c * scale));
    // Target texel (u, v) shows the colour of the template point it covers: rotate(sphere(u, v)).
    let png = texture_png(256, 128, |u, v| color(rotate(sphere_point(u, v))));
    let grey = texture_png(4, 4, |_, _| [0.2, 0.2, 0.2]);
    let diagonal = bbox_diagonal(&target.positions);
    Pair {
        source_glb: mesh_glb(&source, Some(&grey), 1.0),
        target_glb: mesh_glb(&target, Some(&png), 1.0),
        source,
        target,
        diagonal,
    }
}

fn bbox_diagonal(p: &[[f32; 3]]) -> f64 {
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

fn constraints(scale: f64, extra: Value) -> Value {
    let corr: Vec<Value> = landmarks()
        .iter()
        .map(|p| {
            json!({"source": {"point": p.map(|c| c * scale)},
                   "target": {"point": f(*p).map(|c| c * scale)}})
        })
        .collect();
    let mut c = json!({"version": 1, "method": "elastiface", "correspondences": corr,
        "output": {"texture_size": 256, "padding": 4}});
    if let Value::Object(m) = extra {
        for (k, v) in m {
            c[k] = v;
        }
    }
    c
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// Mean and max over template vertices of |x_i − f(p_i)| / diagonal.
fn map_error(template: &MeshData, fitted: &[[f32; 3]], diagonal: f64) -> (f64, f64) {
    let e: Vec<f64> = template
        .positions
        .iter()
        .zip(fitted)
        .map(|(p, x)| dist(x.map(f64::from), f(normalize(p.map(f64::from)))) / diagonal)
        .collect();
    (
        e.iter().sum::<f64>() / e.len() as f64,
        e.iter().copied().fold(0.0, f64::max),
    )
}

/// The baseline: similarity from the correspondences, then every vertex snapped to its closest
/// target point.
fn snapping_baseline(pair: &Pair) -> Vec<[f32; 3]> {
    let from: Vec<[f64; 3]> = landmarks();
    let to: Vec<[f64; 3]> = landmarks().iter().map(|p| f(*p)).collect();
    let s = best_similarity(&from, &to);
    let faces: Vec<[u32; 3]> = pair
        .target
        .indices
        .chunks(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let bvh = Bvh::build(&pair.target.positions, &faces);
    pair.source
        .positions
        .iter()
        .map(|p| {
            let q = s.apply(p.map(f64::from)).map(|c| c as f32);
            bvh.closest_point(q, f32::INFINITY).unwrap().point
        })
        .collect()
}

/// PSNR (dB) of the re-laid texture against the colour of the template point of every covered
/// texel (what a perfect map would show).
fn relaid_psnr(template: &MeshData, out: &retex::engine::pipeline::TransferOutput) -> f64 {
    let asset = output_asset(out);
    let t = asset.materials[0]
        .base_color_texture
        .expect("re-laid texture");
    let img = asset.images[asset.textures[t.texture].image.unwrap()]
        .decoded
        .clone()
        .unwrap();
    let uvs = template.uvs.as_ref().unwrap();
    let tris: Vec<[[f32; 2]; 3]> = template
        .indices
        .chunks(3)
        .map(|t| [0, 1, 2].map(|k| uvs[t[k] as usize]))
        .collect();
    let map = rasterize_uv_layout(&tris, img.width, img.height);
    let (mut se, mut n) = (0.0f64, 0usize);
    for y in 0..img.height {
        for x in 0..img.width {
            let Some(hit) = map.hit(x, y) else { continue };
            let t = &template.indices[3 * hit.triangle as usize..][..3];
            let mut p = [0.0; 3];
            for k in 0..3 {
                let q = template.positions[t[k] as usize];
                for d in 0..3 {
                    p[d] += hit.bary[k] as f64 * q[d] as f64;
                }
            }
            let want = color(normalize(p)).map(srgb8);
            let got = img.pixels[(y * img.width + x) as usize];
            for d in 0..3 {
                se += (want[d] as f64 - got[d] as f64).powi(2);
                n += 1;
            }
        }
    }
    10.0 * (255.0f64.powi(2) / (se / n as f64)).log10()
}

fn report(out: &retex::engine::pipeline::TransferOutput) -> &Value {
    &out.report.method_report
}

#[test]
fn elastiface_bump_and_stretch_beats_snapping() {
    // Measured 0.36 % (0.67 % before the backward rounds); bound + 0.24 points.
    bump_case("elastiface_bump.glb", 0.006);
}

/// The thresholds of `elastiface_bump_and_stretch_beats_snapping` over five pairs (bump height,
/// stretch, tessellation turn); the figures are in the README's elastiface section.
#[test]
fn elastiface_bump_threshold_sweep() {
    let variants = [
        (0.5, [1.6, 1.0, 0.8], 0.3),
        (1.0, [1.3, 1.2, 0.7], 1.2),
        (0.8, [1.0, 1.0, 1.0], 0.7),
        (0.6, [1.8, 0.9, 0.8], 2.0),
    ];
    for (k, (bump, stretch, turn)) in variants.into_iter().enumerate() {
        VARIANT.with(|v| {
            v.set(Variant {
                bump,
                stretch,
                turn,
            })
        });
        eprintln!("variant bump {bump} stretch {stretch:?} turn {turn}:");
        // Measured 2026-12-02 with the backward rounds of the originals stage: 0.19-0.70 %
        // (the bump without stretch the largest; 1.03 % before them). Bound: the largest
        // figure + 0.2 points, under the 1 %.
        bump_case(&format!("elastiface_bump_sweep{k}.glb"), 0.009);
    }
}

fn bump_case(name: &str, max_hausdorff: f64) {
    let pair = pair(1.0);
    let out = run_glbs(
        &pair.source_glb,
        &pair.target_glb,
        constraints(1.0, json!({})),
    )
    .unwrap();
    assert_validator_clean(&out.model, name);
    let r = report(&out);
    let asset = output_asset(&out);
    let fitted = &asset.primitives[0].positions;
    assert_eq!(fitted.len(), pair.source.positions.len());
    assert_eq!(
        asset.primitives[0].triangles.len() * 3,
        pair.source.indices.len()
    );
    let (mean, max) = map_error(&pair.source, fitted, pair.diagonal);
    let (base_mean, base_max) = map_error(&pair.source, &snapping_baseline(&pair), pair.diagonal);
    let h = r["hausdorff"]["max"].as_f64().unwrap();
    let flipped = r["flipped"]["area_fraction"].as_f64().unwrap();
    let turned = r["turned_over"]["area_fraction"].as_f64().unwrap();
    let res = r["residuals"]["max"].as_f64().unwrap();
    let psnr = relaid_psnr(&pair.source, &out);
    eprintln!(
        "bump: psnr {psnr:.2}; map error mean {mean:.5} max {max:.5}; snapping mean {base_mean:.5} max {base_max:.5}; {} \
         hausdorff {h:.5}; flipped {flipped:.2e}; turned over {turned:.2e}; residual max {res:.5}; timings {}",
        r["hausdorff"],
        stage_timings(&out.report.timings)
    );
    // Every output vertex (also those of triangles dropped as degenerate at the poles) lies on
    // the target.
    let faces: Vec<[u32; 3]> = pair
        .target
        .indices
        .chunks(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let bvh = Bvh::build(&pair.target.positions, &faces);
    let worst = fitted
        .iter()
        .map(|p| {
            bvh.closest_point(*p, f32::INFINITY)
                .unwrap()
                .distance_squared
                .sqrt() as f64
        })
        .fold(0.0, f64::max);
    assert!(
        worst < 0.01 * pair.diagonal,
        "a vertex lies {worst} off the target"
    );
    assert!(
        mean < 0.5 * base_mean,
        "mean map error {mean} vs snapping {base_mean}"
    );
    assert!(h < max_hausdorff, "hausdorff {h}");
    assert!(flipped < 1e-4, "flipped area {flipped}");
    assert!(turned < 1e-4, "turned-over area {turned}");
    assert!(res < 0.01, "correspondence residual {res}");
    assert!(psnr > 28.0, "re-laid texture psnr {psnr}");
}

/// The positions of the output's only primitive.
fn fitted_positions(out: &retex::engine::pipeline::TransferOutput) -> Vec<[f32; 3]> {
    output_asset(out).primitives[0].positions.clone()
}

#[test]
fn elastiface_scaling_both_inputs_by_1000_scales_the_output() {
    let (a, b) = (pair(1.0), pair(1000.0));
    let out_a = run_glbs(&a.source_glb, &a.target_glb, constraints(1.0, json!({}))).unwrap();
    let out_b = run_glbs(&b.source_glb, &b.target_glb, constraints(1000.0, json!({}))).unwrap();
    let (pa, pb) = (fitted_positions(&out_a), fitted_positions(&out_b));
    let worst = pa
        .iter()
        .zip(&pb)
        .map(|(x, y)| dist(x.map(|c| c as f64 * 1000.0), y.map(f64::from)))
        .fold(0.0, f64::max);
    eprintln!(
        "scale: worst |1000 a - b| / diagonal = {:.2e}",
        worst / b.diagonal
    );
    assert!(worst < 1e-5 * b.diagonal, "worst deviation {worst}");
}

#[test]
fn elastiface_template_fitted_to_itself_returns_itself() {
    let source = uv_sphere(48, 24, |p| p);
    let grey = texture_png(4, 4, |_, _| [0.5, 0.2, 0.2]);
    let glb = mesh_glb(&source, Some(&grey), 1.0);
    let corr: Vec<Value> = landmarks()
        .iter()
        .map(|p| json!({"source": {"point": p}, "target": {"point": p}}))
        .collect();
    let c = json!({"version": 1, "method": "elastiface", "correspondences": corr,
        "output": {"texture_size": 64}});
    let out = run_glbs(&glb, &glb, c).unwrap();
    let fitted = fitted_positions(&out);
    let diagonal = bbox_diagonal(&source.positions);
    let worst = source
        .positions
        .iter()
        .zip(&fitted)
        .map(|(a, b)| dist(a.map(f64::from), b.map(f64::from)))
        .fold(0.0, f64::max);
    eprintln!(
        "idempotence: worst {:.2e} of the diagonal",
        worst / diagonal
    );
    assert!(worst <= 1e-6 * diagonal, "moved by {worst}");
}

#[test]
fn elastiface_writes_positions_through_the_source_node_transform() {
    let p = pair(1.0);
    // The same template, stored at half size under a node that scales by 2.
    let half = p.source.mapped(|q| q.map(|c| c * 0.5));
    let grey = texture_png(4, 4, |_, _| [0.2, 0.2, 0.2]);
    let scaled = mesh_glb(&half, Some(&grey), 2.0);
    let plain = run_glbs(&p.source_glb, &p.target_glb, constraints(1.0, json!({}))).unwrap();
    let out = run_glbs(&scaled, &p.target_glb, constraints(1.0, json!({}))).unwrap();
    assert_validator_clean(&out.model, "elastiface_node_scale.glb");
    let worst = fitted_positions(&plain)
        .iter()
        .zip(&fitted_positions(&out))
        .map(|(a, b)| dist(a.map(f64::from), b.map(|c| 2.0 * c as f64)))
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-5 * p.diagonal,
        "world positions differ by {worst}"
    );
}

/// Floats of a VEC3 float accessor of a GLB (tightly packed, not sparse).
fn accessor_vec3(glb: &[u8], accessor: usize) -> Vec<[f32; 3]> {
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&glb[20..20 + len]).unwrap();
    let bin = &glb[20 + len + 8..];
    let a = &doc["accessors"][accessor];
    let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let start = v["byteOffset"].as_u64().unwrap_or(0) as usize
        + a["byteOffset"].as_u64().unwrap_or(0) as usize;
    (0..a["count"].as_u64().unwrap() as usize)
        .map(|i| {
            std::array::from_fn(|k| {
                let o = start + 12 * i + 4 * k;
                f32::from_le_bytes(bin[o..o + 4].try_into().unwrap())
            })
        })
        .collect()
}

#[test]
fn elastiface_morph_target_holds_the_displacement_in_the_source_frame() {
    let p = pair(1.0);
    let extra = json!({"params": {"output": "morph_target"}});
    let out = run_glbs(&p.source_glb, &p.target_glb, constraints(1.0, extra)).unwrap();
    assert_validator_clean(&out.model, "elastiface_morph.glb");
    let plain = run_glbs(&p.source_glb, &p.target_glb, constraints(1.0, json!({}))).unwrap();
    // POSITION is the template's.
    assert_eq!(fitted_positions(&out), p.source.positions);
    let len = u32::from_le_bytes(out.model[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&out.model[20..20 + len]).unwrap();
    assert_eq!(
        doc["meshes"][0]["extras"]["targetNames"],
        json!(["elastiface"])
    );
    let target = doc["meshes"][0]["primitives"][0]["targets"][0]["POSITION"]
        .as_u64()
        .unwrap() as usize;
    let deltas = accessor_vec3(&out.model, target);
    // template + delta = the fitted shape with the initial similarity undone.
    let s = &out.report.method_report["initial_similarity"];
    let scale = s["scale"].as_f64().unwrap();
    let r: Vec<Vec<f64>> = serde_json::from_value(s["rotation"].clone()).unwrap();
    let t: Vec<f64> = serde_json::from_value(s["translation"].clone()).unwrap();
    let worst = fitted_positions(&plain)
        .iter()
        .zip(p.source.positions.iter().zip(&deltas))
        .map(|(world, (base, d))| {
            let q: [f64; 3] = std::array::from_fn(|k| world[k] as f64 - t[k]);
            let back: [f64; 3] =
                std::array::from_fn(|c| (0..3).map(|k| r[k][c] * q[k]).sum::<f64>() / scale);
            dist(back, std::array::from_fn(|k| (base[k] + d[k]) as f64))
        })
        .fold(0.0, f64::max);
    assert!(worst < 1e-5 * p.diagonal, "morph target differs by {worst}");
}
