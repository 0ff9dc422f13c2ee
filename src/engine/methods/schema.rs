//! The methods' params schemas, read from `api/constraints.schema.json` (compiled in), so the
//! registry can hand each method's schema to the service and the CLI.
//!
//! The file is still written by hand and kept in step with the Params structs by the
//! `constraints_schema` tests (defaults and field names compared with the code); deriving it from
//! the structs is the open part 5 of issue 8.

use std::sync::OnceLock;

fn document() -> &'static serde_json::Value {
    static DOC: OnceLock<serde_json::Value> = OnceLock::new();
    DOC.get_or_init(|| {
        serde_json::from_str(include_str!("../../../api/constraints.schema.json"))
            .unwrap_or_default()
    })
}

/// The schema of `$defs/<name>` with the shared definitions it refers to inlined under `$defs`.
pub fn params_def(name: &str) -> serde_json::Value {
    let doc = document();
    let mut schema = doc["$defs"][name].clone();
    if let Some(obj) = schema.as_object_mut() {
        let defs = doc["$defs"].as_object().cloned().unwrap_or_default();
        obj.insert("$defs".into(), serde_json::Value::Object(defs));
    }
    schema
}
