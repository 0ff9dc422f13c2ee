//! Bad input over HTTP: every malformed upload from the ingest list (bad GLB, lying chunk
//! lengths, `../` URIs, a PNG decompression bomb, out-of-range indices), missing parts, bad
//! constraints and size limits gets a 4xx problem naming the field and the limit, never a 5xx,
//! and nothing is accepted.

use crate::common;

use crate::service_common::*;

/// A one-triangle .gltf with `tri.bin`; `patch` edits the JSON.
fn triangle_parts(patch: impl FnOnce(&mut serde_json::Value)) -> Vec<Part<'static>> {
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let mut json = serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "tri.bin", "byteLength": 44}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3,
                       "min": [0, 0, 0], "max": [1, 1, 0]},
                      {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]
    });
    patch(&mut json);
    let spot = asset("src_spot_keenan/spot_textured_derived.glb");
    vec![
        ("source", "spot.glb", spot),
        ("target", "tri.gltf", serde_json::to_vec(&json).unwrap()),
        ("target", "tri.bin", bin),
        ("constraints", "c.json", constraints(64)),
    ]
}

#[test]
fn malformed_uploads_get_4xx_problems_never_5xx() {
    let s = TestServer::start(|c| {
        c.max_texture_size = 1024;
        c.max_part_bytes = 4 << 20;
        c.max_body_bytes = 12 << 20;
    });
    let spot = asset("src_spot_keenan/spot_textured_derived.glb");
    let with = |i: usize, part: Part<'static>| {
        let mut p = spot_parts(64);
        p[i] = part;
        p
    };
    // A GLB whose JSON chunk length lies.
    let mut lying = spot.clone();
    lying[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
    let mut truncated = spot.clone();
    truncated.truncate(spot.len() / 2);
    let bomb = {
        let mut p = triangle_parts(|j| {
            j["images"] = serde_json::json!([{"uri": "bomb.png"}]);
            j["textures"] = serde_json::json!([{"source": 0}]);
            j["materials"] =
                serde_json::json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
            j["meshes"][0]["primitives"][0]["material"] = 0.into();
        });
        p.push(("target", "bomb.png", common::bomb_png(100_000, 100_000)));
        p
    };
    // (what, parts, status, field prefix, limit name)
    type Case = (
        &'static str,
        Vec<Part<'static>>,
        u16,
        &'static str,
        Option<&'static str>,
    );
    let cases: Vec<Case> = vec![
        (
            "garbage glb",
            with(0, ("source", "x.glb", b"not a model at all".to_vec())),
            422,
            "source",
            None,
        ),
        (
            "lying chunk length",
            with(1, ("target", "x.glb", lying)),
            422,
            "target",
            None,
        ),
        (
            "truncated glb",
            with(1, ("target", "x.glb", truncated)),
            422,
            "target",
            None,
        ),
        (
            "../ uri",
            triangle_parts(|j| j["buffers"][0]["uri"] = "../../etc/passwd".into()),
            422,
            "target.buffers[0].uri",
            None,
        ),
        (
            "bomb png",
            bomb,
            422,
            "target.images[0]",
            Some("max_image_side"),
        ),
        (
            "index out of range",
            triangle_parts(|j| j["accessors"][1]["count"] = 4.into()),
            422,
            "target",
            None,
        ),
        (
            "missing target",
            spot_parts(64)
                .into_iter()
                .filter(|p| p.0 != "target")
                .collect(),
            400,
            "target",
            None,
        ),
        (
            // Without a constraints part the defaults apply: texture 2048 > this server's 1024.
            "missing constraints",
            spot_parts(64)
                .into_iter()
                .filter(|p| p.0 != "constraints")
                .collect(),
            422,
            "constraints.output.texture_size",
            Some("max_texture_size"),
        ),
        (
            "bad json constraints",
            with(2, ("constraints", "c.json", b"{not json".to_vec())),
            422,
            "constraints",
            None,
        ),
        (
            "unknown method",
            with(
                2,
                (
                    "constraints",
                    "c.json",
                    br#"{"version":1,"method":"magic"}"#.to_vec(),
                ),
            ),
            422,
            "constraints.method",
            None,
        ),
        (
            "texture over the server max",
            with(2, ("constraints", "c.json", constraints(2048))),
            422,
            "constraints.output.texture_size",
            Some("max_texture_size"),
        ),
        (
            "unknown part",
            with(2, ("colour", "c.json", constraints(64))),
            400,
            "colour",
            None,
        ),
        (
            "path in filename",
            with(0, ("source", "../spot.glb", spot.clone())),
            400,
            "source",
            None,
        ),
        (
            "part over max_part_bytes",
            with(0, ("source", "big.glb", vec![0u8; 5 << 20])),
            413,
            "source",
            Some("max_part_bytes"),
        ),
    ];
    for (what, parts, status, field, limit) in cases {
        let r = submit(&s.base, &parts, &[]);
        assert!(r.status < 500, "{what}: {}", r.status);
        let p = r.problem(status);
        assert!(
            p["field"].as_str().unwrap_or("").starts_with(field),
            "{what}: {p}"
        );
        if let Some(l) = limit {
            assert_eq!(p["limit"]["name"], l, "{what}: {p}");
        }
    }
    // The whole body over max_body_bytes: 413 naming the limit.
    let parts: Vec<Part<'static>> = (0..4)
        .map(|_| ("source", "x.bin", vec![1u8; 3_500_000]))
        .collect();
    let p = submit(&s.base, &parts, &[]).problem(413);
    assert_eq!(p["limit"]["name"], "max_body_bytes", "{p}");
    // Not multipart at all.
    let r = request(
        "POST",
        &format!("{}/v1/jobs", s.base),
        &[("Content-Type", "application/json")],
        Some(b"{}"),
    );
    assert!((400..500).contains(&r.status), "{}", r.status);
    // Nothing was accepted.
    assert!(get(&format!("{}/v1/jobs", s.base)).json()["jobs"]
        .as_array()
        .unwrap()
        .is_empty());
}

/// Rejections decided before the body is read to its end (a part over its limit, the whole body
/// over its limit, a bad header) still reach a client that writes its whole body before reading
/// (as ureq and curl without `Expect` do): the server drains the rest instead of resetting the
/// connection. Repeated, since a reset is a race the client loses only sometimes.
#[test]
fn early_rejections_reach_clients_still_writing() {
    let s = TestServer::start(|c| {
        c.max_part_bytes = 4 << 20;
        c.max_body_bytes = 12 << 20;
    });
    let big_part: Vec<Part<'static>> = vec![("source", "big.glb", vec![0u8; 9 << 20])];
    let big_body: Vec<Part<'static>> = (0..4)
        .map(|_| ("source", "x.bin", vec![1u8; 3_500_000]))
        .collect();
    for round in 0..8 {
        let p = submit(&s.base, &big_part, &[]).problem(413);
        assert_eq!(p["limit"]["name"], "max_part_bytes", "round {round}: {p}");
        let p = submit(&s.base, &big_body, &[]).problem(413);
        assert_eq!(p["limit"]["name"], "max_body_bytes", "round {round}: {p}");
        let p = submit(&s.base, &big_part, &[("Idempotency-Key", "")]).problem(400);
        assert_eq!(p["field"], "Idempotency-Key", "round {round}: {p}");
    }
}

/// A client that waits for `100 Continue` and declares a body over `max_body_bytes` gets the
/// 413 at once, without being asked for the body.
#[test]
fn expect_continue_over_the_limit_is_answered_without_the_body() {
    use std::io::{Read, Write};
    let s = TestServer::start(|c| c.max_body_bytes = 1 << 20);
    let addr = s.base.trim_start_matches("http://").to_string();
    let mut tcp = std::net::TcpStream::connect(&addr).unwrap();
    tcp.set_read_timeout(Some(std::time::Duration::from_secs(20)))
        .unwrap();
    write!(
        tcp,
        "POST /v1/jobs HTTP/1.1\r\nHost: {addr}\r\nContent-Type: multipart/form-data; boundary=b\r\nContent-Length: {}\r\nExpect: 100-continue\r\nConnection: close\r\n\r\n",
        2u64 << 20
    )
    .unwrap();
    let mut answer = Vec::new();
    let _ = tcp.read_to_end(&mut answer);
    let text = String::from_utf8_lossy(&answer);
    assert!(text.starts_with("HTTP/1.1 413"), "{text}");
    assert!(!text.contains("100 Continue"), "{text}");
    assert!(text.contains("max_body_bytes"), "{text}");
}
