//! Downloads: `GET /v1/jobs/{id}/result` (the output model),
//! `GET /v1/jobs/{id}/artifacts/{name}` (baked PNGs, `report.json`, previews) and
//! `GET /v1/jobs/{id}/files/{name}`, the same files under the name issue 16 gives the previews
//! (`files/preview.png`, `files/source_preview.png`, `files/target_preview.png`).
//!
//! Each answer carries a strong ETag (the content's SHA-256, RFC 9110 §8.8.3), honours
//! `If-None-Match` (304) and single byte ranges (RFC 9110 §14: `bytes=a-b`, `bytes=a-`,
//! `bytes=-n`; `If-Range` with the ETag), and names the file in `Content-Disposition`.
//! Multi-range requests are answered with the whole file, which RFC 9110 allows.

use axum::extract::{Path, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use uuid::Uuid;

use super::jobs::{if_none_match, JobId};
use super::problem::ApiError;
use super::{blocking, AppState};
use crate::service::model::{ArtifactRef, JobStatus};

/// A range that does not overlap the file (416).
#[derive(Debug, PartialEq, Eq)]
pub struct Unsatisfiable;

/// Parses a single `bytes=` range against a file of `len` bytes. `Ok(None)`: serve the whole
/// file.
pub fn parse_range(value: &str, len: u64) -> Result<Option<(u64, u64)>, Unsatisfiable> {
    let Some(spec) = value.trim().strip_prefix("bytes=") else {
        return Ok(None);
    };
    if spec.contains(',') {
        return Ok(None);
    }
    let (a, b) = spec.split_once('-').ok_or(Unsatisfiable)?;
    let (a, b) = (a.trim(), b.trim());
    let range = if a.is_empty() {
        let n: u64 = b.parse().map_err(|_| Unsatisfiable)?;
        if n == 0 || len == 0 {
            return Err(Unsatisfiable);
        }
        (len.saturating_sub(n), len - 1)
    } else {
        let start: u64 = a.parse().map_err(|_| Unsatisfiable)?;
        let end: u64 = if b.is_empty() {
            len.saturating_sub(1)
        } else {
            b.parse::<u64>()
                .map_err(|_| Unsatisfiable)?
                .min(len.saturating_sub(1))
        };
        if start >= len || end < start {
            return Err(Unsatisfiable);
        }
        (start, end)
    };
    Ok(Some(range))
}

fn content_disposition(name: &str) -> String {
    let ascii: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_graphic() && c != '"' && c != '\\' {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("attachment; filename=\"{ascii}\"")
}

async fn serve_artifact(
    state: &AppState,
    artifact: ArtifactRef,
    download_name: String,
    headers: &HeaderMap,
) -> Result<Response, ApiError> {
    let tag = format!("\"{}\"", artifact.sha256);
    let mut base = HeaderMap::new();
    let mut set = |name: header::HeaderName, value: &str| {
        if let Ok(v) = HeaderValue::from_str(value) {
            base.insert(name, v);
        }
    };
    set(header::ETAG, &tag);
    set(header::CONTENT_TYPE, &artifact.media_type);
    set(
        header::CONTENT_DISPOSITION,
        &content_disposition(&download_name),
    );
    set(header::ACCEPT_RANGES, "bytes");
    set(
        header::CACHE_CONTROL,
        "private, max-age=31536000, immutable",
    );
    if if_none_match(headers, &tag) {
        let mut resp = StatusCode::NOT_MODIFIED.into_response();
        resp.headers_mut().extend(base);
        return Ok(resp);
    }
    let len = artifact.size;
    let if_range_ok = match headers.get(header::IF_RANGE).and_then(|v| v.to_str().ok()) {
        None => true,
        Some(v) => v.trim() == tag,
    };
    let range = match headers.get(header::RANGE).and_then(|v| v.to_str().ok()) {
        Some(r) if if_range_ok => match parse_range(r, len) {
            Ok(r) => r,
            Err(Unsatisfiable) => {
                let mut resp = ApiError::new(
                    StatusCode::RANGE_NOT_SATISFIABLE,
                    "range-not-satisfiable",
                    "Range not satisfiable",
                    format!("{r:?} does not overlap the {len} bytes of {download_name}"),
                )
                .field("Range")
                .into_response();
                if let Ok(v) = HeaderValue::from_str(&format!("bytes */{len}")) {
                    resp.headers_mut().insert(header::CONTENT_RANGE, v);
                }
                return Ok(resp);
            }
        },
        _ => None,
    };
    let blobs = state.blobs.clone();
    let key = artifact.key.clone();
    match range {
        Some((start, end)) => {
            let bytes = blocking(move || blobs.read_range(&key, start, end - start + 1)).await?;
            let mut resp = (StatusCode::PARTIAL_CONTENT, bytes).into_response();
            resp.headers_mut().extend(base);
            if let Ok(v) = HeaderValue::from_str(&format!("bytes {start}-{end}/{len}")) {
                resp.headers_mut().insert(header::CONTENT_RANGE, v);
            }
            Ok(resp)
        }
        None => {
            let bytes = blocking(move || blobs.get(&key)).await?;
            let mut resp = (StatusCode::OK, bytes).into_response();
            resp.headers_mut().extend(base);
            Ok(resp)
        }
    }
}

async fn finished_job(
    state: &AppState,
    id: Uuid,
) -> Result<crate::service::model::JobRecord, ApiError> {
    let jobs = state.jobs.clone();
    let record = blocking(move || jobs.get(id))
        .await?
        .ok_or_else(|| ApiError::job_not_found(id))?;
    if record.status != JobStatus::Succeeded {
        let detail = match record.status {
            JobStatus::Enqueued | JobStatus::Processing => {
                format!(
                    "job {id} is {}; the result exists once it succeeded",
                    record.status.as_str()
                )
            }
            s => format!("job {id} is {} and has no result", s.as_str()),
        };
        let mut err = ApiError::new(
            StatusCode::CONFLICT,
            "job-not-succeeded",
            "Job has not succeeded",
            detail,
        )
        .field("status");
        if !record.status.is_terminal() {
            err = err.retry_after(1);
        }
        return Err(err);
    }
    Ok(record)
}

/// Download the result model.
#[utoipa::path(get, path = "/v1/jobs/{id}/result", tag = "results",
    params(("id" = Uuid, Path, description = "Job id"),
           ("Range" = Option<String>, Header, description = "One byte range, e.g. `bytes=0-1023`")),
    responses(
        (status = 200, description = "The output model; strong ETag (SHA-256)", content_type = "model/gltf-binary", body = Vec<u8>),
        (status = 206, description = "The requested byte range", content_type = "model/gltf-binary", body = Vec<u8>),
        (status = 304, description = "Unchanged"),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 416, description = "Range not satisfiable", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn result(
    State(state): State<AppState>,
    JobId(id): JobId,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = finished_job(&state, id).await?;
    let artifact = record
        .artifacts
        .first()
        .cloned()
        .ok_or_else(|| ApiError::internal(format!("job {id} succeeded without a result")))?;
    let ext = if artifact.media_type == "model/gltf+json" {
        "gltf"
    } else {
        "glb"
    };
    serve_artifact(&state, artifact, format!("retex-{id}.{ext}"), &headers).await
}

/// Download one artifact of a finished job.
#[utoipa::path(get, path = "/v1/jobs/{id}/artifacts/{name}", tag = "results",
    params(("id" = Uuid, Path, description = "Job id"), ("name" = String, Path, description = "Artifact name")),
    responses(
        (status = 200, description = "The artifact; strong ETag (SHA-256)", body = Vec<u8>),
        (status = 206, description = "The requested byte range", body = Vec<u8>),
        (status = 304, description = "Unchanged"),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job or artifact", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn artifact(
    State(state): State<AppState>,
    JobId(id): JobId,
    Path((_, name)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    named(&state, id, name, &headers).await
}

/// Download one file of a finished job: its previews (`preview.png` of the result,
/// `source_preview.png`, `target_preview.png`) or any other artifact.
#[utoipa::path(get, path = "/v1/jobs/{id}/files/{name}", tag = "results",
    params(("id" = Uuid, Path, description = "Job id"),
           ("name" = String, Path, description = "File name, e.g. `preview.png`"),
           ("If-None-Match" = Option<String>, Header, description = "An ETag from an earlier answer (304 when it still matches)")),
    responses(
        (status = 200, description = "The file (previews are `image/png` turntable strips); strong ETag (SHA-256)", body = Vec<u8>),
        (status = 206, description = "The requested byte range", body = Vec<u8>),
        (status = 304, description = "Unchanged"),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job or file (a preview that did not render is absent; the report says why)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 409, description = "The job has not succeeded", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn file(
    State(state): State<AppState>,
    JobId(id): JobId,
    Path((_, name)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    named(&state, id, name, &headers).await
}

/// Serves the artifact `name` of the succeeded job `id`.
async fn named(
    state: &AppState,
    id: Uuid,
    name: String,
    headers: &HeaderMap,
) -> Result<Response, ApiError> {
    let record = finished_job(state, id).await?;
    let artifact = record
        .artifacts
        .iter()
        .find(|a| a.name == name)
        .cloned()
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::NOT_FOUND,
                "artifact-not-found",
                "Artifact not found",
                format!(
                    "job {id} has no artifact {:?}",
                    super::problem::clip(&name, super::problem::ECHO_CHARS)
                ),
            )
            .field("name")
        })?;
    serve_artifact(state, artifact, name, headers).await
}

#[cfg(test)]
mod tests {
    use super::{parse_range, Unsatisfiable};

    #[test]
    fn ranges() {
        assert_eq!(parse_range("bytes=0-9", 100), Ok(Some((0, 9))));
        assert_eq!(parse_range("bytes=90-", 100), Ok(Some((90, 99))));
        assert_eq!(parse_range("bytes=-10", 100), Ok(Some((90, 99))));
        assert_eq!(parse_range("bytes=50-500", 100), Ok(Some((50, 99))));
        assert_eq!(parse_range("bytes=100-", 100), Err(Unsatisfiable));
        assert_eq!(parse_range("bytes=5-1", 100), Err(Unsatisfiable));
        assert_eq!(parse_range("bytes=0-1,5-6", 100), Ok(None));
        assert_eq!(parse_range("items=0-1", 100), Ok(None));
    }
}
