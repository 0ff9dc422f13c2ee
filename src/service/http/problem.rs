//! RFC 9457 problem responses: every 4xx/5xx of the API is `application/problem+json` with a
//! stable `type` (`/problems/<kind>`), the failing `field` (a multipart part name, a JSON path
//! such as `constraints.output.texture_size`, or a glTF path such as
//! `source.meshes[0].primitives[0].indices`) and the `limit` that was exceeded, where one was.
//!
//! Engine errors (ingest, constraints, methods) map through the one table,
//! [`crate::service::problem_table`], so a submission's answer and a failed job's `error` agree;
//! this file adds the HTTP-only problems (store errors, body limits, malformed requests).

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::IngestError;
use crate::service::model::Problem;
use crate::service::problem_table;
use crate::service::store::StoreError;

/// Media type of problem bodies.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// `Retry-After` of a 507 for a full disk.
pub const STORAGE_RETRY_SECS: u64 = 30;

/// Most characters of a client's value a problem repeats back (cursors, ids, names).
pub const ECHO_CHARS: usize = 64;

/// The first `max` characters of `s`, with `…` when it was longer: what a problem may repeat
/// of a client's value without echoing an arbitrarily long input back.
pub fn clip(s: &str, max: usize) -> String {
    match s.char_indices().nth(max) {
        Some((cut, _)) => format!("{}…", &s[..cut]),
        None => s.to_string(),
    }
}

/// An error answer of the API: a [`Problem`] plus optional extra headers.
#[derive(Debug, Clone)]
pub struct ApiError {
    /// The body (boxed: errors travel through many `Result`s).
    pub problem: Box<Problem>,
    /// `Retry-After` seconds, for 503.
    pub retry_after: Option<u64>,
    /// The storage failed (see [`StorageFailure`]).
    pub storage_failure: bool,
}

/// Response extension of an answer caused by a failing storage (full disk, locked database,
/// I/O error): the request middleware reports it to the runner, so claims pause and `/readyz`
/// turns not ready for a while.
#[derive(Clone, Copy, Debug)]
pub struct StorageFailure;

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
            storage_failure: false,
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

    /// 500 for a bug or a storage failure. The detail goes to the log only: the body never
    /// carries raw OS or database text.
    pub fn internal(detail: impl std::fmt::Display) -> Self {
        tracing::error!(%detail, "internal error");
        Self::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "internal",
            "Internal server error",
            "the server failed to complete the request; the details are in its log",
        )
    }

    /// A file-system failure on the server's side (temporary upload files): as [`Self::storage`].
    pub fn io(e: std::io::Error) -> Self {
        Self::storage(&StoreError::Io(e))
    }

    /// A failure of the storage: 507 `insufficient-storage` for a full disk (with
    /// `Retry-After`), 503 `store-busy` for a locked database (with `Retry-After`), else 500.
    /// The raw error is logged, never sent.
    pub fn storage(e: &StoreError) -> Self {
        let mut answer = Self::storage_answer(e);
        answer.storage_failure = e.is_storage_failure();
        answer
    }

    fn storage_answer(e: &StoreError) -> Self {
        if e.is_storage_full() {
            tracing::error!(error = %e, "storage full");
            return Self::new(
                StatusCode::INSUFFICIENT_STORAGE,
                "insufficient-storage",
                "Insufficient storage",
                "the server's storage is full; try again later",
            )
            .retry_after(STORAGE_RETRY_SECS);
        }
        if let StoreError::Busy(_) = e {
            tracing::warn!(error = %e, "job database busy");
            return Self::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "store-busy",
                "Store busy",
                "the job database is busy (held by another writer); try again shortly",
            )
            .retry_after(1);
        }
        Self::internal(e)
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

    /// 503 when `queue_len` jobs are waiting; with `Retry-After`.
    pub fn queue_full(queue_len: u64) -> Self {
        Self::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "queue-full",
            "Queue full",
            format!("{queue_len} jobs are waiting; try again later"),
        )
        .limit("queue_len", queue_len)
        .retry_after(5)
    }

    /// 400 for a malformed request (missing part, bad header, bad query).
    pub fn bad_request(kind: &str, field: &str, detail: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, kind, "Bad request", detail).field(field)
    }

    /// A problem from the one table.
    pub fn from_problem(problem: Problem) -> Self {
        if problem.status >= 500 {
            tracing::error!(detail = %problem.detail, kind = %problem.kind, "internal error");
        }
        Self {
            problem: Box::new(problem),
            retry_after: None,
            storage_failure: false,
        }
    }

    /// 422 for constraints that cannot be used; the field is `constraints.<path>`.
    pub fn constraints(e: &ConstraintsError) -> Self {
        Self::from_problem(problem_table::constraints_problem(e))
    }

    /// 422 (or 413 for size limits) for an input that does not load; `side` is the part name.
    pub fn ingest(side: &str, e: &IngestError) -> Self {
        Self::from_problem(problem_table::ingest_problem(side, e))
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
                format!(
                    "cursor {:?} was not issued by this server (pass the `next` of the previous page unchanged)",
                    clip(&c, ECHO_CHARS)
                ),
            ),
            StoreError::QueueFull { limit } => Self::queue_full(limit),
            other => Self::storage(&other),
        }
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
        if self.storage_failure {
            resp.extensions_mut().insert(StorageFailure);
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
    fn clip_keeps_short_values_and_cuts_long_ones() {
        assert_eq!(clip("abc", 5), "abc");
        assert_eq!(clip("abcdef", 3), "abc…");
        assert_eq!(clip("ééé", 2), "éé…");
    }

    #[test]
    fn constraint_errors_are_prefixed() {
        let e = ConstraintsError::new("output.texture_size", "too big");
        let p = ApiError::constraints(&e).problem;
        assert_eq!(p.field.as_deref(), Some("constraints.output.texture_size"));
    }
}
