//! The `detail` method end to end (Berkiten et al. 2017; issue 13, "Interface"): GLBs in, the
//! target with a displacement texture, a normal map and TANGENT out, plus `displaced.glb`.
//!
//! The case: a unit icosphere whose upper half carries bumps (the detailed source, its plain
//! sphere given as the base), onto a UV sphere stretched to an ellipsoid (the target, with UVs).
//! The detail must land on the target's upper half (the height and normal features say where),
//! the maps must agree with the displaced mesh, and every output must be validator-clean.

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::export::mesh_glb;
use retex::engine::asset::{Asset, BlobSet};
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput, TransferOutput};
use serde_json::json;

use crate::common::{assert_validator_clean, load_bytes};
use crate::common_geometry::jittered_sphere;
use crate::elastiface_common::{mesh_glb as uv_mesh_glb, uv_sphere};

/// Bump height at a unit-sphere point: wavelength 0.25 in x and z, on the upper half only
/// (smooth ramp over y ∈ [0, 0.2]).
fn bumps(p: [f64; 3]) -> f64 {
    let w = std::f64::consts::TAU / 0.25;
    let ramp = (p[1] / 0.2).clamp(0.0, 1.0);
    0.02 * ramp * (w * p[0]).sin() * (w * p[2]).sin()
}

/// (detailed source, its base, the target) as GLBs.
fn sphere_case() -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    sphere_pair(32, bumps)
}

/// A unit icosphere of `frequency` displaced radially by `field` (the detailed source), the
/// plain icosphere of frequency 32 (its base) and the UV ellipsoid (1.1, 1, 0.9) (the target),
/// as GLBs.
pub(crate) fn sphere_pair(
    frequency: usize,
    field: fn([f64; 3]) -> f64,
) -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let base = jittered_sphere(1.0, 32, 0.0);
    let dense = jittered_sphere(1.0, frequency, 0.0);
    let detailed: Vec<[f32; 3]> = dense
        .positions
        .iter()
        .map(|p| {
            let q = p.map(f64::from);
            let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
            let n = q.map(|x| x / r);
            n.map(|x| (x * (1.0 + field(n))) as f32)
        })
        .collect();
    let source = mesh_glb(&detailed, &dense.faces).unwrap();
    let base = mesh_glb(&base.positions, &base.faces).unwrap();
    let target = uv_sphere(128, 64, |p| [1.1 * p[0], p[1], 0.9 * p[2]]);
    (source, base, uv_mesh_glb(&target, None, 1.0))
}

/// The sphere case's constraints: 3 levels, finest edge 0.012 × the diagonal, 512² maps.
fn sphere_constraints() -> serde_json::Value {
    json!({"version": 1, "method": "detail",
        "params": {"levels": 3, "finest_edge_length": 0.012},
        "output": {"texture_size": 512}})
}

pub(crate) fn run(
    source: &[u8],
    base: Option<&[u8]>,
    target: &[u8],
    c: serde_json::Value,
) -> TransferOutput {
    let c = Constraints::from_json(c.to_string().as_bytes()).unwrap();
    let blobs = |name: &str, bytes: &[u8]| {
        let mut b = BlobSet::new();
        b.insert(name, bytes.to_vec());
        b
    };
    let (sb, tb, bb) = (
        blobs("s.glb", source),
        blobs("t.glb", target),
        blobs("b.glb", base.unwrap_or_default()),
    );
    let mut input = TransferInput::pair(
        ModelInput {
            main: "s.glb",
            blobs: &sb,
        },
        ModelInput {
            main: "t.glb",
            blobs: &tb,
        },
        c,
    );
    if base.is_some() {
        input = input.with_source_base(ModelInput {
            main: "b.glb",
            blobs: &bb,
        });
    }
    transfer(&input, &Control::new()).unwrap()
}

pub(crate) fn std(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len().max(1) as f64;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The bytes of `displaced.glb`.
fn displaced_glb(out: &TransferOutput) -> &[u8] {
    let a = out.artifacts.iter().find(|a| a.name == "displaced.glb");
    &a.expect("displaced.glb").bytes
}

/// Std of the radial detail of `displaced.glb` over the upper (y/r ∈ [0.3, 0.95)) and lower
/// (y/r ∈ [−0.95, −0.3)) bands.
fn upper_lower_std(out: &TransferOutput) -> (f64, f64) {
    let d = radial_detail(&load_bytes(displaced_glb(out), "displaced.glb"));
    let part = |lo: f64, hi: f64| -> Vec<f64> {
        d.iter()
            .filter(|(y, _)| (lo..hi).contains(y))
            .map(|x| x.1)
            .collect()
    };
    (std(&part(0.3, 0.95)), std(&part(-0.95, -0.3)))
}

/// Radial deviation of the displaced target from the ellipsoid, per vertex, with its height.
fn radial_detail(displaced: &Asset) -> Vec<(f64, f64)> {
    let p = &displaced.primitives[0];
    p.positions
        .iter()
        .map(|q| {
            let e = [q[0] as f64 / 1.1, q[1] as f64, q[2] as f64 / 0.9];
            let r = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
            (e[1] / r, r - 1.0)
        })
        .collect()
}

#[test]
fn detail_lands_on_the_upper_half_with_maps_tangents_and_a_displaced_glb() {
    let (source, base, target) = sphere_case();
    let c = sphere_constraints();
    let t0 = std::time::Instant::now();
    let out = run(&source, Some(&base), &target, c);
    println!("detail transfer: {:.2} s", t0.elapsed().as_secs_f64());
    let report = &out.report.method_report;
    println!(
        "{}",
        serde_json::to_string_pretty(&json!({
            "levels": report["levels"], "metric": {
                "diagonal_by_group": report["metric"]["diagonal_by_group"],
                "rank": report["metric"]["rank"], "iterations": report["metric"]["iterations"]},
            "seconds": report["seconds"], "source_range": report["source_range"],
            "target_range": report["target_range"],
            "synthesis": report["synthesis"].as_array().unwrap().iter()
                .map(|l| json!([l["patch_size"], l["grid_step"], l["passes"], l["source_samples"]]))
                .collect::<Vec<_>>()}))
        .unwrap()
    );
    assert_validator_clean(&out.model, "detail_sphere.glb");
    assert_validator_clean(displaced_glb(&out), "detail_sphere_displaced.glb");

    // Detail on the upper half, not the lower (the source's bumps ramp in over y ∈ [0, 0.2]).
    let (upper, lower) = upper_lower_std(&out);
    println!("detail std: upper {upper:.5}, lower {lower:.5} (source bumps: 0.01)");
    // Measured: upper 0.00737, lower 0.00011 (the synthesis keeps about three quarters of the
    // source's std; README "detail"). With the absolute λ's zero metric and 8 candidates it was
    // 0.0053 / 0.0004.
    assert!(upper > 0.004, "upper {upper}");
    assert!(upper > 10.0 * lower, "upper {upper} lower {lower}");
    let png = |name: &str| {
        let a = out.artifacts.iter().find(|a| a.name == name).expect(name);
        let _ = std::fs::write(std::env::temp_dir().join(name), &a.bytes);
        image::load_from_memory(&a.bytes).unwrap()
    };
    let normal = png("detail_normal_material0.png").to_rgb8();
    let height = png("detail_displacement_material0.png").to_luma16();
    let (offset, scale) = (extra_f64(&out, "offset"), extra_f64(&out, "scale"));
    let (rms_map, rms_disp, rms_lower) = slopes(&normal, &height, offset, scale);
    println!("rms slope: normal map {rms_map:.3}, displacement texture {rms_disp:.3}, lower {rms_lower:.3}");
    // Measured: normal map 0.116, displacement texture 0.156 (ratio 0.74: the map interpolates
    // per-vertex gradients, the area-weighted means of the faces' constant ones, which smooths
    // the per-face slopes the texture's finite differences see), lower half 0.010.
    assert!(
        rms_disp > 0.1,
        "the displacement texture is flat: {rms_disp}"
    );
    assert!(
        (0.6..=1.4).contains(&(rms_map / rms_disp)),
        "{rms_map} vs {rms_disp}"
    );
    assert!(
        rms_lower < 0.5 * rms_map,
        "lower half {rms_lower} vs upper {rms_map}"
    );

    // The maps and the frames they are read in.
    let asset = load_bytes(&out.model, "out.glb");
    let mat = &asset.json["materials"][0];
    assert!(mat["normalTexture"]["index"].is_u64(), "{mat}");
    let extra = &mat["extras"]["retex_displacement"];
    assert!(
        extra["index"].is_u64() && extra["scale"].as_f64().unwrap() > 0.0,
        "{extra}"
    );
    let prim = &asset.json["meshes"][0]["primitives"][0]["attributes"];
    assert!(
        prim["TANGENT"].is_u64() && prim["NORMAL"].is_u64(),
        "{prim}"
    );
}

pub(crate) fn extra_f64(out: &TransferOutput, key: &str) -> f64 {
    let asset = load_bytes(&out.model, "out.glb");
    asset.json["materials"][0]["extras"]["retex_displacement"][key]
        .as_f64()
        .unwrap()
}

/// RMS slope over the upper band (colatitude 0.15π-0.4π) decoded from the normal map (tangent
/// of the tilt from the frame's normal) and from finite differences of the displacement texture
/// (world units: the ellipsoid's parametric speeds), and the normal map's over the lower band.
pub(crate) fn slopes(
    normal: &image::RgbImage,
    height: &image::ImageBuffer<image::Luma<u16>, Vec<u16>>,
    offset: f64,
    scale: f64,
) -> (f64, f64, f64) {
    let size = normal.width() as usize;
    let d = |x: usize, y: usize| {
        offset + scale * height.get_pixel(x as u32, y as u32)[0] as f64 / 65535.0
    };
    let tilt = |x: usize, y: usize| {
        let p = normal.get_pixel(x as u32, y as u32);
        let c = [0, 1, 2].map(|k| p[k] as f64 / 255.0 * 2.0 - 1.0);
        (c[0] * c[0] + c[1] * c[1]).sqrt() / c[2].max(1e-3)
    };
    let (mut map, mut disp, mut lower, mut n, mut nl) = (0.0, 0.0, 0.0, 0usize, 0usize);
    let pi = std::f64::consts::PI;
    for y in 1..size - 1 {
        let v = (y as f64 + 0.5) / size as f64;
        for x in 1..size - 1 {
            if (0.6..0.85).contains(&v) {
                lower += tilt(x, y).powi(2);
                nl += 1;
            }
            if !(0.15..0.4).contains(&v) {
                continue;
            }
            let u = (x as f64 + 0.5) / size as f64;
            let (th, ph) = (pi * v, 2.0 * pi * u);
            let pu =
                2.0 * pi * th.sin() * (1.21 * ph.cos().powi(2) + 0.81 * ph.sin().powi(2)).sqrt();
            let pv = pi
                * (1.21 * (th.cos() * ph.cos()).powi(2)
                    + th.sin().powi(2)
                    + 0.81 * (th.cos() * ph.sin()).powi(2))
                .sqrt();
            let h = 1.0 / size as f64;
            let du = (d(x + 1, y) - d(x - 1, y)) / (2.0 * h * pu);
            let dv = (d(x, y + 1) - d(x, y - 1)) / (2.0 * h * pv);
            disp += du * du + dv * dv;
            map += tilt(x, y).powi(2);
            n += 1;
        }
    }
    (
        (map / n as f64).sqrt(),
        (disp / n as f64).sqrt(),
        (lower / nl as f64).sqrt(),
    )
}

#[test]
#[ignore = "reads ../shared/assets"]
fn a_scan_onto_a_textured_head_gives_valid_maps_without_the_heads_own_features() {
    use crate::common::shared_asset;
    let read = |p: &str| std::fs::read(shared_asset(p)).unwrap();
    let source = read("tgt_nefertiti_bust_odedstein/nefertiti-lowres_derived.glb");
    let target = read("src_lee_perry_smith_head/LeePerrySmith.glb");
    let c = json!({"version": 1, "method": "detail", "output": {"texture_size": 1024}});
    let out = run(&source, None, &target, c);
    assert_validator_clean(&out.model, "detail_nefertiti_on_lps.glb");
    assert_validator_clean(displaced_glb(&out), "detail_nefertiti_on_lps_displaced.glb");
    let r = &out.report.method_report;
    let finest = r["levels"].as_array().unwrap().last().unwrap().clone();
    println!("finest level {finest}, seconds {}", r["seconds"]);
    // The scan is in mm, the head in its own units: scaled to the head's diagonal.
    let scale = r["source_scale"].as_f64().unwrap();
    assert!((0.015..0.025).contains(&scale), "scale {scale}");
    // Detail was synthesised (the displacement varies) and stays small against the head
    // (measured: -0.051 .. 0.103 on a diagonal of 12.77).
    let [lo, hi] = [0, 1].map(|k| r["target_range"][k].as_f64().unwrap());
    println!("target displacement range {lo:.4} .. {hi:.4}");
    assert!(hi - lo > 0.01 && hi - lo < 0.1 * 12.77, "{lo} .. {hi}");
    // The normal map holds only the detail: mostly near the frame's normal (measured: mean tilt
    // 3.1°, no texel above 45°), never the head's ears or nostrils as large tilts (baking the
    // displaced level's own normals put them there).
    let png = out
        .artifacts
        .iter()
        .find(|a| a.name.starts_with("detail_normal"))
        .unwrap();
    let img = image::load_from_memory(&png.bytes).unwrap().to_rgb8();
    let tilts: Vec<f64> = img
        .pixels()
        .map(|p| {
            let c = [0, 1, 2].map(|k| p[k] as f64 / 255.0 * 2.0 - 1.0);
            (c[0] * c[0] + c[1] * c[1]).sqrt().atan2(c[2]).to_degrees()
        })
        .collect();
    let steep = tilts.iter().filter(|t| **t > 45.0).count() as f64 / tilts.len() as f64;
    let mean = tilts.iter().sum::<f64>() / tilts.len() as f64;
    println!(
        "normal map: mean tilt {mean:.1}°, above 45°: {:.3} %",
        100.0 * steep
    );
    assert!(mean > 1.0 && mean < 20.0, "mean tilt {mean}");
    assert!(steep < 0.01, "{steep}");
    // The scan is no denser than the default finest level: nothing for §3.3.2 to add.
    let refinement = &r["outputs"]["refinement"];
    assert_eq!(refinement["applied"], false, "{refinement}");
    assert!(
        refinement["skipped_because"]
            .as_str()
            .is_some_and(|s| s.contains("per finest edge")),
        "{refinement}"
    );

    // A finest level 2.2 times coarser than the scan: the refinement fills the band between.
    let coarse = |refine: bool| {
        json!({"version": 1, "method": "detail", "output": {"texture_size": 1024},
            "params": {"finest_edge_length": 0.012, "refine": refine}})
    };
    let on = run(&source, None, &target, coarse(true));
    let off = run(&source, None, &target, coarse(false));
    assert_validator_clean(&on.model, "detail_nefertiti_on_lps_refined.glb");
    let refinement = &on.report.method_report["outputs"]["refinement"];
    println!("refinement {refinement}");
    assert_eq!(refinement["applied"], true, "{refinement}");
    let fine = |out: &TransferOutput| {
        let (d, n) = crate::detail_refine::decoded_displacement(out);
        let low = crate::detail_refine::gaussian_blur(&d, n, 3.0);
        let hp: Vec<f64> = d.iter().zip(&low).map(|(a, b)| a - b).collect();
        std(&hp)
    };
    let (fine_on, fine_off) = (fine(&on), fine(&off));
    println!("fine band (σ = 3 texels) std: refined {fine_on:.5}, level only {fine_off:.5}");
    // Measured: see the README ("texture-space refinement").
    assert!(fine_on > 1.5 * fine_off, "{fine_on} vs {fine_off}");
}

#[test]
fn a_displacement_texture_source_is_read_as_base_plus_map_and_bad_ones_are_named() {
    // detail's own output (the ellipsoid with its 16-bit map in extras.retex_displacement) is
    // a source: its mesh is the base, the map the detail. Onto the plain ellipsoid again.
    let (source, base, target) = sphere_case();
    let c = sphere_constraints();
    let first = run(&source, Some(&base), &target, c.clone());
    // The learned metric (default) and equal weights, which checks the map's reading. Measured:
    // learned upper 0.00533, lower 0.00011; equal weights 0.00500 / 0.00011 (0.00543 and 0.00512
    // with the former z-score floor 1e-3). With the absolute λ
    // the learned metric was zero (solver residue weighting HKS / WKS 0.41 / 0.39, symmetric
    // about the equator here) and lost the detail: 0.0002 / 0.0002. README "An absolute λ leaves
    // the learned metric zero".
    let learned = run(&first.model, None, &target, c.clone());
    let metric = &learned.report.method_report["metric"];
    assert_eq!(metric["zero_metric"], false, "{metric}");
    let (upper, lower) = upper_lower_std(&learned);
    println!("learned from the map source: upper {upper:.5}, lower {lower:.5}");
    assert!(
        upper > 2.0 * lower && upper > 0.002,
        "upper {upper} lower {lower}"
    );
    let mut c2 = c.clone();
    c2["params"]["metric"] = json!("identity");
    let second = run(&first.model, None, &target, c2);
    let r = &second.report.method_report;
    let levels = r["levels"].as_array().unwrap();
    assert!(
        levels.iter().all(|l| l["displacement_missing"] == 0),
        "{levels:?}"
    );
    assert_eq!(r["base_given"], true);
    let [lo, hi] = [0, 1].map(|k| r["source_range"][k].as_f64().unwrap());
    let first_range = &first.report.method_report["target_range"];
    println!("map source range {lo:.4} .. {hi:.4} (written: {first_range})");
    // The map's range as written (16-bit, read back bilinear at the level's vertices).
    assert!(hi - lo > 0.5 * 0.025, "{lo} .. {hi}");
    let (upper, lower) = upper_lower_std(&second);
    println!("detail std from the map source: upper {upper:.5}, lower {lower:.5}");
    assert!(
        upper > 2.0 * lower && upper > 0.002,
        "upper {upper} lower {lower}"
    );
    assert_validator_clean(&second.model, "detail_from_map.glb");

    // A map whose texture index names nothing: an error naming the source and the field.
    let mut asset = load_bytes(&first.model, "first.glb");
    asset.json["materials"][0]["extras"]["retex_displacement"]["index"] = json!(99);
    let broken = crate::common::glb(&asset.json, &asset.buffers[0]);
    let cc = Constraints::from_json(c.to_string().as_bytes()).unwrap();
    let (sb, tb) = {
        let mut a = BlobSet::new();
        a.insert("s.glb", broken);
        let mut b = BlobSet::new();
        b.insert("t.glb", target.clone());
        (a, b)
    };
    let input = TransferInput::pair(
        ModelInput {
            main: "s.glb",
            blobs: &sb,
        },
        ModelInput {
            main: "t.glb",
            blobs: &tb,
        },
        cc,
    );
    let e = transfer(&input, &Control::new()).unwrap_err().to_string();
    assert!(e.contains("retex_displacement") && e.contains("99"), "{e}");
}
