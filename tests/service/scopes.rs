//! Token scopes (issue 9, item 9): a `read:` token may only read, a `submit:` token may also
//! submit and cancel, and only an admin token (`admin:` or no prefix) may delete jobs, so one
//! client cannot delete another's jobs; a token short of the scope gets 403
//! `insufficient-scope` with an RFC 6750 challenge.

use std::time::Duration;

use crate::service_common::*;

fn bearer(token: &str) -> String {
    format!("Bearer {token}")
}

#[test]
fn scopes_limit_what_each_token_may_do() {
    let s = TestServer::start(|c| {
        c.tokens = vec![
            "read:dashboard-secret".into(),
            "submit:client-a-secret".into(),
            "operator-secret".into(),
        ];
    });
    let (reader, client, admin) = (
        bearer("dashboard-secret"),
        bearer("client-a-secret"),
        bearer("operator-secret"),
    );
    let jobs = format!("{}/v1/jobs", s.base);
    // The scope prefix is configuration, not part of the secret.
    request(
        "GET",
        &jobs,
        &[("Authorization", &bearer("read:dashboard-secret"))],
        None,
    )
    .problem(401);
    assert_eq!(
        request("GET", &jobs, &[("Authorization", &reader)], None).status,
        200
    );

    // A read token cannot submit.
    let r = submit(&s.base, &spot_parts(16), &[("Authorization", &reader)]);
    let p = r.problem(403);
    assert_eq!(p["type"], "/problems/insufficient-scope", "{p}");
    assert_eq!(p["field"], "Authorization", "{p}");
    let challenge = r.header("www-authenticate").unwrap_or_default();
    assert!(challenge.contains("insufficient_scope"), "{challenge}");
    assert!(challenge.contains("scope=\"submit\""), "{challenge}");

    // A submit token submits, reads its job, and cannot delete it (nor anyone's).
    let r = submit(&s.base, &spot_parts(16), &[("Authorization", &client)]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let job = format!("{jobs}/{id}");
    let end = std::time::Instant::now() + Duration::from_secs(120);
    loop {
        let doc = request("GET", &job, &[("Authorization", &client)], None).json();
        if terminal(doc["status"].as_str().unwrap()) {
            break;
        }
        assert!(std::time::Instant::now() < end, "{doc}");
        std::thread::sleep(Duration::from_millis(50));
    }
    for token in [&reader, &client] {
        let p = request("DELETE", &job, &[("Authorization", token)], None).problem(403);
        assert_eq!(p["type"], "/problems/insufficient-scope", "{p}");
    }
    assert_eq!(
        request("GET", &job, &[("Authorization", &reader)], None).status,
        200
    );
    // The admin token may.
    let r = request("DELETE", &job, &[("Authorization", &admin)], None);
    assert_eq!(r.status, 204, "{}", String::from_utf8_lossy(&r.body));
    request("GET", &job, &[("Authorization", &admin)], None).problem(404);
}

/// Job ownership: a submit token cancels only the jobs it submitted, and its Idempotency-Keys
/// never replay another token's job.
#[test]
fn submit_tokens_cancel_only_their_own_jobs_and_keys_are_per_token() {
    let s = TestServer::start(|c| {
        c.tokens = vec![
            "submit:farm-a-secret".into(),
            "submit:farm-b-secret".into(),
            "admin:ops-secret".into(),
        ];
        c.workers = 1;
    });
    let (farm_a, farm_b, admin) = (
        bearer("farm-a-secret"),
        bearer("farm-b-secret"),
        bearer("ops-secret"),
    );
    let jobs = format!("{}/v1/jobs", s.base);
    // A slow job keeps the worker busy so the next ones stay enqueued.
    let slow = submit(&s.base, &spot_parts(8192), &[("Authorization", &admin)]);
    assert_eq!(slow.status, 202);
    let with_key = [
        ("Authorization", farm_a.as_str()),
        ("Idempotency-Key", "k1"),
    ];
    let r = submit(&s.base, &spot_parts(16), &with_key);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let a_job = r.json()["id"].as_str().unwrap().to_string();

    // Farm B may read farm A's job but not cancel it.
    let cancel_a = format!("{jobs}/{a_job}/cancel");
    assert_eq!(
        request(
            "GET",
            &format!("{jobs}/{a_job}"),
            &[("Authorization", &farm_b)],
            None
        )
        .status,
        200
    );
    let p = request("POST", &cancel_a, &[("Authorization", &farm_b)], None).problem(403);
    assert_eq!(p["type"], "/problems/not-job-owner", "{p}");
    assert_eq!(p["field"], "Authorization", "{p}");

    // The same key from farm B is a new job; from farm A a replay.
    let r = submit(
        &s.base,
        &spot_parts(16),
        &[
            ("Authorization", farm_b.as_str()),
            ("Idempotency-Key", "k1"),
        ],
    );
    assert_eq!(r.status, 202, "another token's key must not replay");
    let b_job = r.json()["id"].as_str().unwrap().to_string();
    assert_ne!(b_job, a_job);
    let r = submit(&s.base, &spot_parts(16), &with_key);
    assert_eq!(r.status, 200);
    assert_eq!(r.json()["id"].as_str(), Some(a_job.as_str()));

    // Farm A cancels its own job; the admin cancels farm B's and the slow one.
    let r = request("POST", &cancel_a, &[("Authorization", &farm_a)], None);
    assert!([200, 202].contains(&r.status), "{}", r.status);
    for id in [&b_job, slow.json()["id"].as_str().unwrap()] {
        let r = request(
            "POST",
            &format!("{jobs}/{id}/cancel"),
            &[("Authorization", &admin)],
            None,
        );
        assert!([200, 202].contains(&r.status), "{}", r.status);
    }
    for id in [&a_job, &b_job] {
        let doc = wait_for_with(
            &s.base,
            id,
            &[("Authorization", &admin)],
            Duration::from_secs(60),
            terminal,
        );
        assert_eq!(doc["status"], "canceled", "{doc}");
    }
}

/// An upload with a wrong or read-only token gets its 401/403, not a reset connection: the
/// server reads the rest of the body (up to the linger limit) before answering.
#[test]
fn a_refused_upload_still_gets_its_answer() {
    let s = TestServer::start(|c| {
        c.tokens = vec!["read:dashboard-secret".into()];
    });
    let big = vec![7u8; 8 << 20];
    let parts = vec![("target", "t.glb", big)];
    for (token, status) in [("wrong-secret", 401), ("dashboard-secret", 403)] {
        let auth = bearer(token);
        submit(&s.base, &parts, &[("Authorization", &auth)]).problem(status);
    }
}
