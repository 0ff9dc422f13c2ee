//! Job routes: submit (`POST /v1/jobs`), read (`GET /v1/jobs/{id}` with ETag/304), list
//! (`GET /v1/jobs`), cancel (`POST /v1/jobs/{id}/cancel`) and delete (`DELETE /v1/jobs/{id}`).
//!
//! A submission is validated completely, its files are moved into the blob store under
//! `jobs/<id>/inputs/...` and its record is committed before `202 Accepted` is sent, so an
//! accepted job survives `kill -9` from the moment the client sees the answer.

use std::collections::HashSet;

use axum::extract::{
    FromRequest, FromRequestParts, Multipart, Query, RawPathParams, Request, State,
};
use axum::http::request::Parts;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use chrono::{DateTime, Utc};
use serde::Deserialize;
use utoipa::IntoParams;
use uuid::Uuid;

use super::caller::{caller_of, Caller};
use super::doc::{JobDocument, JobList, JobSummary};
use super::ingest::{read_upload, safe_key_name, UploadModel};
use super::linger::{content_length, SharedBody};
use super::problem::{clip, ApiError, ECHO_CHARS};
use super::{blocking, AppState};
use crate::service::model::{JobInputs, JobProgress, JobRecord, JobStatus, ModelFiles};
use crate::service::store::{BlobStore, CreateOutcome, ListFilter, StoreError};

/// Seconds a client is told to wait before polling a new job.
const RETRY_AFTER_SECS: u64 = 1;

fn job_response(
    status: StatusCode,
    record: &JobRecord,
    extra: &[(header::HeaderName, String)],
) -> Response {
    let doc = JobDocument::from_record(record);
    let mut resp = (status, Json(doc)).into_response();
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&etag(record)) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    for (name, value) in extra {
        if let Ok(v) = HeaderValue::from_str(value) {
            h.insert(name.clone(), v);
        }
    }
    resp
}

/// The ETag of a job document: its revision.
pub fn etag(record: &JobRecord) -> String {
    format!("\"r{}\"", record.revision)
}

/// Whether `If-None-Match` names `tag` (or `*`); weak comparison (RFC 9110 §13.1.2).
pub fn if_none_match(headers: &HeaderMap, tag: &str) -> bool {
    let want = tag.trim_start_matches("W/");
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(str::trim)
        .any(|t| t == "*" || t.trim_start_matches("W/") == want)
}

/// The `{id}` of a job route; a malformed one is a 400 problem (`invalid-job-id`, field `id`)
/// rather than axum's plain-text path rejection.
pub struct JobId(pub Uuid);

impl<S: Send + Sync> FromRequestParts<S> for JobId {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        let params = RawPathParams::from_request_parts(parts, state)
            .await
            .map_err(|e| ApiError::internal(e.body_text()))?;
        let raw = params
            .iter()
            .find(|(name, _)| *name == "id")
            .map(|(_, v)| v)
            .ok_or_else(|| ApiError::internal("a job route without an {id} parameter"))?;
        Uuid::parse_str(raw).map(JobId).map_err(|_| {
            ApiError::bad_request(
                "invalid-job-id",
                "id",
                format!("{:?} is not a job id (a UUID)", clip(raw, ECHO_CHARS)),
            )
        })
    }
}

async fn load_job(state: &AppState, id: Uuid) -> Result<JobRecord, ApiError> {
    let jobs = state.jobs.clone();
    blocking(move || jobs.get(id))
        .await?
        .ok_or_else(|| ApiError::job_not_found(id))
}

fn model_files(
    side: &str,
    id: Uuid,
    model: &UploadModel,
    blobs: &dyn BlobStore,
) -> Result<ModelFiles, StoreError> {
    let mut taken = HashSet::new();
    let mut files = Vec::with_capacity(model.files.len());
    for (i, f) in model.files.iter().enumerate() {
        let key = format!(
            "jobs/{id}/inputs/{side}/{}",
            safe_key_name(&f.name, i, &mut taken)
        );
        blobs.put_file(&key, &f.path)?;
        files.push((f.name.clone(), key));
    }
    Ok(ModelFiles {
        main: model.main.clone(),
        files,
    })
}

async fn queue_depth(state: &AppState) -> Result<u64, ApiError> {
    let jobs = state.jobs.clone();
    let counts = blocking(move || jobs.counts()).await?;
    Ok(counts
        .by_status
        .iter()
        .filter(|(s, _)| *s == JobStatus::Enqueued)
        .map(|(_, n)| *n)
        .sum())
}

/// Submit a job.
#[utoipa::path(post, path = "/v1/jobs", tag = "jobs",
    request_body(content = super::doc::SubmitForm, content_type = "multipart/form-data"),
    params(("Idempotency-Key" = Option<String>, Header, description = "Retry-safe submission key (kept at least 24 h)")),
    responses(
        (status = 202, description = "Accepted; `Location` names the job", body = JobDocument),
        (status = 200, description = "Replay of an Idempotency-Key: the job created first", body = JobDocument),
        (status = 400, description = "Malformed multipart body", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 413, description = "A size limit was exceeded (named in `limit`)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 422, description = "Invalid model or constraints, or Idempotency-Key reused", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 503, description = "Queue full or job database busy; see Retry-After", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 507, description = "The server's storage is full (`insufficient-storage`); see Retry-After", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn submit(State(state): State<AppState>, request: Request) -> Result<Response, ApiError> {
    let (parts, body) = request.into_parts();
    let limit = state.config.max_body_bytes;
    let (shared, limited) = SharedBody::new(body, limit);
    let headers = parts.headers.clone();
    let result = if content_length(&headers).is_some_and(|n| n > limit) {
        Err(ApiError::too_large("body", "max_body_bytes", limit))
    } else {
        let caller = caller_of(&parts.extensions, &state);
        let request = Request::from_parts(parts, limited);
        match Multipart::from_request(request, &state).await {
            Ok(multipart) => submit_multipart(&state, &headers, &caller, multipart).await,
            Err(rejection) => Err(ApiError::bad_request(
                "invalid-multipart",
                "body",
                rejection.body_text(),
            )),
        }
    };
    let result = result.map_err(|e| {
        if shared.over_limit() {
            ApiError::too_large("body", "max_body_bytes", limit)
        } else {
            e
        }
    });
    if result.is_err() && shared.worth_draining(&headers, limit) {
        // Read the rest so the client, still writing, gets the answer and not a reset.
        shared.drain().await;
    }
    result
}

/// Validates and stores a multipart submission.
async fn submit_multipart(
    state: &AppState,
    headers: &HeaderMap,
    caller: &Caller,
    multipart: Multipart,
) -> Result<Response, ApiError> {
    let key = match headers.get("idempotency-key") {
        None => None,
        Some(v) => match v.to_str() {
            Ok(s) if !s.is_empty() && s.len() <= 255 => Some(caller.idempotency_key(s.to_string())),
            _ => {
                return Err(ApiError::bad_request(
                    "invalid-idempotency-key",
                    "Idempotency-Key",
                    "must be 1..=255 visible ASCII characters",
                ))
            }
        },
    };
    // A cheap early refusal before the upload is read. The binding check is in the store's
    // create transaction; a known Idempotency-Key skips this one, so a retry after a lost 202
    // gets its job (200) even while the queue is full.
    let known_key = match &key {
        Some(k) => {
            let (jobs, k) = (state.jobs.clone(), k.clone());
            blocking(move || jobs.job_of_key(&k)).await?.is_some()
        }
        None => false,
    };
    if !known_key && queue_depth(state).await? >= state.config.queue_len {
        return Err(ApiError::queue_full(state.config.queue_len));
    }
    let upload = read_upload(
        multipart,
        &state.config,
        &state.registry,
        state.blobs.clone(),
    )
    .await?;
    let id = Uuid::now_v7();
    let record = JobRecord {
        id,
        status: JobStatus::Enqueued,
        method: upload.constraints.method.as_str().to_string(),
        progress: JobProgress::default(),
        created_at: Utc::now(),
        started_at: None,
        finished_at: None,
        error: None,
        report: None,
        attempts: 0,
        idempotency_key: key,
        owner: caller.owner.clone(),
        request_hash: upload.request_hash.clone(),
        inputs: JobInputs::default(),
        artifacts: Vec::new(),
        revision: 0,
    };
    let (jobs, blobs) = (state.jobs.clone(), state.blobs.clone());
    let queue_len = state.config.queue_len;
    let outcome = blocking(move || {
        let mut record = record;
        let stored = (|| {
            let optional = |side: &str, m: &Option<_>| {
                m.as_ref()
                    .map(|m| model_files(side, id, m, blobs.as_ref()))
                    .transpose()
            };
            let source = optional("source", &upload.source)?;
            let target = model_files("target", id, &upload.target, blobs.as_ref())?;
            let source_base = optional("source_base", &upload.source_base)?;
            let constraints = format!("jobs/{id}/inputs/constraints.json");
            blobs.put(&constraints, &upload.constraints_bytes)?;
            let pattern = match &upload.pattern {
                Some(p) => {
                    let key = format!(
                        "jobs/{id}/inputs/pattern/{}",
                        safe_key_name(&p.name, 0, &mut HashSet::new())
                    );
                    blobs.put_file(&key, &p.path)?;
                    Some(key)
                }
                None => None,
            };
            record.inputs = JobInputs {
                source,
                target,
                source_base,
                constraints,
                pattern,
            };
            jobs.create_bounded(&record, queue_len)
        })();
        if !matches!(stored, Ok(CreateOutcome::Created)) {
            // A replay, a mismatch or a failure: the new files belong to no job.
            let _ = blobs.delete_prefix(&format!("jobs/{id}/"));
        }
        stored.map(|o| (o, record))
    })
    .await?;
    match outcome {
        (CreateOutcome::Existing(existing), _) => {
            let location = format!("/v1/jobs/{}", existing.id);
            Ok(job_response(
                StatusCode::OK,
                &existing,
                &[(header::LOCATION, location)],
            ))
        }
        (CreateOutcome::Created, record) => {
            tracing::info!(job = %id, method = %record.method, "job accepted");
            let jobs = state.jobs.clone();
            // The stored revision, so the ETag matches what GET answers.
            let stored = blocking(move || jobs.get(id)).await;
            let stored = match stored {
                Ok(s) => s.unwrap_or(record),
                Err(e) => {
                    state.runner.notify();
                    return Err(e);
                }
            };
            // Announced before the runner is woken, so event streams see `enqueued` first.
            state.runner.announce(&stored);
            state.runner.notify();
            Ok(job_response(
                StatusCode::ACCEPTED,
                &stored,
                &[
                    (header::LOCATION, format!("/v1/jobs/{id}")),
                    (header::RETRY_AFTER, RETRY_AFTER_SECS.to_string()),
                ],
            ))
        }
    }
}

/// Read a job.
#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id"),
           ("If-None-Match" = Option<String>, Header, description = "ETag of a previous answer")),
    responses(
        (status = 200, description = "The job document; `ETag` is its revision", body = JobDocument),
        (status = 304, description = "Unchanged since the given ETag"),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn get_job(
    State(state): State<AppState>,
    JobId(id): JobId,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = load_job(&state, id).await?;
    let tag = etag(&record);
    if if_none_match(&headers, &tag) {
        let mut resp = StatusCode::NOT_MODIFIED.into_response();
        if let Ok(v) = HeaderValue::from_str(&tag) {
            resp.headers_mut().insert(header::ETAG, v);
        }
        return Ok(resp);
    }
    let retry = if record.status.is_terminal() {
        vec![]
    } else {
        vec![(header::RETRY_AFTER, RETRY_AFTER_SECS.to_string())]
    };
    Ok(job_response(StatusCode::OK, &record, &retry))
}

/// Query of `GET /v1/jobs`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    /// Only jobs with this status.
    status: Option<String>,
    /// Only jobs of this method.
    method: Option<String>,
    /// Only jobs created strictly before this instant (RFC 3339).
    created_before: Option<DateTime<Utc>>,
    /// Only jobs created strictly after this instant (RFC 3339).
    created_after: Option<DateTime<Utc>>,
    /// Page size, 1..=500 (default 50).
    limit: Option<usize>,
    /// Cursor from the previous page's `next`.
    next: Option<String>,
}

/// List jobs, newest first.
#[utoipa::path(get, path = "/v1/jobs", tag = "jobs", params(ListQuery),
    responses(
        (status = 200, description = "One page of jobs", body = JobList),
        (status = 400, description = "Bad filter or cursor", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn list_jobs(
    State(state): State<AppState>,
    Query(q): Query<ListQuery>,
) -> Result<Json<JobList>, ApiError> {
    let status = match q.status.as_deref() {
        None => None,
        Some(s) => Some(JobStatus::parse(s).ok_or_else(|| {
            ApiError::bad_request(
                "invalid-query",
                "status",
                format!("unknown status {s:?}: expected enqueued, processing, succeeded, failed or canceled"),
            )
        })?),
    };
    let limit = q.limit.unwrap_or(50);
    if !(1..=500).contains(&limit) {
        return Err(
            ApiError::bad_request("invalid-query", "limit", "must be within 1..=500")
                .limit("max_page_size", 500),
        );
    }
    let filter = ListFilter {
        status,
        method: q.method,
        created_after: q.created_after,
        created_before: q.created_before,
        limit,
        cursor: q.next,
    };
    let jobs = state.jobs.clone();
    let page = blocking(move || jobs.list(&filter)).await?;
    Ok(Json(JobList {
        jobs: page.jobs.iter().map(JobSummary::from_record).collect(),
        next: page.next,
    }))
}

/// Cancel a job.
#[utoipa::path(post, path = "/v1/jobs/{id}/cancel", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job was enqueued and is now canceled", body = JobDocument),
        (status = 202, description = "The job is processing and stops within a second", body = JobDocument),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 403, description = "A read token, or a submit token and another owner's job", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 409, description = "The job already finished", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn cancel_job(
    State(state): State<AppState>,
    JobId(id): JobId,
    caller: Caller,
) -> Result<Response, ApiError> {
    let owner = load_job(&state, id).await?.owner;
    if !caller.may_manage(owner.as_deref()) {
        return Err(caller.not_owner());
    }
    let jobs = state.jobs.clone();
    let record = blocking(move || jobs.cancel_if_enqueued(id, Utc::now())).await?;
    if record.status == JobStatus::Processing {
        state.runner.cancel(id);
        return Ok(job_response(StatusCode::ACCEPTED, &record, &[]));
    }
    state.runner.announce(&record);
    state.runner.notify();
    Ok(job_response(StatusCode::OK, &record, &[]))
}

/// Delete a finished job and its files.
#[utoipa::path(delete, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 204, description = "Deleted"),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 409, description = "The job has not finished", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn delete_job(
    State(state): State<AppState>,
    JobId(id): JobId,
) -> Result<StatusCode, ApiError> {
    let (jobs, blobs) = (state.jobs.clone(), state.blobs.clone());
    blocking(move || {
        jobs.delete(id)?;
        blobs.delete_prefix(&format!("jobs/{id}/"))
    })
    .await?;
    Ok(StatusCode::NO_CONTENT)
}
