//! The `correlation` method through the HTTP API (issue 11): a job with `params.debug` lists its
//! debug files (`guidance.glb`, `segmentation.glb`) among the job's artifacts, and they download
//! as validator-clean models; without `debug` they are not listed.

use std::time::Duration;

use crate::common;
use crate::service_common::{get, submit, terminal, wait_for, Part, Resp, TestServer};

fn spot() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/src_spot_keenan/spot_textured_derived.glb"
    ))
    .unwrap()
}

fn spot_low() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/tgt_spot_remeshed_odedstein/spot_low_resolution_derived.glb"
    ))
    .unwrap()
}

fn id_of(r: &Resp) -> String {
    r.json()["id"].as_str().unwrap().to_string()
}

#[test]
fn correlation_debug_files_are_listed_and_downloadable() {
    let s = TestServer::start(|_| {});
    for debug in [true, false] {
        let constraints = format!(
            r#"{{"version": 1, "method": "correlation", "output": {{"vertex_colors": true}},
                "params": {{"samples": 8192, "vertex_color_samples": 8000, "debug": {debug}}}}}"#
        );
        let parts: Vec<Part<'static>> = vec![
            ("source", "spot.glb", spot()),
            ("target", "spot_low.glb", spot_low()),
            ("constraints", "constraints.json", constraints.into_bytes()),
        ];
        let r = submit(&s.base, &parts, &[]);
        assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
        let id = id_of(&r);
        let doc = wait_for(&s.base, &id, Duration::from_secs(300), terminal);
        assert_eq!(doc["status"], "succeeded", "{doc}");
        let listed: Vec<(String, String)> = doc["links"]["artifacts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| {
                (
                    a["name"].as_str().unwrap().to_string(),
                    a["href"].as_str().unwrap().to_string(),
                )
            })
            .collect();
        for name in ["guidance.glb", "segmentation.glb"] {
            let link = listed.iter().find(|(n, _)| n == name);
            assert_eq!(link.is_some(), debug, "{name}: {listed:?}");
            if let Some((_, href)) = link {
                let r = get(&format!("{}{href}", s.base));
                assert_eq!(r.status, 200, "{href}");
                common::assert_validator_clean(&r.body, &format!("service_correlation_{name}"));
            }
        }
    }
}
