//! Issue 16, part 2 (server side): the dashboard's static files are served at `/` and
//! `/dashboard/...` without a token, with content types, ETags and caching; the vendored
//! library is sent gzip-compressed; `GET /v1/methods` and `GET /v1/jobs/{id}/constraints` feed
//! the page and, like every API route, need the token when tokens are configured.

use std::time::Duration;

use crate::service_common::*;

#[test]
fn static_files_need_no_token_and_revalidate_with_etags() {
    let s = TestServer::start(|c| c.tokens = vec!["dash-secret".into()]);
    let page = get(&format!("{}/", s.base));
    assert_eq!(page.status, 200);
    assert_eq!(
        page.header("content-type"),
        Some("text/html; charset=utf-8")
    );
    assert_eq!(page.header("cache-control"), Some("no-cache"));
    let html = String::from_utf8_lossy(&page.body);
    assert!(html.contains("/dashboard/app.js"), "{html}");
    let tag = page.header("etag").unwrap().to_string();
    let again = request(
        "GET",
        &format!("{}/", s.base),
        &[("If-None-Match", &tag)],
        None,
    );
    assert_eq!(again.status, 304);

    for (path, media) in [
        ("/dashboard/app.js", "text/javascript; charset=utf-8"),
        ("/dashboard/app.css", "text/css; charset=utf-8"),
        (
            "/dashboard/vendor/model-viewer.LICENSE",
            "text/plain; charset=utf-8",
        ),
    ] {
        let r = get(&format!("{}{path}", s.base));
        assert_eq!(r.status, 200, "{path}");
        assert_eq!(r.header("content-type"), Some(media), "{path}");
        assert!(r.body.len() > 1000, "{path}: {} bytes", r.body.len());
    }
    let mv = format!("{}/dashboard/vendor/model-viewer.min.js", s.base);
    let r = request("GET", &mv, &[("Accept-Encoding", "gzip")], None);
    assert_eq!(r.status, 200);
    assert_eq!(
        r.header("content-type"),
        Some("text/javascript; charset=utf-8")
    );
    assert_eq!(r.header("cache-control"), Some("public, max-age=86400"));
    assert_eq!(r.header("vary"), Some("Accept-Encoding"));
    let r = request("GET", &mv, &[("Accept-Encoding", "identity")], None);
    r.problem(406);

    get(&format!("{}/dashboard/nope.js", s.base)).problem(404);
    get(&format!("{}/dashboard/../Cargo.toml", s.base)).problem(404);
    // The API still needs the token.
    get(&format!("{}/v1/jobs", s.base)).problem(401);
    get(&format!("{}/v1/methods", s.base)).problem(401);
}

#[test]
fn methods_list_their_inputs_and_params_schemas() {
    let s = TestServer::start(|_| {});
    let doc = get(&format!("{}/v1/methods", s.base)).json();
    let methods = doc["methods"].as_array().unwrap();
    assert_eq!(methods[0]["id"], "project", "{doc}");
    let find = |id: &str| methods.iter().find(|m| m["id"] == id).unwrap();
    assert_eq!(find("project")["inputs"]["source"], "required");
    assert_eq!(find("project")["inputs"]["target"], "required");
    assert_eq!(find("project")["inputs"]["pattern"], "unused");
    assert_eq!(find("pattern")["inputs"]["pattern"], "required");
    let samples = &find("meshmatch")["params_schema"]["properties"]["samples"];
    assert!(
        samples["minimum"].is_number() && samples["default"].is_number(),
        "{samples}"
    );
    assert!(doc["constraints_schema"]["properties"]["output"].is_object());
}

#[test]
fn a_job_shows_the_constraints_it_was_submitted_with() {
    let s = TestServer::start(|_| {});
    let r = submit(&s.base, &spot_parts(64), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let c = get(&format!("{}/v1/jobs/{id}/constraints", s.base));
    assert_eq!(c.status, 200);
    assert_eq!(c.header("content-type"), Some("application/json"));
    assert_eq!(c.body, constraints(64));
    wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    get(&format!(
        "{}/v1/jobs/0190c5a0-0000-7000-8000-000000000000/constraints",
        s.base
    ))
    .problem(404);
}
