//! The method seam through the HTTP API (issue 8): the methods and their params are checked at
//! submission (422 naming the field, not a 202 and a failed job), the parts a method needs follow
//! its declared inputs, and a method registered only in this test runs end to end.

use retex::engine::methods::Registry;

use crate::common::planar_pattern::{small_jpeg, PLANAR_PATTERN};
use crate::service_common::{get, submit, terminal, wait_for, Part, TestServer};

fn spot() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/src_spot_keenan/spot_textured_derived.glb"
    ))
    .unwrap()
}

fn constraints(json: &str) -> Part<'static> {
    ("constraints", "c.json", json.as_bytes().to_vec())
}

#[test]
fn unknown_methods_and_bad_params_are_422_at_submission() {
    let server = TestServer::start(|_| {});
    let base = &server.base;
    let pair = |c: &str| {
        vec![
            ("source", "spot.glb", spot()),
            ("target", "spot.glb", spot()),
            constraints(c),
        ]
    };
    // Every method id has a built-in method now; an id that is not one is a 422 naming it.
    let p = submit(base, &pair(r#"{"version": 1, "method": "detial"}"#), &[]).problem(422);
    assert_eq!(p["type"], "/problems/invalid-constraints", "{p}");
    assert!(p["detail"].as_str().unwrap().contains("detial"), "{p}");
    let r = submit(
        base,
        &pair(r#"{"version": 1, "method": "meshmatch", "params": {"samples": 5}}"#),
        &[],
    );
    let p = r.problem(422);
    assert_eq!(p["field"], "constraints.params.samples", "{p}");
    let p = submit(
        base,
        &pair(r#"{"version": 1, "method": "meshmatch", "params": {"hks": {"hks_times": -1}}}"#),
        &[],
    )
    .problem(422);
    assert_eq!(p["field"], "constraints.params.hks.hks_times", "{p}");
    let p = submit(
        base,
        &pair(r#"{"version": 1, "params": {"max_distance": 0}}"#),
        &[],
    )
    .problem(422);
    assert_eq!(p["field"], "constraints.params.max_distance", "{p}");
    // Nothing was accepted.
    let list = get(&format!("{base}/v1/jobs")).json();
    assert_eq!(list["jobs"].as_array().map_or(0, Vec::len), 0, "{list}");
}

#[test]
fn parts_follow_the_methods_declared_inputs() {
    let server = TestServer::start(|_| {});
    // project reads a source.
    let p = submit(&server.base, &[("target", "spot.glb", spot())], &[]).problem(400);
    assert_eq!(p["field"], "source", "{p}");
    // Without a constraints part the job is {"version": 1}: project, defaults.
    let r = submit(
        &server.base,
        &[
            ("source", "spot.glb", spot()),
            ("target", "spot.glb", spot()),
        ],
        &[],
    );
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
}

#[test]
fn a_method_registered_in_a_test_runs_end_to_end() {
    let registry = Registry::builtin().with(&PLANAR_PATTERN);
    let server = TestServer::start_with_registry(registry, |_| {});
    let base = &server.base;
    let jpeg = small_jpeg();
    // The pattern is required by this method: a clear 400 without it.
    let p = submit(
        base,
        &[
            ("target", "spot.glb", spot()),
            constraints(r#"{"version": 1, "method": "pattern"}"#),
        ],
        &[],
    )
    .problem(400);
    assert_eq!(p["field"], "pattern", "{p}");
    // No source part: this method does not read one.
    let r = submit(
        base,
        &[
            ("target", "spot.glb", spot()),
            ("pattern", "tiles.jpg", jpeg.clone()),
            constraints(r#"{"version": 1, "method": "pattern"}"#),
        ],
        &[],
    );
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let job = wait_for(base, &id, std::time::Duration::from_secs(120), terminal);
    assert_eq!(job["status"], "succeeded", "{job}");
    assert!((job["progress"]["fraction"].as_f64().unwrap() - 1.0).abs() < 1e-9);
    let result = get(&format!("{base}/v1/jobs/{id}/result"));
    assert_eq!(result.status, 200);
    crate::common::assert_validator_clean(&result.body, "seam_http_test_method.glb");
    let back = crate::common::load_bytes(&result.body, "r.glb");
    assert_eq!(
        back.images.last().unwrap().bytes.as_slice(),
        jpeg.as_slice()
    );
    let extra = get(&format!("{base}/v1/jobs/{id}/artifacts/planar.txt"));
    assert_eq!(extra.status, 200);
    assert_eq!(extra.body, b"planar projection onto x/y");
    let image = get(&format!("{base}/v1/jobs/{id}/artifacts/pattern.jpg"));
    assert_eq!(image.body, jpeg);
}
