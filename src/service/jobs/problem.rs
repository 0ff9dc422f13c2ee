//! The one table from engine errors to RFC 9457 problems (a failed job's `error`).
//!
//! Every problem type is `/problems/<kind>` with a stable kebab-case kind: ingest errors use
//! [`IngestError::kind`], constraints errors are `invalid-constraints` with `field` set to the
//! JSON path inside the constraints document (`constraints.output.texture_size`), an unknown or
//! unimplemented method is `method-not-implemented`, surface errors are named after their
//! variant. Errors in what the client sent are status 422; bugs and environment failures are 500.

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::export::ExportError;
use crate::engine::asset::IngestError;
use crate::engine::mesh::surface::MeshError;
use crate::engine::methods::meshmatch::MeshMatchError;
use crate::engine::methods::project::ProjectError;
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

/// An upload that cannot be loaded; `side` is `source` or `target`.
pub fn ingest_problem(side: &str, e: &IngestError) -> Problem {
    use IngestError::*;
    let status = if matches!(e, Internal(_)) { 500 } else { 422 };
    let path: Option<String> = match e {
        InvalidDocument { path, .. }
        | WrongAccessorType { path, .. }
        | UnequalCount { path, .. }
        | MissingPosition { path }
        | IndexOutOfRange { path, .. }
        | PrimitiveRestartIndex { path, .. }
        | NonFinite { path, .. }
        | UnresolvedReference { path, .. } => Some(path.clone()),
        ForbiddenUri { what, .. }
        | InvalidUri { what, .. }
        | DataUriTooLarge { what, .. }
        | MissingFile { what, .. } => Some(what.clone()),
        BufferWithoutData { buffer } | BufferLengthMismatch { buffer, .. } => {
            Some(format!("buffers[{buffer}]"))
        }
        BufferViewOutOfRange { view, .. } | InvalidStride { view, .. } => {
            Some(format!("bufferViews[{view}]"))
        }
        AccessorOutOfRange { accessor, .. }
        | StrideTooSmall { accessor, .. }
        | InvalidAccessor { accessor, .. } => Some(format!("accessors[{accessor}]")),
        InvalidNodeHierarchy { node, .. }
        | NodeTooDeep { node, .. }
        | NonFiniteTransform { node } => Some(format!("nodes[{node}]")),
        ImageTooLarge { image, .. }
        | UnrecognizedImage { image }
        | ImageDecode { image, .. }
        | ImageWithoutData { image } => Some(format!("images[{image}]")),
        _ => None,
    };
    let limit = match e {
        InputTooLarge { max, .. }
        | JsonTooLarge { max, .. }
        | DataUriTooLarge { max, .. }
        | TooManyVertices { max, .. }
        | TooManyTriangles { max, .. }
        | NodeTooDeep { max, .. }
        | ImageTooLarge { max, .. } => Some(serde_json::Value::from(*max)),
        _ => None,
    };
    let field = match path.filter(|p| p != "/" && !p.is_empty()) {
        Some(p) => format!("{side}.{p}"),
        None => side.to_string(),
    };
    Problem {
        field: Some(field),
        limit,
        ..problem(
            e.kind(),
            &format!("the {side} model cannot be loaded"),
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

/// The problem of a failed transfer. [`TransferError::Cancelled`] is not a failure (the runner
/// finishes such jobs as canceled); it maps to `/problems/canceled` for completeness.
pub fn transfer_problem(e: &TransferError) -> Problem {
    match e {
        TransferError::Ingest { side, source } => ingest_problem(side, source),
        TransferError::Constraints(c) => constraints_problem(c),
        TransferError::MethodNotImplemented(m) => Problem {
            field: Some("constraints.method".into()),
            ..problem(
                "method-not-implemented",
                "the method is not implemented yet",
                422,
                format!("method {m:?} is not implemented yet; available: project, meshmatch"),
            )
        },
        TransferError::Project(ProjectError::Mesh { side, source }) => {
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
        TransferError::Project(ProjectError::Constraints(c)) => constraints_problem(c),
        TransferError::Project(ProjectError::Cancelled(_)) | TransferError::Cancelled => problem(
            "canceled",
            "the job was canceled",
            409,
            "the job was canceled".into(),
        ),
        TransferError::Meshmatch(m) => meshmatch_problem(m, e),
        TransferError::Export(ExportError::TooLarge { bytes }) => Problem {
            limit: Some(serde_json::Value::from(u64::from(u32::MAX))),
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

/// The problem of a failed `meshmatch` run: bad parameters name their field (422), bad meshes
/// their side (422), anything else is the engine's fault (500).
fn meshmatch_problem(m: &MeshMatchError, e: &TransferError) -> Problem {
    match m {
        MeshMatchError::Param { name, .. } => Problem {
            field: Some(format!("constraints.params.{name}")),
            ..problem(
                "invalid-constraints",
                "the constraints are invalid",
                422,
                e.to_string(),
            )
        },
        MeshMatchError::Constraints(c) => constraints_problem(c),
        MeshMatchError::Mesh { side, source } => Problem {
            field: Some(side.to_string()),
            ..problem(
                mesh_kind(source),
                &format!("the {side} surface cannot be built"),
                422,
                e.to_string(),
            )
        },
        MeshMatchError::Hierarchy(_)
        | MeshMatchError::Resample(_)
        | MeshMatchError::Features(_) => problem(
            "unusable-mesh",
            "a mesh cannot be prepared for matching",
            422,
            e.to_string(),
        ),
        _ => problem("meshmatch-failed", "meshmatch failed", 500, e.to_string()),
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
    fn ingest_limit_is_reported() {
        let e = IngestError::TooManyTriangles { count: 10, max: 5 };
        let p = ingest_problem("target", &e);
        assert_eq!(p.kind, "/problems/too-many-triangles");
        assert_eq!(p.field.as_deref(), Some("target"));
        assert_eq!(p.limit, Some(serde_json::json!(5)));
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
    }
}
