//! Durable storage behind two traits: [`JobStore`] (job records, idempotency keys) and
//! [`BlobStore`] (uploaded files and results). The embedded implementations are SQLite in WAL
//! mode with `synchronous=FULL` ([`sqlite::SqliteJobStore`]) and a data directory with atomic
//! writes ([`fs::FsBlobStore`]); [`postgres::PgJobStore`] and [`object::ObjectBlobStore`] (S3,
//! GCS, Azure or a local folder) are the networked stores that several `retex serve` replicas
//! share (issue 17), behind the same traits.
//!
//! Leases (multi-replica stores only): a store whose jobs several processes claim says so
//! through [`JobStore::lease_duration`]; the runner then renews the lease of each running job
//! with [`JobStore::heartbeat`] (which also carries a cancel requested through any replica) and
//! calls [`JobStore::reclaim_expired`] periodically, so the jobs of a replica that died go back
//! to the queue. The defaults (no lease, nothing to reclaim) keep the single-process semantics
//! of SQLite.
//!
//! Both traits are synchronous (SQLite and the file system are); async callers use
//! `tokio::task::spawn_blocking`. Blob keys are relative paths of `[A-Za-z0-9._-]` segments
//! separated by `/` (e.g. `jobs/<id>/inputs/source/Fox.bin`), validated by the blob store.

use std::io::Write;
use std::path::PathBuf;

use chrono::{DateTime, Utc};
use uuid::Uuid;

use super::model::{ArtifactRef, JobProgress, JobRecord, JobStatus, Problem};

pub mod fs;
pub mod object;
pub mod postgres;
pub mod spool;
pub mod sqlite;

/// Storage failures.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// No job with this id.
    #[error("job {0} not found")]
    NotFound(Uuid),
    /// The job is not in a state that allows the operation.
    #[error("job {id} is {status:?}: {what}")]
    Conflict {
        /// The job.
        id: Uuid,
        /// Its current status.
        status: JobStatus,
        /// What was refused.
        what: &'static str,
    },
    /// The Idempotency-Key was used before with a different request.
    #[error("idempotency key {key:?} was used with a different request (job {existing})")]
    IdempotencyMismatch {
        /// The key.
        key: String,
        /// The job created with it.
        existing: Uuid,
    },
    /// A blob key that is not a safe relative path.
    #[error("invalid blob key {0:?}")]
    InvalidKey(String),
    /// No blob under this key.
    #[error("blob {0:?} not found")]
    BlobNotFound(String),
    /// [`BlobStore::put_new`]: a blob is already stored under this key (it is left as it was).
    #[error("blob {0:?} already exists")]
    BlobExists(String),
    /// An object store (S3, GCS, Azure) failed or could not be reached.
    #[error("object store: {0}")]
    ObjectStore(String),
    /// File system failure.
    #[error("io: {0}")]
    Io(#[from] std::io::Error),
    /// Database failure.
    #[error("database: {0}")]
    Database(String),
    /// The database is locked by another connection or process (SQLite busy/locked after the
    /// busy timeout): transient.
    #[error("database busy: {0}")]
    Busy(String),
    /// The database could not grow: its disk is full (SQLite `SQLITE_FULL`).
    #[error("database disk full: {0}")]
    DatabaseFull(String),
    /// A list cursor that this store did not issue.
    #[error("invalid cursor {0:?}")]
    InvalidCursor(String),
    /// [`JobStore::create_bounded`]: `limit` jobs are already enqueued.
    #[error("queue full: {limit} jobs are enqueued")]
    QueueFull {
        /// The queue length limit.
        limit: u64,
    },
}

/// Result of [`JobStore::create`].
#[derive(Clone, Debug, PartialEq)]
pub enum CreateOutcome {
    /// The job was inserted.
    Created,
    /// A job with the same Idempotency-Key and the same request hash exists: this one.
    Existing(Box<JobRecord>),
}

/// How a job ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Finish {
    /// With results (the first artifact is the result model).
    Succeeded {
        /// Stored outputs.
        artifacts: Vec<ArtifactRef>,
        /// The method report.
        report: serde_json::Value,
    },
    /// With an error.
    Failed {
        /// What went wrong.
        error: Problem,
        /// A partial report, if any.
        report: Option<serde_json::Value>,
    },
    /// Canceled by a client while processing.
    Canceled,
}

impl Finish {
    /// Writes this ending into `job` (status, results or error, `finished_at`, revision): the
    /// one transition every store applies inside its own transaction.
    pub fn apply(self, job: &mut JobRecord, now: DateTime<Utc>) {
        match self {
            Finish::Succeeded { artifacts, report } => {
                job.status = JobStatus::Succeeded;
                job.artifacts = artifacts;
                job.report = Some(report);
                job.error = None;
                job.progress.stage = "done".into();
                job.progress.fraction = 1.0;
                job.progress.stages_done = job.progress.stages_total;
            }
            Finish::Failed { error, report } => {
                job.status = JobStatus::Failed;
                job.error = Some(error);
                job.report = report;
            }
            Finish::Canceled => job.status = JobStatus::Canceled,
        }
        job.finished_at = Some(now);
        job.revision += 1;
    }
}

impl StoreError {
    /// The disk or the quota is full (`ENOSPC`, `EDQUOT`, `SQLITE_FULL`): a condition of the
    /// server, not of the request, that may clear when space is freed.
    pub fn is_storage_full(&self) -> bool {
        match self {
            StoreError::Io(e) => is_full(e),
            StoreError::DatabaseFull(_) => true,
            _ => false,
        }
    }

    /// A failure of the storage itself (file system or database) rather than an answer about
    /// the request (not found, conflict, bad key or cursor, full queue).
    pub fn is_storage_failure(&self) -> bool {
        matches!(
            self,
            StoreError::Io(_)
                | StoreError::ObjectStore(_)
                | StoreError::Database(_)
                | StoreError::Busy(_)
                | StoreError::DatabaseFull(_)
        )
    }
}

/// Whether an I/O error means the disk or the quota is full.
pub fn is_full(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::StorageFull | std::io::ErrorKind::QuotaExceeded
    )
}

/// Filter and page of [`JobStore::list`]; newest first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ListFilter {
    /// Only this status.
    pub status: Option<JobStatus>,
    /// Only this method.
    pub method: Option<String>,
    /// Only jobs created strictly after this instant.
    pub created_after: Option<DateTime<Utc>>,
    /// Only jobs created strictly before this instant.
    pub created_before: Option<DateTime<Utc>>,
    /// Page size (1..=500).
    pub limit: usize,
    /// Opaque cursor from a previous page's `next`.
    pub cursor: Option<String>,
}

/// One page of jobs.
#[derive(Clone, Debug, PartialEq)]
pub struct ListPage {
    /// Jobs, newest first.
    pub jobs: Vec<JobRecord>,
    /// Cursor of the next page, if there is one.
    pub next: Option<String>,
}

/// What [`JobStore::recover`] did at start-up.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recovery {
    /// Jobs that were processing and were put back in the queue.
    pub requeued: Vec<Uuid>,
    /// Jobs that were processing too many times and were failed.
    pub failed: Vec<Uuid>,
}

impl Recovery {
    /// Settles one job whose claim ended without a finish (found processing at start-up, or its
    /// lease expired): back to the queue with its progress cleared, or failed with
    /// `/problems/too-many-attempts` once it was started `max_attempts` times; the revision is
    /// bumped and the job's id noted in `requeued` or `failed`. The one transition every store
    /// applies inside its own transaction.
    pub fn settle(&mut self, job: &mut JobRecord, max_attempts: u32, now: DateTime<Utc>) {
        if job.attempts >= max_attempts {
            job.status = JobStatus::Failed;
            job.finished_at = Some(now);
            job.error = Some(too_many_attempts(job.attempts, max_attempts));
            self.failed.push(job.id);
        } else {
            job.status = JobStatus::Enqueued;
            job.progress = JobProgress::default();
            self.requeued.push(job.id);
        }
        job.revision += 1;
    }
}

/// The error of a job that recovery fails after `attempts` interrupted starts.
fn too_many_attempts(attempts: u32, max_attempts: u32) -> Problem {
    Problem {
        kind: "/problems/too-many-attempts".into(),
        title: "the job was interrupted too many times".into(),
        status: 500,
        detail: format!(
            "the job was started {attempts} times and interrupted each time (server stopped or crashed); the limit is {max_attempts}"
        ),
        field: None,
        limit: Some(max_attempts.into()),
    }
}

/// Counts for metrics.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StatusCounts {
    /// Jobs per status.
    pub by_status: Vec<(JobStatus, u64)>,
    /// Creation time of the oldest enqueued job.
    pub oldest_enqueued: Option<DateTime<Utc>>,
}

/// What [`JobStore::heartbeat`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lease {
    /// The lease is ours and was renewed; `cancel_requested` when a client asked (through any
    /// replica) to cancel the job.
    Held {
        /// A cancel request is recorded on the job.
        cancel_requested: bool,
    },
    /// The job is no longer ours: finished, deleted, or reclaimed by another replica after the
    /// lease expired. The runner stops it and records nothing.
    Lost,
}

/// Durable job records.
pub trait JobStore: Send + Sync + 'static {
    /// Inserts an enqueued job. With an idempotency key that was seen within the key retention:
    /// the same request hash returns [`CreateOutcome::Existing`], another one
    /// [`StoreError::IdempotencyMismatch`]. The queue is unbounded (see
    /// [`JobStore::create_bounded`]).
    fn create(&self, job: &JobRecord) -> Result<CreateOutcome, StoreError> {
        self.create_bounded(job, u64::MAX)
    }
    /// As [`JobStore::create`], but refuses with [`StoreError::QueueFull`] when `queue_len`
    /// jobs are already enqueued, checked in the same transaction as the insert (so concurrent
    /// submissions cannot overshoot). An existing Idempotency-Key wins over a full queue: its
    /// replay is [`CreateOutcome::Existing`] (or a mismatch) whatever the queue holds.
    fn create_bounded(&self, job: &JobRecord, queue_len: u64) -> Result<CreateOutcome, StoreError>;
    /// The job an Idempotency-Key was used for, if the key is still remembered.
    fn job_of_key(&self, key: &str) -> Result<Option<Uuid>, StoreError>;
    /// The job, if it exists.
    fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError>;
    /// Jobs matching the filter, newest first, one page.
    fn list(&self, filter: &ListFilter) -> Result<ListPage, StoreError>;
    /// Atomically takes the oldest enqueued job: status processing, `started_at = now`,
    /// `attempts + 1`. `None` when the queue is empty.
    fn claim_next(&self, now: DateTime<Utc>) -> Result<Option<JobRecord>, StoreError>;
    /// Records progress of a processing job (ignored once the job is terminal).
    fn update_progress(&self, id: Uuid, progress: &JobProgress) -> Result<(), StoreError>;
    /// Moves an enqueued or processing job to its terminal state in one transaction.
    fn finish(
        &self,
        id: Uuid,
        outcome: Finish,
        now: DateTime<Utc>,
    ) -> Result<JobRecord, StoreError>;
    /// Cancels an enqueued job at once and returns it; a processing job is returned unchanged
    /// (the runner stops it cooperatively); a terminal job is a [`StoreError::Conflict`].
    fn cancel_if_enqueued(&self, id: Uuid, now: DateTime<Utc>) -> Result<JobRecord, StoreError>;
    /// Start-up recovery: processing jobs go back to enqueued, or fail once `attempts` reached
    /// `max_attempts`.
    fn recover(&self, max_attempts: u32, now: DateTime<Utc>) -> Result<Recovery, StoreError>;
    /// Graceful stop: puts these jobs back to enqueued if they are still processing, and gives
    /// back the attempt their claim counted, so only starts interrupted by a crash count
    /// against `max_attempts`. Returns the re-enqueued records.
    fn requeue_stopped(
        &self,
        ids: &[Uuid],
        now: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError>;
    /// Removes a terminal job's record (a non-terminal one is a [`StoreError::Conflict`]).
    fn delete(&self, id: Uuid) -> Result<JobRecord, StoreError>;
    /// Removes terminal jobs finished before `finished_before` and idempotency keys older than
    /// `keys_before`; returns the removed records so their blobs can be deleted.
    fn prune(
        &self,
        finished_before: DateTime<Utc>,
        keys_before: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError>;
    /// Counts per status and the age of the queue.
    fn counts(&self) -> Result<StatusCounts, StoreError>;
    /// A cheap live check that the store takes writes now, for `/readyz`. Default: a read
    /// ([`JobStore::counts`]).
    fn probe(&self) -> Result<(), StoreError> {
        self.counts().map(|_| ())
    }
    /// How long a claim holds a job without a [`JobStore::heartbeat`]; `None` (the default)
    /// for a store used by one process only, whose claims last until that process restarts.
    fn lease_duration(&self) -> Option<std::time::Duration> {
        None
    }
    /// Renews the lease of a job this store handle claimed and reports a cancel request.
    /// Default (no leases): held, no request (cancels reach the runner in-process).
    fn heartbeat(&self, _id: Uuid, _now: DateTime<Utc>) -> Result<Lease, StoreError> {
        Ok(Lease::Held {
            cancel_requested: false,
        })
    }
    /// Puts processing jobs whose lease expired before `now` back in the queue (or fails them
    /// at `max_attempts`, as [`JobStore::recover`]); live leases are never touched. Default:
    /// nothing (no leases).
    fn reclaim_expired(
        &self,
        _max_attempts: u32,
        _now: DateTime<Utc>,
    ) -> Result<Recovery, StoreError> {
        Ok(Recovery::default())
    }
    /// Asks the store to call `sink` with every change that *another* store handle (another
    /// replica) commits to a job, soon after its commit: a job enqueued, claimed, its stored
    /// progress, its end, a cancel request. Returns false (the default) when the store has no
    /// such feed: then only this process writes, and the runner already knows every change.
    /// Best effort: a change may be missed (e.g. while the feed reconnects); callers keep
    /// polling as the fallback.
    fn watch_changes(&self, _sink: ChangeSink) -> bool {
        false
    }
}

/// A change to a job committed by another replica (see [`JobStore::watch_changes`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JobChange {
    /// The job.
    pub id: Uuid,
    /// Its status after the change.
    pub status: JobStatus,
    /// Its stored revision after the change.
    pub revision: u64,
    /// Its stored progress after the change.
    pub progress: JobProgress,
    /// A client asked (through any replica) to cancel the processing job.
    #[serde(default)]
    pub cancel_requested: bool,
}

/// Receiver of [`JobChange`]s; called on a store thread, so it must not block.
pub type ChangeSink = Box<dyn Fn(JobChange) + Send + Sync>;

/// Key of the blob [`BlobStore::probe`] rewrites (outside `jobs/`, so no job owns it).
pub const PROBE_KEY: &str = "health/probe";
/// Bytes [`BlobStore::probe`] writes: one page, so a disk without a free block fails it.
pub const PROBE_BYTES: usize = 4096;

/// Durable blobs (uploads and results).
pub trait BlobStore: Send + Sync + 'static {
    /// Writes `bytes` under `key` atomically (temporary file, fsync, rename).
    fn put(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError>;
    /// Writes `bytes` under `key` only if nothing is stored there yet (a create-only,
    /// conditional put: `If-None-Match: *` on S3, a hard link on a file system), else
    /// [`StoreError::BlobExists`] and the stored blob is unchanged. Job outputs go through it,
    /// so a result once written is never replaced.
    fn put_new(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError>;
    /// Moves a finished temporary file (from [`BlobStore::temp_dir`]) under `key` atomically.
    fn put_file(&self, key: &str, temp: &std::path::Path) -> Result<(), StoreError>;
    /// Reads a whole blob.
    fn get(&self, key: &str) -> Result<Vec<u8>, StoreError>;
    /// Size of a blob in bytes.
    fn len(&self, key: &str) -> Result<u64, StoreError>;
    /// Reads `len` bytes starting at `offset` (for HTTP Range requests).
    fn read_range(&self, key: &str, offset: u64, len: u64) -> Result<Vec<u8>, StoreError>;
    /// Deletes every blob whose key starts with `prefix` (a whole job: `jobs/<id>/`).
    fn delete_prefix(&self, prefix: &str) -> Result<(), StoreError>;
    /// A folder on the same file system for streaming uploads before [`BlobStore::put_file`].
    fn temp_dir(&self) -> PathBuf;
    /// Creates (truncating) the file `path` inside [`BlobStore::temp_dir`] and returns a writer
    /// for the upload being spooled into it; the file is later taken by
    /// [`BlobStore::put_file`] or removed by the caller. Default: `std::fs::File::create`.
    /// (The seam through which tests make the spooling fail, e.g. with `ENOSPC`.)
    fn create_temp(&self, path: &std::path::Path) -> std::io::Result<Box<dyn Write + Send>> {
        Ok(Box::new(std::fs::File::create(path)?))
    }
    /// A cheap live check that blobs can be written now, for `/readyz`: by default one
    /// [`BlobStore::put`] of [`PROBE_BYTES`] under the key [`PROBE_KEY`] (a temporary file,
    /// written, fsynced and renamed over the previous probe: the path every blob write takes).
    fn probe(&self) -> Result<(), StoreError> {
        self.put(PROBE_KEY, &[0u8; PROBE_BYTES])
    }
    /// Removes files of [`BlobStore::temp_dir`] not modified for `older_than`: partial uploads
    /// left by a crash (an upload in flight writes its file at least every body timeout).
    /// Returns how many were removed.
    fn sweep_temp(&self, older_than: std::time::Duration) -> Result<usize, StoreError>;
}
