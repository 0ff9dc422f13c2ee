//! The constraints JSON Schema (`api/constraints.schema.json`), generated: the top level (version,
//! method, seed, correspondences, output, params) is written here from the code's defaults and
//! limits, and each registered method's params schema ([`super::Method::params_schema`], derived
//! from its Params struct, see [`super::params`]) becomes `$defs/<id>_params`, applied through a
//! per-method conditional in `allOf`:
//!
//! ```json
//! {"if": {"properties": {"method": {"const": "meshmatch"}}, "required": ["method"]},
//!  "then": {"properties": {"params": {"$ref": "#/$defs/meshmatch_params"}}}}
//! ```
//!
//! The default method's condition has no `required`, so it also holds when `method` is absent.
//! The committed file is checked against [`constraints_schema_json`] by the
//! `constraints_schema` tests; `RETEX_UPDATE_SCHEMA=1 cargo test --test engine constraints_schema`
//! rewrites it.

use serde_json::{json, Map, Value};

use super::Registry;
use crate::engine::asset::constraints::{
    Constraints, MethodId, OutputOptions, MAX_CORRESPONDENCES, MAX_PADDING, TEXTURE_SIZE_RANGE,
};

/// The constraints schema of the built-in methods ([`Registry::builtin`]).
pub fn constraints_schema() -> Value {
    constraints_schema_for(&Registry::builtin())
}

/// [`constraints_schema`] as written to `api/constraints.schema.json` (pretty, trailing newline).
pub fn constraints_schema_json() -> String {
    let mut text = serde_json::to_string_pretty(&constraints_schema()).unwrap_or_default();
    text.push('\n');
    text
}

/// The constraints schema with the params of every method in `registry`.
pub fn constraints_schema_for(registry: &Registry) -> Value {
    let defaults = Constraints::default();
    let output = serde_json::to_value(OutputOptions::default()).unwrap_or_default();
    let mut defs = Map::new();
    defs.insert("vec3".into(), vec3());
    defs.insert("place".into(), place());
    let mut conditions = Vec::new();
    let mut names = Vec::new();
    for method in registry.methods() {
        let id = method.id();
        let name = format!("{}_params", id.as_str());
        let mut schema = method.params_schema();
        if let Some(obj) = schema.as_object_mut() {
            obj.remove("$schema");
            // Definitions of a params schema move to the document's (its `#/$defs/..` references
            // then resolve from the document root).
            if let Some(Value::Object(nested)) = obj.remove("$defs") {
                for (k, v) in nested {
                    let previous = defs.insert(k.clone(), v.clone());
                    assert!(
                        previous.is_none_or(|p| p == v),
                        "two params schemas define $defs/{k} differently"
                    );
                }
            }
        }
        defs.insert(name.clone(), schema);
        let mut condition = json!({"properties": {"method": {"const": id.as_str()}}});
        if id != defaults.method {
            condition["required"] = json!(["method"]);
        }
        conditions.push(json!({
            "if": condition,
            "then": {"properties": {"params": {"$ref": format!("#/$defs/{name}")}}},
        }));
        names.push(format!("`{}`: $defs/{name}", id.as_str()));
    }
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "retex/constraints-v1",
        "title": "retex constraints JSON v1",
        "description": "The job description shared by every method. Only `version` is required; \
            unknown fields are errors. Generated from the code (retex::engine::methods::constraints_schema).",
        "type": "object",
        "additionalProperties": false,
        "required": ["version"],
        "properties": {
            "version": {"const": 1},
            "method": {
                "enum": MethodId::ALL.map(MethodId::as_str),
                "default": defaults.method.as_str(),
            },
            "seed": {"type": "integer", "minimum": 0, "default": defaults.seed},
            "correspondences": {
                "type": "array",
                "maxItems": MAX_CORRESPONDENCES,
                "default": [],
                "items": {
                    "type": "object",
                    "additionalProperties": false,
                    "required": ["source", "target"],
                    "properties": {
                        "source": {"$ref": "#/$defs/place"},
                        "target": {"oneOf": [
                            {"$ref": "#/$defs/place"},
                            {"type": "array", "minItems": 1, "items": {"$ref": "#/$defs/place"}},
                        ]},
                    },
                },
            },
            "output": {
                "type": "object",
                "additionalProperties": false,
                "properties": {
                    "texture_size": {
                        "type": "integer",
                        "minimum": TEXTURE_SIZE_RANGE.start(),
                        "maximum": TEXTURE_SIZE_RANGE.end(),
                        "default": output["texture_size"],
                    },
                    "padding": {
                        "type": "integer",
                        "minimum": 0,
                        "maximum": MAX_PADDING,
                        "default": output["padding"],
                    },
                    "vertex_colors": {
                        "type": "boolean",
                        "default": output["vertex_colors"],
                        "description": "Write COLOR_0 on the target's own vertices instead of baking textures.",
                    },
                    "uv": {
                        "enum": ["auto", "keep", "vertex_colors"],
                        "default": output["uv"],
                        "description": "auto: keep the target's UVs, generate an atlas (TEXCOORD_0, vertices split at chart seams, the baked base-colour texture, or detail's normal map, TANGENT and displacement texture) for primitives without them; keep: primitives without UVs get COLOR_0 on a refined copy (detail: the displaced finest level); vertex_colors: COLOR_0 on every primitive, no textures.",
                    },
                    "atlas_parameterization": {
                        "enum": ["lscm", "arap"],
                        "default": output["atlas_parameterization"],
                        "description": "How a generated atlas (uv: auto) flattens each chart. lscm: least-squares conformal maps (angles kept, areas may vary); arap: LSCM refined by as-rigid-as-possible iterations (Liu et al. 2008), kept per chart when neither its L2 nor its L-infinity stretch is above LSCM's and no triangle flips: less area distortion, sometimes fewer charts, for 25-40 % more atlas time and a less tightly packed texture.",
                    },
                    "format": {"enum": ["glb", "gltf"], "default": output["format"]},
                },
            },
            "params": {
                "type": "object",
                "default": {},
                "description": format!(
                    "Method parameters; each method rejects fields it does not know. Their schema \
                     depends on `method` (see allOf): {}; other methods: any object.",
                    names.join(", ")
                ),
            },
        },
        "allOf": conditions,
        "$defs": defs,
    })
}

fn vec3() -> Value {
    json!({"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3})
}

fn index() -> Value {
    json!({"type": "integer", "minimum": 0})
}

/// The three forms of a place on a mesh (`SurfaceRef`).
fn place() -> Value {
    json!({"oneOf": [
        {
            "type": "object",
            "additionalProperties": false,
            "required": ["point"],
            "properties": {"point": {"$ref": "#/$defs/vec3"}},
            "description": "A world-space point, snapped to the nearest surface point.",
        },
        {
            "type": "object",
            "additionalProperties": false,
            "required": ["mesh", "primitive", "triangle", "barycentric"],
            "properties": {
                "mesh": index(),
                "primitive": index(),
                "triangle": index(),
                "barycentric": {
                    "type": "array",
                    "items": {"type": "number", "minimum": 0},
                    "minItems": 3,
                    "maxItems": 3,
                },
            },
        },
        {
            "type": "object",
            "additionalProperties": false,
            "required": ["vertex"],
            "properties": {"vertex": {
                "type": "object",
                "additionalProperties": false,
                "required": ["mesh", "primitive", "index"],
                "properties": {"mesh": index(), "primitive": index(), "index": index()},
            }},
        },
    ]})
}
