//! The one table from engine errors to RFC 9457 problems, used both for answers at submission
//! (`POST /v1/jobs`, through [`crate::service::http::problem::ApiError`]) and for a failed job's
//! `error`, so the same error has the same type, status, `field` and `limit` everywhere.
//!
//! Every problem type is `/problems/<kind>` with a stable kebab-case kind: ingest errors use
//! [`IngestError::kind`]; constraints errors are `invalid-constraints` with `field` set to the
//! JSON path inside the constraints document (`constraints.params.samples`); an unknown or
//! unimplemented method is `method-not-implemented`; method errors map by their category
//! ([`MethodError`]), never by method. `limit` is always `{"name": ..., "value": ...}`. Errors in
//! what the client sent are 422 (413 for an input over a byte limit); bugs and environment
//! failures are 500.

use serde_json::json;

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::export::ExportError;
use crate::engine::asset::IngestError;
use crate::engine::mesh::surface::MeshError;
use crate::engine::methods::MethodError;
use crate::engine::pipeline::TransferError;
use crate::service::model::Problem;

fn problem(kind: &str, title: &str, status: u16, detail: String) -> Problem {
    Problem {
        kind: format!("/problems/{kind}"),
        title: title.to_string(),
        status,
        detail,
        field: None,
        limit: None,
    }
}

/// The `limit` member: the setting's name and its value.
pub fn limit(name: &str, value: impl Into<serde_json::Value>) -> Option<serde_json::Value> {
    Some(json!({"name": name, "value": value.into()}))
}

/// The JSON path of a constraints error, as a problem field (`constraints` for the document).
pub fn constraints_field(path: &str) -> String {
    if path.is_empty() || path == "." {
        "constraints".to_string()
    } else {
        format!("constraints.{path}")
    }
}

/// A constraints document that cannot be used.
pub fn constraints_problem(e: &ConstraintsError) -> Problem {
    Problem {
        field: Some(constraints_field(&e.path)),
        ..problem(
            "invalid-constraints",
            "the constraints are invalid",
            422,
            e.to_string(),
        )
    }
}

/// `output.texture_size` over the service's `max_texture_size`.
pub fn texture_size_problem(size: u32, max: u32) -> Problem {
    Problem {
        field: Some("constraints.output.texture_size".into()),
        limit: limit("max_texture_size", max),
        ..problem(
            "texture-size-over-limit",
            "the output texture size is over the limit",
            422,
            format!("output.texture_size {size} exceeds max_texture_size = {max}"),
        )
    }
}

/// The glTF path (without the side) and the exceeded limit of an ingest error.
fn ingest_location(e: &IngestError) -> (Option<String>, Option<(&'static str, u64)>) {
    use IngestError::*;
    match e {
        MissingMain { name } | EmptyFile { name } => (Some(name.clone()), None),
        InputTooLarge { max, .. } => (None, Some(("max_input_bytes", *max))),
        JsonTooLarge { max, .. } => (None, Some(("max_json_bytes", *max))),
        InvalidDocument { path, .. } => (Some(path.clone()), None),
        UnsupportedVersion { .. } => (Some("asset.version".into()), None),
        UnsupportedExtension(_) => (Some("extensionsRequired".into()), None),
        ForbiddenUri { what, .. } | InvalidUri { what, .. } | MissingFile { what, .. } => {
            (Some(format!("{what}.uri")), None)
        }
        DataUriTooLarge { what, max, .. } => (
            Some(format!("{what}.uri")),
            Some(("max_data_uri_bytes", *max)),
        ),
        BufferWithoutData { buffer } | BufferLengthMismatch { buffer, .. } => {
            (Some(format!("buffers[{buffer}]")), None)
        }
        UnresolvedReference { path, .. }
        | WrongAccessorType { path, .. }
        | UnequalCount { path, .. }
        | MissingPosition { path }
        | IndexOutOfRange { path, .. }
        | PrimitiveRestartIndex { path, .. }
        | NonFinite { path, .. } => (Some(path.clone()), None),
        BufferViewOutOfRange { view, .. } | InvalidStride { view, .. } => {
            (Some(format!("bufferViews[{view}]")), None)
        }
        AccessorOutOfRange { accessor, .. }
        | StrideTooSmall { accessor, .. }
        | InvalidAccessor { accessor, .. } => (Some(format!("accessors[{accessor}]")), None),
        TooManyVertices { max, .. } => (None, Some(("max_vertices", *max))),
        GeometryBudget { what, max, .. } => (
            None,
            Some((
                if *what == "vertices" {
                    "max_vertices"
                } else {
                    "max_triangles"
                },
                *max,
            )),
        ),
        ImageBudget { image, max, .. } => (
            Some(format!("images[{image}]")),
            Some(("max_decoded_image_bytes", *max)),
        ),
        TooManyTriangles { max, .. } => (None, Some(("max_triangles", *max))),
        InvalidNodeHierarchy { node, .. } | NonFiniteTransform { node } => {
            (Some(format!("nodes[{node}]")), None)
        }
        NodeTooDeep { node, max, .. } => (
            Some(format!("nodes[{node}]")),
            Some(("max_node_depth", *max)),
        ),
        ImageTooLarge {
            image,
            width,
            height,
            max,
        } => {
            let name = if u64::from(*width).max(u64::from(*height)) > *max {
                "max_image_side"
            } else {
                "max_image_pixels"
            };
            (Some(format!("images[{image}]")), Some((name, *max)))
        }
        UnrecognizedImage { image } | ImageDecode { image, .. } | ImageWithoutData { image } => {
            (Some(format!("images[{image}]")), None)
        }
        _ => (None, None),
    }
}

/// An input that cannot be loaded; `side` is the part name (`source`, `target`, `source_base`,
/// `pattern`).
pub fn ingest_problem(side: &str, e: &IngestError) -> Problem {
    let (path, lim) = ingest_location(e);
    let status = match e {
        IngestError::InputTooLarge { .. } => 413,
        IngestError::Internal(_) => 500,
        _ => 422,
    };
    let field = match path.filter(|p| p != "/" && !p.is_empty()) {
        Some(p) if side == "pattern" => p.replace("images[0]", "pattern"),
        Some(p) => format!("{side}.{p}"),
        None => side.to_string(),
    };
    Problem {
        field: Some(field),
        limit: lim.and_then(|(name, value)| limit(name, value)),
        ..problem(
            e.kind(),
            &format!("the {side} input cannot be loaded"),
            status,
            format!("{side}: {e}"),
        )
    }
}

fn mesh_kind(e: &MeshError) -> &'static str {
    match e {
        MeshError::EmptySurface => "empty-surface",
        MeshError::AllDegenerate { .. } => "all-degenerate",
        MeshError::InvalidParam { .. } => "invalid-parameter",
        MeshError::VertexIndexOutOfRange { .. } => "vertex-index-out-of-range",
        MeshError::NonFinitePosition { .. } => "non-finite-position",
        MeshError::TooLarge { .. } => "surface-too-large",
    }
}

/// A failed method, by the error's category.
pub fn method_problem(e: &MethodError) -> Problem {
    match e {
        MethodError::Cancelled => problem(
            "canceled",
            "the job was canceled",
            409,
            "the job was canceled".into(),
        ),
        MethodError::Constraints(c) => constraints_problem(c),
        MethodError::Mesh { side, source } => {
            let status = if matches!(source, MeshError::InvalidParam { .. }) {
                500
            } else {
                422
            };
            Problem {
                field: Some(side.to_string()),
                ..problem(
                    mesh_kind(source),
                    &format!("the {side} surface cannot be built"),
                    status,
                    e.to_string(),
                )
            }
        }
        MethodError::UnusableInput {
            field,
            kind,
            message,
        } => Problem {
            field: field.clone(),
            ..problem(kind, "an input cannot be used", 422, message.clone())
        },
        MethodError::Internal(m) => problem("internal", "internal error", 500, m.clone()),
    }
}

/// The problem of a failed transfer. [`TransferError::Cancelled`] is not a failure (the runner
/// finishes such jobs as canceled); it maps to `/problems/canceled` for completeness.
pub fn transfer_problem(e: &TransferError) -> Problem {
    match e {
        TransferError::Ingest { side, source } => ingest_problem(side, source),
        TransferError::Constraints(c) => constraints_problem(c),
        TransferError::MethodNotImplemented { .. } => Problem {
            field: Some("constraints.method".into()),
            ..problem(
                "method-not-implemented",
                "the method is not implemented yet",
                422,
                e.to_string(),
            )
        },
        TransferError::MissingInput { input, .. } => Problem {
            field: Some(input.to_string()),
            ..problem(
                "missing-input",
                "the method needs an input that was not given",
                422,
                e.to_string(),
            )
        },
        TransferError::WorkingSet { field, max, .. } => Problem {
            field: Some(if field == "inputs" {
                "target".to_string()
            } else {
                constraints_field(field)
            }),
            limit: limit("max_method_bytes", *max),
            ..problem(
                "working-set-over-budget",
                "the method would need too much memory",
                422,
                e.to_string(),
            )
        },
        TransferError::Method(m) => method_problem(m),
        TransferError::Cancelled => method_problem(&MethodError::Cancelled),
        TransferError::Export(ExportError::TooLarge { bytes }) => Problem {
            limit: limit("glb_bytes", u64::from(u32::MAX)),
            ..problem(
                "output-too-large",
                "the output is too large",
                422,
                format!("output of {bytes} bytes exceeds the glTF binary limit of 4 GiB"),
            )
        },
        TransferError::Export(other) => problem(
            "export-failed",
            "writing the output failed",
            500,
            other.to_string(),
        ),
    }
}

/// A job that panicked on the engine pool.
pub fn panic_problem(message: &str) -> Problem {
    problem(
        "internal",
        "internal error",
        500,
        format!("the job panicked: {message}"),
    )
}

/// A job whose success the job store refused to record, again and again
/// ([`crate::service::jobs::runner::FINISH_SLOW_ROUNDS`] rounds): recorded as failed instead.
pub fn result_not_stored_problem() -> Problem {
    problem(
        "result-not-stored",
        "result not stored",
        500,
        "the job ran, but the job store refused to record its result (see the server log); submit it again".into(),
    )
}

/// A failure of the service around the engine (blob store, database).
pub fn internal_problem(detail: String) -> Problem {
    problem("internal", "internal error", 500, detail)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constraints_error_names_the_json_path() {
        let e = crate::engine::asset::constraints::Constraints::from_json(
            br#"{"version":1,"output":{"texture_size":"big"}}"#,
        )
        .unwrap_err();
        let p = transfer_problem(&TransferError::Constraints(e));
        assert_eq!(p.kind, "/problems/invalid-constraints");
        assert_eq!(p.status, 422);
        assert_eq!(p.field.as_deref(), Some("constraints.output.texture_size"));
    }

    #[test]
    fn ingest_limit_is_reported_the_same_way_everywhere() {
        let e = IngestError::TooManyTriangles { count: 10, max: 5 };
        let p = ingest_problem("target", &e);
        assert_eq!(p.kind, "/problems/too-many-triangles");
        assert_eq!(p.field.as_deref(), Some("target"));
        assert_eq!(p.limit, Some(json!({"name": "max_triangles", "value": 5})));
        let p = ingest_problem(
            "source",
            &IngestError::AccessorOutOfRange {
                accessor: 3,
                view: 1,
                offset: 0,
                end: 9,
                len: 4,
            },
        );
        assert_eq!(p.field.as_deref(), Some("source.accessors[3]"));
        assert_eq!(p.status, 422);
        let p = ingest_problem("source", &IngestError::InputTooLarge { bytes: 9, max: 4 });
        assert_eq!(p.status, 413);
        let e = IngestError::ForbiddenUri {
            what: "buffers[0]".into(),
            uri: "../x".into(),
        };
        let p = ingest_problem("source", &e);
        assert_eq!(p.field.as_deref(), Some("source.buffers[0].uri"));
    }

    #[test]
    fn method_errors_map_by_category() {
        let p = method_problem(&MethodError::Constraints(ConstraintsError::new(
            "params.samples",
            "5 is outside the range 256..=262144",
        )));
        assert_eq!(p.field.as_deref(), Some("constraints.params.samples"));
        assert_eq!(p.status, 422);
        let p = method_problem(&MethodError::Internal("boom".into()));
        assert_eq!((p.kind.as_str(), p.status), ("/problems/internal", 500));
        let p = transfer_problem(&TransferError::MethodNotImplemented {
            method: "pattern",
            available: "project, meshmatch".into(),
        });
        assert_eq!(p.field.as_deref(), Some("constraints.method"));
        assert!(p.detail.contains("available: project, meshmatch"), "{p:?}");
    }
}
