//! Contract details of the API (issue 9, item 11): top-level document errors name the part,
//! fast jobs report their real stage counts, a malformed job id is a 400 problem (and the
//! OpenAPI says so), job lists carry summaries rather than full reports, CORS allows
//! `If-Range`, an invalid cursor is not echoed back whole, and the README's blob layout is
//! where the files are.

use std::io::{Read, Write};
use std::time::Duration;

use chrono::Utc;
use retex::service::model::{JobInputs, JobProgress, JobRecord, JobStatus, ModelFiles};
use uuid::Uuid;

use crate::service_common::*;

/// Sends a raw HTTP/1.1 request (`Connection: close`) and returns the whole answer.
fn raw(s: &TestServer, request: &str) -> String {
    let mut tcp = std::net::TcpStream::connect(s.base.trim_start_matches("http://")).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    tcp.write_all(request.as_bytes()).unwrap();
    let mut out = Vec::new();
    tcp.read_to_end(&mut out).unwrap();
    String::from_utf8_lossy(&out).into_owned()
}

#[test]
fn top_level_document_errors_name_the_part() {
    let s = TestServer::start(|_| {});
    for doc in [
        &b"[1, 2]"[..],
        br#"{"asset": {"version": "2.0"}, "meshes": 5}"#,
    ] {
        let parts = vec![
            ("source", "s.gltf", doc.to_vec()),
            ("target", "t.gltf", doc.to_vec()),
        ];
        let p = submit(&s.base, &parts, &[]).problem(422);
        let field = p["field"].as_str().unwrap();
        assert!(field == "source" || field == "target", "{p}");
    }
}

#[test]
fn a_fast_job_reports_its_real_stage_counts() {
    // Progress snapshots every minute: the job ends long before the first one.
    let s = TestServer::start(|c| c.progress_interval_ms = 60_000);
    let r = submit(&s.base, &spot_parts(16), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    let stages = &doc["progress"]["stages"];
    assert!(stages["total"].as_u64().unwrap() > 0, "{doc}");
    assert_eq!(stages["done"], stages["total"], "{doc}");
}

#[test]
fn a_malformed_job_id_is_a_400_problem_naming_it() {
    let s = TestServer::start(|_| {});
    let long = "x".repeat(5000);
    for path in [
        "/v1/jobs/not-a-uuid".to_string(),
        "/v1/jobs/not-a-uuid/result".into(),
        "/v1/jobs/not-a-uuid/events".into(),
        "/v1/jobs/not-a-uuid/artifacts/report.json".into(),
        "/v1/jobs/not-a-uuid/files/preview.png".into(),
        format!("/v1/jobs/{long}"),
    ] {
        let p = get(&format!("{}{path}", s.base)).problem(400);
        assert_eq!(p["type"], "/problems/invalid-job-id", "{p}");
        assert_eq!(p["field"], "id", "{p}");
        assert!(p["detail"].as_str().unwrap().len() < 200, "{p}");
    }
    let p = request("DELETE", &format!("{}/v1/jobs/12345", s.base), &[], None).problem(400);
    assert_eq!(p["type"], "/problems/invalid-job-id", "{p}");
    // The contract lists the 400 on every job route.
    let api = get(&format!("{}/v1/openapi.json", s.base)).json();
    for (path, method) in [
        ("/v1/jobs/{id}", "get"),
        ("/v1/jobs/{id}", "delete"),
        ("/v1/jobs/{id}/cancel", "post"),
        ("/v1/jobs/{id}/result", "get"),
        ("/v1/jobs/{id}/artifacts/{name}", "get"),
        ("/v1/jobs/{id}/files/{name}", "get"),
        ("/v1/jobs/{id}/events", "get"),
    ] {
        assert!(
            api["paths"][path][method]["responses"]["400"].is_object(),
            "{method} {path} lists no 400"
        );
    }
}

/// A finished job with a report of about 8 KB, stored directly.
fn fat_job(n: usize) -> JobRecord {
    let now = Utc::now();
    let notes: Vec<String> = (0..200)
        .map(|i| format!("warning {i} of job {n}"))
        .collect();
    JobRecord {
        id: Uuid::now_v7(),
        status: JobStatus::Succeeded,
        method: "project".into(),
        progress: JobProgress::default(),
        created_at: now,
        started_at: Some(now),
        finished_at: Some(now),
        error: None,
        report: Some(serde_json::json!({ "warnings": notes })),
        attempts: 1,
        idempotency_key: None,
        owner: None,
        request_hash: format!("h{n}"),
        inputs: JobInputs {
            source: None,
            target: ModelFiles::default(),
            source_base: None,
            constraints: "jobs/x/inputs/constraints.json".into(),
            pattern: None,
        },
        artifacts: vec![],
        revision: 1,
    }
}

#[test]
fn job_lists_carry_summaries_and_the_full_report_is_on_the_job() {
    let s = TestServer::start(|_| {});
    let jobs: Vec<JobRecord> = (0..150).map(fat_job).collect();
    for j in &jobs {
        s.state.jobs.create(j).unwrap();
    }
    let page = get(&format!("{}/v1/jobs?limit=500", s.base));
    assert_eq!(page.status, 200);
    let list = page.json();
    let items = list["jobs"].as_array().unwrap();
    assert_eq!(items.len(), 150);
    assert!(
        items.iter().all(|j| j.get("report").is_none()),
        "{}",
        items[0]
    );
    // A page stays small: well under 1 KB a job (the reports alone are 8 KB each).
    assert!(
        page.body.len() < 150 * 1024,
        "a page of 150 is {} bytes",
        page.body.len()
    );
    let one = get(&format!("{}/v1/jobs/{}", s.base, jobs[0].id)).json();
    assert_eq!(one["report"]["warnings"].as_array().unwrap().len(), 200);
    assert_eq!(items[149]["id"], one["id"]);
    assert_eq!(items[149]["revision"], one["revision"]);
}

#[test]
fn cors_allows_if_range() {
    let s = TestServer::start(|c| c.cors_origins = vec!["https://dash.example".into()]);
    let answer = raw(
        &s,
        "OPTIONS /v1/jobs/0190c5a0-0000-7000-8000-000000000000/result HTTP/1.1\r\nHost: t\r\nOrigin: https://dash.example\r\nAccess-Control-Request-Method: GET\r\nAccess-Control-Request-Headers: if-range, range\r\nConnection: close\r\n\r\n",
    );
    let allowed = answer
        .lines()
        .find(|l| {
            l.to_ascii_lowercase()
                .starts_with("access-control-allow-headers:")
        })
        .unwrap_or_else(|| panic!("no allow-headers: {answer}"))
        .to_ascii_lowercase();
    assert!(allowed.contains("if-range"), "{allowed}");
}

#[test]
fn an_invalid_cursor_is_not_echoed_back_whole() {
    let s = TestServer::start(|_| {});
    let cursor = "A".repeat(4000);
    let r = get(&format!("{}/v1/jobs?next={cursor}", s.base));
    let p = r.problem(400);
    assert_eq!(p["type"], "/problems/invalid-cursor", "{p}");
    assert_eq!(p["field"], "next", "{p}");
    assert!(r.body.len() < 600, "{} bytes: {p}", r.body.len());
}

#[test]
fn the_readme_blob_layout_is_where_the_files_are() {
    let s = TestServer::start(|_| {});
    let r = submit(&s.base, &spot_parts(16), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    for (documented, actual) in [
        (
            "<data>/blobs/blobs/jobs/<id>/inputs/source/<file>",
            format!("blobs/blobs/jobs/{id}/inputs/source/spot.glb"),
        ),
        (
            "<data>/blobs/blobs/jobs/<id>/inputs/target/<file>",
            format!("blobs/blobs/jobs/{id}/inputs/target/spot.glb"),
        ),
        (
            "<data>/blobs/blobs/jobs/<id>/inputs/constraints.json",
            format!("blobs/blobs/jobs/{id}/inputs/constraints.json"),
        ),
        (
            "<data>/blobs/blobs/jobs/<id>/outputs/a<n>/result.glb",
            format!("blobs/blobs/jobs/{id}/outputs/a1/result.glb"),
        ),
    ] {
        assert!(readme.contains(documented), "README lacks {documented}");
        assert!(s.data.path().join(&actual).is_file(), "no {actual}");
    }
    assert!(readme.contains("<data>/blobs/tmp/"));
    assert!(s.data.path().join("blobs/tmp").is_dir());
}
