//! One source of truth per parameter: the JSON Schema of a method's `params` is derived from its
//! Params struct (`schemars`), and the range check at submission and in the job reads the bounds
//! from that same schema.
//!
//! - **Where ranges live**: on the fields, as `#[schemars(range(min = .., max = ..))]` (inclusive
//!   `minimum` / `maximum`) plus `#[schemars(extend("exclusiveMinimum" = ..))]` for open ends
//!   (`(0, 10]`). Defaults come from the struct's `Default` (container `#[serde(default)]`), docs
//!   from its doc comments. Nothing else states a range: the field docs no longer repeat it.
//! - **How the check reads them**: [`check_ranges`] serializes the typed params (defaults filled
//!   in, values as the code will use them) and walks the value against [`schema_of`] the type:
//!   `minimum`, `maximum`, `exclusiveMinimum`, `exclusiveMaximum` on numbers, `properties` of
//!   objects (nested structs such as `hks`), `items` of arrays, the branches of `anyOf` / `oneOf`
//!   that fit the value (an `Option` is a nullable type or a `null` branch; an enum's variants are
//!   `oneOf` branches told apart by their required key). Fields whose derived `format` is `float`
//!   (Rust `f32`) are compared in `f32`, exactly as the hand-written checks did (the published
//!   schema leaves these non-standard formats out). Types and unknown fields are serde's job
//!   ([`Constraints::method_params`]), which runs first.
//! - **Errors** name the field below `params` and keep the established wording:
//!   `params.hks.eigenpairs: 5 is outside the range 8..=500`; integer ranges print as `a..=b`,
//!   real ones as `[a, b]` / `(a, b]`.
//! - Checks a schema cannot express (meshmatch's `hks.up` must be a non-zero vector) stay in code,
//!   next to the struct.
//!
//! Options that several methods share are defined once in [`super::shared_params`].

use std::fmt::Write as _;

use schemars::generate::SchemaSettings;
use schemars::JsonSchema;
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Number, Value};

use crate::engine::asset::constraints::{Constraints, ConstraintsError};

/// The JSON Schema (draft 2020-12) of `T` as the constraints accept it: nested types inlined (the
/// schema is self-contained, no `$ref`), defaults from `T::default()`, descriptions from the doc
/// comments (lines joined, rustdoc links as plain code), `f32` numbers written in their shortest
/// form (`0.02`, not `0.019999999552965164`).
///
/// schemars' numeric `format`s (`uint`, `float`, ...) are left out: they are no JSON Schema
/// formats, and validators in strict mode (Ajv) refuse unknown ones. The range check reads them
/// ([`check_ranges`] uses the same derivation with the formats kept).
pub fn schema_of<T: JsonSchema>() -> Value {
    let mut schema = derive::<T>();
    strip_numeric_formats(&mut schema);
    schema
}

/// [`schema_of`] with schemars' numeric `format`s kept (`float` marks an `f32`).
pub(crate) fn derive<T: JsonSchema>() -> Value {
    let mut settings = SchemaSettings::draft2020_12();
    settings.inline_subschemas = true;
    let mut schema = settings
        .into_generator()
        .into_root_schema_for::<T>()
        .to_value();
    tidy_f32(&mut schema);
    tidy_descriptions(&mut schema);
    schema
}

/// The `format`s schemars gives Rust's number types.
const NUMERIC_FORMATS: [&str; 14] = [
    "int8", "int16", "int32", "int64", "int128", "int", "uint8", "uint16", "uint32", "uint64",
    "uint128", "uint", "float", "double",
];

fn strip_numeric_formats(v: &mut Value) {
    match v {
        Value::Object(m) => {
            if m.get("format")
                .and_then(Value::as_str)
                .is_some_and(|f| NUMERIC_FORMATS.contains(&f))
            {
                m.remove("format");
            }
            m.values_mut().for_each(strip_numeric_formats);
        }
        Value::Array(a) => a.iter_mut().for_each(strip_numeric_formats),
        _ => {}
    }
}

/// Doc comments as descriptions: lines of a paragraph joined with a space, `` [`x`] `` as `` `x` ``.
fn tidy_descriptions(v: &mut Value) {
    match v {
        Value::Object(m) => {
            for (k, x) in m.iter_mut() {
                match x {
                    Value::String(text) if k == "description" || k == "title" => {
                        *text = text
                            .split("\n\n")
                            .map(|para| {
                                para.split('\n')
                                    .map(str::trim)
                                    .collect::<Vec<_>>()
                                    .join(" ")
                            })
                            .collect::<Vec<_>>()
                            .join("\n\n")
                            .replace("[`", "`")
                            .replace("`]", "`");
                    }
                    _ => tidy_descriptions(x),
                }
            }
        }
        Value::Array(a) => a.iter_mut().for_each(tidy_descriptions),
        _ => {}
    }
}

/// Rewrites every non-integral number that is exactly an `f32` as the shortest decimal that reads
/// back to that `f32` (a serialized `f32` default is widened to `f64` on its way into JSON).
fn tidy_f32(v: &mut Value) {
    match v {
        Value::Number(n) if n.is_f64() => {
            let x = n.as_f64().unwrap_or_default();
            let f = x as f32;
            if f.is_finite() && f64::from(f) == x && x.fract() != 0.0 {
                if let Some(short) = f.to_string().parse::<f64>().ok().and_then(Number::from_f64) {
                    *n = short;
                }
            }
        }
        Value::Array(a) => a.iter_mut().for_each(tidy_f32),
        Value::Object(m) => m.values_mut().for_each(tidy_f32),
        _ => {}
    }
}

/// A value outside the range its schema gives.
#[derive(Clone, Debug, PartialEq)]
pub struct OutOfRange {
    /// The JSON path below `params` (`samples`, `hks.eigenpairs`, `example.faces[0].mesh`).
    pub field: String,
    /// The value (NaN when it was not a finite number).
    pub value: f64,
    /// The value as written in messages (`5`, `0.5`; an `f32` as the code prints it).
    pub value_text: String,
    /// The range as text: `256..=262144` for integers, `(0, 10]` or `[0, 1]` for reals.
    pub range: String,
}

impl OutOfRange {
    /// `5 is outside the range 256..=262144`.
    pub fn message(&self) -> String {
        format!("{} is outside the range {}", self.value_text, self.range)
    }
}

impl std::fmt::Display for OutOfRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "params.{}: {}", self.field, self.message())
    }
}

impl std::error::Error for OutOfRange {}

impl From<OutOfRange> for ConstraintsError {
    fn from(e: OutOfRange) -> Self {
        ConstraintsError::new(format!("params.{}", e.field), e.message())
    }
}

/// Parses a method's params from the constraints (serde: types, unknown fields, defaults) and
/// checks every range against the schema derived from `P`.
///
/// # Errors
/// A [`ConstraintsError`] naming `params.<path>`.
pub fn parse<P>(c: &Constraints) -> Result<P, ConstraintsError>
where
    P: DeserializeOwned + Serialize + JsonSchema,
{
    let p: P = c.method_params()?;
    check_ranges(&p)?;
    Ok(p)
}

/// Checks every range of `params` against the schema derived from its type.
///
/// # Errors
/// The first value (in key order) outside its range.
pub fn check_ranges<P: Serialize + JsonSchema>(params: &P) -> Result<(), OutOfRange> {
    let value = serde_json::to_value(params).unwrap_or(Value::Null);
    check_value(&derive::<P>(), &value)
}

/// Checks the ranges that `schema` gives anywhere inside `value` (see the module docs for what is
/// read; without `format: float` a number compares as `f64`). Only ranges are checked: types,
/// required and unknown fields are serde's.
///
/// # Errors
/// The first value (in key order) outside its range; its `field` is the path inside `value`.
pub fn check_value(schema: &Value, value: &Value) -> Result<(), OutOfRange> {
    let mut path = String::new();
    walk(schema, schema, value, &mut path)
}

fn walk(root: &Value, schema: &Value, value: &Value, path: &mut String) -> Result<(), OutOfRange> {
    let Some(s) = schema.as_object() else {
        return Ok(()); // `true` / `false` schemas hold no range.
    };
    if let Some(target) = s
        .get("$ref")
        .and_then(Value::as_str)
        .and_then(|r| r.strip_prefix('#'))
        .and_then(|p| root.pointer(p))
    {
        walk(root, target, value, path)?;
    }
    if let Some(all) = s.get("allOf").and_then(Value::as_array) {
        for branch in all {
            walk(root, branch, value, path)?;
        }
    }
    for key in ["anyOf", "oneOf"] {
        for branch in s.get(key).and_then(Value::as_array).into_iter().flatten() {
            if fits(branch, value) {
                walk(root, branch, value, path)?;
            }
        }
    }
    match value {
        Value::Number(n) => check_number(s, n, path),
        Value::Null if has_range(s) && !allows(s, "null") => Err(out_of_range(
            s,
            path,
            f64::NAN,
            "a non-finite number".into(),
        )),
        Value::Object(fields) => {
            let Some(props) = s.get("properties").and_then(Value::as_object) else {
                return Ok(());
            };
            for (k, v) in fields {
                if let Some(sub) = props.get(k) {
                    let len = path.len();
                    if !path.is_empty() {
                        path.push('.');
                    }
                    path.push_str(k);
                    walk(root, sub, v, path)?;
                    path.truncate(len);
                }
            }
            Ok(())
        }
        Value::Array(items) => {
            let Some(sub) = s.get("items") else {
                return Ok(());
            };
            for (i, v) in items.iter().enumerate() {
                let len = path.len();
                let _ = write!(path, "[{i}]");
                walk(root, sub, v, path)?;
                path.truncate(len);
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

const RANGE_KEYS: [&str; 4] = ["minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"];

fn has_range(s: &Map<String, Value>) -> bool {
    RANGE_KEYS.iter().any(|k| s.contains_key(*k))
}

/// Whether the schema's `type` (a string or a list) names `ty`; no `type` allows everything.
fn allows(s: &Map<String, Value>, ty: &str) -> bool {
    match s.get("type") {
        None => true,
        Some(Value::String(t)) => t == ty || (ty == "integer" && t == "number"),
        Some(Value::Array(ts)) => ts
            .iter()
            .any(|t| t == ty || (ty == "integer" && t == "number")),
        Some(_) => false,
    }
}

/// Whether a branch of `anyOf` / `oneOf` describes `value`: its type, its `const`, and for objects
/// its required keys (and, when it denies others, no key it does not list).
fn fits(branch: &Value, value: &Value) -> bool {
    let Some(b) = branch.as_object() else {
        return branch.as_bool().unwrap_or(false);
    };
    let ty = match value {
        Value::Null => "null",
        Value::Bool(_) => "boolean",
        Value::Number(n) if n.is_f64() => "number",
        Value::Number(_) => "integer",
        Value::String(_) => "string",
        Value::Array(_) => "array",
        Value::Object(_) => "object",
    };
    if !allows(b, ty) {
        return false;
    }
    if b.get("const").is_some_and(|c| c != value) {
        return false;
    }
    if let Value::Object(fields) = value {
        let required = b.get("required").and_then(Value::as_array);
        if required
            .into_iter()
            .flatten()
            .any(|k| k.as_str().is_none_or(|k| !fields.contains_key(k)))
        {
            return false;
        }
        if b.get("additionalProperties") == Some(&Value::Bool(false)) {
            let props = b.get("properties").and_then(Value::as_object);
            if fields
                .keys()
                .any(|k| !props.is_some_and(|p| p.contains_key(k)))
            {
                return false;
            }
        }
    }
    true
}

/// Integer ranges print as `a..=b`, real ones as intervals.
fn is_integer(s: &Map<String, Value>) -> bool {
    allows(s, "integer") && !allows(s, "number")
}

fn is_f32(s: &Map<String, Value>) -> bool {
    s.get("format").and_then(Value::as_str) == Some("float")
}

fn check_number(s: &Map<String, Value>, n: &Number, path: &str) -> Result<(), OutOfRange> {
    if !has_range(s) {
        return Ok(());
    }
    let x = n.as_f64().unwrap_or(f64::NAN);
    let f32_field = is_f32(s);
    // Compare as the code's type does: f32 fields in f32; integers exactly.
    let cmp = |bound: &Value| -> Option<std::cmp::Ordering> {
        let b = bound.as_number()?;
        if let (Some(v), Some(b)) = (as_i128(n), as_i128(b)) {
            return Some(v.cmp(&b));
        }
        let b = b.as_f64()?;
        if f32_field {
            (x as f32).partial_cmp(&(b as f32))
        } else {
            x.partial_cmp(&b)
        }
    };
    use std::cmp::Ordering::{Equal, Greater, Less};
    let ok = s
        .get("minimum")
        .is_none_or(|b| matches!(cmp(b), Some(Greater | Equal)))
        && s.get("maximum")
            .is_none_or(|b| matches!(cmp(b), Some(Less | Equal)))
        && s.get("exclusiveMinimum")
            .is_none_or(|b| cmp(b) == Some(Greater))
        && s.get("exclusiveMaximum")
            .is_none_or(|b| cmp(b) == Some(Less));
    if ok {
        return Ok(());
    }
    let text = if let Some(i) = as_i128(n) {
        i.to_string()
    } else if f32_field {
        (x as f32).to_string()
    } else {
        x.to_string()
    };
    Err(out_of_range(s, path, x, text))
}

fn as_i128(n: &Number) -> Option<i128> {
    n.as_i64()
        .map(i128::from)
        .or_else(|| n.as_u64().map(i128::from))
}

fn out_of_range(s: &Map<String, Value>, path: &str, value: f64, value_text: String) -> OutOfRange {
    OutOfRange {
        field: path.to_string(),
        value,
        value_text,
        range: range_text(s),
    }
}

/// `256..=262144`, `1..`, `(0, 10]`, `[0, 1]`, `[0, ∞)`.
fn range_text(s: &Map<String, Value>) -> String {
    let f32_field = is_f32(s);
    let num = |v: &Value| -> String {
        match v.as_number() {
            Some(n) if as_i128(n).is_some() => as_i128(n).unwrap_or_default().to_string(),
            Some(n) if f32_field => (n.as_f64().unwrap_or_default() as f32).to_string(),
            Some(n) => n.as_f64().unwrap_or_default().to_string(),
            None => v.to_string(),
        }
    };
    let (lo, lo_open) = match (s.get("minimum"), s.get("exclusiveMinimum")) {
        (_, Some(b)) => (Some(num(b)), true),
        (Some(b), None) => (Some(num(b)), false),
        (None, None) => (None, true),
    };
    let (hi, hi_open) = match (s.get("maximum"), s.get("exclusiveMaximum")) {
        (_, Some(b)) => (Some(num(b)), true),
        (Some(b), None) => (Some(num(b)), false),
        (None, None) => (None, true),
    };
    if is_integer(s) && !lo_open && !hi_open {
        return format!("{}..={}", lo.unwrap_or_default(), hi.unwrap_or_default());
    }
    if is_integer(s) && !lo_open && hi.is_none() {
        return format!("{}..", lo.unwrap_or_default());
    }
    format!(
        "{}{}, {}{}",
        if lo_open { '(' } else { '[' },
        lo.unwrap_or_else(|| "-∞".into()),
        hi.unwrap_or_else(|| "∞".into()),
        if hi_open { ')' } else { ']' },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn err(schema: Value, value: Value) -> Option<String> {
        check_value(&schema, &value)
            .err()
            .map(|e| format!("{}: {}", e.field, e.message()))
    }

    #[test]
    fn bounds_and_their_wording() {
        let int = json!({"type": "integer", "format": "uint", "minimum": 256, "maximum": 262144});
        assert_eq!(err(int.clone(), json!(256)), None);
        assert_eq!(err(int.clone(), json!(262144)), None);
        assert_eq!(
            err(int.clone(), json!(5)).as_deref(),
            Some(": 5 is outside the range 256..=262144")
        );
        let open = json!({"type": ["number", "null"], "format": "float",
                          "exclusiveMinimum": 0, "maximum": 10});
        assert_eq!(err(open.clone(), json!(null)), None);
        assert_eq!(err(open.clone(), json!(10)), None);
        assert_eq!(err(open.clone(), json!(1e-30)), None);
        assert_eq!(
            err(open.clone(), json!(0)).as_deref(),
            Some(": 0 is outside the range (0, 10]")
        );
        assert_eq!(
            err(open, json!(10.5)).as_deref(),
            Some(": 10.5 is outside the range (0, 10]")
        );
        // f32 fields compare in f32, as the code's own checks did.
        let weld = json!({"type": "number", "format": "float", "minimum": 0, "maximum": 0.01});
        assert_eq!(err(weld.clone(), json!(f64::from(0.01f32))), None);
        assert_eq!(
            err(weld, json!(0.02)).as_deref(),
            Some(": 0.02 is outside the range [0, 0.01]")
        );
        let finite = json!({"type": "number", "format": "float", "minimum": 0});
        assert_eq!(
            err(finite, json!(null)).as_deref(),
            Some(": a non-finite number is outside the range [0, ∞)")
        );
    }

    #[test]
    fn nested_objects_arrays_and_branches() {
        let schema = json!({"type": "object", "properties": {
            "hks": {"type": "object", "properties": {
                "eigenpairs": {"type": "integer", "minimum": 8, "maximum": 500}}},
            "example": {"anyOf": [{"oneOf": [
                {"type": "object", "required": ["faces"], "additionalProperties": false,
                 "properties": {"faces": {"type": "array", "items": {"type": "object",
                    "properties": {"mesh": {"type": "integer", "minimum": 0}}}}}},
                {"type": "object", "required": ["vertex_color"], "additionalProperties": false,
                 "properties": {"vertex_color": {"type": "object", "properties": {
                    "threshold": {"type": "number", "minimum": 0, "maximum": 1}}}}}
            ]}, {"type": "null"}]}
        }});
        let e = |v| err(schema.clone(), v);
        assert_eq!(e(json!({"hks": {"eigenpairs": 8}, "example": null})), None);
        assert_eq!(
            e(json!({"hks": {"eigenpairs": 7}})).as_deref(),
            Some("hks.eigenpairs: 7 is outside the range 8..=500")
        );
        assert_eq!(
            e(json!({"example": {"vertex_color": {"threshold": 1.5}}})).as_deref(),
            Some("example.vertex_color.threshold: 1.5 is outside the range [0, 1]")
        );
        assert_eq!(
            e(json!({"example": {"faces": [{"mesh": 0}, {"mesh": -1}]}})).as_deref(),
            Some("example.faces[1].mesh: -1 is outside the range 0..")
        );
    }

    #[test]
    fn descriptions_read_as_text() {
        let mut v = json!({"properties": {"a": {"description": "One line\nand the next ([`Foo::bar`]).\n\nSecond."},
                           "description": {"type": "string"}}});
        tidy_descriptions(&mut v);
        assert_eq!(
            v,
            json!({"properties": {"a": {"description": "One line and the next (`Foo::bar`).\n\nSecond."},
                   "description": {"type": "string"}}})
        );
    }

    #[test]
    fn f32_defaults_are_written_short() {
        let mut v = json!({"default": f64::from(0.02f32), "third": f64::from(1.0f32 / 3.0),
                           "exact": 0.01, "one": 1.0});
        tidy_f32(&mut v);
        assert_eq!(
            v,
            json!({"default": 0.02, "third": 0.33333334, "exact": 0.01, "one": 1.0})
        );
    }
}
