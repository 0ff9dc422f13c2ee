//! `api/constraints.schema.json` must describe what the code accepts: same fields, same defaults.

use retex::engine::asset::constraints::{Constraints, OutputOptions};
use retex::engine::methods::project::ProjectParams;
use serde_json::Value;
use std::collections::BTreeSet;

fn schema() -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/api/constraints.schema.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn keys(v: &Value) -> BTreeSet<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

#[test]
fn top_level_and_output_fields_match_the_code() {
    let s = schema();
    let code = serde_json::to_value(Constraints::default()).unwrap();
    assert_eq!(keys(&s["properties"]), keys(&code));
    let out = serde_json::to_value(OutputOptions::default()).unwrap();
    assert_eq!(keys(&s["properties"]["output"]["properties"]), keys(&out));
    for (k, v) in out.as_object().unwrap() {
        assert_eq!(
            &s["properties"]["output"]["properties"][k]["default"], v,
            "output.{k}"
        );
    }
}

#[test]
fn project_params_match_the_code() {
    let s = schema();
    let code = serde_json::to_value(ProjectParams::default()).unwrap();
    let props = &s["$defs"]["project_params"]["properties"];
    assert_eq!(keys(props), keys(&code));
    for (k, v) in code.as_object().unwrap() {
        if !v.is_null() {
            let d = &props[k]["default"];
            assert!(
                d == v
                    || (d.as_f64().is_some()
                        && (d.as_f64().unwrap() - v.as_f64().unwrap()).abs() < 1e-9),
                "params.{k}: schema {d} vs code {v}"
            );
        }
    }
}

/// Every default that is a number or a string matches within 1e-6; nested objects compare key by
/// key.
fn defaults_agree(props: &Value, code: &Value, path: &str) {
    assert_eq!(keys(props), keys(code), "{path}");
    for (k, v) in code.as_object().unwrap() {
        let d = &props[k]["default"];
        if v.is_null() {
            continue;
        }
        if v.is_object() {
            defaults_agree(&props[k]["properties"], v, &format!("{path}.{k}"));
        } else if let (Some(a), Some(b)) = (d.as_f64(), v.as_f64()) {
            assert!((a - b).abs() < 1e-6, "{path}.{k}: schema {d} vs code {v}");
        } else {
            assert_eq!(d, v, "{path}.{k}");
        }
    }
}

#[test]
fn meshmatch_params_match_the_code() {
    let s = schema();
    let code = serde_json::to_value(retex::engine::methods::meshmatch::MeshMatchParams::default())
        .unwrap();
    defaults_agree(
        &s["$defs"]["meshmatch_params"]["properties"],
        &code,
        "params",
    );
}
