//! RFC 9457 problem responses: every 4xx/5xx of the API is `application/problem+json` with a
//! stable `type` (`/problems/<kind>`), the failing `field` (a multipart part name, a JSON path
//! such as `constraints.output.texture_size`, or a glTF path such as
//! `source.meshes[0].primitives[0].indices`) and the `limit` that was exceeded, where one was.
//!
//! This file is the one table from engine and store errors to problem types: ingest errors by
//! [`IngestError::kind`], constraint errors by their JSON path, store errors by variant.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::IngestError;
use crate::service::model::Problem;
use crate::service::store::StoreError;

/// Media type of problem bodies.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// An error answer of the API: a [`Problem`] plus optional extra headers.
#[derive(Debug, Clone)]
pub struct ApiError {
    /// The body (boxed: errors travel through many `Result`s).
    pub problem: Box<Problem>,
    /// `Retry-After` seconds, for 503.
    pub retry_after: Option<u64>,
}

impl ApiError {
    /// A problem of type `/problems/{kind}`.
    pub fn new(status: StatusCode, kind: &str, title: &str, detail: impl Into<String>) -> Self {
        Self {
            problem: Box::new(Problem {
                kind: format!("/problems/{kind}"),
                title: title.to_string(),
                status: status.as_u16(),
                detail: detail.into(),
                field: None,
                limit: None,
            }),
            retry_after: None,
        }
    }

    /// Names the failing field.
    pub fn field(mut self, field: impl Into<String>) -> Self {
        self.problem.field = Some(field.into());
        self
    }

    /// Names the exceeded limit: `{"name": ..., "value": ...}`.
    pub fn limit(mut self, name: &str, value: impl Into<serde_json::Value>) -> Self {
        self.problem.limit = Some(json!({"name": name, "value": value.into()}));
        self
    }

    /// Adds `Retry-After`.
    pub fn retry_after(mut self, secs: u64) -> Self {
        self.retry_after = Some(secs);
        self
    }

    /// HTTP status.
    pub fn status(&self) -> StatusCode {
        StatusCode::from_u16(self.problem.status).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR)
    }

    /// 404 for an unknown job.
    pub fn job_not_found(id: impl std::fmt::Display) -> Self {
        Self::new(
            StatusCode::NOT_FOUND,
            "job-not-found",
            "Job not found",
            format!("there is no job {id}"),
        )
    }

    /// 500 for a bug or a storage failure (logged with the detail).
    pub fn internal(detail: impl std::fmt::Display) -> Self {
        tracing::error!(%detail, "internal error");
        Self::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal",
            "Internal server error",
            detail.to_string(),
        )
    }

    /// 413 for a body or part over a size limit.
    pub fn too_large(field: &str, limit_name: &str, limit: u64) -> Self {
        Self::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "payload-too-large",
            "Payload too large",
            format!("{field} exceeds {limit_name} = {limit} bytes"),
        )
        .field(field)
        .limit(limit_name, limit)
    }

    /// 400 for a malformed request (missing part, bad header, bad query).
    pub fn bad_request(kind: &str, field: &str, detail: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, kind, "Bad request", detail).field(field)
    }

    /// 422 for constraints that cannot be used; the field is `constraints.<path>`.
    pub fn constraints(e: &ConstraintsError) -> Self {
        let field = if e.path == "." || e.path.is_empty() {
            "constraints".to_string()
        } else {
            format!("constraints.{}", e.path)
        };
        Self::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-constraints",
            "Invalid constraints",
            e.to_string(),
        )
        .field(field)
    }

    /// 422 (or 413 for size limits) for a model that does not load; `side` is the part name.
    pub fn ingest(side: &str, e: &IngestError) -> Self {
        let (field, limit) = ingest_location(e);
        let status = match e {
            IngestError::InputTooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            IngestError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
            _ => StatusCode::UNPROCESSABLE_ENTITY,
        };
        let field = match field {
            Some(path) => format!("{side}.{path}"),
            None => side.to_string(),
        };
        let mut err =
            Self::new(status, e.kind(), "Invalid model", format!("{side}: {e}")).field(field);
        if let Some((name, value)) = limit {
            err = err.limit(name, value);
        }
        err
    }

    /// Maps a storage error.
    pub fn store(e: StoreError) -> Self {
        match e {
            StoreError::NotFound(id) => Self::job_not_found(id),
            StoreError::Conflict { id, status, what } => Self::new(
                StatusCode::CONFLICT,
                "job-state-conflict",
                "Job state conflict",
                format!("job {id} is {}: {what}", status.as_str()),
            )
            .field("status"),
            StoreError::IdempotencyMismatch { key, existing } => Self::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                "idempotency-key-reused",
                "Idempotency-Key reused with a different request",
                format!("Idempotency-Key {key:?} was used for job {existing} with a different request body"),
            )
            .field("Idempotency-Key"),
            StoreError::BlobNotFound(key) => Self::new(
                StatusCode::NOT_FOUND,
                "artifact-not-found",
                "Artifact not found",
                format!("no stored file {key:?}"),
            ),
            StoreError::InvalidCursor(c) => Self::bad_request(
                "invalid-cursor",
                "next",
                format!("cursor {c:?} was not issued by this server"),
            ),
            other => Self::internal(other),
        }
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

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let body = serde_json::to_vec(&*self.problem).unwrap_or_default();
        let mut resp = (status, body).into_response();
        resp.headers_mut()
            .insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        if let Some(secs) = self.retry_after {
            resp.headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(secs));
        }
        resp
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        ApiError::store(e)
    }
}

/// Turns axum's own rejections (bad path, bad query, method not allowed) into problems too.
pub fn from_status(status: StatusCode, detail: String) -> ApiError {
    let kind = match status {
        StatusCode::NOT_FOUND => "not-found",
        StatusCode::METHOD_NOT_ALLOWED => "method-not-allowed",
        StatusCode::PAYLOAD_TOO_LARGE => "payload-too-large",
        StatusCode::REQUEST_TIMEOUT => "request-timeout",
        StatusCode::UNSUPPORTED_MEDIA_TYPE => "unsupported-media-type",
        s if s.is_server_error() => "internal",
        _ => "bad-request",
    };
    let title = status.canonical_reason().unwrap_or("Error");
    ApiError::new(status, kind, title, detail)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ingest_errors_carry_path_and_limit() {
        let e = IngestError::TooManyTriangles { count: 10, max: 5 };
        let p = ApiError::ingest("target", &e).problem;
        assert_eq!(p.kind, "/problems/too-many-triangles");
        assert_eq!(p.status, 422);
        assert_eq!(p.field.as_deref(), Some("target"));
        assert_eq!(p.limit.unwrap()["name"], "max_triangles");
        let e = IngestError::ForbiddenUri {
            what: "buffers[0]".into(),
            uri: "../x".into(),
        };
        let p = ApiError::ingest("source", &e).problem;
        assert_eq!(p.field.as_deref(), Some("source.buffers[0].uri"));
    }

    #[test]
    fn constraint_errors_are_prefixed() {
        let e = ConstraintsError::new("output.texture_size", "too big");
        let p = ApiError::constraints(&e).problem;
        assert_eq!(p.field.as_deref(), Some("constraints.output.texture_size"));
    }
}
