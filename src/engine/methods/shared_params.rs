//! The options several methods share (`vertex_color_samples`, `snap_tolerance`, `weld_tolerance`),
//! defined once: their doc, default and range live on [`SharedParams`] and nowhere else.
//!
//! **Why not `#[serde(flatten)]`**: a flattened `SharedParams` inside each method's Params would be
//! the obvious single definition, but serde does not support `flatten` together with
//! `deny_unknown_fields` (which every Params struct needs: a misspelt option must be an error).
//! It half works, and worse than today: a wrong type in a flattened field loses its JSON path
//! (`{"snap_tolerance": "x"}` is reported at `params`, not `params.snap_tolerance`), and an unknown
//! field no longer lists the expected ones (checked with serde 1.0.229 and serde_path_to_error 0.1.20).
//!
//! **What is done instead**: each Params struct keeps the three fields at the top level of
//! `params` (the JSON the user writes is unchanged) with a one-line doc pointing here, and
//! - its `Default` takes their values from [`SharedParams::default`];
//! - its derived schema goes through [`shared_fields`] (`#[schemars(transform = ..)]` on the
//!   struct), which replaces the three properties with those of [`SharedParams`]' schema: the doc,
//!   default and range written below. The range check ([`super::params::check_ranges`]) reads the
//!   schema, so it enforces the same bounds.
//!
//! A test (`constraints_schema::shared_options_have_one_definition`) checks that every built-in
//! method's params schema carries exactly these property schemas.

use schemars::{JsonSchema, Schema};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::engine::mesh::WeldParams;

/// Options shared by the methods that read them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SharedParams {
    /// Vertex count of the refined copy written for target primitives without UVs (COLOR_0).
    /// Default 100,000.
    #[schemars(range(min = 1, max = 4_000_000))]
    pub vertex_color_samples: usize,
    /// Largest distance from a correspondence point to its surface, as a fraction of that
    /// surface's bounding-box diagonal. Default 0.02.
    #[schemars(range(max = 1), extend("exclusiveMinimum" = 0))]
    pub snap_tolerance: f32,
    /// Relative weld tolerance of both surfaces: vertices closer than this fraction of the
    /// bounding-box diagonal are merged; 0 merges only identical positions. Default 1e-6.
    #[schemars(range(min = 0, max = 0.01))]
    pub weld_tolerance: f32,
}

impl Default for SharedParams {
    fn default() -> Self {
        Self {
            vertex_color_samples: 100_000,
            snap_tolerance: 0.02,
            weld_tolerance: WeldParams::default().relative_tolerance,
        }
    }
}

/// The property schemas of [`SharedParams`], by field name, as published.
pub fn shared_properties() -> serde_json::Map<String, Value> {
    properties(super::params::schema_of::<SharedParams>())
}

fn properties(mut schema: Value) -> serde_json::Map<String, Value> {
    match schema.get_mut("properties") {
        Some(Value::Object(props)) => std::mem::take(props),
        _ => serde_json::Map::new(),
    }
}

/// Schema transform for a Params struct that holds (some of) the shared options: replaces their
/// property schemas with [`SharedParams`]' (doc, default, range). Use as
/// `#[schemars(transform = super::shared_params::shared_fields)]`.
pub fn shared_fields(schema: &mut Schema) {
    let Some(Value::Object(props)) = schema.get_mut("properties") else {
        return;
    };
    // As derived (numeric formats kept for the range check; the published schema drops them).
    for (name, shared) in properties(super::params::derive::<SharedParams>()) {
        if let Some(slot) = props.get_mut(&name) {
            *slot = shared;
        }
    }
}
