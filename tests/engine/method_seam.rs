//! The method seam (issue 8): output shapes of the coming methods built from synthetic edits
//! export validator-clean and read back as written, and a method that exists only in this test
//! runs end to end through the pipeline from a registry, with no other file touched.

use retex::engine::asset::constraints::{Constraints, MethodId, OutputFormat};
use retex::engine::asset::edits::{
    AttributeData, Edit, EditedAsset, EncodedImage, MorphDeltas, TextureSlot, TextureWrap,
};
use retex::engine::asset::export::{export, ExportError};
use retex::engine::asset::{Asset, BlobSet};
use retex::engine::control::Control;
use retex::engine::methods::Registry;
use retex::engine::pipeline::{
    transfer, transfer_with, ImageInput, ModelInput, TransferError, TransferInput,
};
use retex::engine::texture::encode::encode_png_srgb;
use serde_json::{json, Value};

use crate::common::planar_pattern::{small_jpeg, unwelded_with_planar_uvs, PLANAR_PATTERN};
use crate::common::{assert_validator_clean, load_bytes};

fn spot() -> (Vec<u8>, Asset) {
    let bytes = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/src_spot_keenan/spot_textured_derived.glb"
    ))
    .unwrap();
    let asset = load_bytes(&bytes, "spot.glb");
    (bytes, asset)
}

/// Spot as the only file of a blob set, named `spot.glb`.
fn spot_blobs() -> BlobSet {
    let mut blobs = BlobSet::new();
    blobs.insert("spot.glb", spot().0);
    blobs
}

/// The JSON chunk of a GLB.
fn gltf_json(glb: &[u8]) -> Value {
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&glb[20..20 + len]).unwrap()
}

fn gradient_png(size: u32) -> Vec<u8> {
    let px: Vec<[f32; 4]> = (0..size * size)
        .map(|i| {
            let (x, y) = (
                (i % size) as f32 / size as f32,
                (i / size) as f32 / size as f32,
            );
            [x, y, 0.5, 1.0]
        })
        .collect();
    encode_png_srgb(&px, size, size)
}

#[test]
fn elastiface_shaped_output_exports_clean() {
    let (_, source) = spot();
    let p = 0;
    let n = source.primitives[p].positions.len();
    let fitted: Vec<[f32; 3]> = source.primitives[p]
        .positions
        .iter()
        .map(|q| [q[0] * 1.2, q[1] * 0.9, q[2]])
        .collect();
    let deltas: Vec<[f32; 3]> = fitted
        .iter()
        .zip(&source.primitives[p].positions)
        .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
        .collect();
    let material = source.primitives[p].material;
    let edits = vec![
        Edit::SetAttribute {
            primitive: p,
            name: "POSITION".into(),
            data: AttributeData::Vec3(fitted.clone()),
        },
        Edit::RemoveAttribute {
            primitive: p,
            name: "TANGENT".into(),
        },
        Edit::AddMorphTarget {
            mesh: source.primitives[p].mesh,
            name: "elastiface".into(),
            weight: 0.0,
            deltas: vec![MorphDeltas {
                primitive: p,
                positions: deltas,
                normals: None,
            }],
        },
        Edit::SetTexture {
            material,
            slot: TextureSlot::BaseColor,
            image: EncodedImage::srgb8_png("relaid_basecolor", gradient_png(64)),
            tex_coord: 0,
            wrap: TextureWrap::Repeat,
            primitives: vec![p],
        },
    ];
    let glb = export(&source, &edits, OutputFormat::Glb).unwrap();
    assert_validator_clean(&glb, "seam_elastiface_shaped.glb");
    let back = load_bytes(&glb, "out.glb");
    assert_eq!(back.primitives[p].positions.len(), n);
    assert_eq!(back.primitives[p].positions[7], fitted[7]);
    assert_eq!(back.primitives[p].triangles, source.primitives[p].triangles);
    let j = gltf_json(&glb);
    let mesh = &j["meshes"][source.primitives[p].mesh];
    assert_eq!(mesh["extras"]["targetNames"], json!(["elastiface"]));
    assert_eq!(mesh["weights"], json!([0.0]));
    let target = &mesh["primitives"][source.primitives[p].primitive]["targets"][0];
    assert!(j["accessors"][target["POSITION"].as_u64().unwrap() as usize]["min"].is_array());
}

#[test]
fn pattern_shaped_output_passes_the_jpeg_through() {
    let (_, target) = spot();
    let jpeg = small_jpeg();
    let mut edits: Vec<Edit> = (0..target.primitives.len())
        .map(|p| Edit::ReplacePrimitive {
            primitive: p,
            geometry: unwelded_with_planar_uvs(&target, p),
        })
        .collect();
    edits.push(Edit::SetTexture {
        material: target.primitives[0].material,
        slot: TextureSlot::BaseColor,
        image: EncodedImage::passthrough("pattern", jpeg.clone(), "image/jpeg"),
        tex_coord: 0,
        wrap: TextureWrap::Repeat,
        primitives: (0..target.primitives.len()).collect(),
    });
    let glb = export(&target, &edits, OutputFormat::Glb).unwrap();
    assert_validator_clean(&glb, "seam_pattern_shaped.glb");
    let back = load_bytes(&glb, "out.glb");
    let image = back.images.last().unwrap();
    assert_eq!(image.mime_type, "image/jpeg");
    assert_eq!(
        image.bytes.as_slice(),
        jpeg.as_slice(),
        "image bytes unmodified"
    );
    let prim = &back.primitives[0];
    assert_eq!(
        prim.positions.len(),
        3 * prim.triangles.len(),
        "unwelded corners"
    );
    assert!(
        prim.tex_coords[0].iter().any(|uv| uv[0] > 1.0),
        "UVs beyond [0,1] (REPEAT)"
    );
}

#[test]
fn detail_shaped_output_has_normal_map_tangents_and_16_bit_extras() {
    let (_, target) = spot();
    let p = 0;
    let n = target.primitives[p].positions.len();
    let material = target.primitives[p].material.expect("spot has a material");
    let size = 32u32;
    let normal_texels: Vec<f32> = (0..size * size).flat_map(|_| [0.5, 0.5, 1.0]).collect();
    let height: Vec<f32> = (0..size * size)
        .map(|i| (i % size) as f32 / size as f32)
        .collect();
    // Tangents along +x (w = 1); the sphere-like Spot has no +x normals everywhere, but any unit
    // xyz with w = ±1 is a valid TANGENT.
    let tangents = vec![[1.0f32, 0.0, 0.0, 1.0]; n];
    let edits = vec![
        Edit::SetTexture {
            material: Some(material),
            slot: TextureSlot::Normal { scale: 1.0 },
            image: EncodedImage::linear8("retex_normal", size, size, 3, &normal_texels),
            tex_coord: 0,
            wrap: TextureWrap::Repeat,
            primitives: vec![p],
        },
        Edit::SetAttribute {
            primitive: p,
            name: "TANGENT".into(),
            data: AttributeData::Vec4(tangents),
        },
        Edit::SetMaterialExtra {
            material,
            key: "retex_displacement".into(),
            value: json!({"scale": 0.02, "offset": -0.01}),
        },
        Edit::SetTexture {
            material: Some(material),
            slot: TextureSlot::Extras("retex_displacement"),
            image: EncodedImage::gray16("retex_displacement", size, size, &height),
            tex_coord: 0,
            wrap: TextureWrap::ClampToEdge,
            primitives: vec![p],
        },
    ];
    let glb = export(&target, &edits, OutputFormat::Glb).unwrap();
    assert_validator_clean(&glb, "seam_detail_shaped.glb");
    let j = gltf_json(&glb);
    let m = &j["materials"][material];
    assert!(m["normalTexture"]["index"].is_u64(), "{m}");
    let disp = &m["extras"]["retex_displacement"];
    assert_eq!(disp["scale"], json!(0.02));
    let tex = &j["textures"][disp["index"].as_u64().unwrap() as usize];
    assert_eq!(
        j["samplers"][tex["sampler"].as_u64().unwrap() as usize]["wrapS"],
        33071
    );
    let back = load_bytes(&glb, "out.glb");
    let img = &back.images[tex["source"].as_u64().unwrap() as usize];
    let decoded = image::load_from_memory(&img.bytes).unwrap();
    assert_eq!(decoded.color(), image::ColorType::L16, "16-bit grayscale");
    let gray = decoded.to_luma16();
    assert_eq!(
        gray.get_pixel(size - 1, 0).0[0],
        ((31.0 / 32.0) * 65535.0f32 + 0.5) as u16
    );
}

#[test]
fn edits_that_do_not_fit_are_errors() {
    let (_, asset) = spot();
    let short = Edit::SetAttribute {
        primitive: 0,
        name: "NORMAL".into(),
        data: AttributeData::Vec3(vec![[0.0, 0.0, 1.0]; 3]),
    };
    assert!(matches!(
        export(&asset, &[short], OutputFormat::Glb),
        Err(ExportError::MismatchedEdit { .. })
    ));
    let wrong_type = Edit::SetAttribute {
        primitive: 0,
        name: "TANGENT".into(),
        data: AttributeData::Vec3(vec![[0.0; 3]; asset.primitives[0].positions.len()]),
    };
    assert!(export(&asset, &[wrong_type], OutputFormat::Glb).is_err());
    let missing = Edit::ClearTexture {
        material: 99,
        slot: TextureSlot::BaseColor,
    };
    assert!(matches!(
        export(&asset, &[missing], OutputFormat::Glb),
        Err(ExportError::BadEdit {
            what: "material",
            ..
        })
    ));
}

#[test]
fn a_method_registered_in_a_test_runs_through_the_pipeline() {
    let blobs = spot_blobs();
    let jpeg = small_jpeg();
    let constraints = Constraints::from_json(br#"{"version": 1, "method": "pattern"}"#).unwrap();
    let target = ModelInput {
        main: "spot.glb",
        blobs: &blobs,
    };
    let input = TransferInput::new(target, constraints).with_pattern(ImageInput {
        name: "p.jpg",
        bytes: &jpeg,
    });
    // An id a registry lacks (every id has a built-in method now, so one without `detail`): a
    // clear error listing what is available.
    let detail = Constraints::from_json(br#"{"version": 1, "method": "detail"}"#).unwrap();
    let unregistered = TransferInput::new(target, detail).with_pattern(ImageInput {
        name: "p.jpg",
        bytes: &jpeg,
    });
    let partial = Registry::builtin().without(MethodId::Detail);
    match transfer_with(&partial, &unregistered, &Control::new()) {
        Err(e @ TransferError::MethodNotImplemented { .. }) => {
            assert!(
                e.to_string().contains("available: project, meshmatch"),
                "{e}"
            )
        }
        other => panic!("expected not implemented, got {other:?}"),
    }
    let registry = Registry::builtin().with(&PLANAR_PATTERN);
    let control = Control::new();
    let out = transfer_with(&registry, &input, &control).unwrap();
    assert_eq!(out.report.edited, EditedAsset::Target);
    assert_eq!(out.report.method_report["pattern_size"], json!([32, 16]));
    assert!((control.progress().fraction - 1.0).abs() < 1e-12);
    let stages: Vec<&str> = out
        .report
        .timings
        .iter()
        .map(|t| t.stage.as_str())
        .collect();
    assert_eq!(stages, ["load", "planar uvs", "export"]);
    let names: Vec<&str> = out.artifacts.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["pattern.jpg", "planar.txt", "report.json"]);
    assert_validator_clean(&out.model, "seam_test_method.glb");
    let back = load_bytes(&out.model, "out.glb");
    assert_eq!(
        back.images.last().unwrap().bytes.as_slice(),
        jpeg.as_slice()
    );

    // The required pattern is checked before anything runs.
    let no_pattern = TransferInput::new(target, input.constraints().clone());
    assert!(matches!(
        transfer_with(&registry, &no_pattern, &Control::new()),
        Err(TransferError::MissingInput {
            input: "pattern",
            ..
        })
    ));
}

#[test]
fn a_source_the_method_does_not_read_is_ignored_with_a_warning() {
    let blobs = spot_blobs();
    let m = ModelInput {
        main: "spot.glb",
        blobs: &blobs,
    };
    let jpeg = small_jpeg();
    let c = Constraints::from_json(br#"{"version": 1, "method": "pattern"}"#).unwrap();
    let input = TransferInput::pair(m, m, c).with_pattern(ImageInput {
        name: "p.jpg",
        bytes: &jpeg,
    });
    let registry = Registry::builtin().with(&PLANAR_PATTERN);
    let out = transfer_with(&registry, &input, &Control::new()).unwrap();
    assert!(
        out.report
            .warnings
            .iter()
            .any(|w| w.contains("does not read a source")),
        "{:?}",
        out.report.warnings
    );
}

#[test]
fn project_needs_a_source_and_checks_params_before_loading() {
    let blobs = spot_blobs();
    let m = ModelInput {
        main: "spot.glb",
        blobs: &blobs,
    };
    let input = TransferInput::new(m, Constraints::default());
    assert!(matches!(
        transfer(&input, &Control::new()),
        Err(TransferError::MissingInput {
            input: "source",
            ..
        })
    ));
    let c = Constraints::from_json(
        br#"{"version": 1, "method": "meshmatch", "params": {"hks": {"hks_times": "many"}}}"#,
    )
    .unwrap();
    match transfer(&TransferInput::pair(m, m, c), &Control::new()) {
        Err(TransferError::Constraints(e)) => assert_eq!(e.path, "params.hks.hks_times"),
        other => panic!("expected a constraints error, got {other:?}"),
    }
}

/// A field that checks every sample it is given (the primitive, triangle and barycentric
/// coordinates reproduce the world position) and returns the normal encoded as a normal map.
struct CheckedNormals<'a> {
    asset: &'a Asset,
    worst: std::sync::Mutex<f32>,
    samples: std::sync::atomic::AtomicUsize,
}

impl retex::engine::methods::output::SurfaceField for CheckedNormals<'_> {
    fn sample(
        &self,
        at: &retex::engine::methods::output::SurfaceSample,
        _hint: Option<u32>,
        out: &mut [f32; 4],
    ) -> Option<u32> {
        let prim = &self.asset.primitives[at.primitive];
        let inst = &self.asset.instances[0];
        let t = prim.triangles[at.triangle];
        let mut p = [0.0f64; 3];
        for (k, &v) in t.iter().enumerate() {
            let w = inst.transform_point(prim.positions[v as usize]);
            for c in 0..3 {
                p[c] += at.barycentric[k] as f64 * w[c];
            }
        }
        let err = (0..3)
            .map(|c| (p[c] as f32 - at.position[c]).abs())
            .fold(0.0f32, f32::max);
        let mut worst = self.worst.lock().unwrap();
        *worst = worst.max(err);
        self.samples
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        for c in 0..3 {
            out[c] = 0.5 + 0.5 * at.normal[c];
        }
        Some(0)
    }
}

#[test]
fn an_n_channel_field_sees_the_full_surface_point_and_bakes_a_normal_map() {
    use retex::engine::methods::output::{write_field, FieldOutput, TexelEncoding};
    let (_, asset) = spot();
    let field = CheckedNormals {
        asset: &asset,
        worst: std::sync::Mutex::new(0.0),
        samples: Default::default(),
    };
    let c = Constraints::from_json(br#"{"version": 1, "output": {"texture_size": 128}}"#).unwrap();
    let output = FieldOutput {
        slot: TextureSlot::Normal { scale: 1.0 },
        encoding: TexelEncoding::Linear8 { channels: 3 },
        name: "retex_normal",
        vertex_attribute: None,
        vertex_samples: 1000,
    };
    let (edits, report) = write_field(&asset, &c, &output, &field, &Control::new()).unwrap();
    let n = field.samples.load(std::sync::atomic::Ordering::Relaxed) as u64;
    assert_eq!(
        n, report.textures[0].covered,
        "one sample per covered texel"
    );
    let worst = *field.worst.lock().unwrap();
    assert!(worst < 1e-4, "sample position off its triangle by {worst}");
    let glb = export(&asset, &edits, OutputFormat::Glb).unwrap();
    assert_validator_clean(&glb, "seam_normal_field.glb");
    let j = gltf_json(&glb);
    let m = asset.primitives[0].material.unwrap();
    let tex = j["materials"][m]["normalTexture"]["index"]
        .as_u64()
        .unwrap() as usize;
    let back = load_bytes(&glb, "out.glb");
    let img = &back.images[j["textures"][tex]["source"].as_u64().unwrap() as usize];
    let decoded = image::load_from_memory(&img.bytes).unwrap();
    assert_eq!(decoded.color(), image::ColorType::Rgb8);
    // Normals are unit: at least the covered texels decode to length ~1 (padding averages).
    let rgb = decoded.to_rgb8();
    let unit = rgb
        .pixels()
        .filter(|p| {
            let v: Vec<f32> = p.0.iter().map(|&x| x as f32 / 127.5 - 1.0).collect();
            ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 0.05
        })
        .count();
    let covered = report.textures[0].covered as f64;
    assert!(
        unit as f64 >= 0.95 * covered,
        "{unit} unit texels of {covered} covered"
    );
}

/// A constant colour.
struct Constant([f32; 4]);

impl retex::engine::methods::color_output::ColorField for Constant {
    fn color_at(&self, _p: [f32; 3], _n: [f32; 3], _h: Option<u32>) -> Option<([f32; 4], u32)> {
        Some((self.0, 0))
    }
}

#[test]
fn the_color_0_fallback_keeps_to_its_vertex_budget() {
    use retex::engine::methods::color_output::write_color_field;
    let (_, mut asset) = spot();
    for p in &mut asset.primitives {
        p.tex_coords.clear();
    }
    // `uv: keep`: the COLOR_0 path, not the generated atlas (tests/engine/uv_atlas.rs).
    let mut c = Constraints::default();
    c.output.uv = retex::engine::asset::constraints::UvMode::Keep;
    for budget in [5_000usize, 12_000, 20_000, 35_000, 60_000, 100_000] {
        let (edits, report) = write_color_field(
            &asset,
            &c,
            budget,
            &Constant([0.2, 0.4, 0.6, 1.0]),
            &Control::new(),
        )
        .unwrap();
        let written: usize = report.vertex_colors.iter().map(|v| v.vertices).sum();
        assert!(report.vertex_colors.iter().all(|v| v.refined));
        assert!(
            written as f64 <= 1.1 * budget as f64 && written as f64 >= 0.6 * budget as f64,
            "budget {budget}: {written} vertices"
        );
        let glb = export(&asset, &edits, OutputFormat::Glb).unwrap();
        let back = load_bytes(&glb, "out.glb");
        assert_eq!(back.primitives[0].positions.len(), written);
    }
}

#[test]
fn meshmatch_progress_never_goes_backwards_and_reaches_one_at_the_end() {
    let blobs = spot_blobs();
    let m = ModelInput {
        main: "spot.glb",
        blobs: &blobs,
    };
    let c = Constraints::from_json(
        br#"{"version": 1, "method": "meshmatch", "output": {"texture_size": 128},
             "params": {"samples": 2048, "write_nnf": false}}"#,
    )
    .unwrap();
    let input = TransferInput::pair(m, m, c);
    let control = Control::new();
    let mut seen = Vec::new();
    let out = std::thread::scope(|s| {
        let worker = s.spawn(|| transfer(&input, &control));
        while !worker.is_finished() {
            let p = control.progress();
            seen.push((p.fraction, p.stage));
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        worker.join().unwrap()
    });
    let out = out.unwrap();
    assert!(seen.len() > 20, "only {} polls", seen.len());
    // Timings come from the control's stages (no stopwatch inside the method): every EM
    // iteration of every level shows its target fans, E-step and vote, and the report keeps no
    // millisecond fields of its own.
    let stages: Vec<&str> = out
        .report
        .timings
        .iter()
        .map(|t| t.stage.as_str())
        .collect();
    for name in ["geodesic fans", "E-step", "vote"] {
        let n = stages
            .iter()
            .filter(|s| s.contains(" iteration 1: ") && s.ends_with(name))
            .count();
        let levels = out.report.method_report["synthesis"]["levels"]
            .as_array()
            .unwrap()
            .len();
        assert_eq!(n, levels, "{name}: {stages:?}");
    }
    let report = out.report.method_report.to_string();
    assert!(!report.contains("_ms\""), "{report}");
    for w in seen.windows(2) {
        assert!(
            w[1].0 >= w[0].0,
            "progress went back: {:?} -> {:?}",
            w[0],
            w[1]
        );
    }
    // 1.0 only once the run finished: the poll loop may catch the moment between `finish()`
    // and the thread's exit, so a 1.0 sample must carry the final stage.
    let last_stage = control.progress().stage;
    assert!(
        seen.iter().all(|(f, s)| *f < 1.0 || *s == last_stage),
        "1.0 before the end"
    );
    // The levels move the fraction through most of the range, not in one jump at the end.
    let mid = seen.iter().filter(|(f, _)| *f > 0.2 && *f < 0.9).count();
    assert!(mid > 5, "{mid} polls between 20% and 90%: {seen:?}");
    assert_eq!(control.progress().fraction, 1.0);
}
