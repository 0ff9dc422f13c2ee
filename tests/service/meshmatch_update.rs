//! MeshMatch texture update (§5.3, issue 14 item 5) through the HTTP API: the striped capsule
//! whose second half was lengthened after painting (`tests/engine/meshmatch_update.rs`), with the
//! copy region found automatically. The job must succeed; the result must be validator-clean,
//! the report must count the copied synthesis vertices, the copied part must be the source's
//! colour, and the job must say nothing was lost on the way (no warning about a copy region off
//! the source).

#[path = "../engine/meshmatch_common.rs"]
mod meshmatch_common;

use crate::service_common::{run_job, Part, TestServer};
use meshmatch_common::{colored_points, update_copy_error, update_pair};

#[test]
fn meshmatch_texture_update_runs_through_the_api() {
    let server = TestServer::start(|_| {});
    let base = &server.base;
    let pair = update_pair(2.0);
    let constraints = serde_json::json!({"version": 1, "method": "meshmatch", "seed": 1,
        "output": {"vertex_colors": true},
        "params": {"samples": 4096, "vertex_color_samples": 20000, "update": {}}});
    let parts: Vec<Part<'_>> = vec![
        ("source", "painted.glb", pair.source.clone()),
        ("target", "edited.glb", pair.target.clone()),
        (
            "constraints",
            "c.json",
            constraints.to_string().into_bytes(),
        ),
    ];
    let (job, result) = run_job(base, &parts, "api_meshmatch_update.glb");
    let report = &job["report"]["method_report"];
    let (copied, total) = (
        report["copied_samples"].as_u64().unwrap(),
        report["target_samples"].as_u64().unwrap(),
    );
    // The target's x ≤ 2 lies on the source: about 63% of its area.
    assert!(
        copied > total / 2 && copied < total * 4 / 5,
        "copied {copied} of {total}"
    );
    let warnings = job["report"]["warnings"].as_array().unwrap();
    assert!(
        !warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("update:")),
        "{warnings:?}"
    );
    let (err, n) = update_copy_error(&colored_points(&result), 0.05, 1.9);
    assert!(
        n > 200 && err < 0.02,
        "copied part: error {err} over {n} points"
    );
}
