//! The job record: what the store keeps for every job and what `GET /v1/jobs/{id}` shows.
//!
//! Status transitions: `enqueued → processing → succeeded | failed | canceled`, and
//! `enqueued → canceled`; `processing → enqueued` on recovery after a crash (counted in
//! `attempts`) and on a graceful shutdown (not counted). Terminal states never change.

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use uuid::Uuid;

/// Job status.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JobStatus {
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

impl JobStatus {
    /// Whether the status can never change again.
    pub fn is_terminal(self) -> bool {
        matches!(
            self,
            JobStatus::Succeeded | JobStatus::Failed | JobStatus::Canceled
        )
    }

    /// The lowercase name used in JSON, SQL and query strings.
    pub fn as_str(self) -> &'static str {
        match self {
            JobStatus::Enqueued => "enqueued",
            JobStatus::Processing => "processing",
            JobStatus::Succeeded => "succeeded",
            JobStatus::Failed => "failed",
            JobStatus::Canceled => "canceled",
        }
    }

    /// Parses the lowercase name.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "enqueued" => JobStatus::Enqueued,
            "processing" => JobStatus::Processing,
            "succeeded" => JobStatus::Succeeded,
            "failed" => JobStatus::Failed,
            "canceled" => JobStatus::Canceled,
            _ => return None,
        })
    }
}

/// Progress as clients see it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JobProgress {
    /// Current stage name (`load`, `surface`, `align`, `bake`, `pad`, `export`, `done`).
    pub stage: String,
    /// Overall fraction done, 0..=1.
    pub fraction: f64,
    /// Stages finished.
    pub stages_done: u32,
    /// Stages planned.
    pub stages_total: u32,
}

/// An RFC 9457 problem object (also used as a failed job's `error`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Problem {
    /// Stable problem type URI reference, e.g. `/problems/accessor-out-of-range`.
    #[serde(rename = "type")]
    pub kind: String,
    /// Short summary of the problem type.
    pub title: String,
    /// HTTP status.
    pub status: u16,
    /// Human-readable explanation of this occurrence.
    pub detail: String,
    /// The failing field or JSON path, where there is one (`constraints.output.texture_size`,
    /// `source`, `meshes[0].primitives[1].attributes.POSITION`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
    /// The limit that was exceeded, where one was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub limit: Option<serde_json::Value>,
}

/// One uploaded model: its main file and every file of it, as blob keys.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModelFiles {
    /// Name of the main .glb/.gltf inside `files`.
    pub main: String,
    /// (name inside the model's file set, blob key) pairs.
    pub files: Vec<(String, String)>,
}

/// What a job was submitted with (all stored as blobs before the job is accepted).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JobInputs {
    /// The source model, for methods that read one.
    #[serde(default)]
    pub source: Option<ModelFiles>,
    /// The target.
    pub target: ModelFiles,
    /// The smooth base of the source, for methods that read one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_base: Option<ModelFiles>,
    /// Blob key of the constraints JSON.
    pub constraints: String,
    /// Blob key of the optional pattern image.
    pub pattern: Option<String>,
}

/// A stored output of a finished job.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArtifactRef {
    /// File name (`result.glb`, `report.json`, `retex_basecolor_material0.png`).
    pub name: String,
    /// MIME type.
    pub media_type: String,
    /// Blob key.
    pub key: String,
    /// Size in bytes.
    pub size: u64,
    /// Hex SHA-256 of the content (the strong ETag).
    pub sha256: String,
}

/// Everything the store keeps about a job.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    /// Job id.
    pub id: Uuid,
    /// Status.
    pub status: JobStatus,
    /// Method id (`project`, ...).
    pub method: String,
    /// Last known progress.
    pub progress: JobProgress,
    /// When the job was accepted.
    pub created_at: DateTime<Utc>,
    /// When a worker last started it.
    pub started_at: Option<DateTime<Utc>>,
    /// When it reached a terminal state.
    pub finished_at: Option<DateTime<Utc>>,
    /// The problem, for failed jobs.
    pub error: Option<Problem>,
    /// The method report (coverage, timings per stage, warnings), for finished jobs.
    pub report: Option<serde_json::Value>,
    /// How many times a worker started it, less the starts a graceful shutdown interrupted
    /// (crash recoveries count).
    pub attempts: u32,
    /// The client's Idempotency-Key, if given (prefixed by the owner id and `/` when
    /// authentication is on: keys are kept per owner).
    pub idempotency_key: Option<String>,
    /// Owner id of the submitting token (see `http::auth`); `None` without authentication.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub owner: Option<String>,
    /// Hex SHA-256 over the request's parts (to tell a replay from a different body).
    pub request_hash: String,
    /// The inputs.
    pub inputs: JobInputs,
    /// The outputs (set when the job succeeds; the first is the result model).
    pub artifacts: Vec<ArtifactRef>,
    /// Monotonic revision, bumped on every change (ETag of the job document).
    pub revision: u64,
}
