//! The OpenAPI 3.1 description of the API, generated from the handlers' annotations and the
//! document types with `utoipa`, served at `GET /v1/openapi.json` and committed as
//! `api/openapi.yaml` (a test fails when the two differ).

use axum::Json;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};

use super::{dashboard, doc, events, files, job_stream, jobs, metrics, ops};

struct BearerAuth;

impl Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

/// The API description.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "retex",
        description = "Texture transfer jobs between glTF meshes. Errors are RFC 9457 `application/problem+json`. When the server is configured with tokens, every route but /healthz and /readyz needs `Authorization: Bearer <token>` (401 without a valid one). A token's scope is `read` (GET), `submit` (also POST: submit, cancel) or `admin` (also DELETE); a request beyond its token's scope is 403 `insufficient-scope`.",
        license(name = "MIT OR Apache-2.0", identifier = "MIT OR Apache-2.0"),
    ),
    paths(
        jobs::submit, jobs::list_jobs, jobs::get_job, jobs::cancel_job, jobs::delete_job,
        files::result, files::artifact, files::file, events::events, job_stream::job_stream, dashboard::api::methods, dashboard::api::constraints,
        ops::healthz, ops::readyz, metrics::metrics, openapi_json,
    ),
    components(schemas(
        doc::JobDocument, doc::JobSummary, doc::JobList, doc::JobLinks, doc::ArtifactLink, doc::ProgressDoc,
        doc::StageCount, doc::JobEventDoc, doc::ProblemSchema, doc::JobStatusSchema, doc::SubmitForm,
        dashboard::MethodList, dashboard::MethodDoc, dashboard::InputsDoc, dashboard::InputUseDoc,
    )),
    modifiers(&BearerAuth),
    security((), ("bearer" = [])),
    tags(
        (name = "jobs", description = "Submit, follow, cancel and delete jobs"),
        (name = "results", description = "Download outputs"),
        (name = "operations", description = "Health, readiness, metrics, this document"),
    )
)]
pub struct ApiDoc;

/// The spec with the crate's version.
pub fn spec() -> utoipa::openapi::OpenApi {
    let mut api = ApiDoc::openapi();
    api.info.version = env!("CARGO_PKG_VERSION").to_string();
    api
}

/// The spec as YAML (the committed `api/openapi.yaml`).
pub fn spec_yaml() -> String {
    spec().to_yaml().unwrap_or_default()
}

/// This OpenAPI document.
#[utoipa::path(get, path = "/v1/openapi.json", tag = "operations",
    responses((status = 200, description = "OpenAPI 3.1 document", body = Object)))]
pub async fn openapi_json() -> Json<utoipa::openapi::OpenApi> {
    Json(spec())
}
