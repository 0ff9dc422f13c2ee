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
