//! `api/constraints.schema.json` is generated from the code and describes what the code accepts:
//! the committed file equals the generated one (the only test that reads the file; the others
//! check the generated schema), its defaults equal the structs' `Default`, the shared options have
//! one definition, one conditional per method applies its params schema, and the runtime range
//! check enforces the schema's bounds (a value at each bound passes, one just outside fails,
//! naming `params.<path>`).
//!
//! After changing a Params struct: `RETEX_UPDATE_SCHEMA=1 cargo test --release --test engine
//! constraints_schema` rewrites the file.

use retex::engine::asset::constraints::{Constraints, MethodId, OutputOptions};
use retex::engine::methods::meshmatch::MeshMatchParams;
use retex::engine::methods::project::ProjectParams;
use retex::engine::methods::shared_params::shared_properties;
use retex::engine::methods::{constraints_schema, constraints_schema_json, Registry, SharedParams};
use serde_json::{json, Value};
use std::collections::BTreeSet;

fn keys(v: &Value) -> BTreeSet<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

#[test]
fn committed_file_is_the_generated_schema() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/api/constraints.schema.json");
    let generated = constraints_schema_json();
    if std::env::var("RETEX_UPDATE_SCHEMA").is_ok_and(|v| v == "1") {
        std::fs::write(path, &generated).unwrap();
    }
    let file = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        file == generated,
        "api/constraints.schema.json differs from the code: run \
         RETEX_UPDATE_SCHEMA=1 cargo test --release --test engine constraints_schema"
    );
}

#[test]
fn top_level_and_output_fields_match_the_code() {
    let s = constraints_schema();
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
    let ids: Vec<&str> = s["properties"]["method"]["enum"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    for id in &ids {
        assert!(MethodId::parse(id).is_ok(), "{id}");
    }
    assert_eq!(ids.len(), MethodId::ALL.len());
    for key in ["$schema", "$id", "title", "description"] {
        assert!(s[key].is_string(), "{key}");
    }
    for def in ["place", "vec3"] {
        assert!(s["$defs"][def].is_object(), "{def}");
    }
}

/// One conditional per registered method; only the default method's holds without `method`.
#[test]
fn each_method_gets_its_params_schema_through_a_condition() {
    let s = constraints_schema();
    let registry = Registry::builtin();
    let all = s["allOf"].as_array().unwrap();
    assert_eq!(all.len(), registry.methods().count());
    for (cond, method) in all.iter().zip(registry.methods()) {
        let id = method.id().as_str();
        assert_eq!(cond["if"]["properties"]["method"]["const"], id);
        let reference = cond["then"]["properties"]["params"]["$ref"]
            .as_str()
            .unwrap();
        assert_eq!(reference, format!("#/$defs/{id}_params"));
        let mut own = method.params_schema();
        own.as_object_mut().unwrap().remove("$schema");
        assert_eq!(s["$defs"][format!("{id}_params")], own, "{id}");
        let required = &cond["if"]["required"];
        if method.id() == MethodId::default() {
            assert!(
                required.is_null(),
                "{id}: must also hold when `method` is absent"
            );
        } else {
            assert_eq!(required, &json!(["method"]), "{id}");
        }
    }
    // The derived schemas name no other document part.
    assert!(!s.to_string().contains("#/definitions"));
}

/// Equal, numbers that are not integers compared as `f32` (the schema writes an `f32` default in
/// its shortest form, the code's value serializes widened to `f64`).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) if x.is_f64() || y.is_f64() => {
            x.as_f64().map(|x| x as f32) == y.as_f64().map(|y| y as f32)
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same(x, y))
        }
        (Value::Object(x), Value::Object(y)) => {
            keys(a) == keys(b) && x.iter().all(|(k, v)| same(v, &y[k]))
        }
        _ => a == b,
    }
}

/// Every field has a default in the schema, equal to the code's; nested objects also key by key.
fn defaults_agree(props: &Value, code: &Value, path: &str) {
    assert_eq!(keys(props), keys(code), "{path}");
    for (k, v) in code.as_object().unwrap() {
        let d = &props[k]["default"];
        assert!(same(d, v), "{path}.{k}: schema {d} vs code {v}");
        if v.is_object() {
            defaults_agree(&props[k]["properties"], v, &format!("{path}.{k}"));
        }
    }
}

#[test]
fn defaults_are_the_codes() {
    let s = constraints_schema();
    defaults_agree(
        &s["$defs"]["project_params"]["properties"],
        &serde_json::to_value(ProjectParams::default()).unwrap(),
        "params",
    );
    defaults_agree(
        &s["$defs"]["meshmatch_params"]["properties"],
        &serde_json::to_value(MeshMatchParams::default()).unwrap(),
        "params",
    );
    // Written short: an f32 default reads back as itself.
    assert_eq!(
        s["$defs"]["meshmatch_params"]["properties"]["affinity"]["properties"]["sigma_fraction"]
            ["default"],
        json!(0.33333334)
    );
    assert_eq!(
        s["$defs"]["project_params"]["properties"]["snap_tolerance"]["default"],
        json!(0.02)
    );
}

#[test]
fn shared_options_have_one_definition() {
    let s = constraints_schema();
    let shared = shared_properties();
    assert_eq!(
        shared.keys().collect::<Vec<_>>(),
        ["snap_tolerance", "vertex_color_samples", "weld_tolerance"]
    );
    for (name, schema) in &shared {
        for method in ["project_params", "meshmatch_params"] {
            assert_eq!(
                &s["$defs"][method]["properties"][name], schema,
                "{method}.{name}"
            );
        }
        assert!(schema["description"].is_string(), "{name}");
    }
    let d = serde_json::to_value(SharedParams::default()).unwrap();
    let p = serde_json::to_value(ProjectParams::default()).unwrap();
    let m = serde_json::to_value(MeshMatchParams::default()).unwrap();
    for name in shared.keys() {
        assert_eq!(p[name], d[name], "project {name}");
        assert_eq!(m[name], d[name], "meshmatch {name}");
    }
}

/// (Three correspondences are given: elastiface's check refuses fewer, whatever the params.)
fn check(method: MethodId, params: Value) -> Result<(), String> {
    let p =
        |x: f64| json!({"source": {"point": [x, 0.0, 0.0]}, "target": {"point": [x, 0.0, 0.0]}});
    let c: Constraints = serde_json::from_value(json!({"version": 1, "method": method.as_str(),
        "params": params, "correspondences": [p(0.0), p(1.0), p(2.0)]}))
    .unwrap();
    let m = Registry::builtin().get(method).unwrap();
    m.check(&c)
        .map_err(|e| format!("{}: {}", e.path, e.message))
}

/// Sets `path` (`hks.eigenpairs`) to `v` in an empty params object.
fn at(path: &str, v: Value) -> Value {
    let mut root = json!({});
    let mut cur = &mut root;
    let parts: Vec<&str> = path.split('.').collect();
    for p in &parts[..parts.len() - 1] {
        cur = cur.as_object_mut().unwrap().entry(*p).or_insert(json!({}));
    }
    cur[parts[parts.len() - 1]] = v;
    root
}

/// `params` with every required sibling along `path` that it lacks set to that field's minimum
/// (`blend.feather_rings` alone would be refused for the missing `blend.weight`, hiding the
/// bound under test).
fn with_required(schema: &Value, path: &str, mut params: Value) -> Value {
    let mut node = schema;
    let mut cur = &mut params;
    for part in path.split('.') {
        if let (Some(required), Some(obj)) = (node["required"].as_array(), cur.as_object_mut()) {
            for name in required.iter().filter_map(Value::as_str) {
                if let Some(min) = node["properties"][name]["minimum"].as_f64() {
                    obj.entry(name).or_insert(json!(min));
                }
            }
        }
        node = &node["properties"][part];
        match cur.get_mut(part) {
            Some(next) => cur = next,
            None => break,
        }
    }
    params
}

/// The bounds as they were before the schema was derived (no behaviour change): in-range values,
/// and out-of-range ones with the error they give.
#[test]
fn bounds_pass_and_values_just_outside_fail() {
    use MethodId::{Meshmatch, Project};
    let pass = [
        (Project, "max_distance", json!(10)),
        (Project, "max_distance", json!(1e-6)),
        (Project, "max_normal_angle", json!(180)),
        (Project, "max_distance", json!(null)),
        (Project, "vertex_color_samples", json!(1)),
        (Project, "vertex_color_samples", json!(4_000_000)),
        (Project, "snap_tolerance", json!(1)),
        (Project, "weld_tolerance", json!(0)),
        (Project, "weld_tolerance", json!(0.01)),
        (Meshmatch, "samples", json!(256)),
        (Meshmatch, "samples", json!(262_144)),
        (Meshmatch, "source_samples", json!(null)),
        (Meshmatch, "convergence", json!(0)),
        (Meshmatch, "convergence", json!(1)),
        (Meshmatch, "fan_radius", json!(20)),
        (Meshmatch, "finest_shape_weight", json!(100)),
        (Meshmatch, "hks.hks_times", json!(1)),
        (Meshmatch, "hks.hks_times", json!(64)),
        (Meshmatch, "hks.eigenpairs", json!(8)),
        (Meshmatch, "hks.eigenpairs", json!(500)),
        (Meshmatch, "hks.up", json!(null)),
        (Meshmatch, "affinity.sigma_fraction", json!(10)),
        (Meshmatch, "weld_tolerance", json!(0.01)),
        (
            Meshmatch,
            "example",
            json!({"vertex_color": {"channel": "r", "threshold": 1}}),
        ),
        (
            Meshmatch,
            "example",
            json!({"image": {"index": 0, "channel": "a", "threshold": 0}}),
        ),
    ];
    for (method, path, v) in pass {
        assert_eq!(check(method, at(path, v.clone())), Ok(()), "{path} = {v}");
    }
    let fail = [
        (
            Project,
            "max_distance",
            json!(0),
            "0 is outside the range (0, 10]",
        ),
        (
            Project,
            "max_distance",
            json!(10.001),
            "10.001 is outside the range (0, 10]",
        ),
        (
            Project,
            "max_normal_angle",
            json!(0),
            "0 is outside the range (0, 180]",
        ),
        (
            Project,
            "vertex_color_samples",
            json!(4_000_001),
            "4000001 is outside the range 1..=4000000",
        ),
        (
            Project,
            "vertex_color_samples",
            json!(0),
            "0 is outside the range 1..=4000000",
        ),
        (
            Project,
            "snap_tolerance",
            json!(0),
            "0 is outside the range (0, 1]",
        ),
        (
            Project,
            "weld_tolerance",
            json!(0.0101),
            "0.0101 is outside the range [0, 0.01]",
        ),
        (
            Meshmatch,
            "samples",
            json!(255),
            "255 is outside the range 256..=262144",
        ),
        (
            Meshmatch,
            "samples",
            json!(262_145),
            "262145 is outside the range 256..=262144",
        ),
        (
            Meshmatch,
            "source_samples",
            json!(5),
            "5 is outside the range 256..=262144",
        ),
        (
            Meshmatch,
            "min_vertices",
            json!(15),
            "15 is outside the range 16..=100000",
        ),
        (
            Meshmatch,
            "iterations",
            json!(101),
            "101 is outside the range 1..=100",
        ),
        (
            Meshmatch,
            "convergence",
            json!(1.5),
            "1.5 is outside the range [0, 1]",
        ),
        (Meshmatch, "rings", json!(9), "9 is outside the range 1..=8"),
        (
            Meshmatch,
            "spokes",
            json!(3),
            "3 is outside the range 4..=64",
        ),
        (
            Meshmatch,
            "fan_radius",
            json!(0),
            "0 is outside the range (0, 20]",
        ),
        (
            Meshmatch,
            "feature_vertices",
            json!(99),
            "99 is outside the range 100..=1000000",
        ),
        (
            Meshmatch,
            "shape_weight",
            json!(-0.5),
            "-0.5 is outside the range [0, 100]",
        ),
        (
            Meshmatch,
            "finest_shape_weight",
            json!(100.5),
            "100.5 is outside the range [0, 100]",
        ),
        (
            Meshmatch,
            "vote_sigma",
            json!(0),
            "0 is outside the range (0, 10]",
        ),
        (
            Meshmatch,
            "vertex_color_samples",
            json!(0),
            "0 is outside the range 1..=4000000",
        ),
        (
            Meshmatch,
            "snap_tolerance",
            json!(1.01),
            "1.01 is outside the range (0, 1]",
        ),
        (
            Meshmatch,
            "weld_tolerance",
            json!(0.02),
            "0.02 is outside the range [0, 0.01]",
        ),
        (
            Meshmatch,
            "hks.hks_times",
            json!(0),
            "0 is outside the range 1..=64",
        ),
        (
            Meshmatch,
            "hks.hks_times",
            json!(65),
            "65 is outside the range 1..=64",
        ),
        (
            Meshmatch,
            "hks.eigenpairs",
            json!(7),
            "7 is outside the range 8..=500",
        ),
        (
            Meshmatch,
            "hks.eigenpairs",
            json!(501),
            "501 is outside the range 8..=500",
        ),
        (
            Meshmatch,
            "affinity.sigma_fraction",
            json!(0),
            "0 is outside the range (0, 10]",
        ),
        (
            Meshmatch,
            "affinity.sigma_fraction",
            json!(10.5),
            "10.5 is outside the range (0, 10]",
        ),
    ];
    for (method, path, v, message) in fail {
        assert_eq!(
            check(method, at(path, v.clone())),
            Err(format!("params.{path}: {message}")),
            "{path} = {v}"
        );
    }
    // Nested in an enum variant.
    assert_eq!(
        check(
            Meshmatch,
            json!({"example": {"vertex_color": {"channel": "g", "threshold": 1.01}}})
        ),
        Err("params.example.vertex_color.threshold: 1.01 is outside the range [0, 1]".into())
    );
    // What a schema cannot say stays in code.
    assert!(check(Meshmatch, json!({"hks": {"up": [0, 0, 0]}}))
        .unwrap_err()
        .starts_with("params.hks: "));
}

/// Every bound the derived schemas give, found by walking them: the bound itself passes (or, when
/// exclusive, fails) and a value just beyond it fails, at the field's path.
#[test]
fn every_schema_bound_is_enforced() {
    fn bounds(schema: &Value, path: &str, out: &mut Vec<(String, Value)>) {
        if let Some(props) = schema["properties"].as_object() {
            for (k, sub) in props {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                bounds(sub, &p, out);
            }
        }
        if schema.get("minimum").is_some()
            || schema.get("maximum").is_some()
            || schema.get("exclusiveMinimum").is_some()
        {
            out.push((path.to_string(), schema.clone()));
        }
    }
    let registry = Registry::builtin();
    let mut count = 0;
    for method in registry.methods() {
        let mut fields = Vec::new();
        bounds(&method.params_schema(), "", &mut fields);
        for (path, s) in fields {
            let integer = s["type"] == "integer" || s["type"][0] == "integer";
            let step = |b: f64| {
                if integer {
                    1.0
                } else {
                    b.abs().max(1.0) * 1e-3
                }
            };
            let num = |x: f64| {
                if integer {
                    json!(x as i64)
                } else {
                    json!(x)
                }
            };
            let id = method.id();
            let schema = method.params_schema();
            let at = |path: &str, v: Value| with_required(&schema, path, at(path, v));
            let expect_err = |v: Value| {
                let e = check(id, at(&path, v.clone()));
                assert!(
                    e.as_ref()
                        .is_err_and(|e| e.starts_with(&format!("params.{path}:"))),
                    "{path} = {v}: {e:?}"
                );
            };
            if let Some(b) = s["minimum"].as_f64() {
                assert_eq!(check(id, at(&path, num(b))), Ok(()), "{path} = {b}");
                expect_err(num(b - step(b)));
                count += 1;
            }
            if let Some(b) = s["exclusiveMinimum"].as_f64() {
                expect_err(num(b));
                assert_eq!(
                    check(id, at(&path, num(b + step(b)))),
                    Ok(()),
                    "{path} just above {b}"
                );
                count += 1;
            }
            if let Some(b) = s["maximum"].as_f64() {
                assert_eq!(check(id, at(&path, num(b))), Ok(()), "{path} = {b}");
                expect_err(num(b + step(b)));
                count += 1;
            }
        }
    }
    assert!(count >= 40, "{count} bounds");
}
