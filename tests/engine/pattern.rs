//! The `pattern` method (issue 12, Soler et al. 2002) measured from its output file: the image
//! is the input's, every face is covered, no face is flipped, texel density and anisotropy from
//! each face's UV Jacobian, seam error across patch borders normalised so that random placement
//! scores about 1; against planar, cube and random-per-patch baselines on a sphere, on a folded
//! sheet (developable: flat clusters must map isometrically) and on a real mesh.

use retex::engine::asset::constraints::Constraints;
use retex::engine::methods::Registry;
use serde_json::{json, Value};

use crate::common::{assert_validator_clean, load_bytes, shared_asset};
use crate::elastiface_common::{uv_sphere, MeshData};
use crate::pattern_common::*;

fn report(out: &retex::engine::pipeline::TransferOutput) -> Value {
    out.report.method_report.clone()
}

/// Writes the output for a preview when `RETEX_PATTERN_DUMP` names a folder.
fn dump(out: &retex::engine::pipeline::TransferOutput, name: &str) {
    if let Ok(dir) = std::env::var("RETEX_PATTERN_DUMP") {
        std::fs::write(std::path::Path::new(&dir).join(name), &out.model).unwrap();
    }
}

/// The output contract: the image bytes, coverage, no COLOR_0, validator-clean.
fn check_contract(
    out: &retex::engine::pipeline::TransferOutput,
    png: &[u8],
    mesh: &MeshData,
    name: &str,
) {
    assert_validator_clean(&out.model, name);
    let back = load_bytes(&out.model, "out.glb");
    assert_eq!(
        back.images.last().unwrap().bytes.as_slice(),
        png,
        "image passed through"
    );
    let prim = &back.primitives[0];
    assert_eq!(
        prim.triangles.len() * 3,
        mesh.indices.len(),
        "every face kept"
    );
    assert!(prim.colors.is_none(), "no COLOR_0");
    assert!(prim.tex_coords[0]
        .iter()
        .all(|uv| uv.iter().all(|c| c.is_finite())));
}

fn sphere() -> MeshData {
    uv_sphere(48, 24, |p| p)
}

#[test]
fn sphere_beats_planar_cube_and_random_baselines() {
    let mesh = sphere();
    let png = tile_png(64);
    let image = Image::decode(&png);
    let scale = 0.8;
    let ppw = 64.0 / scale;
    for (seed, seed_params) in [
        (1, json!({"scale": scale})),
        (2, json!({"scale": scale})),
        (3, json!({"scale": scale, "orientation_deg": 30})),
        (
            4,
            json!({"scale": scale, "first_face": {"primitive": 0, "triangle": 700}}),
        ),
    ] {
        let out = run_pattern_seeded(&mesh, &png, seed_params.clone(), seed);
        check_contract(&out, &png, &mesh, "pattern_sphere.glb");
        dump(&out, "pattern_sphere.glb");
        let ours = uv_mesh(&load_bytes(&out.model, "o.glb"));
        let m = measure(&ours, &image, ppw);
        let random = measure(&randomised_patches(&ours, 5), &image, ppw);
        let planar = measure(&planar(&mesh, scale), &image, ppw);
        let cube = measure(&cube(&mesh, scale), &image, ppw);
        println!("seed {seed} {seed_params}: ours {m:?}\n random {random:?}\n planar {planar:?}\n cube {cube:?}\n report {}", report(&out));
        assert_eq!(m.flipped, 0, "no flipped face");
        assert!(
            m.density[0] > 0.8 && m.density[2] < 1.25,
            "density {:?}",
            m.density
        );
        assert!(m.anisotropy[1] < 1.3, "anisotropy {:?}", m.anisotropy);
        assert!(
            (0.7..1.3).contains(&random.seam),
            "random placement ≈ 1: {}",
            random.seam
        );
        assert!(
            m.seam < 0.6 * random.seam,
            "seams {} vs random {}",
            m.seam,
            random.seam
        );
        assert!(
            planar.anisotropy[1] > 2.0 * m.anisotropy[1],
            "planar stretches"
        );
        assert!(
            cube.anisotropy[1] > m.anisotropy[1] + 0.1,
            "cube stretches more"
        );
        assert!(
            m.seam < cube.seam,
            "cube seams {} vs ours {}",
            cube.seam,
            m.seam
        );
    }
}

#[test]
fn folded_sheet_maps_isometrically() {
    let png = tile_png(64);
    let image = Image::decode(&png);
    for angle in [0.5f64, 1.0, 2.0] {
        let mesh = folded_sheet(12, angle);
        let scale = 1.0;
        let out = run_pattern(&mesh, &png, json!({"scale": scale}));
        check_contract(&out, &png, &mesh, "pattern_sheet.glb");
        let ours = uv_mesh(&load_bytes(&out.model, "o.glb"));
        let m = measure(&ours, &image, 64.0 / scale);
        let planar = measure(&planar_xz(&mesh, scale), &image, 64.0 / scale);
        println!(
            "fold {angle}: ours {m:?}\n planar {planar:?}\n report {}",
            report(&out)
        );
        assert_eq!(m.flipped, 0);
        assert!(
            m.density[0] > 0.98 && m.density[2] < 1.02,
            "isometric density {:?}",
            m.density
        );
        assert!(
            m.anisotropy[1] < 1.02,
            "isometric anisotropy {:?}",
            m.anisotropy
        );
        assert!(
            m.seam_fraction < 0.01,
            "one patch: seams {}",
            m.seam_fraction
        );
        assert!(
            planar.anisotropy[1] > 1.0 / angle.cos().abs().max(0.05) - 0.05,
            "planar stretches the fold {:?}",
            planar.anisotropy
        );
    }
}

#[test]
fn scale_changes_texel_density() {
    let mesh = sphere();
    let png = tile_png(64);
    let image = Image::decode(&png);
    let mut medians = Vec::new();
    for scale in [0.5, 1.0, 2.0] {
        let out = run_pattern(&mesh, &png, json!({"scale": scale}));
        let ours = uv_mesh(&load_bytes(&out.model, "o.glb"));
        // Absolute px per world unit: measured against 1.
        let m = measure(&ours, &image, 1.0);
        medians.push(m.density[1]);
        assert!(
            (m.density[1] * scale / 64.0 - 1.0).abs() < 0.1,
            "scale {scale}: {:?}",
            m.density
        );
    }
    println!("median px per world unit at scale 0.5, 1, 2: {medians:?}");
    assert!((medians[0] / medians[1] - 2.0).abs() < 0.2);
    assert!((medians[1] / medians[2] - 2.0).abs() < 0.2);
}

#[test]
fn non_toroidal_pattern_keeps_uvs_inside_the_image() {
    let mesh = sphere();
    let png = tile_png(64);
    let out = run_pattern(&mesh, &png, json!({"scale": 0.5, "toroidal": false}));
    check_contract(&out, &png, &mesh, "pattern_clamp.glb");
    // The image covers 0.5 world units, the sphere's clusters at the top levels are larger: they
    // are split (`too_large`), never clamped; a 2,208-face sphere's faces all fit.
    let r = report(&out);
    let too_large: u64 = r["driver"]["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["too_large"].as_u64().unwrap())
        .sum();
    assert!(too_large > 0, "{r}");
    assert!(
        !r["warnings"].to_string().contains("clamped"),
        "{}",
        r["warnings"]
    );
    let back = load_bytes(&out.model, "o.glb");
    assert!(back.primitives[0].tex_coords[0]
        .iter()
        .all(|uv| uv.iter().all(|c| (0.0..=1.0).contains(c))));
    let json_part =
        &out.model[20..20 + u32::from_le_bytes(out.model[12..16].try_into().unwrap()) as usize];
    let doc: Value = serde_json::from_slice(json_part).unwrap();
    let samplers = doc["samplers"].as_array().unwrap();
    assert!(
        samplers
            .iter()
            .any(|s| s["wrapS"] == 33071 && s["wrapT"] == 33071),
        "{samplers:?}"
    );
}

#[test]
fn bad_params_are_refused_with_their_path() {
    let method = Registry::builtin()
        .get(retex::engine::asset::constraints::MethodId::Pattern)
        .unwrap();
    for (params, path) in [
        (json!({"scale": -1.0}), "params.scale"),
        (json!({"band": 0}), "params.band"),
        (json!({"orientations": 0}), "params.orientations"),
        (json!({"children": 1}), "params.children"),
        (json!({"nope": 1}), "params"),
    ] {
        let c = json!({"version": 1, "method": "pattern", "params": params});
        let c = Constraints::from_json(c.to_string().as_bytes()).unwrap();
        let e = method.check(&c).unwrap_err();
        assert!(e.to_string().contains(path), "{params}: {e}");
    }
}

#[test]
#[ignore = "needs ../shared/assets"]
fn real_mesh_beats_baselines() {
    let path = shared_asset("tgt_spot_remeshed_odedstein/spot_derived.glb");
    let glb = std::fs::read(&path).unwrap();
    let target = load_bytes(&glb, "spot.glb");
    let png = tile_png(64);
    let image = Image::decode(&png);
    let scale = 0.5;
    let out = run_pattern_glb(&glb, &png, json!({"scale": scale}), 1);
    assert_validator_clean(&out.model, "pattern_spot.glb");
    dump(&out, "pattern_spot.glb");
    let ours = uv_mesh(&load_bytes(&out.model, "o.glb"));
    let ppw = 64.0 / scale;
    let m = measure(&ours, &image, ppw);
    let random = measure(&randomised_patches(&ours, 5), &image, ppw);
    let mesh = MeshData {
        positions: target.primitives[0].positions.clone(),
        uvs: None,
        indices: target.primitives[0]
            .triangles
            .iter()
            .flatten()
            .copied()
            .collect(),
    };
    let planar = measure(&planar(&mesh, scale), &image, ppw);
    let cube = measure(&cube(&mesh, scale), &image, ppw);
    println!(
        "spot: ours {m:?}\n random {random:?}\n planar {planar:?}\n cube {cube:?}\n report {}",
        report(&out)
    );
    assert_eq!(m.flipped, 0);
    assert!(
        m.density[0] > 0.75 && m.density[2] < 1.3,
        "density {:?}",
        m.density
    );
    assert!(
        m.seam < 0.6 * random.seam,
        "seams {} vs random {}",
        m.seam,
        random.seam
    );
    assert!(planar.anisotropy[1] > 2.0 * m.anisotropy[1]);
    assert!(cube.anisotropy[1] > m.anisotropy[1]);
}

/// Issue 12, Tests: "for an anisotropic pattern, orientation coherence across seams". Stripes
/// ([`stripes_png`], running along u) on the sphere, several seeds: the mean angle between the
/// stripe axes of the two faces of every seam edge ([`stripe_seam_angle`]) against the
/// random-per-patch baseline (the method's own patches, each turned at random: 45° expected).
#[test]
fn stripes_stay_coherent_across_seams() {
    let mesh = sphere();
    let png = stripes_png(64);
    let mut figures = Vec::new();
    for seed in [1u64, 2, 3, 4] {
        let out = run_pattern_seeded(&mesh, &png, json!({"scale": 0.8}), seed);
        check_contract(&out, &png, &mesh, "pattern_stripes.glb");
        dump(&out, "pattern_stripes.glb");
        let ours = uv_mesh(&load_bytes(&out.model, "o.glb"));
        let (angle, seams) = stripe_seam_angle(&ours);
        let (random, _) = stripe_seam_angle(&randomised_patches(&ours, seed + 10));
        println!("seed {seed}: stripe axis angle across {seams} seam edges {angle:.1}° (random patches {random:.1}°)");
        assert!(seams > 50, "seed {seed}: {seams} seam edges");
        assert!((35.0..55.0).contains(&random), "random ≈ 45°: {random}");
        figures.push((seed, angle, random));
    }
    // Measured (seeds 1-4): 24.9 / 18.3 / 21.8 / 31.4° against 45.8 / 44.0 / 43.6 / 44.4°.
    let mean_ratio = figures.iter().map(|f| f.1 / f.2).sum::<f64>() / figures.len() as f64;
    for (seed, angle, random) in figures {
        assert!(
            angle < 0.75 * random,
            "seed {seed}: {angle:.1}° vs random {random:.1}°"
        );
    }
    assert!(mean_ratio < 0.6, "mean ratio to random {mean_ratio:.2}");
}

/// Seed sweep behind the README's quality figures and the sphere seed-4 question (is 0.50 the
/// seed re-draw or chance?): `cargo test --release --test engine bench_pattern_seed_sweep --
/// --ignored --nocapture`. Prints, per seed, the measured seam error of ours and of the same
/// patches placed at random, and from `report.json` the re-drawn splits, fits and patches; the
/// sphere with and without `first_face` (seeds 1-12), Spot at scale 0.5 (seeds 1-4).
#[test]
#[ignore = "benchmark sweep, needs ../shared/assets"]
fn bench_pattern_seed_sweep() {
    let png = tile_png(64);
    let image = Image::decode(&png);
    let row = |name: &str, out: &retex::engine::pipeline::TransferOutput, scale: f64| -> f64 {
        let ours = uv_mesh(&load_bytes(&out.model, "o.glb"));
        let ppw = 64.0 / scale;
        let m = measure(&ours, &image, ppw);
        let random = measure(&randomised_patches(&ours, 5), &image, ppw);
        let r = report(out);
        let d = &r["driver"];
        println!(
            "{name}: seam {:.3} random {:.3} ratio {:.3} flipped {} redraws {} fits {} patches {}",
            m.seam,
            random.seam,
            m.seam / random.seam,
            m.flipped,
            r["seed_redraws"],
            d["fits"],
            d["patches"]
        );
        m.seam / random.seam
    };
    let mesh = sphere();
    for (label, params) in [
        ("sphere", json!({"scale": 0.8})),
        (
            "sphere first_face 700",
            json!({"scale": 0.8, "first_face": {"primitive": 0, "triangle": 700}}),
        ),
    ] {
        let ratios: Vec<f64> = (1..=12)
            .map(|seed| {
                let out = run_pattern_seeded(&mesh, &png, params.clone(), seed);
                row(&format!("{label} seed {seed}"), &out, 0.8)
            })
            .collect();
        let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
        let sd = (ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>()
            / (ratios.len() - 1) as f64)
            .sqrt();
        println!("{label}: seam / random over seeds 1-12: mean {mean:.3} sd {sd:.3}");
    }
    let glb = std::fs::read(shared_asset("tgt_spot_remeshed_odedstein/spot_derived.glb")).unwrap();
    for seed in 1..=4 {
        let out = run_pattern_glb(&glb, &png, json!({"scale": 0.5}), seed);
        row(&format!("spot seed {seed}"), &out, 0.5);
    }
}
