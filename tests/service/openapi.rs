//! The OpenAPI contract and the deploy configuration: the committed `api/openapi.yaml` equals
//! the spec generated from the code, the served `/v1/openapi.json` equals it too, the spec is
//! structurally valid OpenAPI 3 (required fields, every route, every `$ref` resolves), and the
//! example TOML in `deploy/` loads with the real config loader.
//!
//! After changing the API: `RETEX_UPDATE_OPENAPI=1 cargo test --test service openapi::`.

use std::path::PathBuf;

use crate::service_common::*;
use retex::service::config::ServeConfig;
use retex::service::http::openapi;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn committed_yaml_matches_the_code() {
    let generated = openapi::spec_yaml();
    let file = root().join("api/openapi.yaml");
    if std::env::var("RETEX_UPDATE_OPENAPI").is_ok_and(|v| v == "1") {
        std::fs::write(&file, &generated).unwrap();
    }
    let committed = std::fs::read_to_string(&file).unwrap_or_default();
    assert!(
        committed == generated,
        "api/openapi.yaml differs from the code: run RETEX_UPDATE_OPENAPI=1 cargo test --test service openapi::"
    );
}

fn collect_refs(v: &serde_json::Value, out: &mut Vec<String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                if k == "$ref" {
                    out.push(x.as_str().unwrap().to_string());
                }
                collect_refs(x, out);
            }
        }
        serde_json::Value::Array(a) => a.iter().for_each(|x| collect_refs(x, out)),
        _ => {}
    }
}

#[test]
fn served_spec_is_the_code_spec_and_is_valid_openapi() {
    let s = TestServer::start(|_| {});
    let served = get(&format!("{}/v1/openapi.json", s.base)).json();
    let code: serde_json::Value =
        serde_json::from_str(&openapi::spec().to_json().unwrap()).unwrap();
    assert_eq!(served, code, "served spec differs from the code");

    assert!(served["openapi"].as_str().unwrap().starts_with("3."));
    assert_eq!(served["info"]["title"], "retex");
    assert!(served["info"]["version"].is_string());
    let paths = served["paths"].as_object().unwrap();
    let expected = [
        ("/v1/jobs", "post"),
        ("/v1/jobs", "get"),
        ("/v1/jobs/{id}", "get"),
        ("/v1/jobs/{id}", "delete"),
        ("/v1/jobs/{id}/cancel", "post"),
        ("/v1/jobs/{id}/result", "get"),
        ("/v1/jobs/{id}/artifacts/{name}", "get"),
        ("/v1/jobs/{id}/events", "get"),
        ("/v1/jobs/{id}/files/{name}", "get"),
        ("/v1/events", "get"),
        ("/healthz", "get"),
        ("/readyz", "get"),
        ("/metrics", "get"),
        ("/v1/openapi.json", "get"),
    ];
    for (path, method) in expected {
        let op = &paths[path][method];
        assert!(op.is_object(), "{method} {path} missing");
        let responses = op["responses"].as_object().unwrap();
        assert!(!responses.is_empty(), "{method} {path}: no responses");
        for (code, r) in responses {
            assert!(
                code.parse::<u16>().is_ok(),
                "{method} {path}: status {code}"
            );
            assert!(
                r["description"].is_string(),
                "{method} {path} {code}: description"
            );
        }
        // Every path parameter is declared.
        for seg in path.split('/').filter(|s| s.starts_with('{')) {
            let name = seg.trim_matches(|c| c == '{' || c == '}');
            let params = op["parameters"].as_array().unwrap();
            assert!(
                params
                    .iter()
                    .any(|p| p["name"] == name && p["in"] == "path" && p["required"] == true),
                "{method} {path}: path parameter {name}"
            );
        }
    }
    let mut refs = Vec::new();
    collect_refs(&served, &mut refs);
    assert!(!refs.is_empty());
    for r in refs {
        let name = r
            .strip_prefix("#/components/schemas/")
            .expect("local schema ref");
        assert!(
            served["components"]["schemas"][name].is_object(),
            "dangling {r}"
        );
    }
    assert!(served["components"]["securitySchemes"]["bearer"].is_object());
}

#[test]
fn example_config_loads_with_the_real_loader() {
    let path = root().join("deploy/retex.example.toml");
    let c = ServeConfig::from_file(&path).unwrap();
    assert_eq!(c.addr.port(), 8080);
    assert_eq!(c.data_dir, PathBuf::from("/var/lib/retex"));
    assert_eq!(c.ttl_secs, 7 * 24 * 3600);
    assert_eq!(c.db_path(), PathBuf::from("/var/lib/retex/jobs.sqlite3"));
    assert_eq!(
        (c.lease_secs, c.poll_secs, c.database_url.as_deref()),
        (30, 1, None)
    );
    // The compose file and the k8s deployment pass the same settings through the environment.
    let compose = std::fs::read_to_string(root().join("deploy/compose.yaml")).unwrap();
    let deployment = std::fs::read_to_string(root().join("deploy/k8s/deployment.yaml")).unwrap();
    for text in [&compose, &deployment] {
        assert!(text.contains("RETEX_DATA_DIR") && text.contains("/var/lib/retex"));
        assert!(text.contains("0.0.0.0:8080"));
    }
    assert!(deployment.contains("/healthz") && deployment.contains("/readyz"));
    let mut env_applied = c.clone();
    env_applied
        .apply_env(|k| (k == "RETEX_ADDR").then(|| "0.0.0.0:9999".into()))
        .unwrap();
    assert_eq!(env_applied.addr.port(), 9999);
}
