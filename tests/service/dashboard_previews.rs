//! Issue 16, part 1: every succeeded job stores turntable previews of its result and inputs as
//! artifacts, served with ETags; the preview stage is counted in the job's progress and timed in
//! its report.

use std::time::Duration;

use retex::engine::asset::{BlobSet, IngestLimits};
use retex::engine::control::Control;
use retex::service::jobs::preview::{
    amend_report, combined_progress, render_previews, PreviewInput, ENGINE_SHARE,
};

use crate::service_common::*;

/// Decodes a PNG answer and checks it shows a model: every view of the strip has a share of
/// non-background pixels and the image is not one flat colour.
fn assert_turntable(body: &[u8], views: u32, size: u32, what: &str) {
    let img = image::load_from_memory(body)
        .unwrap_or_else(|e| panic!("{what}: not a PNG: {e}"))
        .to_rgb8();
    assert_eq!(img.dimensions(), (views * size, size), "{what}");
    // The renderer's background is sRGB 231 grey.
    let bg = |p: &image::Rgb<u8>| p.0.iter().all(|&c| c.abs_diff(231) <= 1);
    for v in 0..views {
        let mut covered = 0u32;
        for y in 0..size {
            for x in v * size..(v + 1) * size {
                covered += u32::from(!bg(img.get_pixel(x, y)));
            }
        }
        let share = covered as f64 / (size * size) as f64;
        // Spot fills 18-26 % of each view at 256 px; an empty or clipped render fails this.
        assert!(
            (0.1..0.9).contains(&share),
            "{what}: view {v} covers {share:.3}"
        );
    }
    let n = (img.width() * img.height()) as f64;
    let lum: Vec<f64> = img
        .pixels()
        .map(|p| 0.299 * p.0[0] as f64 + 0.587 * p.0[1] as f64 + 0.114 * p.0[2] as f64)
        .collect();
    let mean = lum.iter().sum::<f64>() / n;
    let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n;
    assert!(var > 100.0, "{what}: luminance variance {var:.1}");
}

#[test]
fn a_succeeded_job_serves_its_previews_with_etags() {
    let s = TestServer::start(|_| {});
    let r = submit(&s.base, &spot_parts(256), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");

    let names: Vec<&str> = doc["links"]["artifacts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["name"].as_str().unwrap())
        .collect();
    for want in ["preview.png", "source_preview.png", "target_preview.png"] {
        assert!(names.contains(&want), "{want} missing from {names:?}");
    }
    // The preview stages ran after the method and are counted and timed.
    let stages = &doc["progress"]["stages"];
    assert_eq!(stages["done"], stages["total"], "{doc}");
    assert_eq!(doc["progress"]["fraction"], 1.0, "{doc}");
    let timed: Vec<&str> = doc["report"]["timings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["stage"].as_str().unwrap())
        .collect();
    let at = timed.iter().position(|t| *t == "preview: result");
    let export = timed.iter().position(|t| *t == "export");
    assert!(at.is_some() && export < at, "{timed:?}");
    let warnings = doc["report"]["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .all(|w| !w.as_str().unwrap().starts_with("preview")),
        "{warnings:?}"
    );

    let url = format!("{}/v1/jobs/{id}/artifacts/preview.png", s.base);
    let r = get(&url);
    assert_eq!(r.status, 200);
    assert_eq!(r.header("content-type"), Some("image/png"));
    assert_turntable(&r.body, 4, 256, "preview.png");
    let etag = r.header("etag").expect("an ETag").to_string();
    let again = request("GET", &url, &[("If-None-Match", &etag)], None);
    assert_eq!(again.status, 304);
    assert!(again.body.is_empty());

    for name in ["source_preview.png", "target_preview.png"] {
        let r = get(&format!("{}/v1/jobs/{id}/artifacts/{name}", s.base));
        assert_eq!(r.status, 200, "{name}");
        assert_turntable(&r.body, 4, 128, name);
    }
    // The path, /files/, serves the same bytes with the same ETag, and 304s.
    let files = format!("{}/v1/jobs/{id}/files/preview.png", s.base);
    let f = get(&files);
    assert_eq!(f.status, 200);
    assert_eq!(f.header("content-type"), Some("image/png"));
    assert_eq!(f.header("etag"), Some(etag.as_str()));
    assert_eq!(f.body, r.body);
    let again = request("GET", &files, &[("If-None-Match", &etag)], None);
    assert_eq!(again.status, 304);
    assert!(again.body.is_empty());
    for name in ["source_preview.png", "target_preview.png"] {
        let url = format!("{}/v1/jobs/{id}/files/{name}", s.base);
        let r = get(&url);
        assert_eq!(r.status, 200, "{name}");
        assert_turntable(&r.body, 4, 128, name);
        let tag = r.header("etag").expect("an ETag").to_string();
        assert_eq!(
            request("GET", &url, &[("If-None-Match", &tag)], None).status,
            304
        );
        // A stale tag gets the file again.
        assert_eq!(
            request("GET", &url, &[("If-None-Match", "\"stale\"")], None).status,
            200
        );
    }
    let p = get(&format!("{}/v1/jobs/{id}/files/nothing.png", s.base)).problem(404);
    assert_eq!(p["field"], "name", "{p}");
    // report.json carries the preview timings too.
    let report = get(&format!("{}/v1/jobs/{id}/artifacts/report.json", s.base)).json();
    assert!(
        report["timings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|t| t["stage"] == "preview: target"),
        "{report}"
    );
}

#[test]
fn a_model_that_does_not_load_is_a_warning_and_the_stage_still_finishes() {
    let mut blobs = BlobSet::new();
    blobs.insert("m.glb", b"not a glb at all".to_vec());
    let inputs = [PreviewInput {
        artifact: "preview.png",
        stage: "preview: result",
        main: "m.glb",
        blobs: &blobs,
        views: 2,
        size: 32,
    }];
    let control = Control::new();
    let out = render_previews(&inputs, &IngestLimits::default(), &control, || false).unwrap();
    assert!(out.files.is_empty());
    assert_eq!(out.warnings.len(), 1);
    assert!(
        out.warnings[0].starts_with("preview: preview.png"),
        "{:?}",
        out.warnings
    );
    let p = control.progress();
    assert_eq!((p.stages_done, p.stages_total), (1, 1));
    assert!((p.fraction - 1.0).abs() < 1e-12);
    let mut report = serde_json::json!({"timings": [], "warnings": ["w"]});
    amend_report(&mut report, &control, &out.warnings);
    assert_eq!(report["timings"][0]["stage"], "preview: result");
    assert_eq!(report["warnings"].as_array().unwrap().len(), 2);
}

#[test]
fn a_cancelled_job_renders_nothing() {
    let blobs = BlobSet::new();
    let inputs = [PreviewInput {
        artifact: "preview.png",
        stage: "preview: result",
        main: "m.glb",
        blobs: &blobs,
        views: 2,
        size: 32,
    }];
    assert!(render_previews(&inputs, &IngestLimits::default(), &Control::new(), || true).is_none());
}

#[test]
fn progress_is_monotone_across_the_engine_and_the_previews() {
    let engine = Control::new();
    let preview = Control::new();
    engine.stage("load", 0).unwrap();
    let a = combined_progress(engine.progress(), preview.progress());
    engine.finish();
    let b = combined_progress(engine.progress(), preview.progress());
    assert!((b.fraction - ENGINE_SHARE).abs() < 1e-12);
    preview.stage("preview: result", 1).unwrap();
    let c = combined_progress(engine.progress(), preview.progress());
    assert_eq!(c.stage, "preview: result");
    preview.finish();
    let d = combined_progress(engine.progress(), preview.progress());
    assert!(a.fraction <= b.fraction && b.fraction <= c.fraction && c.fraction < d.fraction);
    assert!((d.fraction - 1.0).abs() < 1e-12);
    assert_eq!(d.stages_done, d.stages_total);
    assert_eq!(d.stages_total, 2);
}
