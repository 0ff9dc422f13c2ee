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
