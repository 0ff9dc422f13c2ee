//! The HTTP service end to end over a real socket (port 0): submit with curl-style multipart
//! bodies built from Spot and Fox (`tests/data`), follow by polling and by SSE, download and
//! validate with the Khronos validator; cancellation; idempotency; ETag/304; Range; pagination;
//! auth; CORS; queue-full 503; and that the engine runs on the runner's threads only.

use crate::common;

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use crate::service_common::*;

fn id_of(r: &Resp) -> String {
    match r.json()["id"].as_str() {
        Some(id) => id.to_string(),
        None => panic!("{}: {}", r.status, String::from_utf8_lossy(&r.body)),
    }
}

#[test]
fn spot_glb_submit_poll_download_validate() {
    let s = TestServer::start(|_| {});
    let r = submit(&s.base, &spot_parts(256), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = id_of(&r);
    assert_eq!(
        r.header("location"),
        Some(format!("/v1/jobs/{id}").as_str())
    );
    assert!(r.header("retry-after").is_some());
    let doc = r.json();
    assert_eq!(doc["status"], "enqueued");
    assert_eq!(doc["links"]["result"], format!("/v1/jobs/{id}/result"));

    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    assert!(
        doc["finished_at"].is_string() && doc["report"].is_object(),
        "{doc}"
    );
    assert!(!doc["links"]["artifacts"].as_array().unwrap().is_empty());

    // ETag / If-None-Match on the job document.
    let r = get(&format!("{}/v1/jobs/{id}", s.base));
    let tag = r.header("etag").unwrap().to_string();
    let r = request(
        "GET",
        &format!("{}/v1/jobs/{id}", s.base),
        &[("If-None-Match", &tag)],
        None,
    );
    assert_eq!(r.status, 304);

    // The result: a GLB with a strong ETag, that validates; ranges; 304.
    let url = format!("{}/v1/jobs/{id}/result", s.base);
    let r = get(&url);
    assert_eq!(r.status, 200);
    assert_eq!(r.header("content-type"), Some("model/gltf-binary"));
    assert!(r.header("content-disposition").unwrap().contains(".glb"));
    assert_eq!(&r.body[..4], b"glTF");
    common::assert_validator_clean(&r.body, "service_spot_result.glb");
    let etag = r.header("etag").unwrap().to_string();
    assert_eq!(etag.len(), 66, "sha-256 etag: {etag}");
    let part = request("GET", &url, &[("Range", "bytes=4-11")], None);
    assert_eq!(part.status, 206);
    assert_eq!(part.body, r.body[4..12]);
    assert_eq!(
        part.header("content-range").unwrap(),
        format!("bytes 4-11/{}", r.body.len())
    );
    let tail = request("GET", &url, &[("Range", "bytes=-16")], None);
    assert_eq!(tail.body, r.body[r.body.len() - 16..]);
    let bad = request(
        "GET",
        &url,
        &[("Range", &format!("bytes={}-", r.body.len()))],
        None,
    );
    bad.problem(416);
    assert_eq!(
        request("GET", &url, &[("If-None-Match", &etag)], None).status,
        304
    );

    // Artifacts are listed and downloadable; report.json is JSON.
    let r = get(&format!("{}/v1/jobs/{id}/artifacts/report.json", s.base));
    assert_eq!(r.status, 200);
    assert!(r.json().is_object());
    get(&format!("{}/v1/jobs/{id}/artifacts/nope.png", s.base)).problem(404);

    // Metrics count requests by route template.
    let m = String::from_utf8(get(&format!("{}/metrics", s.base)).body).unwrap();
    assert!(m.contains(r#"route="/v1/jobs/{id}",status="200""#), "{m}");
    assert!(m.contains("retex_queue_depth 0"), "{m}");
    assert!(m.contains(r#"retex_jobs{status="succeeded"} 1"#), "{m}");
    assert!(m.contains("retex_stage_duration_seconds_bucket"), "{m}");

    // DELETE removes it and its files.
    assert_eq!(
        request("DELETE", &format!("{}/v1/jobs/{id}", s.base), &[], None).status,
        204
    );
    get(&format!("{}/v1/jobs/{id}", s.base)).problem(404);
    assert!(!s.data.path().join(format!("blobs/jobs/{id}")).exists());
}

#[test]
fn fox_multi_file_gltf_followed_through_sse() {
    let s = TestServer::start(|_| {});
    let fox = common::test_data("src_fox_khronos/glTF/Fox.gltf");
    let mut parts = model_parts_from(&fox, "source");
    parts.extend(model_parts_from(&fox, "target"));
    parts.push(("constraints", "c.json", constraints(256)));
    assert!(
        parts.len() >= 5,
        "Fox has .gltf, .bin and a texture per side"
    );
    let r = submit(&s.base, &parts, &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = id_of(&r);
    let events = read_events(&format!("{}/v1/jobs/{id}/events", s.base), None);
    let (last_name, _, last) = events.last().unwrap();
    assert_eq!(last_name, "done");
    assert_eq!(last["status"], "succeeded", "{events:?}");
    let ids: Vec<u64> = events.iter().map(|e| e.1).collect();
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "ids increase: {ids:?}");
    // Resuming after the last id gives just the terminal event.
    let again = read_events(
        &format!("{}/v1/jobs/{id}/events", s.base),
        Some(&ids.last().unwrap().to_string()),
    );
    assert_eq!(again.len(), 1);
    assert_eq!(again[0].0, "done");
    let r = get(&format!("{}/v1/jobs/{id}/result", s.base));
    assert_eq!(r.status, 200);
    common::assert_validator_clean(&r.body, "service_fox_result.glb");
}

#[test]
fn fox_as_a_zip_is_accepted() {
    let s = TestServer::start(|_| {});
    let fox = common::test_data("src_fox_khronos/glTF/Fox.gltf");
    let mut zip_bytes = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut zip_bytes);
        for (_, name, bytes) in model_parts_from(&fox, "source") {
            z.start_file(
                format!("glTF/{name}"),
                zip::write::SimpleFileOptions::default(),
            )
            .unwrap();
            std::io::Write::write_all(&mut z, &bytes).unwrap();
        }
        z.finish().unwrap();
    }
    let zip = zip_bytes.into_inner();
    let parts = vec![
        ("source", "fox.zip", zip.clone()),
        ("target", "fox.zip", zip),
        ("constraints", "c.json", constraints(64)),
    ];
    let r = submit(&s.base, &parts, &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let doc = wait_for(&s.base, &id_of(&r), Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
}

#[test]
fn cancel_enqueued_and_processing_jobs() {
    let s = TestServer::start(|c| c.workers = 1);
    let slow = submit(&s.base, &spot_parts(8192), &[]);
    assert_eq!(slow.status, 202, "{}", String::from_utf8_lossy(&slow.body));
    let slow_id = id_of(&slow);
    wait_for(&s.base, &slow_id, Duration::from_secs(60), |st| {
        st != "enqueued"
    });
    let queued = submit(&s.base, &spot_parts(64), &[]);
    let queued_id = id_of(&queued);
    // Enqueued: canceled at once.
    let r = request(
        "POST",
        &format!("{}/v1/jobs/{queued_id}/cancel", s.base),
        &[],
        None,
    );
    assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
    assert_eq!(r.json()["status"], "canceled");
    // Processing: stops within about a second (asserted with a generous bound: the machine may
    // be busy with other tests).
    std::thread::sleep(Duration::from_millis(500));
    let t = std::time::Instant::now();
    let r = request(
        "POST",
        &format!("{}/v1/jobs/{slow_id}/cancel", s.base),
        &[],
        None,
    );
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let doc = wait_for(&s.base, &slow_id, Duration::from_secs(10), terminal);
    assert_eq!(doc["status"], "canceled", "{doc}");
    assert!(
        t.elapsed() < Duration::from_secs(5),
        "cancel took {:?}",
        t.elapsed()
    );
    // Terminal: 409; result of a canceled job: 409.
    request(
        "POST",
        &format!("{}/v1/jobs/{slow_id}/cancel", s.base),
        &[],
        None,
    )
    .problem(409);
    get(&format!("{}/v1/jobs/{slow_id}/result", s.base)).problem(409);
    assert_eq!(
        get(&format!("{}/v1/jobs/{queued_id}", s.base)).json()["status"],
        "canceled"
    );
}

#[test]
fn queue_full_answers_503_and_delete_of_running_job_is_409() {
    let s = TestServer::start(|c| {
        c.workers = 1;
        c.queue_len = 1;
    });
    let slow = submit(&s.base, &spot_parts(8192), &[]);
    let slow_id = id_of(&slow);
    wait_for(&s.base, &slow_id, Duration::from_secs(60), |st| {
        st != "enqueued"
    });
    assert_eq!(submit(&s.base, &spot_parts(64), &[]).status, 202);
    let full = submit(&s.base, &spot_parts(64), &[]);
    let p = full.problem(503);
    assert!(full.header("retry-after").is_some());
    assert_eq!(p["limit"]["name"], "queue_len");
    request(
        "DELETE",
        &format!("{}/v1/jobs/{slow_id}", s.base),
        &[],
        None,
    )
    .problem(409);
    get(&format!("{}/v1/jobs/{slow_id}/result", s.base)).problem(409);
    request(
        "POST",
        &format!("{}/v1/jobs/{slow_id}/cancel", s.base),
        &[],
        None,
    );
}

#[test]
fn idempotency_key_replays_and_mismatches() {
    let s = TestServer::start(|_| {});
    let key = [("Idempotency-Key", "build-1234")];
    let first = submit(&s.base, &spot_parts(64), &key);
    assert_eq!(first.status, 202);
    let again = submit(&s.base, &spot_parts(64), &key);
    assert!(
        again.status == 200 || again.status == 202,
        "{}",
        again.status
    );
    assert_eq!(id_of(&again), id_of(&first));
    let other = submit(&s.base, &spot_parts(128), &key);
    let p = other.problem(422);
    assert_eq!(p["type"], "/problems/idempotency-key-reused");
    let list = get(&format!("{}/v1/jobs", s.base)).json();
    assert_eq!(
        list["jobs"].as_array().unwrap().len(),
        1,
        "no duplicate job: {list}"
    );
}

#[test]
fn list_filters_and_paginates_newest_first() {
    let s = TestServer::start(|_| {});
    let mut ids = Vec::new();
    for _ in 0..5 {
        ids.push(id_of(&submit(&s.base, &spot_parts(16), &[])));
    }
    let mut seen = Vec::new();
    let mut url = format!("{}/v1/jobs?limit=2", s.base);
    loop {
        let page = get(&url).json();
        let jobs = page["jobs"].as_array().unwrap();
        assert!(jobs.len() <= 2);
        seen.extend(jobs.iter().map(|j| j["id"].as_str().unwrap().to_string()));
        match page["next"].as_str() {
            Some(n) => url = format!("{}/v1/jobs?limit=2&next={n}", s.base),
            None => break,
        }
    }
    ids.reverse();
    assert_eq!(seen, ids, "every job once, newest first");
    for id in &ids {
        wait_for(&s.base, id, Duration::from_secs(120), terminal);
    }
    let ok = get(&format!(
        "{}/v1/jobs?status=succeeded&method=project",
        s.base
    ))
    .json();
    assert_eq!(ok["jobs"].as_array().unwrap().len(), 5);
    let none = get(&format!("{}/v1/jobs?status=failed", s.base)).json();
    assert!(none["jobs"].as_array().unwrap().is_empty());
    let future = get(&format!(
        "{}/v1/jobs?created_after=2999-01-01T00:00:00Z",
        s.base
    ))
    .json();
    assert!(future["jobs"].as_array().unwrap().is_empty());
    get(&format!("{}/v1/jobs?status=bogus", s.base)).problem(400);
    get(&format!("{}/v1/jobs?limit=0", s.base)).problem(400);
    get(&format!("{}/v1/jobs?next=garbage", s.base)).problem(400);
}

#[test]
fn retention_prunes_finished_jobs_and_files() {
    let s = TestServer::start(|c| {
        c.ttl_secs = 1;
        c.prune_interval_secs = 1;
    });
    let id = id_of(&submit(&s.base, &spot_parts(16), &[]));
    wait_for(&s.base, &id, Duration::from_secs(60), terminal);
    let start = std::time::Instant::now();
    while get(&format!("{}/v1/jobs/{id}", s.base)).status != 404 {
        assert!(start.elapsed() < Duration::from_secs(10), "not pruned");
        std::thread::sleep(Duration::from_millis(200));
    }
    assert!(!s.data.path().join(format!("blobs/jobs/{id}")).exists());
}

#[test]
fn tokens_guard_everything_but_health_and_cors_exposes_headers() {
    let s = TestServer::start(|c| {
        c.tokens = vec!["s3cret-token".into()];
        c.cors_origins = vec!["https://dash.example".into()];
    });
    assert_eq!(get(&format!("{}/healthz", s.base)).status, 200);
    let p = get(&format!("{}/v1/jobs", s.base)).problem(401);
    assert_eq!(p["field"], "Authorization");
    let wrong = [("Authorization", "Bearer s3cret-tokem")];
    request("GET", &format!("{}/v1/jobs", s.base), &wrong, None).problem(401);
    let right = [("Authorization", "Bearer s3cret-token")];
    assert_eq!(
        request("GET", &format!("{}/v1/jobs", s.base), &right, None).status,
        200
    );
    let r = submit(&s.base, &spot_parts(16), &right);
    assert_eq!(r.status, 202);
    let r = request(
        "GET",
        &format!("{}/v1/jobs", s.base),
        &[
            ("Origin", "https://dash.example"),
            ("Authorization", "Bearer s3cret-token"),
        ],
        None,
    );
    assert_eq!(
        r.header("access-control-allow-origin"),
        Some("https://dash.example")
    );
    let exposed = r
        .header("access-control-expose-headers")
        .unwrap()
        .to_ascii_lowercase();
    for h in ["location", "etag", "retry-after"] {
        assert!(exposed.contains(h), "{exposed}");
    }
    let r = request(
        "GET",
        &format!("{}/healthz", s.base),
        &[("Origin", "https://evil.example")],
        None,
    );
    assert_eq!(r.header("access-control-allow-origin"), None);
}

#[test]
fn unknown_jobs_and_routes_are_problems() {
    let s = TestServer::start(|_| {});
    let id = "0190d3c6-0000-7000-8000-000000000000";
    for path in ["", "/result", "/events", "/artifacts/report.json"] {
        get(&format!("{}/v1/jobs/{id}{path}", s.base)).problem(404);
    }
    request(
        "POST",
        &format!("{}/v1/jobs/{id}/cancel", s.base),
        &[],
        None,
    )
    .problem(404);
    request("DELETE", &format!("{}/v1/jobs/{id}", s.base), &[], None).problem(404);
    get(&format!("{}/v1/jobs/not-a-uuid", s.base)).problem(400);
    get(&format!("{}/v2/nothing", s.base)).problem(404);
    assert_eq!(get(&format!("{}/readyz", s.base)).status, 200);
}

#[test]
fn the_engine_runs_only_on_runner_threads() {
    let s = TestServer::start(|_| {});
    let calls = Arc::new(AtomicUsize::new(0));
    let bad = Arc::new(AtomicBool::new(false));
    let (c, b) = (calls.clone(), bad.clone());
    s.state.runner.set_engine_hook(Some(Arc::new(
        move |_job: &retex::service::model::JobRecord| {
            c.fetch_add(1, Ordering::SeqCst);
            let on_tokio = tokio::runtime::Handle::try_current().is_ok();
            if on_tokio || !retex::service::jobs::runner::on_engine_thread() {
                b.store(true, Ordering::SeqCst);
            }
        },
    )));
    let id = id_of(&submit(&s.base, &spot_parts(16), &[]));
    let doc = wait_for(&s.base, &id, Duration::from_secs(60), terminal);
    assert_eq!(doc["status"], "succeeded");
    assert_eq!(calls.load(Ordering::SeqCst), 1);
    assert!(!bad.load(Ordering::SeqCst), "engine ran on a tokio thread");
}

/// A `meshmatch` job end to end: progress shows its levels, the result validates, and the
/// nearest-neighbour field is downloadable as the `nnf.bin` artifact and decodes.
#[test]
fn meshmatch_job_serves_its_result_and_nnf() {
    let s = TestServer::start(|_| {});
    let spot = asset("src_spot_keenan/spot_textured_derived.glb");
    let target = asset("tgt_spot_remeshed_odedstein/spot_low_resolution_derived.glb");
    let parts: Vec<Part<'static>> = vec![
        ("source", "spot.glb", spot),
        ("target", "spot_low.glb", target),
        (
            "constraints",
            "constraints.json",
            br#"{"version": 1, "method": "meshmatch", "output": {"vertex_colors": true},
                 "params": {"samples": 8192}}"#
                .to_vec(),
        ),
    ];
    let r = submit(&s.base, &parts, &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = id_of(&r);
    let mut stages = std::collections::BTreeSet::new();
    let doc = {
        let start = std::time::Instant::now();
        loop {
            let doc = get(&format!("{}/v1/jobs/{id}", s.base)).json();
            if let Some(stage) = doc["progress"]["stage"].as_str() {
                stages.insert(stage.to_string());
            }
            if terminal(doc["status"].as_str().unwrap()) {
                break doc;
            }
            assert!(start.elapsed() < Duration::from_secs(120), "{doc}");
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    assert_eq!(doc["status"], "succeeded", "{doc}");
    // Polling shows the method's own stages. Which ones a 10 ms poll catches depends on the
    // machine's speed (a run caught none of the short iteration stages), so the iteration
    // stages are checked in the job's report, which lists every stage.
    assert!(
        stages.iter().any(|s| s.starts_with("meshmatch level")),
        "stages seen: {stages:?}"
    );
    let report = get(&format!("{}/v1/jobs/{id}/artifacts/report.json", s.base)).json();
    let timed: Vec<&str> = report["timings"]
        .as_array()
        .map(|t| t.iter().filter_map(|x| x["stage"].as_str()).collect())
        .unwrap_or_default();
    assert!(
        timed
            .iter()
            .any(|s| s.starts_with("meshmatch level") && s.contains("iteration")),
        "stages in the report: {timed:?}"
    );
    let r = get(&format!("{}/v1/jobs/{id}/result", s.base));
    common::assert_validator_clean(&r.body, "service_meshmatch_result.glb");
    let nnf = get(&format!("{}/v1/jobs/{id}/artifacts/nnf.bin", s.base));
    assert_eq!(nnf.status, 200);
    let file = retex::engine::methods::meshmatch::nnf_file::NnfFile::decode(&nnf.body)
        .expect("nnf.bin decodes");
    assert_eq!(
        file.target_positions.len() as u64,
        doc["report"]["method_report"]["target_samples"]
            .as_u64()
            .unwrap()
    );
}

#[test]
fn constraints_part_is_optional_and_defaults_to_version_1() {
    let s = TestServer::start(|_| {});
    let parts: Vec<_> = spot_parts(64)
        .into_iter()
        .filter(|p| p.0 != "constraints")
        .collect();
    let r = submit(&s.base, &parts, &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = id_of(&r);
    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    let report = get(&format!("{}/v1/jobs/{id}/artifacts/report.json", s.base)).json();
    assert_eq!(report["method"], "project", "{report}");
}
