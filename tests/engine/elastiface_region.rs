//! The part-based morph of §5 (`params.blend.region`, issue 10 item 8): positions by the
//! Poisson blend of cotan Laplacians (Alexa 2003), texture by the gradient-domain blend (Pérez
//! et al. 2003) inside the region, the template unchanged outside.
//!
//! The pair: the UV-sphere template onto the turned, finer sphere stretched by `diag(s)` (as in
//! `elastiface_blend`), two stretches; regions: the upper hemisphere as a face list (feathered
//! by default, and unfeathered for the Laplacian check), a COLOR_0 gradient `r = clamp(1.5 z)`,
//! and every face. What is checked, against quantities the test computes itself from the
//! template, the w = 1 output and the reported similarity:
//! - vertices of weight 0 stay within 1e-6 of the diagonal of the template;
//! - every free vertex satisfies `L x = (1 − ω) L a + ω L b` (template cotan Laplacian, a the
//!   template, b the fitted shape in the template's placement), far better than the naive
//!   masked linear blend does;
//! - region = all faces equals the linear blend `(1 − w) a + w b`;
//! - no triangle is flipped (the shapes are star-shaped about the origin);
//! - texels outside the region are the template's; inside, the texel gradients follow the
//!   blended gradients; across the region's border band the gradient error is far below the
//!   naive masked blend's.
//!
//! `RETEX_ELASTIFACE_OUT` keeps the GLBs for `retex preview`.

use std::collections::HashMap;

use retex::engine::asset::{Asset, DecodedImage};
use retex::engine::texture::bake::rasterize_uv_layout;
use serde_json::{json, Value};

use crate::common::assert_validator_clean;
use crate::elastiface_common::*;

const STRETCHES: [[f64; 3]; 2] = [[1.4, 1.0, 0.8], [0.8, 1.2, 1.5]];

fn tcolor(u: f64, v: f64) -> [f64; 3] {
    [0.8, 0.1 + 0.5 * u, 0.7 - 0.5 * v]
}

fn constraints(stretch: [f64; 3], blend: Value) -> Value {
    let mut c = sphere_constraints(stretch, 9);
    c["params"] = json!({ "blend": blend });
    c["output"] = json!({"texture_size": 256, "padding": 4});
    c
}

fn target_glb(stretch: [f64; 3]) -> Vec<u8> {
    let (tgt, _) = stretched_sphere(stretch);
    let png = texture_png(256, 128, |u, v| sphere_color(turn(sphere_point(u, v))));
    mesh_glb(&tgt, Some(&png), 1.0)
}

fn keep(name: &str, model: &[u8]) {
    if let Ok(dir) = std::env::var("RETEX_ELASTIFACE_OUT") {
        std::fs::write(std::path::Path::new(&dir).join(name), model).unwrap();
    }
}

/// Welded ids by (rounded) position.
fn weld(p: &[[f32; 3]]) -> (Vec<usize>, usize) {
    let mut ids = HashMap::new();
    let w = p
        .iter()
        .map(|q| {
            let key = q.map(|c| (c as f64 * 1e6).round() as i64);
            let n = ids.len();
            *ids.entry(key).or_insert(n)
        })
        .collect();
    (w, ids.len())
}

/// `(L x)_i = Σ_j ½(cot α + cot β)(x_j − x_i)` on the welded template.
fn cotan_laplacian(mesh: &MeshData, x: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let (ids, n) = weld(&mesh.positions);
    let mut a = vec![[0.0f64; 3]; n];
    for (v, &i) in ids.iter().enumerate() {
        a[i] = mesh.positions[v].map(f64::from);
    }
    let mut xs = vec![[0.0f64; 3]; n];
    for (v, &i) in ids.iter().enumerate() {
        xs[i] = x[v];
    }
    let mut out = vec![[0.0f64; 3]; n];
    for t in mesh.indices.chunks(3) {
        let c = [0, 1, 2].map(|k| ids[t[k] as usize]);
        if c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
            continue;
        }
        for k in 0..3 {
            let (o, i, j) = (c[k], c[(k + 1) % 3], c[(k + 2) % 3]);
            let e1 = sub(a[i], a[o]);
            let e2 = sub(a[j], a[o]);
            let cr = cross(e1, e2);
            let cot = dot(e1, e2) / dot(cr, cr).sqrt();
            for d in 0..3 {
                let f = 0.5 * cot * (xs[j][d] - xs[i][d]);
                out[i][d] += f;
                out[j][d] -= f;
            }
        }
    }
    ids.iter().map(|&i| out[i]).collect()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// The fitted positions (w = 1 output) brought back by the reported initial similarity.
fn fitted_in_template_frame(out: &TransferOutputLite) -> Vec<[f64; 3]> {
    let s = &out.report["initial_similarity"];
    let r: Vec<Vec<f64>> = serde_json::from_value(s["rotation"].clone()).unwrap();
    let t: Vec<f64> = serde_json::from_value(s["translation"].clone()).unwrap();
    let scale = s["scale"].as_f64().unwrap();
    out.positions
        .iter()
        .map(|q| {
            let d: Vec<f64> = (0..3).map(|k| q[k] as f64 - t[k]).collect();
            std::array::from_fn(|c| (0..3).map(|k| r[k][c] * d[k]).sum::<f64>() / scale)
        })
        .collect()
}

struct TransferOutputLite {
    positions: Vec<[f32; 3]>,
    report: Value,
    asset: Asset,
}

fn run(s: &[u8], t: &[u8], c: Value, name: &str) -> TransferOutputLite {
    let out = run_glbs(s, t, c).expect("transfer");
    assert_validator_clean(&out.model, name);
    keep(name, &out.model);
    let asset = output_asset(&out);
    TransferOutputLite {
        positions: asset.primitives[0].positions.clone(),
        report: out.report.method_report.clone(),
        asset,
    }
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

fn upper_faces(mesh: &MeshData) -> Vec<u32> {
    (0..mesh.indices.len() / 3)
        .filter(|&f| {
            let z: f64 = (0..3)
                .map(|k| mesh.positions[mesh.indices[3 * f + k] as usize][2] as f64)
                .sum();
            z > 0.0
        })
        .map(|f| f as u32)
        .collect()
}

/// Per template vertex: 1 on the listed faces' vertices (welded), else 0.
fn face_weights(mesh: &MeshData, faces: &[u32]) -> Vec<f64> {
    let (ids, n) = weld(&mesh.positions);
    let mut on = vec![false; n];
    for &f in faces {
        for k in 0..3 {
            on[ids[mesh.indices[3 * f as usize + k] as usize]] = true;
        }
    }
    ids.iter().map(|&i| f64::from(u8::from(on[i]))).collect()
}

/// Checks fixed vertices, the Laplacian formula at free vertices (when `omega` is exact) and
/// flips; returns (fixed error, formula residual, naive residual) relative to the diagonal.
fn check_geometry(
    mesh: &MeshData,
    out: &[[f32; 3]],
    fitted: &[[f64; 3]],
    omega: &[f64],
    label: &str,
) -> (f64, f64, f64) {
    let diag = diagonal(&mesh.positions);
    let a: Vec<[f64; 3]> = mesh.positions.iter().map(|p| p.map(f64::from)).collect();
    let x: Vec<[f64; 3]> = out.iter().map(|p| p.map(f64::from)).collect();
    let naive: Vec<[f64; 3]> = (0..a.len())
        .map(|v| std::array::from_fn(|k| (1.0 - omega[v]) * a[v][k] + omega[v] * fitted[v][k]))
        .collect();
    let (la, lb, lx, ln) = (
        cotan_laplacian(mesh, &a),
        cotan_laplacian(mesh, fitted),
        cotan_laplacian(mesh, &x),
        cotan_laplacian(mesh, &naive),
    );
    let (mut fixed, mut res, mut res_naive) = (0.0f64, 0.0f64, 0.0f64);
    let mut worst = 0;
    for v in 0..a.len() {
        if omega[v] == 0.0 {
            let m = norm(sub(x[v], a[v])) / diag;
            if m > fixed {
                (fixed, worst) = (m, v);
            }
            continue;
        }
        let want: [f64; 3] =
            std::array::from_fn(|k| (1.0 - omega[v]) * la[v][k] + omega[v] * lb[v][k]);
        res = res.max(norm(sub(lx[v], want)) / diag);
        res_naive = res_naive.max(norm(sub(ln[v], want)) / diag);
    }
    let flipped = mesh
        .indices
        .chunks(3)
        .filter(|t| {
            let p = [0, 1, 2].map(|k| x[t[k] as usize]);
            let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
            let c: [f64; 3] = std::array::from_fn(|k| p[0][k] + p[1][k] + p[2][k]);
            norm(n) > 1e-12 * diag * diag && dot(n, c) <= 0.0
        })
        .count();
    eprintln!(
        "region {label}: weight-0 vertices moved ≤ {fixed:.1e}, Laplacian residual at free \
         vertices ≤ {res:.2e} (naive masked blend {res_naive:.2e}) of the diagonal, {flipped} \
         flipped"
    );
    assert!(
        fixed < 1e-6,
        "{label}: fixed vertices moved {fixed} (worst: vertex {worst} at {:?})",
        a[worst]
    );
    assert_eq!(flipped, 0, "{label}: flipped triangles");
    (fixed, res, res_naive)
}

fn template_glb(mesh: &MeshData) -> Vec<u8> {
    mesh_glb(mesh, Some(&texture_png(256, 128, tcolor)), 1.0)
}

#[test]
fn elastiface_region_geometry_is_the_poisson_blend() {
    let mesh = uv_sphere(48, 24, |p| p);
    let s = template_glb(&mesh);
    let upper = upper_faces(&mesh);
    let all: Vec<u32> = (0..(mesh.indices.len() / 3) as u32).collect();
    let diag = diagonal(&mesh.positions);
    for stretch in STRETCHES {
        let t = target_glb(stretch);
        let full = run(
            &s,
            &t,
            constraints(stretch, json!({"weight": 1.0})),
            "region_w1.glb",
        );
        let fitted = fitted_in_template_frame(&full);
        for w in [0.5, 1.0] {
            let label = format!("stretch {stretch:?} w {w}");
            // The hemisphere, unfeathered: weights known exactly.
            let r = face_weights(&mesh, &upper);
            let omega: Vec<f64> = r.iter().map(|x| w * x).collect();
            let c = constraints(
                stretch,
                json!({"weight": w, "region": upper, "feather_rings": 0}),
            );
            let out = run(&s, &t, c, "region_faces.glb");
            let (ids, _) = weld(&mesh.positions);
            let mut fixed: Vec<usize> = (0..r.len())
                .filter(|&v| r[v] == 0.0)
                .map(|v| ids[v])
                .collect();
            fixed.sort_unstable();
            fixed.dedup();
            assert_eq!(out.report["region"]["fixed_vertices"], json!(fixed.len()));
            let (_, res, naive) = check_geometry(
                &mesh,
                &out.positions,
                &fitted,
                &omega,
                &format!("{label} hemisphere"),
            );
            assert!(
                res < 1e-5 && res < 0.01 * naive,
                "{label}: Laplacian residual {res} (naive {naive})"
            );
            // Feathered (default 2 rings): fixed vertices and flips only.
            let c = constraints(stretch, json!({"weight": w, "region": upper}));
            let out = run(&s, &t, c, "region_feathered.glb");
            check_geometry(
                &mesh,
                &out.positions,
                &fitted,
                &omega,
                &format!("{label} feathered"),
            );
            // Every face: the linear blend in the template's placement.
            let c = constraints(stretch, json!({"weight": w, "region": all}));
            let out = run(&s, &t, c, "region_all.glb");
            let mut err = 0.0f64;
            for v in 0..mesh.positions.len() {
                let want: [f64; 3] = std::array::from_fn(|k| {
                    (1.0 - w) * mesh.positions[v][k] as f64 + w * fitted[v][k]
                });
                err = err.max(norm(sub(out.positions[v].map(f64::from), want)) / diag);
            }
            eprintln!("region {label} all faces: max distance to the linear blend {err:.2e} of the diagonal");
            assert!(
                err < 1e-5,
                "{label}: region = all differs from the linear blend by {err}"
            );
        }
    }
}

fn base_image(asset: &Asset) -> DecodedImage {
    let tex = asset.materials[0]
        .base_color_texture
        .expect("baked texture");
    let image = asset.textures[tex.texture].image.expect("image");
    (*asset.images[image].decoded.clone().expect("decoded")).clone()
}

/// Per texel (row-major, `None` if uncovered): UV and region weight ρ (`r` interpolated).
fn texel_weights(mesh: &MeshData, r: &[f64], size: u32) -> Vec<Option<([f64; 2], f64)>> {
    let uvs = mesh.uvs.as_ref().unwrap();
    let tris: Vec<[u32; 3]> = mesh.indices.chunks(3).map(|t| [t[0], t[1], t[2]]).collect();
    let uv_tris: Vec<[[f32; 2]; 3]> = tris.iter().map(|t| t.map(|v| uvs[v as usize])).collect();
    let map = rasterize_uv_layout(&uv_tris, size, size);
    map.hits
        .iter()
        .map(|h| {
            h.map(|h| {
                let t = tris[h.triangle as usize];
                let b = h.bary.map(f64::from);
                let uv = [0, 1].map(|d| (0..3).map(|k| b[k] * uvs[t[k] as usize][d] as f64).sum());
                let rho = (0..3).map(|k| b[k] * r[t[k] as usize]).sum();
                (uv, rho)
            })
        })
        .collect()
}

fn lin_px(img: &DecodedImage, i: usize) -> [f64; 3] {
    let p = img.pixels[i];
    [linear(p[0]), linear(p[1]), linear(p[2])]
}

#[test]
fn elastiface_region_texture_is_the_gradient_domain_blend() {
    let mesh = uv_sphere(48, 24, |p| p);
    let s = template_glb(&mesh);
    let upper = upper_faces(&mesh);
    let r = face_weights(&mesh, &upper);
    let size = 256u32;
    let texels = texel_weights(&mesh, &r, size);
    for stretch in STRETCHES {
        let t = target_glb(stretch);
        let full = run(
            &s,
            &t,
            constraints(stretch, json!({"weight": 1.0})),
            "region_w1.glb",
        );
        let relaid = base_image(&full.asset);
        for w in [0.5, 0.8] {
            let label = format!("stretch {stretch:?} w {w}");
            let c = constraints(
                stretch,
                json!({"weight": w, "region": upper, "feather_rings": 0}),
            );
            let out = run(&s, &t, c, "region_texture.glb");
            let img = base_image(&out.asset);
            assert_eq!((img.width, relaid.width), (size, size));
            // Outside: the template.
            let (mut out_err, mut out_max, mut n_out) = (0.0f64, 0u8, 0usize);
            for (i, tx) in texels.iter().enumerate() {
                let Some((uv, rho)) = tx else { continue };
                if *rho > 0.0 {
                    continue;
                }
                let a = tcolor(uv[0], uv[1]);
                for d in 0..3 {
                    let e = img.pixels[i][d].abs_diff(srgb8(a[d]));
                    out_err += e as f64;
                    out_max = out_max.max(e);
                }
                n_out += 1;
            }
            let out_err = out_err / (3 * n_out) as f64;
            let sz = size as usize;
            let inside = |r: f64| r >= 1.0 - 1e-6;
            // Template, re-laid and result colours, and ρ.
            type Texel = ([f64; 3], [f64; 3], [f64; 3], f64);
            let at = |i: usize| -> Option<Texel> {
                let (uv, rho) = texels[i]?;
                Some((
                    tcolor(uv[0], uv[1]),
                    lin_px(&relaid, i),
                    lin_px(&img, i),
                    rho,
                ))
            };
            // Interior: pairs 8 texels apart (the 8-bit rounding would drown 1-texel
            // differences), both inside, against the blended guidance (there the difference of
            // the linear blend); baseline: the template's own difference.
            let (mut int_se, mut int_base, mut n_int) = (0.0f64, 0.0f64, 0usize);
            for i in 0..texels.len() {
                for j in [i + 8, i + 8 * sz] {
                    if j >= texels.len() || (j == i + 8 && i % sz + 8 >= sz) {
                        continue;
                    }
                    let (Some((ap, bp, fp, rp)), Some((aq, bq, fq, rq))) = (at(i), at(j)) else {
                        continue;
                    };
                    if !(inside(rp) && inside(rq)) {
                        continue;
                    }
                    for d in 0..3 {
                        let g = (1.0 - w) * (ap[d] - aq[d]) + w * (bp[d] - bq[d]);
                        int_se += (fp[d] - fq[d] - g).powi(2);
                        int_base += (ap[d] - aq[d] - g).powi(2);
                        n_int += 1;
                    }
                }
            }
            // The step across the border: along every texel row and column (both ways), from an outside texel
            // through the band (0 < ρ < 1) to the first inside texel, the change of the colour
            // minus the sum of the guidance along that path; for the result and for the naive
            // masked blend (1 − wρ)a + wρb.
            let naive = |a: f64, b: f64, rho: f64| (1.0 - w * rho) * a + w * rho * b;
            let (mut step, mut step_naive, mut n_step) = (0.0f64, 0.0f64, 0usize);
            let mut lines: Vec<Vec<usize>> = Vec::new();
            for k in 0..sz {
                let row: Vec<usize> = (0..sz).map(|x| k * sz + x).collect();
                let col: Vec<usize> = (0..sz).map(|y| y * sz + k).collect();
                for line in [row, col] {
                    lines.push(line.iter().rev().copied().collect());
                    lines.push(line);
                }
            }
            for line in &lines {
                let mut start: Option<usize> = None;
                let mut prev: Option<usize> = None;
                let mut sum = [0.0f64; 3];
                for &i in line {
                    let Some((a, b, f, rho)) = at(i) else {
                        (start, prev) = (None, None);
                        continue;
                    };
                    if let (Some(s0), Some(p)) = (start, prev) {
                        let (pa, pb, _, prho) = at(p).unwrap();
                        let o = w * 0.5 * (rho + prho);
                        for d in 0..3 {
                            sum[d] += (1.0 - o) * (a[d] - pa[d]) + o * (b[d] - pb[d]);
                        }
                        if inside(rho) {
                            let (sa, sb, sf, _) = at(s0).unwrap();
                            for d in 0..3 {
                                step += (f[d] - sf[d] - sum[d]).abs();
                                step_naive +=
                                    (naive(a[d], b[d], rho) - naive(sa[d], sb[d], 0.0) - sum[d])
                                        .abs();
                                n_step += 1;
                            }
                            start = None;
                        }
                    }
                    if rho == 0.0 {
                        start = Some(i);
                        sum = [0.0; 3];
                    } else if inside(rho) {
                        start = None;
                    }
                    prev = Some(i);
                }
            }
            let int_rms = (int_se / n_int as f64).sqrt();
            let int_base = (int_base / n_int as f64).sqrt();
            let (step, step_naive) = (
                255.0 * step / n_step as f64,
                255.0 * step_naive / n_step as f64,
            );
            eprintln!(
                "region texture {label}: outside {out_err:.2} levels mean, {out_max} max over \
                 {n_out} texels; interior 8-texel differences rms error {int_rms:.5} (template's \
                 own {int_base:.5}, {n_int} pairs); step across the border {step:.2} (naive \
                 masked blend {step_naive:.2}) linear × 255, mean over {n_step} column crossings"
            );
            assert!(
                out_err < 0.6 && out_max <= 2,
                "{label}: outside differs from the template"
            );
            assert!(
                int_rms < 0.65 * int_base,
                "{label}: interior {int_rms} vs {int_base}"
            );
            assert!(
                step < 0.25 * step_naive,
                "{label}: step {step} vs naive {step_naive}"
            );
        }
    }
}

#[test]
fn elastiface_region_from_a_color0_channel() {
    let mesh = uv_sphere(48, 24, |p| p);
    let r: Vec<f64> = mesh
        .positions
        .iter()
        // z ≤ 1e-6 gives 0 exactly, so that the seam copies (z = ±1e-16) agree.
        .map(|p| match p[2] as f64 {
            z if z <= 1e-6 => 0.0,
            z => (1.5 * z).min(1.0) as f32 as f64,
        })
        .collect();
    let colors: Vec<f32> = r.iter().flat_map(|&x| [x as f32, 0.5, 0.5, 1.0]).collect();
    let s = mesh_glb_with(&mesh, None, 1.0, &[("COLOR_0", 4, colors)]);
    let size = 256;
    let texels = texel_weights(&mesh, &r, size);
    for stretch in STRETCHES {
        let t = target_glb(stretch);
        let full = run(
            &s,
            &t,
            constraints(stretch, json!({"weight": 1.0})),
            "region_w1.glb",
        );
        let fitted = fitted_in_template_frame(&full);
        let w = 0.8;
        let c = constraints(stretch, json!({"weight": w, "region": {"channel": "r"}}));
        let out = run(&s, &t, c, "region_channel.glb");
        let omega: Vec<f64> = r.iter().map(|x| w * x).collect();
        let label = format!("channel r, stretch {stretch:?} w {w}");
        let (_, res, naive) = check_geometry(&mesh, &out.positions, &fitted, &omega, &label);
        assert!(
            res < 1e-5 && res < 0.01 * naive,
            "{label}: residual {res} (naive {naive})"
        );
        let img = base_image(&out.asset);
        let want = [0.0, 0.5, 0.5].map(srgb8);
        let mut max = 0u8;
        for (i, tx) in texels.iter().enumerate() {
            if let Some((_, 0.0)) = tx {
                for d in 0..3 {
                    max = max.max(img.pixels[i][d].abs_diff(want[d]));
                }
            }
        }
        eprintln!("region {label}: texels outside the region within {max} levels of the template");
        assert!(max <= 1, "{label}: outside texels {max} levels off");
    }
}

#[test]
fn elastiface_region_refuses_bad_regions() {
    let mesh = uv_sphere(16, 8, |p| p);
    let s = template_glb(&mesh);
    let stretch = STRETCHES[0];
    let t = target_glb(stretch);
    let faces = (mesh.indices.len() / 3) as u32;
    for (region, words) in [
        (
            json!({"channel": "g"}),
            "no source primitive has COLOR_0".to_string(),
        ),
        (
            json!([0, faces]),
            format!("face index {faces} is out of range"),
        ),
        (json!([]), "empty".to_string()),
        (json!({"channel": "x"}), String::new()),
        (json!("r"), String::new()),
    ] {
        let err = run_glbs(
            &s,
            &t,
            constraints(stretch, json!({"weight": 0.5, "region": region})),
        )
        .expect_err("refused")
        .to_string();
        eprintln!("{region}: {err}");
        assert!(
            err.contains("params.blend.region") && err.contains(&words),
            "{region}: {err}"
        );
    }
}
