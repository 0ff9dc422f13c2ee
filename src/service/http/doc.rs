//! The JSON documents of the API (job, job list, links) and the OpenAPI schemas of the shared
//! service types ([`Problem`], [`JobStatus`]) that live outside this module.
//!
//! A job document is a pure function of the stored [`JobRecord`], so its revision is a valid
//! ETag: the same revision always serializes to the same bytes.

use chrono::{DateTime, Utc};
use serde::Serialize;
use utoipa::ToSchema;
use uuid::Uuid;

use crate::service::model::{JobRecord, JobStatus, Problem};

/// Status of a job; `succeeded`, `failed` and `canceled` are terminal and never change.
#[derive(ToSchema)]
#[schema(as = JobStatus)]
#[allow(dead_code)]
#[serde(rename_all = "lowercase")]
pub enum JobStatusSchema {
    /// Waiting for a worker.
    Enqueued,
    /// Running on a worker.
    Processing,
    /// Finished; the result can be downloaded.
    Succeeded,
    /// Finished with an error (see `error`).
    Failed,
    /// Canceled by a client.
    Canceled,
}

/// RFC 9457 problem details.
#[derive(ToSchema)]
#[schema(as = Problem)]
#[allow(dead_code)]
pub struct ProblemSchema {
    /// Stable problem type, e.g. `/problems/too-many-triangles`.
    #[schema(rename = "type")]
    kind: String,
    /// Short summary of the problem type.
    title: String,
    /// HTTP status.
    status: u16,
    /// What happened this time.
    detail: String,
    /// The failing multipart part, JSON path or glTF path.
    field: Option<String>,
    /// The exceeded limit: `{"name": "max_part_bytes", "value": 1048576}`.
    limit: Option<serde_json::Value>,
}

/// Stage counts of a job's progress.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct StageCount {
    /// Stages finished.
    pub done: u32,
    /// Stages planned.
    pub total: u32,
}

/// Progress of a job.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct ProgressDoc {
    /// Current stage (`load`, `surface`, `align`, `bake`, `pad`, `export`, `done`), empty
    /// before the first.
    pub stage: String,
    /// Overall fraction done, 0..=1.
    pub fraction: f64,
    /// Stages done and planned.
    pub stages: StageCount,
}

/// A downloadable output of a job.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct ArtifactLink {
    /// File name.
    pub name: String,
    /// Download URL.
    pub href: String,
    /// MIME type.
    pub media_type: String,
    /// Size in bytes.
    pub size: u64,
    /// Hex SHA-256 (also the strong ETag of the download).
    pub sha256: String,
}

/// Links of a job document.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct JobLinks {
    /// This document.
    #[serde(rename = "self")]
    #[schema(rename = "self")]
    pub self_: String,
    /// The output model (409 until the job succeeded).
    pub result: String,
    /// Server-sent progress events.
    pub events: String,
    /// Outputs of the finished job.
    pub artifacts: Vec<ArtifactLink>,
}

/// The job document of `GET /v1/jobs/{id}`: the job's summary plus its method report.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct JobDocument {
    /// Everything a job list shows of the job.
    #[serde(flatten)]
    pub summary: JobSummary,
    /// Method figures: coverage, timings per stage, warnings.
    pub report: Option<serde_json::Value>,
}

impl JobDocument {
    /// The document of a stored job.
    pub fn from_record(r: &JobRecord) -> Self {
        Self {
            summary: JobSummary::from_record(r),
            report: r.report.clone(),
        }
    }
}

fn progress_doc(r: &JobRecord) -> ProgressDoc {
    ProgressDoc {
        stage: r.progress.stage.clone(),
        fraction: r.progress.fraction.clamp(0.0, 1.0),
        stages: StageCount {
            done: r.progress.stages_done,
            total: r.progress.stages_total,
        },
    }
}

fn links(r: &JobRecord) -> JobLinks {
    let base = format!("/v1/jobs/{}", r.id);
    let artifacts = r
        .artifacts
        .iter()
        .map(|a| ArtifactLink {
            name: a.name.clone(),
            href: format!("{base}/artifacts/{}", a.name),
            media_type: a.media_type.clone(),
            size: a.size,
            sha256: a.sha256.clone(),
        })
        .collect();
    JobLinks {
        result: format!("{base}/result"),
        events: format!("{base}/events"),
        self_: base,
        artifacts,
    }
}

/// A job in a list: the job document without its `report` (which can run to kilobytes per
/// job); `GET /v1/jobs/{id}` has the full document.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct JobSummary {
    /// Job id.
    pub id: Uuid,
    /// Status.
    #[schema(value_type = JobStatusSchema)]
    pub status: JobStatus,
    /// Method id (`project`, ...).
    pub method: String,
    /// Progress.
    pub progress: ProgressDoc,
    /// When the job was accepted.
    pub created_at: DateTime<Utc>,
    /// When a worker last started it.
    pub started_at: Option<DateTime<Utc>>,
    /// When it reached a terminal state.
    pub finished_at: Option<DateTime<Utc>>,
    /// Why it failed.
    #[schema(value_type = Option<ProblemSchema>)]
    pub error: Option<Problem>,
    /// Times a worker started it.
    pub attempts: u32,
    /// Revision (the ETag of the job document).
    pub revision: u64,
    /// Related resources.
    pub links: JobLinks,
}

impl JobSummary {
    /// The summary of a stored job.
    pub fn from_record(r: &JobRecord) -> Self {
        Self {
            id: r.id,
            status: r.status,
            method: r.method.clone(),
            progress: progress_doc(r),
            created_at: r.created_at,
            started_at: r.started_at,
            finished_at: r.finished_at,
            error: r.error.clone(),
            attempts: r.attempts,
            revision: r.revision,
            links: links(r),
        }
    }
}

/// A page of `GET /v1/jobs`.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct JobList {
    /// Jobs, newest first, summarised (no `report`).
    pub jobs: Vec<JobSummary>,
    /// Opaque cursor of the next page; pass it as `next`.
    pub next: Option<String>,
}

/// A server-sent event's data: the job's status and progress at one revision.
#[derive(Clone, Debug, Serialize, ToSchema)]
pub struct JobEventDoc {
    /// Job id.
    pub id: Uuid,
    /// Status.
    #[schema(value_type = JobStatusSchema)]
    pub status: JobStatus,
    /// Progress.
    pub progress: ProgressDoc,
    /// Revision (also the event id).
    pub revision: u64,
}

/// The multipart form of `POST /v1/jobs`.
#[derive(ToSchema)]
#[allow(dead_code)]
pub struct SubmitForm {
    /// The textured source: one GLB, or a .gltf plus its files as further `source` parts
    /// (each named by its filename), or one zip of them. Required by the methods that read a
    /// source (`project`, `meshmatch`): a missing required part is a 400 naming it; a part the
    /// method does not read is ignored with a warning in the report.
    #[schema(value_type = Option<Vec<String>>, format = Binary)]
    source: Option<Vec<Vec<u8>>>,
    /// The target, in the same forms.
    #[schema(value_type = Vec<String>, format = Binary)]
    target: Vec<Vec<u8>>,
    /// A smooth base of the source, in the same forms, for methods that read one.
    #[schema(value_type = Option<Vec<String>>, format = Binary)]
    source_base: Option<Vec<Vec<u8>>>,
    /// Constraints JSON v1 (`api/constraints.schema.json`). Optional: without it the job runs
    /// with `{"version":1}` (method `project`, every default).
    #[schema(value_type = Option<String>, format = Binary)]
    constraints: Option<Vec<u8>>,
    /// A pattern image (PNG or JPEG), for methods that read one.
    #[schema(value_type = Option<String>, format = Binary)]
    pattern: Option<Vec<u8>>,
}
