//! The per-job memory budget at submission (issue 9, item 1): an upload whose images would decode
//! to more than `max_decoded_image_bytes`, whose instanced meshes exceed `max_triangles`, or whose
//! method params would need more than `max_method_bytes` is a 422 problem naming the part and the
//! limit, before anything is decoded or stored; an image no drawn primitive samples costs
//! nothing and is never decoded.

use std::time::Duration;

use serde_json::json;

use crate::common;
use crate::service_common::*;

fn spot_target() -> Part<'static> {
    (
        "target",
        "spot.glb",
        asset("tgt_spot_remeshed_odedstein/spot_derived.glb"),
    )
}

#[test]
fn a_tiny_png_declaring_16384_squared_is_refused_at_submit_naming_the_image_and_the_limit() {
    let s = TestServer::start(|_| {});
    let bomb = common::bomb_png(16384, 16384);
    assert!(bomb.len() < 100);
    let source = common::textured_triangle_glb(&[bomb], 1);
    let r = submit(
        &s.base,
        &[
            ("source", "bomb.glb", source),
            spot_target(),
            ("constraints", "c.json", constraints(64)),
        ],
        &[],
    );
    let p = r.problem(422);
    assert_eq!(p["type"], "/problems/image-budget-exceeded", "{p}");
    assert_eq!(p["field"], "source.images[0]", "{p}");
    assert_eq!(
        p["limit"],
        json!({"name": "max_decoded_image_bytes", "value": 512u64 << 20}),
        "{p}"
    );
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("16384x16384"), "{detail}");
    // Nothing was accepted.
    let list = get(&format!("{}/v1/jobs", s.base)).json();
    assert_eq!(list["jobs"].as_array().map(Vec::len), Some(0), "{list}");
}

#[test]
fn an_unused_huge_image_is_accepted_and_never_decoded() {
    let s = TestServer::start(|_| {});
    // Image 1 claims 16384² with a few bytes of data: decoding it would fail the job.
    let source = common::textured_triangle_glb(
        &[common::small_png(8, 4), common::bomb_png(16384, 16384)],
        1,
    );
    let r = submit(
        &s.base,
        &[
            ("source", "unused.glb", source),
            spot_target(),
            ("constraints", "c.json", constraints(64)),
        ],
        &[],
    );
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
}

#[test]
fn instanced_triangles_over_max_triangles_are_refused_at_submit() {
    let s = TestServer::start(|c| c.limits.max_triangles = 200);
    // One stored triangle, 300 instances: the surface would hold 300.
    let source = common::textured_triangle_glb(&[common::small_png(2, 2)], 300);
    let r = submit(
        &s.base,
        &[
            ("source", "many.glb", source),
            spot_target(),
            ("constraints", "c.json", constraints(64)),
        ],
        &[],
    );
    let p = r.problem(422);
    assert_eq!(p["type"], "/problems/too-many-triangles", "{p}");
    assert_eq!(p["field"], "source", "{p}");
    assert_eq!(
        p["limit"],
        json!({"name": "max_triangles", "value": 200}),
        "{p}"
    );
}

#[test]
fn an_over_large_meshmatch_sample_count_is_refused_at_submit() {
    let s = TestServer::start(|c| c.limits.max_method_bytes = 512 << 20);
    let spot = asset("src_spot_keenan/spot_textured_derived.glb");
    let c = br#"{"version": 1, "method": "meshmatch", "output": {"texture_size": 64},
                "params": {"samples": 262144}}"#;
    let r = submit(
        &s.base,
        &[
            ("source", "spot.glb", spot),
            spot_target(),
            ("constraints", "c.json", c.to_vec()),
        ],
        &[],
    );
    let p = r.problem(422);
    assert_eq!(p["type"], "/problems/working-set-over-budget", "{p}");
    assert_eq!(p["field"], "constraints.params.samples", "{p}");
    assert_eq!(
        p["limit"],
        json!({"name": "max_method_bytes", "value": 512u64 << 20}),
        "{p}"
    );
}
