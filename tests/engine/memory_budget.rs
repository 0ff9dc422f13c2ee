//! The per-job memory budget (issue 9, item 1): decoded image bytes summed over the images a job
//! decodes, checked from the headers before anything is decoded; images no drawn primitive
//! samples are never decoded; an image is decoded straight into its one buffer; instanced
//! vertex and triangle counts; the methods' own working sets.
//!
//! Peak memory is measured by counting the bytes allocated through the global allocator of this
//! test binary, in a child process that runs one test alone (so no other test allocates
//! meanwhile).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::images::{decode_rgba8, read_header};
use retex::engine::asset::{load, BlobSet, IngestError, IngestLimits};
use retex::engine::control::Control;
use retex::engine::methods::Registry;
use retex::engine::pipeline::{
    checked_method, transfer, ModelInput, TransferError, TransferInput, TransferOutput,
};

use crate::common;

/// Counts live heap bytes while `ON`, and their peak.
struct Counting;

static ON: AtomicBool = AtomicBool::new(false);
static LIVE: AtomicI64 = AtomicI64::new(0);
static PEAK: AtomicI64 = AtomicI64::new(0);

fn count(delta: i64) {
    if ON.load(Ordering::Relaxed) {
        let now = LIVE.fetch_add(delta, Ordering::Relaxed) + delta;
        PEAK.fetch_max(now, Ordering::Relaxed);
    }
}

// SAFETY: every call is forwarded to `System` unchanged; only counters are updated.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size() as i64);
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count(layout.size() as i64);
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        count(-(layout.size() as i64));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count(new_size as i64 - layout.size() as i64);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Peak bytes allocated (above the level at the start) while `f` runs.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, u64) {
    LIVE.store(0, Ordering::SeqCst);
    PEAK.store(0, Ordering::SeqCst);
    ON.store(true, Ordering::SeqCst);
    let out = f();
    ON.store(false, Ordering::SeqCst);
    (out, PEAK.load(Ordering::SeqCst).max(0) as u64)
}

const CHILD: &str = "RETEX_ALLOC_PROBE_CHILD";

/// Runs the ignored test `name` alone in a child process of this test binary and asserts it
/// passed; the child prints its measurements.
fn run_alone(name: &str) {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            name,
            "--exact",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD, "1")
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    println!("{text}");
    assert!(
        out.status.success(),
        "{name} failed in its own process:\n{text}"
    );
    assert!(text.contains("1 passed"), "{name} did not run:\n{text}");
}

/// An RGB8 PNG of `w` x `h` (a smooth pattern, so it compresses well).
fn rgb_png(w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x / 16) as u8, (y / 16) as u8, ((x + y) / 64) as u8])
    });
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .unwrap();
    out
}

fn glb_blobs(glb: Vec<u8>) -> BlobSet {
    let mut b = BlobSet::new();
    b.insert("m.glb", glb);
    b
}

/// Runs the whole transfer on two GLBs held in memory, under `limits`.
fn transfer_glbs(
    source: Vec<u8>,
    target: Vec<u8>,
    constraints: Constraints,
    limits: IngestLimits,
) -> Result<TransferOutput, TransferError> {
    let (src, tgt) = (glb_blobs(source), glb_blobs(target));
    let input = TransferInput::pair(
        ModelInput {
            main: "m.glb",
            blobs: &src,
        },
        ModelInput {
            main: "m.glb",
            blobs: &tgt,
        },
        constraints,
    )
    .with_limits(limits);
    transfer(&input, &Control::new())
}

#[test]
fn a_small_png_declaring_16384_squared_is_refused_naming_the_image_and_the_limit() {
    let bomb = common::bomb_png(16384, 16384);
    assert!(bomb.len() < 100, "{}", bomb.len());
    let glb = common::textured_triangle_glb(&[bomb], 1);
    let e = load("m.glb", &glb_blobs(glb.clone()), &IngestLimits::default()).unwrap_err();
    match &e {
        IngestError::ImageBudget {
            image: 0,
            width: 16384,
            height: 16384,
            bytes,
            max,
            ..
        } => {
            assert_eq!(*bytes, 16384 * 16384 * 4);
            assert_eq!(*max, 512 << 20);
        }
        other => panic!("{other}"),
    }
    assert_eq!(e.kind(), "image-budget-exceeded");
    let text = e.to_string();
    assert!(
        text.contains("images[0]") && text.contains("max_decoded_image_bytes"),
        "{text}"
    );

    // The whole transfer says the same, naming the input, before decoding anything.
    let spot = std::fs::read(common::test_data(
        "tgt_spot_remeshed_odedstein/spot_derived.glb",
    ))
    .unwrap();
    let e = transfer_glbs(glb, spot, Constraints::default(), IngestLimits::default()).unwrap_err();
    assert!(
        matches!(
            &e,
            TransferError::Ingest {
                side: "source",
                source: IngestError::ImageBudget { image: 0, .. }
            }
        ),
        "{e}"
    );
}

#[test]
fn the_budget_is_summed_over_the_inputs_of_a_job() {
    // Each model alone (1 MiB) is within 1.5 MiB; together they are not.
    let limits = IngestLimits {
        max_decoded_image_bytes: 3 << 19,
        ..IngestLimits::default()
    };
    let glb = common::textured_triangle_glb(&[common::bomb_png(512, 512)], 1);
    let e = transfer_glbs(glb.clone(), glb, Constraints::default(), limits).unwrap_err();
    match &e {
        TransferError::Ingest {
            side: "target",
            source:
                IngestError::ImageBudget {
                    image: 0,
                    total,
                    max,
                    ..
                },
        } => assert_eq!((*total, *max), (2 * 512 * 512 * 4, 3 << 19)),
        other => panic!("{other}"),
    }
}

#[test]
fn an_image_no_primitive_samples_is_accepted_and_never_decoded() {
    // Image 1 declares 16384² (1 GiB decoded) and holds a few bytes: decoding it would fail,
    // counting it would exceed the budget. It is on a material no primitive uses.
    let glb = common::textured_triangle_glb(
        &[common::small_png(8, 4), common::bomb_png(16384, 16384)],
        1,
    );
    let a = load("m.glb", &glb_blobs(glb), &IngestLimits::default()).unwrap();
    assert_eq!((a.images[1].width, a.images[1].height), (16384, 16384));
    assert!(a.images[1].decoded.is_none());
    let used = a.images[0]
        .decoded
        .as_ref()
        .expect("the sampled image is decoded");
    assert_eq!((used.width, used.height, used.pixels.len()), (8, 4, 32));
    assert_eq!(
        retex::engine::asset::budget::sampled_images(&a),
        vec![0],
        "only the sampled image"
    );
}

#[test]
fn a_primitive_without_the_uv_set_does_not_decode_its_texture() {
    // The material reads TEXCOORD_1, which the primitive does not have: the texture term is 1
    // and the (undecodable) image is never decoded.
    let glb = common::textured_triangle_glb_with(&[common::bomb_png(64, 64)], 1, |j| {
        j["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"] = 1.into();
    });
    let a = load("m.glb", &glb_blobs(glb), &IngestLimits::default()).unwrap();
    assert!(a.images[0].decoded.is_none());
}

#[test]
fn decoding_matches_image_into_rgba8_for_every_pixel_layout() {
    use image::{DynamicImage, ImageBuffer, Luma, LumaA, Rgb, Rgba};
    let (w, h) = (37u32, 11u32);
    let v = |x: u32, y: u32, k: u32| ((x * 977 + y * 131 + k * 7919) % 65536) as u16;
    let images: Vec<DynamicImage> = vec![
        ImageBuffer::from_fn(w, h, |x, y| Luma([v(x, y, 0) as u8])).into(),
        ImageBuffer::from_fn(w, h, |x, y| LumaA([v(x, y, 0) as u8, v(x, y, 1) as u8])).into(),
        ImageBuffer::from_fn(w, h, |x, y| {
            Rgb([v(x, y, 0) as u8, v(x, y, 1) as u8, v(x, y, 2) as u8])
        })
        .into(),
        ImageBuffer::from_fn(w, h, |x, y| {
            Rgba([v(x, y, 0) as u8, 1, 2, v(x, y, 3) as u8])
        })
        .into(),
        ImageBuffer::from_fn(w, h, |x, y| Luma([v(x, y, 0)])).into(),
        ImageBuffer::from_fn(w, h, |x, y| LumaA([v(x, y, 0), v(x, y, 1)])).into(),
        ImageBuffer::from_fn(w, h, |x, y| Rgb([v(x, y, 0), v(x, y, 1), v(x, y, 2)])).into(),
        ImageBuffer::from_fn(w, h, |x, y| {
            Rgba([v(x, y, 0), v(x, y, 1), v(x, y, 2), v(x, y, 3)])
        })
        .into(),
    ];
    let limits = IngestLimits::default();
    for img in images {
        for format in [image::ImageFormat::Png, image::ImageFormat::Jpeg] {
            let encodable = format == image::ImageFormat::Png
                || matches!(img.color(), image::ColorType::L8 | image::ColorType::Rgb8);
            if !encodable {
                continue;
            }
            let mut bytes = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut bytes), format)
                .unwrap();
            let header = read_header(0, &bytes, &limits).unwrap();
            let expected = image::load_from_memory(&bytes).unwrap().into_rgba8();
            let got = decode_rgba8(0, &bytes, header.format, &limits).unwrap();
            let what = format!("{:?} {format:?}", img.color());
            assert_eq!((got.width, got.height), (w, h), "{what}");
            assert_eq!(
                got.pixels.as_flattened(),
                expected.as_raw().as_slice(),
                "{what}"
            );
            assert_eq!(
                header.decoded_bytes(),
                u64::from(w * h) * u64::from(img.color().bytes_per_pixel().max(4)),
                "{what}"
            );
        }
    }
}

#[test]
fn decoding_a_large_image_holds_about_one_copy() {
    run_alone("memory_budget::decode_peak_probe");
}

/// Run by [`decoding_a_large_image_holds_about_one_copy`] in its own process.
#[test]
#[ignore = "run alone in a child process by decoding_a_large_image_holds_about_one_copy"]
fn decode_peak_probe() {
    if std::env::var_os(CHILD).is_none() {
        return;
    }
    let (w, h) = (4096u32, 4096u32);
    let rgba = u64::from(w * h) * 4;
    let limits = IngestLimits::default();
    for (what, png) in [("rgb8", rgb_png(w, h)), ("rgba8", common::small_png(w, h))] {
        let header = read_header(0, &png, &limits).unwrap();
        let (decoded, peak) = peak_of(|| decode_rgba8(0, &png, header.format, &limits).unwrap());
        assert_eq!(decoded.pixels.len() as u64 * 4, rgba);
        drop(decoded);
        println!(
            "decode {what} {w}x{h} ({} bytes encoded): peak {peak} bytes = {:.3} x the RGBA8 image",
            png.len(),
            peak as f64 / rgba as f64
        );
        assert!(
            peak as f64 <= 1.05 * rgba as f64,
            "{what}: peak {peak} bytes for a {rgba}-byte image"
        );
        // The same through a whole model load: the encoded bytes are held twice (the upload
        // and the asset's copy) and the pixels once.
        let glb = common::textured_triangle_glb(std::slice::from_ref(&png), 1);
        let glb_len = glb.len() as u64;
        let blobs = glb_blobs(glb);
        let (asset, peak) = peak_of(|| load("m.glb", &blobs, &limits).unwrap());
        assert!(asset.images[0].decoded.is_some());
        println!(
            "load {what}: peak {peak} bytes = {:.3} x the RGBA8 image (+ {glb_len} bytes of glb)",
            peak as f64 / rgba as f64
        );
        assert!(
            peak as f64 <= 1.05 * rgba as f64 + 3.0 * glb_len as f64 + (1 << 20) as f64,
            "{what}: load peak {peak}"
        );
    }
}

#[test]
fn instanced_triangles_over_the_budget_are_refused() {
    // One triangle, instanced 300 times: 300 triangles in the surface, 1 stored.
    let glb = common::textured_triangle_glb(&[common::small_png(2, 2)], 300);
    let limits = IngestLimits {
        max_triangles: 200,
        ..IngestLimits::default()
    };
    let e = load("m.glb", &glb_blobs(glb.clone()), &limits).unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::GeometryBudget {
                what: "triangles",
                count: 300,
                max: 200
            }
        ),
        "{e}"
    );
    assert_eq!(e.kind(), "too-many-triangles");
    let limits = IngestLimits {
        max_vertices: 600,
        ..IngestLimits::default()
    };
    let e = load("m.glb", &glb_blobs(glb.clone()), &limits).unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::GeometryBudget {
                what: "vertices",
                count: 900,
                max: 600
            }
        ),
        "{e}"
    );
    // Within the budget per model, over it for the job (source + target).
    let limits = IngestLimits {
        max_triangles: 500,
        ..IngestLimits::default()
    };
    let e = transfer_glbs(glb.clone(), glb, Constraints::default(), limits).unwrap_err();
    assert!(
        matches!(
            e,
            TransferError::Ingest {
                side: "target",
                source: IngestError::GeometryBudget {
                    what: "triangles",
                    count: 600,
                    max: 500
                }
            }
        ),
        "{e}"
    );
}

#[test]
fn an_over_large_meshmatch_sample_count_is_refused_at_check_time() {
    let registry = Registry::builtin();
    let c = |params: &str| {
        Constraints::from_json(
            format!(r#"{{"version": 1, "method": "meshmatch", "params": {params}}}"#).as_bytes(),
        )
        .unwrap()
    };
    let limits = IngestLimits {
        max_method_bytes: 512 << 20,
        ..IngestLimits::default()
    };
    assert!(checked_method(&registry, &c(r#"{"samples": 16384}"#), &limits).is_ok());
    let Err(e) = checked_method(&registry, &c(r#"{"samples": 262144}"#), &limits) else {
        panic!("accepted");
    };
    match &e {
        TransferError::WorkingSet { field, bytes, max } => {
            assert_eq!(field, "params.samples");
            assert_eq!(*max, 512 << 20);
            assert!(*bytes > 1 << 30, "{bytes}");
        }
        other => panic!("{other}"),
    }
    let text = e.to_string();
    assert!(
        text.contains("params.samples") && text.contains("max_method_bytes"),
        "{text}"
    );
    // The default budget takes the largest sample count at the default fans, not with the
    // largest fans.
    let defaults = IngestLimits::default();
    assert!(checked_method(&registry, &c(r#"{"samples": 262144}"#), &defaults).is_ok());
    let Err(e) = checked_method(
        &registry,
        &c(r#"{"samples": 262144, "rings": 8, "spokes": 64}"#),
        &defaults,
    ) else {
        panic!("accepted");
    };
    assert!(matches!(e, TransferError::WorkingSet { .. }), "{e}");
}

#[test]
fn meshmatch_on_inputs_too_large_for_its_working_set_is_refused_before_it_runs() {
    let registry = Registry::builtin();
    let constraints = Constraints::from_json(
        br#"{"version": 1, "method": "meshmatch", "output": {"texture_size": 16},
             "params": {"samples": 256, "source_samples": 256}}"#,
    )
    .unwrap();
    // 2 × 2,000 instanced triangles × 2 KiB > 4 MiB; the params alone (512 synthesis
    // vertices) are within it.
    let limits = IngestLimits {
        max_method_bytes: 4 << 20,
        ..IngestLimits::default()
    };
    assert!(checked_method(&registry, &constraints, &limits).is_ok());
    let glb = common::textured_triangle_glb(&[common::small_png(2, 2)], 2000);
    let e = transfer_glbs(glb.clone(), glb, constraints, limits).unwrap_err();
    match &e {
        TransferError::WorkingSet { field, bytes, max } => {
            assert_eq!(field, "inputs");
            assert_eq!(*max, 4 << 20);
            assert!(*bytes > 4000 * 2048, "{bytes}");
        }
        other => panic!("{other}"),
    }
}

#[test]
fn a_mask_image_the_method_reads_counts_against_the_budget() {
    // Image 1 is on a material no primitive uses, but MeshMatch's by-example mask reads it.
    let target = common::textured_triangle_glb(
        &[common::small_png(8, 4), common::bomb_png(16384, 16384)],
        1,
    );
    let constraints = Constraints::from_json(
        br#"{"version": 1, "method": "meshmatch", "output": {"texture_size": 16},
             "params": {"samples": 256, "source_samples": 256,
                        "example": {"image": {"index": 1, "channel": "r", "threshold": 0.5}}}}"#,
    )
    .unwrap();
    let source = common::textured_triangle_glb(&[common::small_png(2, 2)], 1);
    let e = transfer_glbs(source, target, constraints, IngestLimits::default()).unwrap_err();
    assert!(
        matches!(
            e,
            TransferError::Ingest {
                side: "target",
                source: IngestError::ImageBudget { image: 1, .. }
            }
        ),
        "{e}"
    );
}

#[test]
fn elastiface_on_inputs_too_large_for_its_solves_is_refused_before_it_runs() {
    let registry = Registry::builtin();
    let pairs: Vec<String> = (0..3)
        .map(|i| {
            format!(
                r#"{{"source": {{"vertex": {{"mesh": 0, "primitive": 0, "index": {i}}}}},
                     "target": {{"vertex": {{"mesh": 0, "primitive": 0, "index": {i}}}}}}}"#
            )
        })
        .collect();
    let constraints = Constraints::from_json(
        format!(
            r#"{{"version": 1, "method": "elastiface", "output": {{"texture_size": 16}},
                 "correspondences": [{}]}}"#,
            pairs.join(",")
        )
        .as_bytes(),
    )
    .unwrap();
    // 2 × 2,000 instanced triangles: 4,000 × log₂ → 12 × 160 bytes ≈ 7.7 MB > 4 MiB; the
    // params alone (a 16² texture) are within it.
    let limits = IngestLimits {
        max_method_bytes: 4 << 20,
        ..IngestLimits::default()
    };
    assert!(checked_method(&registry, &constraints, &limits).is_ok());
    let glb = common::textured_triangle_glb(&[common::small_png(2, 2)], 2000);
    match transfer_glbs(glb.clone(), glb, constraints, limits).unwrap_err() {
        TransferError::WorkingSet { field, bytes, max } => {
            assert_eq!(field, "inputs");
            assert_eq!(max, 4 << 20);
            assert!(bytes > 4000 * 12 * 160, "{bytes}");
        }
        other => panic!("{other}"),
    }
}

#[test]
fn an_over_large_correlation_sample_count_is_refused_at_check_time() {
    let registry = Registry::builtin();
    let constraints = Constraints::from_json(
        br#"{"version": 1, "method": "correlation", "output": {"texture_size": 16},
             "params": {"samples": 65536}}"#,
    )
    .unwrap();
    // 2 models × 65,536 samples × 1 KiB = 128 MiB: over 64 MiB, within 256 MiB.
    let tight = IngestLimits {
        max_method_bytes: 64 << 20,
        ..IngestLimits::default()
    };
    match checked_method(&registry, &constraints, &tight) {
        Err(TransferError::WorkingSet { field, bytes, max }) => {
            assert_eq!(field, "params.samples");
            assert_eq!(max, 64 << 20);
            assert!(bytes >= 128 << 20, "{bytes}");
        }
        Err(other) => panic!("{other}"),
        Ok(_) => panic!("accepted"),
    }
    let roomy = IngestLimits {
        max_method_bytes: 256 << 20,
        ..IngestLimits::default()
    };
    assert!(checked_method(&registry, &constraints, &roomy).is_ok());
}

#[test]
fn the_generated_atlas_counts_in_every_colour_methods_working_set() {
    // A million input triangles: with output.uv = auto each texture-writing method counts the
    // atlas it may have to build (1,500 B per triangle); with keep or vertex_colors it does not.
    let registry = Registry::builtin();
    let triangles = 1_000_000;
    let atlas = retex::engine::uv::working_set_bytes(triangles);
    assert_eq!(atlas, 1_500_000_000);
    for method in ["project", "meshmatch", "correlation"] {
        let estimate = |uv: &str| {
            let c = Constraints::from_json(
                format!(r#"{{"version": 1, "method": "{method}", "output": {{"uv": "{uv}"}}}}"#)
                    .as_bytes(),
            )
            .unwrap();
            let m = registry.get(c.method).unwrap();
            m.working_set(&c, triangles).unwrap()
        };
        let auto = estimate("auto");
        for other in ["keep", "vertex_colors"] {
            let without = estimate(other);
            assert_eq!(auto.bytes - without.bytes, atlas, "{method} {other}");
            assert_ne!(without.field, "output.uv", "{method} {other}");
        }
    }
    // Where the atlas is the largest part, the estimate names `output.uv` (the setting that
    // removes it): project and correlation, whose own per-triangle costs are smaller.
    for method in ["project", "correlation"] {
        let c =
            Constraints::from_json(format!(r#"{{"version": 1, "method": "{method}"}}"#).as_bytes())
                .unwrap();
        let ws = registry
            .get(c.method)
            .unwrap()
            .working_set(&c, triangles)
            .unwrap();
        assert_eq!(ws.field, "output.uv", "{method}");
    }
}
