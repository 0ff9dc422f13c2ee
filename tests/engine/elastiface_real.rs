//! The `elastiface` method on a real scan (Lee Perry-Smith, shared assets): a non-rigidly
//! deformed, rotated and scaled copy of the head (its own UVs, no texture) is fitted back onto the
//! textured head. The map is known (vertex i ↦ head vertex i), so correspondence errors are
//! measured against it, and the re-laid texture must reproduce the head's own texture (same UV
//! layout).

use retex::engine::math::{cross, sub};
use retex::engine::methods::align::best_similarity;
use retex::engine::spatial::Bvh;
use retex::engine::texture::bake::rasterize_uv_layout;
use serde_json::{json, Value};

use crate::common::{assert_validator_clean, load_path, psnr_masked, shared_asset};
use crate::elastiface_common::*;

const HEAD: &str = "src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf";

/// A smooth non-rigid deformation (in units of the head's size `d`), then a similarity.
fn deform(p: [f64; 3], c: [f64; 3], d: f64) -> [f64; 3] {
    let q: [f64; 3] = std::array::from_fn(|k| (p[k] - c[k]) / d);
    let w = [
        q[0] * (1.0 + 0.3 * q[1]) + 0.08 * (3.0 * q[1]).sin(),
        q[1] * 1.2 + 0.1 * q[0] * q[0],
        q[2] * 0.8 + 0.06 * (4.0 * q[0]).cos(),
    ];
    let (s, co) = 0.4f64.sin_cos();
    [
        0.5 * (co * w[0] + s * w[2]),
        0.5 * w[1],
        0.5 * (-s * w[0] + co * w[2]),
    ]
}

/// The deformed copy of world positions (the deformation in units of their bounding box).
pub fn deformed_copy(world: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in world {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    world.iter().map(|p| deform(*p, centre, diag)).collect()
}

/// The real-head case: the textured head, its deformed copy as the template (grey texture, the
/// head's UVs) and 18 farthest-point correspondences (template vertex i ↦ head vertex i).
struct HeadCase {
    path: std::path::PathBuf,
    head: retex::engine::asset::Asset,
    world: Vec<[f64; 3]>,
    diag: f64,
    template: MeshData,
    source: Vec<u8>,
    picked: Vec<usize>,
    corr: Vec<Value>,
}

fn head_case() -> HeadCase {
    let path = shared_asset(HEAD);
    let head = load_path(&path);
    assert_eq!(head.primitives.len(), 1);
    let inst = &head.instances[0];
    let prim = &head.primitives[0];
    let world: Vec<[f64; 3]> = prim
        .positions
        .iter()
        .map(|p| inst.transform_point(*p))
        .collect();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &world {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let centre: [f64; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let template = MeshData {
        positions: world
            .iter()
            .map(|p| deform(*p, centre, diag).map(|c| c as f32))
            .collect(),
        uvs: Some(prim.tex_coords[0].clone()),
        indices: prim.triangles.iter().flatten().copied().collect(),
    };
    let grey = texture_png(4, 4, |_, _| [0.5, 0.5, 0.5]);
    let source = mesh_glb(&template, Some(&grey), 1.0);
    // 18 correspondences: farthest-point samples of the head's vertices.
    let mut picked = vec![0usize];
    let mut near = vec![f64::INFINITY; world.len()];
    while picked.len() < 18 {
        let last = world[*picked.last().unwrap()];
        for (i, p) in world.iter().enumerate() {
            let d = (0..3).map(|k| (p[k] - last[k]).powi(2)).sum::<f64>();
            near[i] = near[i].min(d);
        }
        let next = (0..world.len())
            .max_by(|a, b| near[*a].total_cmp(&near[*b]))
            .unwrap();
        picked.push(next);
    }
    let corr: Vec<Value> = picked
        .iter()
        .map(
            |&i| json!({"source": {"point": template.positions[i]}, "target": {"point": world[i]}}),
        )
        .collect();
    HeadCase {
        path,
        head,
        world,
        diag,
        template,
        source,
        picked,
        corr,
    }
}

fn head_constraints(corr: &[Value]) -> Value {
    json!({"version": 1, "method": "elastiface", "correspondences": corr,
        "output": {"texture_size": 1024, "padding": 8}})
}

#[test]
#[ignore = "needs the shared assets (../shared/assets)"]
fn elastiface_deformed_head_back_onto_the_textured_head() {
    let HeadCase {
        path,
        head,
        world,
        diag,
        template,
        source,
        picked,
        corr,
    } = head_case();
    let prim = &head.primitives[0];
    let c = head_constraints(&corr);
    // The inputs, for the CLI and previews.
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("elastiface_head_source.glb"), &source).unwrap();
    std::fs::write(dir.join("elastiface_head_constraints.json"), c.to_string()).unwrap();
    let t0 = std::time::Instant::now();
    let out = run_glbs(&source, &std::fs::read(&path).unwrap_or_default(), c);
    // The head is a .gltf with an external buffer: load it through its blob set instead.
    let out = match out {
        Ok(o) => o,
        Err(_) => run_gltf_target(&source, &path, head_constraints(&corr)),
    };
    let secs = t0.elapsed().as_secs_f64();
    assert_validator_clean(&out.model, "elastiface_head.glb");
    let r = &out.report.method_report;
    let fitted = output_asset(&out).primitives[0].positions.clone();
    let mean = map_error_mean(&fitted, &world, diag);
    let fitted64: Vec<[f64; 3]> = fitted.iter().map(|p| p.map(f64::from)).collect();
    let lips = lip_errors(&world, &prim.triangles, &fitted64, &world, diag);
    // Baseline: similarity from the correspondences, then closest-point snapping.
    let from: Vec<[f64; 3]> = picked
        .iter()
        .map(|&i| template.positions[i].map(f64::from))
        .collect();
    let to: Vec<[f64; 3]> = picked.iter().map(|&i| world[i]).collect();
    let s = best_similarity(&from, &to);
    let w32: Vec<[f32; 3]> = world.iter().map(|p| p.map(|c| c as f32)).collect();
    let bvh = Bvh::build(&w32, &prim.triangles);
    let base: Vec<f64> = template
        .positions
        .iter()
        .zip(&world)
        .map(|(p, w)| {
            let q = bvh
                .closest_point(s.apply(p.map(f64::from)).map(|c| c as f32), f32::INFINITY)
                .unwrap()
                .point;
            (0..3)
                .map(|k| (q[k] as f64 - w[k]).powi(2))
                .sum::<f64>()
                .sqrt()
                / diag
        })
        .collect();
    let base_mean = base.iter().sum::<f64>() / base.len() as f64;
    // The re-laid texture against the head's own texture, on the covered texels.
    let result = output_asset(&out);
    let tex = |a: &retex::engine::asset::Asset| {
        let t = a.materials[a.primitives[0].material.unwrap()]
            .base_color_texture
            .unwrap();
        a.images[a.textures[t.texture].image.unwrap()]
            .decoded
            .clone()
            .unwrap()
    };
    let (want, got) = (tex(&head), tex(&result));
    assert_eq!((want.width, want.height), (got.width, got.height));
    let tris: Vec<[[f32; 2]; 3]> = prim
        .triangles
        .iter()
        .map(|t| t.map(|v| prim.tex_coords[0][v as usize]))
        .collect();
    let mask = rasterize_uv_layout(&tris, want.width, want.height).mask();
    let psnr = psnr_masked(&want.pixels, &got.pixels, &mask);
    let h = r["hausdorff"]["max"].as_f64().unwrap();
    let flipped = r["flipped"]["area_fraction"].as_f64().unwrap();
    let turned = r["turned_over"]["area_fraction"].as_f64().unwrap();
    let against_truth = turned_against_truth(&fitted, &world, &prim.triangles);
    eprintln!(
        "head: map error mean {mean:.5} (snapping {base_mean:.5}); hausdorff {h:.5}; flipped \
         {flipped:.2e}; turned over {turned:.2e} (against the known answer {against_truth:.2e}); \
         psnr {psnr:.2} dB; {lips:?}; {secs:.2} s end to end; timings {}",
        stage_timings(&out.report.timings)
    );
    // The report's turned-over figure sees the folds that `flipped` cannot: most of the area
    // turned over against the known answer, and more than `flipped`.
    assert!(
        turned > 0.5 * against_truth && turned > flipped,
        "turned over {turned} vs known answer {against_truth}, flipped {flipped}"
    );
    assert!(
        mean < 0.6 * base_mean, // measured ratio 0.50
        "map error {mean} vs snapping {base_mean}"
    );
    assert!(psnr > 25.0, "psnr {psnr}");
    // NOT the issue's targets (Hausdorff < 1 %, flipped area < 0.01 %): measured 2026-12-02,
    // Hausdorff 1.1 % and 0.043 % of the area flipped (6.8 % and 0.32 % without the backward
    // rounds of the originals stage; mean map error 1.5 % against 3.0 % for snapping, PSNR
    // 29.4 dB). Open defect; these bounds only guard against regressions.
    assert!(h < 0.015, "hausdorff {h}");
    assert!(flipped < 0.001, "flipped {flipped}");
}

/// Mean distance of fitted vertex i from head vertex i (the known answer), over `diag`.
fn map_error_mean(fitted: &[[f32; 3]], world: &[[f64; 3]], diag: f64) -> f64 {
    let sum: f64 = fitted
        .iter()
        .zip(world)
        .map(|(x, w)| {
            (0..3)
                .map(|k| (x[k] as f64 - w[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum();
    sum / fitted.len().max(1) as f64 / diag
}

/// The known answer's turned-over area: the area fraction of fitted triangles whose normal
/// points against the same triangle's on the head (fitted vertex i should be head vertex i).
fn turned_against_truth(fitted: &[[f32; 3]], world: &[[f64; 3]], tris: &[[u32; 3]]) -> f64 {
    let normal = |x: &dyn Fn(usize) -> [f64; 3], t: [u32; 3]| {
        let [a, b, c] = t.map(|v| x(v as usize));
        cross(sub(b, a), sub(c, a))
    };
    let (mut all, mut against) = (0.0f64, 0.0f64);
    for t in tris {
        let nf = normal(&|i| fitted[i].map(f64::from), *t);
        let nw = normal(&|i| world[i], *t);
        let a = 0.5 * (nf[0] * nf[0] + nf[1] * nf[1] + nf[2] * nf[2]).sqrt();
        all += a;
        if nf[0] * nw[0] + nf[1] * nw[1] + nf[2] * nw[2] < 0.0 {
            against += a;
        }
    }
    against / all
}

/// `free_visibility` on the deformed copy → head: the mouth bag and eye sockets (hidden behind
/// closed lips and lids) follow their fitted neighbours instead of being squeezed into the
/// slits. Against the known answer, the turned-over area and the map error fall; the fitted
/// faces (no free corner) stay on the target. The report's whole-mesh figures grow (the free
/// faces are off the target's own cavities by design), so they are not asserted here.
#[test]
#[ignore = "needs the shared assets (../shared/assets)"]
fn elastiface_free_hidden_cavities_follow_instead_of_folding() {
    let case = head_case();
    let prim = &case.head.primitives[0];
    let target = std::fs::read(&case.path).unwrap_or_default();
    let run = |free: f64| {
        let mut c = head_constraints(&case.corr);
        c["params"] = json!({ "free_visibility": free });
        let out = match run_glbs(&case.source, &target, c.clone()) {
            Ok(o) => o,
            Err(_) => run_gltf_target(&case.source, &case.path, c),
        };
        let fitted = output_asset(&out).primitives[0].positions.clone();
        let mean = map_error_mean(&fitted, &case.world, case.diag);
        let truth = turned_against_truth(&fitted, &case.world, &prim.triangles);
        (out, mean, truth)
    };
    let (_, mean0, truth0) = run(0.0);
    let (out, mean, truth) = run(0.1);
    assert_validator_clean(&out.model, "elastiface_head_free.glb");
    let ff = &out.report.method_report["fitted_faces"];
    let free = ff["free_vertices"].as_u64().unwrap();
    let h = ff["source_to_target"]["max"].as_f64().unwrap();
    let flipped = ff["flipped"]["area_fraction"].as_f64().unwrap();
    eprintln!(
        "free 0.1: {free} free vertices, {} fitted faces; map error {mean:.5} (default \
         {mean0:.5}); turned over against the known answer {truth:.2e} (default {truth0:.2e}); \
         fitted faces: hausdorff {h:.5}, flipped {flipped:.2e}",
        ff["faces"]
    );
    // Measured 2026-12-07: see the README ("Free hidden cavities").
    assert!(free > 500, "free vertices {free}");
    assert!(truth < 0.3 * truth0, "turned over {truth} vs {truth0}");
    assert!(mean < 0.9 * mean0, "map error {mean} vs {mean0}");
    assert!(h < 0.01, "fitted faces hausdorff {h}");
    assert!(flipped < 0.001, "fitted faces flipped {flipped}");
    assert!(out.report.method_report["warnings"]
        .as_array()
        .unwrap()
        .is_empty());
}

/// The same pair with 18 committed correspondences (`tests/data/elastiface/deformed_to_head.json`):
/// 14 farthest-point samples and the four mouth landmarks (both corners, upper and lower lip)
/// that a user places on a face. With them the lips stay put and the whole fit meets the issue's
/// 1 % Hausdorff; with `free_visibility` 0.1 the fitted faces also meet its 0.01 % flipped area.
#[test]
#[ignore = "needs the shared assets (../shared/assets)"]
fn elastiface_deformed_head_with_mouth_landmarks_meets_the_issue_bounds() {
    let case = head_case();
    let prim = &case.head.primitives[0];
    let file = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/elastiface/deformed_to_head.json");
    let committed: Value = serde_json::from_slice(&std::fs::read(file).unwrap()).unwrap();
    let target = std::fs::read(&case.path).unwrap_or_default();
    let run = |free: f64| {
        let mut c = committed.clone();
        c["params"] = json!({ "free_visibility": free });
        let out = match run_glbs(&case.source, &target, c.clone()) {
            Ok(o) => o,
            Err(_) => run_gltf_target(&case.source, &case.path, c),
        };
        let fitted = output_asset(&out).primitives[0].positions.clone();
        let fitted64: Vec<[f64; 3]> = fitted.iter().map(|p| p.map(f64::from)).collect();
        let lips = lip_errors(
            &case.world,
            &prim.triangles,
            &fitted64,
            &case.world,
            case.diag,
        );
        let mean = map_error_mean(&fitted, &case.world, case.diag);
        (out, mean, lips)
    };
    let (out, mean, lips) = run(0.0);
    assert_validator_clean(&out.model, "elastiface_head_mouth.glb");
    let r = &out.report.method_report;
    let h = r["hausdorff"]["max"].as_f64().unwrap();
    let flipped = r["flipped"]["area_fraction"].as_f64().unwrap();
    let (free_out, free_mean, free_lips) = run(0.1);
    let ff = &free_out.report.method_report["fitted_faces"];
    let ff_h = ff["source_to_target"]["max"].as_f64().unwrap();
    let ff_flipped = ff["flipped"]["area_fraction"].as_f64().unwrap();
    eprintln!(
        "mouth landmarks: hausdorff {h:.5}, flipped {flipped:.2e}, map error {mean:.5}, \
         {lips:?}; free 0.1: fitted faces hausdorff {ff_h:.5}, flipped {ff_flipped:.2e}, map \
         error {free_mean:.5}, {free_lips:?}"
    );
    // Measured 2026-12-07 (README "The lip slide"): Hausdorff 0.44 % (1.10 % with the 18
    // farthest-point pairs), lips 0.17 % (0.88 %), map error 1.06 % (1.47 %); flipped
    // 0.033 %, over the issue's 0.01 % (in the collapsed cavities). With free_visibility 0.1,
    // the fitted faces: Hausdorff 0.35 %, flipped 0.0084 %.
    assert!(h < 0.01, "hausdorff {h}");
    assert!(lips.front < 0.003 && lips.lower < 0.003, "{lips:?}");
    assert!(mean < 0.013, "map error {mean}");
    assert!(flipped < 0.001, "flipped {flipped}");
    assert!(ff_h < 0.01, "fitted faces hausdorff {ff_h}");
    assert!(ff_flipped < 1e-4, "fitted faces flipped {ff_flipped}");
    assert!(free_mean < mean, "map error {free_mean} vs {mean}");
}

fn run_gltf_target(
    source: &[u8],
    target: &std::path::Path,
    c: Value,
) -> retex::engine::pipeline::TransferOutput {
    use retex::engine::asset::constraints::Constraints;
    use retex::engine::asset::BlobSet;
    use retex::engine::control::Control;
    use retex::engine::pipeline::{transfer, ModelInput, TransferInput};
    let c = Constraints::from_json(c.to_string().as_bytes()).unwrap();
    let mut sb = BlobSet::new();
    sb.insert("source.glb", source.to_vec());
    let (main, tb) = BlobSet::from_path(target).unwrap();
    let input = TransferInput::pair(
        ModelInput {
            main: "source.glb",
            blobs: &sb,
        },
        ModelInput {
            main: &main,
            blobs: &tb,
        },
        c,
    );
    transfer(&input, &Control::new()).unwrap()
}

/// The part-based morph of §5 on the real head: the template's faces within 0.2 of its diagonal
/// of the nose tip (the head's vertex of largest z; the whole face, mouth cavity included) take
/// the fitted face, the rest of the (deformed) template stays. Checks: vertices on no region face
/// keep the template's position; the region moved; no triangle turned over against the template;
/// texels of triangles outside the region keep the template's grey; the face's texels carry the
/// scan's detail (spread well above the grey's).
#[test]
#[ignore = "needs the shared assets (../shared/assets)"]
fn elastiface_region_blend_on_the_real_head() {
    let case = head_case();
    let prim = &case.head.primitives[0];
    let tp = &case.template.positions;
    let dist = |a: [f32; 3], b: [f32; 3]| {
        (0..3)
            .map(|k| (a[k] as f64 - b[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in tp {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let tdiag = dist(lo, hi);
    let tip = (0..case.world.len())
        .max_by(|a, b| case.world[*a][2].total_cmp(&case.world[*b][2]))
        .unwrap();
    let near: Vec<bool> = tp.iter().map(|p| dist(*p, tp[tip]) < 0.2 * tdiag).collect();
    let faces: Vec<u32> = (0..prim.triangles.len() as u32)
        .filter(|&f| prim.triangles[f as usize].iter().all(|&v| near[v as usize]))
        .collect();
    // A vertex is in the region when any copy of it (split UV seams) lies on a region face.
    let key = |p: [f32; 3]| p.map(f32::to_bits);
    let mut region_keys = std::collections::HashSet::new();
    for &f in &faces {
        for &v in &prim.triangles[f as usize] {
            region_keys.insert(key(tp[v as usize]));
        }
    }
    let in_region: Vec<bool> = tp.iter().map(|p| region_keys.contains(&key(*p))).collect();
    let mut c = head_constraints(&case.corr);
    c["params"] = json!({"blend": {"weight": 1.0, "region": faces}});
    let t0 = std::time::Instant::now();
    let out = run_gltf_target(&case.source, &case.path, c);
    let secs = t0.elapsed().as_secs_f64();
    assert_validator_clean(&out.model, "elastiface_head_region.glb");
    let result = output_asset(&out);
    let got = &result.primitives[0].positions;
    assert_eq!(got.len(), tp.len());
    let (mut fixed_err, mut moved, mut n_in) = (0f64, 0f64, 0usize);
    for v in 0..tp.len() {
        let d = dist(got[v], tp[v]) / tdiag;
        if in_region[v] {
            moved += d;
            n_in += 1;
        } else {
            fixed_err = fixed_err.max(d);
        }
    }
    let moved = moved / n_in.max(1) as f64;
    // Turned-over triangles: the region's output against the template, and the plain fit (w = 1,
    // no region, world placement) against the head itself (the known answer: template vertex i
    // is head vertex i). The fit already turns some triangles over (measured 3.3% of the area:
    // normals more than 90° from the head's); the blend must not add many of its own.
    let normal = |p: &[[f32; 3]], t: [u32; 3]| {
        let [a, b, c] = t.map(|v| p[v as usize].map(f64::from));
        cross(sub(b, a), sub(c, a))
    };
    let turned = |p: &[[f32; 3]], q: &[[f32; 3]], t: [u32; 3]| {
        let (n0, n1) = (normal(p, t), normal(q, t));
        n0.iter().zip(&n1).map(|(x, y)| x * y).sum::<f64>() < 0.0
    };
    let fit = output_asset(&run_gltf_target(
        &case.source,
        &case.path,
        head_constraints(&case.corr),
    ));
    let fit = &fit.primitives[0].positions;
    let head: Vec<[f32; 3]> = case.world.iter().map(|p| p.map(|c| c as f32)).collect();
    let (mut area, mut fit_flips, mut region_flips, mut own_flips) = (0f64, 0f64, 0f64, 0f64);
    for t in &prim.triangles {
        let a = normal(&head, *t).iter().map(|x| x * x).sum::<f64>().sqrt();
        area += a;
        let (by_fit, by_region) = (turned(&head, fit, *t), turned(tp, got, *t));
        fit_flips += if by_fit { a } else { 0.0 };
        region_flips += if by_region { a } else { 0.0 };
        own_flips += if by_region && !by_fit { a } else { 0.0 };
    }
    let (fit_flips, region_flips, own_flips) =
        (fit_flips / area, region_flips / area, own_flips / area);
    // Texels: outside (all three vertices out of the region) against the template's grey; inside
    // (all three in) their spread.
    let img = {
        let t = result.materials[result.primitives[0].material.unwrap()]
            .base_color_texture
            .unwrap();
        result.images[result.textures[t.texture].image.unwrap()]
            .decoded
            .clone()
            .unwrap()
    };
    let tris: Vec<[[f32; 2]; 3]> = prim
        .triangles
        .iter()
        .map(|t| t.map(|v| prim.tex_coords[0][v as usize]))
        .collect();
    let map = rasterize_uv_layout(&tris, img.width, img.height);
    let grey = srgb8(0.5) as f64;
    let (mut out_max, mut out_n) = (0f64, 0usize);
    let mut inside: Vec<f64> = Vec::new();
    for (i, h) in map.hits.iter().enumerate() {
        let Some(h) = h else { continue };
        let t = prim.triangles[h.triangle as usize];
        let px = img.pixels[i];
        let luma = (px[0] as f64 + px[1] as f64 + px[2] as f64) / 3.0;
        if t.iter().all(|&v| !in_region[v as usize]) {
            for ch in &px[..3] {
                out_max = out_max.max((*ch as f64 - grey).abs());
            }
            out_n += 1;
        } else if t.iter().all(|&v| in_region[v as usize]) {
            inside.push(luma);
        }
    }
    let mean = inside.iter().sum::<f64>() / inside.len().max(1) as f64;
    let spread = (inside.iter().map(|x| (x - mean).powi(2)).sum::<f64>()
        / inside.len().max(1) as f64)
        .sqrt();
    eprintln!(
        "head region: {} of {} faces; fixed vertices moved ≤ {fixed_err:.1e}, region vertices \
         {moved:.4} of the diagonal on average; turned-over area: the fit {fit_flips:.4}, the region \
         output {region_flips:.4}, of which not the fit's {own_flips:.4}; {out_n} outside texels \
         within {out_max:.1} levels of grey; {} face texels, luminance spread {spread:.1} levels; \
         {secs:.2} s; timings {}",
        faces.len(),
        prim.triangles.len(),
        inside.len(),
        stage_timings(&out.report.timings)
    );
    assert!(fixed_err < 1e-6, "fixed vertices moved {fixed_err}");
    assert!(moved > 1e-3, "the region did not move ({moved})");
    // Measured 0.0027: a regression guard, not a target.
    assert!(
        own_flips < 0.005,
        "turned-over area of the blend's own {own_flips}"
    );
    assert!(
        out_n > 10_000 && out_max <= 1.0,
        "outside texels {out_n}, {out_max}"
    );
    assert!(
        inside.len() > 10_000 && spread > 8.0,
        "face spread {spread}"
    );
}
