//! MeshMatch (Chen et al. 2012) end to end on Spot (`tests/data`): self transfer with
//! correspondences against the ground truth, patch fidelity, texture by example (§5.3), real
//! transfers (shared assets, ignored by default) that pass the validator with turntable previews,
//! the NNF artifact, determinism with any thread count, and clear errors for bad parameters.

use crate::common;

use crate::common::{assert_validator_clean, load_bytes, load_path, shared_asset, test_data};
use crate::meshmatch_common::{capsule, color_statistics, colored_points, glb_of, run_bytes};
use retex::engine::methods::meshmatch::nnf_file::NnfFile;
use retex::engine::texture::preview::{render_turntable, PreviewParams};

const SPOT: &str = "src_spot_keenan/spot_textured_derived.glb";
const SPOT_REMESHED: &str = "tgt_spot_remeshed_odedstein/spot_derived.glb";

/// Name and bytes of a model in `tests/data`.
fn bytes(rel: &str) -> (String, Vec<u8>) {
    file_bytes(&test_data(rel))
}

/// Name and bytes of a model in the shared assets (only in ignored tests).
pub fn shared_bytes(rel: &str) -> (String, Vec<u8>) {
    file_bytes(&shared_asset(rel))
}

fn file_bytes(p: &std::path::Path) -> (String, Vec<u8>) {
    (
        p.file_name().unwrap().to_string_lossy().into_owned(),
        std::fs::read(p).unwrap(),
    )
}

/// Writes a turntable preview of an output model into `target/test-outputs`.
fn preview(model: &[u8], name: &str) {
    let asset = load_bytes(model, name);
    let img = render_turntable(
        &asset,
        &PreviewParams {
            views: 6,
            size: 192,
            ..Default::default()
        },
    )
    .unwrap();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(format!("{name}.png")), img.to_png()).unwrap();
}

/// Mean of each vertex's value over its 2-ring (a low-pass filter on the mesh).
fn low_pass(values: &[f32], triangles: &[[u32; 3]]) -> Vec<f32> {
    let n = values.len();
    let mut ring: Vec<Vec<u32>> = vec![Vec::new(); n];
    for t in triangles {
        for a in 0..3 {
            for b in 0..3 {
                if a != b {
                    ring[t[a] as usize].push(t[b]);
                }
            }
        }
    }
    let mut v = values.to_vec();
    for _ in 0..2 {
        v = (0..n)
            .map(|i| {
                let s: f32 = ring[i].iter().map(|&j| v[j as usize]).sum::<f32>() + v[i];
                s / (ring[i].len() + 1) as f32
            })
            .collect();
    }
    v
}

fn pearson(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len() as f64;
    let ma = a.iter().map(|x| *x as f64).sum::<f64>() / n;
    let mb = b.iter().map(|x| *x as f64).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (*x as f64 - ma, *y as f64 - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    sab / (saa * sbb).sqrt()
}

/// Eight correspondences at the extremes of Spot along fixed directions (nose, tail, horn tips,
/// sides, hooves); the remeshed target is in the same frame, so each point maps to itself.
fn spot_correspondences() -> serde_json::Value {
    let spot = load_path(&test_data(SPOT));
    let p = &spot.primitives[0].positions;
    let dirs: [[f32; 3]; 8] = [
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.3],
        [1.0, 0.2, 0.0],
        [-1.0, 0.2, 0.0],
        [0.6, -1.0, -0.6],
        [-0.6, -1.0, 0.6],
    ];
    let picks: Vec<serde_json::Value> = dirs
        .iter()
        .map(|d| {
            let best = p
                .iter()
                .max_by(|a, b| {
                    let da = a[0] * d[0] + a[1] * d[1] + a[2] * d[2];
                    let db = b[0] * d[0] + b[1] * d[1] + b[2] * d[2];
                    da.total_cmp(&db)
                })
                .unwrap();
            serde_json::json!({"source": {"point": best}, "target": {"point": best}})
        })
        .collect();
    serde_json::Value::Array(picks)
}

/// Self transfer: Spot onto its isotropic remesh with 8 correspondences. The ground truth is
/// `project` on the same pair (the remesh lies within 0.66% mean / 3.9% max of the original).
/// MeshMatch synthesizes rather than copies, so the comparison is of low-passed luminance:
/// measured correlation 0.85 with the default shape weight (threshold 0.6; 0.73 before the vote's
/// histogram matching with affinities) and 0.92 with shape weight 4 (threshold 0.78), with 16K
/// samples; the same synthesis without shape features (the
/// layout left free: the right colours in the wrong places) measures 0.01 and must fail the
/// threshold. Patch fidelity is reported and bounded: coherence within 3× the source's own
/// self-match distance, completeness over 50%. `project` is the ground truth of a self
/// transfer, so no threshold here can fail it; the stripes and texture-update tests do (it
/// stretches the period ×1.83 and ×1.80).
#[test]
fn self_transfer_with_correspondences_follows_the_ground_truth() {
    let corr = spot_correspondences();
    let (sn, sb) = bytes(SPOT);
    let (tn, tb) = bytes(SPOT_REMESHED);
    let run_with = |method: &str, shape_weight: f32, features: &str| {
        run_bytes(
            (&sn, sb.clone()),
            (&tn, tb.clone()),
            serde_json::json!({"version": 1, "method": method, "seed": 3,
            "correspondences": corr,
            "output": {"vertex_colors": true},
            "params": if method == "meshmatch" {
                serde_json::json!({"samples": 16384, "snap_tolerance": 0.06, "measure_fidelity": true,
                                   "shape_weight": shape_weight, "shape_features": features})
            } else {
                serde_json::json!({"snap_tolerance": 0.06})
            }}),
        )
    };
    let out = |method: &str, shape_weight: f32| run_with(method, shape_weight, "auto");
    let gt = out("project", 0.0);
    let b = colored_points(&gt.model);
    let lum = |pts: &[([f32; 3], [f32; 3])]| -> Vec<f32> {
        pts.iter()
            .map(|(_, c)| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
            .collect()
    };
    let strong = out("meshmatch", 4.0);
    let target = load_bytes(&strong.model, "mm.glb");
    let tris = &target.primitives[0].triangles;
    let a = colored_points(&strong.model);
    assert_eq!(a.len(), b.len());
    let r_strong = pearson(&low_pass(&lum(&a), tris), &low_pass(&lum(&b), tris));
    preview(&strong.model, "meshmatch_self_spot_shape4");
    let mm = out("meshmatch", 2.0);
    assert_validator_clean(&mm.model, "meshmatch_self_spot.glb");
    preview(&mm.model, "meshmatch_self_spot");
    let a = colored_points(&mm.model);
    let r = pearson(&low_pass(&lum(&a), tris), &low_pass(&lum(&b), tris));
    let f = &mm.report.method_report["synthesis"]["fidelity"];
    eprintln!(
        "low-passed luminance correlation {r:.3} (shape weight 4: {r_strong:.3}); fidelity {f}"
    );
    assert!(r >= 0.6, "correlation {r:.3}");
    // The negative control: the same synthesis without shape features draws the source's
    // patches with no regard to where they belong, and the threshold must fail it.
    let free = run_with("meshmatch", 2.0, "none");
    let a = colored_points(&free.model);
    let r_free = pearson(&low_pass(&lum(&a), tris), &low_pass(&lum(&b), tris));
    eprintln!("without shape features (negative control): correlation {r_free:.3}");
    assert!(r_free < 0.6, "negative control correlation {r_free:.3}");
    assert!(
        r_strong >= 0.78,
        "correlation with shape weight 4: {r_strong:.3}"
    );
    let ratio = f["ratio"].as_f64().unwrap();
    let completeness = f["completeness"].as_f64().unwrap();
    assert!(ratio.is_finite() && ratio <= 3.0, "{f}");
    assert!(completeness >= 0.5, "{f}");
}

/// Texture by example (§5.3): a capsule painted with stripes on its left half (x < 2) and plain
/// grey elsewhere; the mask lists the painted triangles, or (second run) is COLOR_0's alpha. The
/// right half gets stripes drawn from the painted half (most values near black or white, none of
/// the original grey left), and the painted half keeps its colours.
#[test]
fn by_example_fills_the_unpainted_part_with_the_painted_texture() {
    let (p, t) = capsule(
        0.5,
        &(0..=80).map(|i| i as f32 * 0.05).collect::<Vec<_>>(),
        48,
        |x| x,
    );
    let stripe = |x: f32| {
        if (x * 2.5).fract() < 0.5 {
            0.05
        } else {
            0.9
        }
    };
    let colors: Vec<[f32; 4]> = p
        .iter()
        .map(|q| {
            let g = if q[0] < 2.0 { stripe(q[0]) } else { 0.5 };
            [g, g, g, if q[0] < 2.0 { 1.0 } else { 0.0 }]
        })
        .collect();
    let painted: Vec<usize> = t
        .iter()
        .enumerate()
        .filter(|(_, tri)| tri.iter().all(|&v| p[v as usize][0] < 2.0))
        .map(|(i, _)| i)
        .collect();
    let model = glb_of(&p, &t, Some(&colors));
    for (name, example) in [
        (
            "meshmatch_by_example",
            serde_json::json!({"faces": [{"mesh": 0, "primitive": 0, "triangles": painted}]}),
        ),
        (
            "meshmatch_by_example_alpha",
            serde_json::json!({"vertex_color": {"channel": "a", "threshold": 0.5}}),
        ),
    ] {
        let out = run_bytes(
            ("painted.glb", model.clone()),
            ("painted.glb", model.clone()),
            serde_json::json!({"version": 1, "method": "meshmatch",
            "output": {"vertex_colors": true},
            "params": {"samples": 12000, "scale": "world", "shape_features": "none",
                       "example": example}}),
        );
        assert_validator_clean(&out.model, &format!("{name}.glb"));
        preview(&out.model, name);
        let pts = colored_points(&out.model);
        let grey = |c: [f32; 3]| (c[0] + c[1] + c[2]) / 3.0;
        let right: Vec<f32> = pts
            .iter()
            .filter(|(q, _)| q[0] > 2.6)
            .map(|(_, c)| grey(*c))
            .collect();
        let left_err: Vec<f32> = pts
            .iter()
            .filter(|(q, _)| q[0] < 1.5 && q[0] > 0.2)
            .map(|(q, c)| (grey(*c) - stripe(q[0])).abs())
            .collect();
        let left: Vec<f32> = pts
            .iter()
            .filter(|(q, _)| q[0] < 1.5 && q[0] > 0.2)
            .map(|(_, c)| grey(*c))
            .collect();
        let share = |v: &[f32], f: &dyn Fn(f32) -> bool| {
            v.iter().filter(|g| f(**g)).count() as f64 / v.len() as f64
        };
        // Stripe edges are box-filtered into greys in the painted part too: compare with it.
        let mid_left = share(&left, &|g| (g - 0.5).abs() < 0.05);
        let extreme =
            right.iter().filter(|g| (**g - 0.5).abs() > 0.25).count() as f64 / right.len() as f64;
        let mid =
            right.iter().filter(|g| (**g - 0.5).abs() < 0.05).count() as f64 / right.len() as f64;
        let dark = right.iter().filter(|g| **g < 0.3).count() as f64 / right.len() as f64;
        let kept = left_err.iter().filter(|e| **e < 0.1).count() as f64 / left_err.len() as f64;
        eprintln!("right half: {extreme:.3} near black/white, {mid:.3} grey (painted half {mid_left:.3}), {dark:.3} dark; left kept {kept:.3}");
        assert!(
            extreme >= 0.7,
            "only {extreme:.3} of the synthesized part is striped"
        );
        // Before the transfer all of it was exactly 0.5; what stays near 0.5 are stripe edges
        // (copied from synthesis vertices between two stripes) and the rounded cap: measured 0.088.
        assert!(
            mid <= mid_left + 0.15,
            "{mid:.3} of the synthesized part is grey (painted part {mid_left:.3})"
        );
        assert!(
            (0.2..=0.8).contains(&dark),
            "dark share {dark:.3}: both stripe colours must appear"
        );
        assert!(kept >= 0.9, "painted part kept at only {kept:.3}");
        let r = &out.report.method_report;
        assert!(r["painted_samples"].as_u64().unwrap() > 0, "{r}");
    }
}

/// Real pairs: Spot onto the cat (no UVs: COLOR_0 on a refined copy) and Blub onto the fish
/// remesh. Both pass the validator; previews are written; the output is drawn from the source's
/// palette (at least 90% of the output colours within 0.08, linear RGB, of some source texel);
/// every colour cluster of the source (k-means, k = 5, sRGB, area-uniform samples) covering at
/// least 5% of it keeps 0.5-2× its share of the output and the shares' total variation is small
/// (issue 14's statistics metric; bounds below), which a constant colour fails (the palette
/// check alone passed with one); and the NNF artifact decodes and agrees with the report.
#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn real_pairs_validate_and_keep_the_source_palette() {
    for (src, tgt, name) in [
        (
            SPOT,
            "tgt_cat_odedstein/cat-low-resolution_derived.glb",
            "meshmatch_spot_cat",
        ),
        (
            "src_blub_keenan/blub_textured_derived.glb",
            "tgt_fish_remeshed_odedstein/fish_low_resolution_derived.glb",
            "meshmatch_blub_fish",
        ),
    ] {
        let (sn, sb) = shared_bytes(src);
        let (tn, tb) = shared_bytes(tgt);
        let out = run_bytes(
            (&sn, sb.clone()),
            (&tn, tb),
            // COLOR_0 is read back: keep the UV-less targets' vertex colours (the default
            // `output.uv = "auto"` bakes them through a generated atlas instead).
            serde_json::json!({"version": 1, "method": "meshmatch",
                "output": {"texture_size": 512, "padding": 4, "uv": "keep"},
                "params": {"samples": 16384}}),
        );
        assert_validator_clean(&out.model, &format!("{name}.glb"));
        preview(&out.model, name);
        let pts = colored_points(&out.model);
        assert!(!pts.is_empty(), "{name}: no colours written");
        let source = load_bytes(&sb, &sn);
        let img = source.images[0].decoded.as_ref().unwrap();
        let lin = |c: u8| {
            let x = c as f32 / 255.0;
            if x <= 0.04045 {
                x / 12.92
            } else {
                ((x + 0.055) / 1.055).powf(2.4)
            }
        };
        let palette: Vec<[f32; 3]> = img
            .pixels
            .iter()
            .step_by(31)
            .map(|p| [lin(p[0]), lin(p[1]), lin(p[2])])
            .collect();
        let sample: Vec<[f32; 3]> = pts
            .iter()
            .step_by(pts.len() / 2000 + 1)
            .map(|p| p.1)
            .collect();
        let near = sample
            .iter()
            .filter(|c| {
                palette
                    .iter()
                    .any(|q| (0..3).map(|k| (c[k] - q[k]).powi(2)).sum::<f32>() < 0.08f32.powi(2))
            })
            .count() as f64
            / sample.len() as f64;
        eprintln!("{name}: {near:.3} of the output colours are within 0.08 of a source texel");
        assert!(
            near >= 0.9,
            "{name}: only {near:.3} of the colours come from the source"
        );
        let stats = color_statistics(&source, &load_bytes(&out.model, "out.glb"));
        eprintln!(
            "{name}: statistics {stats}; issue-14 target {}",
            if stats.kept() { "met" } else { "NOT met" }
        );
        // Issue 14 item 1: every colour cluster covering ≥ 5% of the source keeps 0.5-2× its
        // share (the default vote schedule with HKS features; the plain σ = 0.5 vote left Spot's
        // black at 1.1% of 9%, ratio 7.4-8.0), and the total variation between the shares stays
        // ≤ 0.12 (the issue's target). Measured 0.072 on Spot → cat and 0.039 on Blub → fish;
        // before the HKS time range was cut to a quarter, Spot → cat gave 0.120-0.121 (its
        // orange, 1.9% of Spot, on 12.7% of the cat: tail and paws matched to the horns by the
        // global times). A constant colour fails both (TV = 1 − the largest share, and a lost
        // cluster).
        assert!(
            stats.worst_ratio <= 2.0 && stats.tv <= 0.12,
            "{name}: colour statistics not kept (worst ratio ≤ 2, TV ≤ 0.12): {stats}"
        );
        let nnf = out.artifacts.iter().find(|a| a.name == "nnf.bin").unwrap();
        let file = NnfFile::decode(&nnf.bytes).expect("nnf.bin decodes");
        let r = &out.report.method_report;
        assert_eq!(
            file.target_positions.len() as u64,
            r["target_samples"].as_u64().unwrap()
        );
        assert_eq!(
            file.source_positions.len() as u64,
            r["source_samples"].as_u64().unwrap()
        );
        assert_eq!(file.nnf.source.len(), file.target_positions.len());
        assert!(file
            .nnf
            .source
            .iter()
            .all(|&s| (s as usize) < file.source_positions.len()));
        assert!(file.nnf.rotation.iter().all(|&k| (k as u32) < file.spokes));
    }
}

/// The same inputs and seed give identical bytes with 1 and 2 threads.
#[test]
fn output_is_identical_with_any_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let (sn, sb) = bytes(SPOT);
            let (tn, tb) = bytes("tgt_spot_remeshed_odedstein/spot_low_resolution_derived.glb");
            run_bytes(
                (&sn, sb),
                (&tn, tb),
                serde_json::json!({"version": 1, "method": "meshmatch", "seed": 11,
                    "output": {"texture_size": 256},
                    "params": {"samples": 4096}}),
            )
        })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.model == b.model, "outputs differ between 1 and 2 threads");
    let nnf = |o: &retex::engine::pipeline::TransferOutput| {
        o.artifacts
            .iter()
            .find(|x| x.name == "nnf.bin")
            .unwrap()
            .bytes
            .clone()
    };
    assert!(nnf(&a) == nnf(&b), "fields differ between 1 and 2 threads");
}

/// Bad parameters are errors that name the field.
#[test]
fn bad_parameters_name_their_field() {
    use retex::engine::asset::constraints::Constraints;
    use retex::engine::methods::meshmatch::MeshMatchParams;
    for (params, field) in [
        (serde_json::json!({"samples": 10}), "params.samples"),
        (serde_json::json!({"spokes": 2}), "params.spokes"),
        (serde_json::json!({"fan_radius": 0}), "params.fan_radius"),
        (serde_json::json!({"iterations": 0}), "params.iterations"),
        (serde_json::json!({"samplez": 100}), "params"),
        (
            serde_json::json!({"histogram_weight": -1}),
            "params.histogram_weight",
        ),
        (
            serde_json::json!({"histogram_weight": 1000}),
            "params.histogram_weight",
        ),
        (
            serde_json::json!({"histogram_cost": -0.5}),
            "params.histogram_cost",
        ),
        (
            serde_json::json!({"fine_histogram_cost": -0.1}),
            "params.fine_histogram_cost",
        ),
        (
            serde_json::json!({"fine_histogram_cost": 101}),
            "params.fine_histogram_cost",
        ),
        (
            serde_json::json!({"coarsest_restart_deviation": -0.1}),
            "params.coarsest_restart_deviation",
        ),
        (
            serde_json::json!({"coarsest_restart_deviation": 101}),
            "params.coarsest_restart_deviation",
        ),
        (serde_json::json!({"fan_area_weights": "yes"}), "params"),
        (
            serde_json::json!({"example": {"vertex_color": {"channel": "q", "threshold": 0.5}}}),
            "params.example",
        ),
    ] {
        let c: Constraints = serde_json::from_value(
            serde_json::json!({"version": 1, "method": "meshmatch", "params": params}),
        )
        .unwrap();
        let e = MeshMatchParams::from_constraints(&c).unwrap_err();
        assert!(e.path.starts_with(field), "{params}: {e}");
    }
    // Affinities without correspondences, and a mask triangle out of range, fail the run.
    let (sn, sb) = bytes(SPOT);
    let input = |params: serde_json::Value| {
        let c: Constraints = serde_json::from_value(
            serde_json::json!({"version": 1, "method": "meshmatch", "params": params}),
        )
        .unwrap();
        let mut blobs = retex::engine::asset::BlobSet::new();
        blobs.insert(sn.clone(), sb.clone());
        retex::engine::pipeline::transfer(
            &retex::engine::pipeline::TransferInput::pair(
                retex::engine::pipeline::ModelInput {
                    main: &sn,
                    blobs: &blobs,
                },
                retex::engine::pipeline::ModelInput {
                    main: &sn,
                    blobs: &blobs,
                },
                c,
            ),
            &retex::engine::control::Control::new(),
        )
        .map(|_| ())
        .unwrap_err()
        .to_string()
    };
    let e = input(serde_json::json!({"samples": 1024, "shape_features": "affinity"}));
    assert!(e.contains("shape_features"), "{e}");
    let e = input(serde_json::json!({"samples": 1024,
        "example": {"faces": [{"mesh": 0, "primitive": 0, "triangles": [999999]}]}}));
    assert!(e.contains("params.example.faces[0].triangles[0]"), "{e}");
}

/// Cancelling a running synthesis stops it between passes with a cancellation, not a result.
#[test]
fn cancel_stops_a_running_synthesis() {
    use retex::engine::asset::constraints::Constraints;
    use retex::engine::pipeline::{transfer, ModelInput, TransferError, TransferInput};
    let (sn, sb) = bytes(SPOT);
    let (tn, tb) = bytes(SPOT_REMESHED);
    let mut s = retex::engine::asset::BlobSet::new();
    s.insert(sn.clone(), sb);
    let mut t = retex::engine::asset::BlobSet::new();
    t.insert(tn.clone(), tb);
    let c: Constraints = serde_json::from_value(serde_json::json!(
        {"version": 1, "method": "meshmatch", "params": {"samples": 65536}}))
    .unwrap();
    let control = retex::engine::control::Control::new();
    let remote = control.clone();
    let canceller = std::thread::spawn(move || {
        // Let it get into the levels.
        let start = std::time::Instant::now();
        while !remote.progress().stage.starts_with("meshmatch level")
            && start.elapsed() < std::time::Duration::from_secs(120)
        {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        remote.cancel();
        std::time::Instant::now()
    });
    let result = transfer(
        &TransferInput::pair(
            ModelInput {
                main: &sn,
                blobs: &s,
            },
            ModelInput {
                main: &tn,
                blobs: &t,
            },
            c,
        )
        .with_limits(Default::default()),
        &control,
    );
    let asked = canceller.join().unwrap();
    let waited = asked.elapsed();
    assert!(
        matches!(result, Err(TransferError::Cancelled)),
        "{:?}",
        result.err()
    );
    eprintln!("stopped {waited:?} after the cancel");
}

/// Texture by example on a textured asset: Spot's rear (every triangle with z > −0.1, 60% of the
/// triangles) is the example; the head is synthesized from it. The painted texels come out as
/// they went in (measured: 86% of all texels within 2 levels of the original, threshold 70%),
/// and the output validates; the preview shows the head re-textured with body skin and spots.
#[test]
fn by_example_on_a_textured_asset_keeps_the_painted_texels() {
    let (name, glb) = bytes(SPOT);
    let spot = load_bytes(&glb, &name);
    let prim = &spot.primitives[0];
    let painted: Vec<usize> = prim
        .triangles
        .iter()
        .enumerate()
        .filter(|(_, t)| t.iter().all(|&v| prim.positions[v as usize][2] > -0.1))
        .map(|(i, _)| i)
        .collect();
    let out = run_bytes(
        (&name, glb.clone()),
        (&name, glb.clone()),
        serde_json::json!({"version": 1, "method": "meshmatch",
            "output": {"texture_size": 1024},
            "params": {"samples": 32768,
                       "example": {"faces": [{"mesh": prim.mesh, "primitive": prim.primitive, "triangles": painted}]}}}),
    );
    assert_validator_clean(&out.model, "meshmatch_by_example_spot.glb");
    preview(&out.model, "meshmatch_by_example_spot");
    let result = load_bytes(&out.model, "out.glb");
    let tex = |a: &retex::engine::asset::Asset| {
        let m = &a.materials[a.primitives[0].material.unwrap()];
        let t = &a.textures[m.base_color_texture.unwrap().texture];
        a.images[t.image.unwrap()].decoded.clone().unwrap()
    };
    let (before, after) = (tex(&spot), tex(&result));
    assert_eq!((before.width, before.height), (after.width, after.height));
    let same = before
        .pixels
        .iter()
        .zip(&after.pixels)
        .filter(|(a, b)| (0..3).all(|k| (a[k] as i32 - b[k] as i32).abs() <= 2))
        .count() as f64
        / before.pixels.len() as f64;
    eprintln!("{same:.3} of the texels unchanged");
    assert!(same >= 0.7, "only {same:.3} of the texels kept");
    assert!(same < 0.999, "nothing was synthesized");
    // The synthesized region (the head, well inside the unpainted part) is made of the painted
    // part's colours: its colour clusters (k-means on the painted part) are those of the painted
    // part, not one colour and not the original head.
    use crate::meshmatch_common::{area_uniform_colors_where, statistics_of_samples};
    let rear = area_uniform_colors_where(&spot, 20_000, 1, &|c| c[2] > -0.1);
    let head = |a: &retex::engine::asset::Asset| {
        area_uniform_colors_where(a, 20_000, 2, &|c| c[2] < -0.35)
    };
    let synthesized = statistics_of_samples(&rear, &head(&result));
    let original = statistics_of_samples(&rear, &head(&spot));
    let near_rear = |samples: &[[f32; 3]]| {
        samples
            .iter()
            .filter(|c| {
                rear.iter()
                    .step_by(7)
                    .any(|q| (0..3).map(|k| (c[k] - q[k]).powi(2)).sum::<f32>() < 0.06f32.powi(2))
            })
            .count() as f64
            / samples.len() as f64
    };
    let head_out = head(&result);
    let drawn = near_rear(&head_out[..2000]);
    let drawn_before = near_rear(&head(&spot)[..2000]);
    eprintln!(
        "synthesized head vs painted part: {synthesized}; original head: {original}; \
         head colours within 0.06 (sRGB) of a painted colour: {drawn:.3} (original head {drawn_before:.3})"
    );
    assert!(
        drawn >= 0.95,
        "only {drawn:.3} of the head's colours are painted colours"
    );
    // Closer to the painted part's statistics than the original head (measured TV 0.30 vs
    // 0.51). Not asserted: every painted cluster present (the head comes out 93% white, issue 14
    // item 1).
    assert!(
        synthesized.tv < original.tv,
        "head statistics not moved towards the painted part: {synthesized} vs {original}"
    );
}

/// The third mask form: a glTF image read through the base-colour UVs. The striped capsule gets
/// UVs `u = x / 4` and, as its base-colour texture, a 64 × 8 mask that is white for `u < 0.5`
/// (the painted half) and black elsewhere; `{"image": {"index": 0, "channel": "r"}}` selects the
/// same half as the faces mask, and the unpainted half is filled with stripes.
#[test]
fn by_example_with_an_image_mask() {
    use std::io::Cursor;
    let (p, t) = capsule(
        0.5,
        &(0..=80).map(|i| i as f32 * 0.05).collect::<Vec<_>>(),
        48,
        |x| x,
    );
    let stripe = |x: f32| if (x * 2.5).fract() < 0.5 { 0.05 } else { 0.9 };
    let colors: Vec<[f32; 4]> = p
        .iter()
        .map(|q| {
            let g = if q[0] < 2.0 { stripe(q[0]) } else { 0.5 };
            [g, g, g, 1.0]
        })
        .collect();
    let model = glb_of(&p, &t, Some(&colors));
    // Split the GLB, append UVs and the mask PNG, reference them.
    let jlen = u32::from_le_bytes(model[12..16].try_into().unwrap()) as usize;
    let mut json: serde_json::Value = serde_json::from_slice(&model[20..20 + jlen]).unwrap();
    let blen = u32::from_le_bytes(model[20 + jlen..24 + jlen].try_into().unwrap()) as usize;
    let mut bin = model[28 + jlen..28 + jlen + blen].to_vec();
    let uv_off = bin.len();
    for q in &p {
        // Kept inside the outer texel centres: REPEAT wrapping would blend the far column in.
        let u = (q[0] / 4.0).clamp(1.0 / 128.0, 127.0 / 128.0);
        bin.extend_from_slice(&u.to_le_bytes());
        bin.extend_from_slice(&0.5f32.to_le_bytes());
    }
    let uv_len = bin.len() - uv_off;
    let mask = image::RgbaImage::from_fn(64, 8, |x, _| {
        if (x as f32 + 0.5) / 64.0 < 0.5 {
            image::Rgba([255, 255, 255, 255])
        } else {
            image::Rgba([0, 0, 0, 255])
        }
    });
    let mut png = Vec::new();
    mask.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let png_off = bin.len();
    bin.extend_from_slice(&png);
    let png_len = png.len();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let views = json["bufferViews"].as_array_mut().unwrap();
    views.push(serde_json::json!({"buffer": 0, "byteOffset": uv_off, "byteLength": uv_len, "target": 34962}));
    views.push(serde_json::json!({"buffer": 0, "byteOffset": png_off, "byteLength": png_len}));
    let (uv_view, png_view) = (views.len() - 2, views.len() - 1);
    let accessors = json["accessors"].as_array_mut().unwrap();
    accessors.push(serde_json::json!({"bufferView": uv_view, "componentType": 5126, "count": p.len(), "type": "VEC2"}));
    let uv_accessor = accessors.len() - 1;
    json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = uv_accessor.into();
    json["buffers"][0]["byteLength"] = bin.len().into();
    json["images"] = serde_json::json!([{"bufferView": png_view, "mimeType": "image/png"}]);
    json["textures"] = serde_json::json!([{"source": 0}]);
    json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] =
        serde_json::json!({"index": 0});
    let model = common::glb(&json, &bin);
    let out = run_bytes(
        ("masked.glb", model.clone()),
        ("masked.glb", model),
        serde_json::json!({"version": 1, "method": "meshmatch",
            "output": {"vertex_colors": true},
            "params": {"samples": 12000, "scale": "world", "shape_features": "none",
                       "example": {"image": {"index": 0, "channel": "r", "threshold": 0.5}}}}),
    );
    assert_validator_clean(&out.model, "meshmatch_by_example_image.glb");
    let painted = out.report.method_report["painted_samples"]
        .as_u64()
        .unwrap() as f64;
    let total = out.report.method_report["target_samples"].as_u64().unwrap() as f64;
    // The left half (x < 2) plus its cap is half the area: measured 0.501.
    assert!(
        (0.45..0.55).contains(&(painted / total)),
        "painted share {}",
        painted / total
    );
    let right: Vec<f32> = colored_points(&out.model)
        .iter()
        .filter(|(q, _)| q[0] > 2.6)
        .map(|(_, c)| (c[0] + c[1] + c[2]) / 3.0)
        .collect();
    let extreme =
        right.iter().filter(|g| (**g - 0.5).abs() > 0.25).count() as f64 / right.len() as f64;
    eprintln!(
        "image mask: painted share {:.3}, {extreme:.3} of the right half striped",
        painted / total
    );
    assert!(extreme >= 0.7, "only {extreme:.3} striped");
}
