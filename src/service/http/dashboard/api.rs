//! The two API routes the dashboard needs beside the job routes: `GET /v1/methods` (the parts
//! each method reads and its params JSON Schema, from which the submit form is built) and
//! `GET /v1/jobs/{id}/constraints` (the constraints JSON a job was submitted with, shown on the
//! job page for resubmitting from a script). Both are ordinary API routes: with tokens
//! configured they need one (read scope).

use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;
use utoipa::ToSchema;

use super::super::jobs::JobId;
use super::super::problem::ApiError;
use super::super::{blocking, AppState};
use crate::engine::methods::{constraints_schema_for, InputSpec, InputUse};

/// How a method uses an input part.
#[derive(Clone, Copy, Debug, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum InputUseDoc {
    /// The job is refused without it.
    Required,
    /// Read when given.
    Optional,
    /// Ignored (with a warning) when given.
    Unused,
}

impl From<InputUse> for InputUseDoc {
    fn from(u: InputUse) -> Self {
        match u {
            InputUse::Required => Self::Required,
            InputUse::Optional => Self::Optional,
            InputUse::Unused => Self::Unused,
        }
    }
}

/// The multipart parts a method reads.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct InputsDoc {
    /// `source`.
    pub source: InputUseDoc,
    /// `target` (always required).
    pub target: InputUseDoc,
    /// `source_base`.
    pub source_base: InputUseDoc,
    /// `pattern`.
    pub pattern: InputUseDoc,
}

impl From<InputSpec> for InputsDoc {
    fn from(s: InputSpec) -> Self {
        Self {
            source: s.source.into(),
            target: InputUseDoc::Required,
            source_base: s.source_base.into(),
            pattern: s.pattern.into(),
        }
    }
}

/// One method a job may run.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct MethodDoc {
    /// Its id (`constraints.method`).
    pub id: String,
    /// The parts it reads.
    pub inputs: InputsDoc,
    /// JSON Schema (2020-12) of its `constraints.params`.
    #[schema(value_type = Object)]
    pub params_schema: serde_json::Value,
}

/// `GET /v1/methods`.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct MethodList {
    /// Every method of this server, the default first.
    pub methods: Vec<MethodDoc>,
    /// The whole constraints JSON Schema (`api/constraints.schema.json` for this server's
    /// methods).
    #[schema(value_type = Object)]
    pub constraints_schema: serde_json::Value,
}

/// The methods jobs may run, with their inputs and params schemas.
#[utoipa::path(get, path = "/v1/methods", tag = "jobs",
    responses((status = 200, description = "The methods of this server", body = MethodList)))]
pub async fn methods(State(state): State<AppState>) -> Json<MethodList> {
    let methods = state
        .registry
        .methods()
        .map(|m| MethodDoc {
            id: m.id().as_str().to_string(),
            inputs: m.inputs().into(),
            params_schema: m.params_schema(),
        })
        .collect();
    Json(MethodList {
        methods,
        constraints_schema: constraints_schema_for(&state.registry),
    })
}

/// The constraints JSON a job was submitted with, byte for byte.
#[utoipa::path(get, path = "/v1/jobs/{id}/constraints", tag = "jobs",
    params(("id" = uuid::Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The constraints JSON as submitted (`{\"version\":1}` when none was)", content_type = "application/json", body = Object),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = super::super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn constraints(
    State(state): State<AppState>,
    JobId(id): JobId,
) -> Result<Response, ApiError> {
    let jobs = state.jobs.clone();
    let record = blocking(move || jobs.get(id))
        .await?
        .ok_or_else(|| ApiError::job_not_found(id))?;
    let blobs = state.blobs.clone();
    let key = record.inputs.constraints.clone();
    let bytes = blocking(move || blobs.get(&key)).await?;
    let mut resp = bytes.into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    resp.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    Ok(resp)
}
