//! The embedded [`JobStore`]: one SQLite database in WAL mode with `synchronous=FULL`, so a
//! committed state change survives `kill -9` and power loss.
//!
//! Each job is one row of `jobs`: indexed columns for the queries (`id`, `status`, `method`,
//! `created_at`, `finished_at`, `idempotency_key`, `request_hash`, `revision`) and the full
//! [`JobRecord`] as JSON in `record`. Times are stored as nanoseconds since the Unix epoch (UTC)
//! so they order exactly. Idempotency keys also live in their own table `idempotency_keys`, so a
//! key outlives neither more nor less than its retention (`prune`'s `keys_before`), independent
//! of the job's own TTL. The schema version is kept in `schema_version`; [`SqliteJobStore::open`]
//! creates or migrates the schema and refuses a database written by a newer version.
//!
//! Every state change reads, modifies and writes the record inside one `BEGIN IMMEDIATE`
//! transaction on the single writer connection (behind a mutex), so changes are atomic, ordered
//! and never lost between concurrent callers, even across processes sharing the file (the busy
//! timeout waits for the other writer). Reads go through a small pool of read-only connections
//! (WAL readers do not block the writer). Terminal states never change: any attempt is a
//! [`StoreError::Conflict`]. Every change bumps `revision` by one.
//!
//! `list` pages are ordered by `(created_at desc, id desc)`; the cursor is the URL-safe base64
//! of `"<created_at nanos>|<id>"` of the last job of the page, so pages never overlap or skip
//! jobs even while new jobs arrive.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use base64::Engine as _;
use chrono::{DateTime, Utc};
use rusqlite::{
    params, Connection, OpenFlags, OptionalExtension, Transaction, TransactionBehavior,
};
use uuid::Uuid;

use super::{
    CreateOutcome, Finish, JobStore, ListFilter, ListPage, Recovery, StatusCounts, StoreError,
};
use crate::service::model::{JobProgress, JobRecord, JobStatus};

/// Schema version this code writes.
const SCHEMA_VERSION: i64 = 1;
/// Page size when the filter asks for 0.
pub const DEFAULT_PAGE: usize = 50;
/// Largest page.
pub const MAX_PAGE: usize = 500;
/// How long a writer waits for a lock held by another connection or process before the
/// call fails as [`StoreError::Busy`] (the API answers 503 with `Retry-After` rather than
/// hold the request; the runner retries its writes).
const BUSY_TIMEOUT: Duration = Duration::from_secs(1);
/// Read-only connections.
const READERS: usize = 4;
/// Bytes the `/readyz` probe asks the database for (four 4 KiB pages), in a transaction it
/// rolls back.
const PROBE_DB_BYTES: i64 = 16384;

const SCHEMA_V1: &str = "
CREATE TABLE IF NOT EXISTS jobs (
    id              TEXT PRIMARY KEY NOT NULL,
    status          TEXT NOT NULL,
    method          TEXT NOT NULL,
    created_at      INTEGER NOT NULL,
    finished_at     INTEGER,
    idempotency_key TEXT UNIQUE,
    request_hash    TEXT NOT NULL,
    revision        INTEGER NOT NULL,
    record          TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_created ON jobs (created_at DESC, id DESC);
CREATE INDEX IF NOT EXISTS jobs_status_created ON jobs (status, created_at, id);
CREATE INDEX IF NOT EXISTS jobs_finished ON jobs (finished_at) WHERE finished_at IS NOT NULL;
CREATE TABLE IF NOT EXISTS idempotency_keys (
    key          TEXT PRIMARY KEY NOT NULL,
    request_hash TEXT NOT NULL,
    job_id       TEXT NOT NULL,
    created_at   INTEGER NOT NULL
);
CREATE INDEX IF NOT EXISTS idempotency_keys_created ON idempotency_keys (created_at);
";

impl From<rusqlite::Error> for StoreError {
    fn from(e: rusqlite::Error) -> Self {
        use rusqlite::ErrorCode;
        match e.sqlite_error_code() {
            Some(ErrorCode::DatabaseBusy | ErrorCode::DatabaseLocked) => {
                StoreError::Busy(e.to_string())
            }
            Some(ErrorCode::DiskFull) => StoreError::DatabaseFull(e.to_string()),
            _ => StoreError::Database(e.to_string()),
        }
    }
}

impl From<serde_json::Error> for StoreError {
    fn from(e: serde_json::Error) -> Self {
        StoreError::Database(format!("job record json: {e}"))
    }
}

/// Nanoseconds since the epoch (saturating outside 1677..2262, far from any real job time).
pub(super) fn nanos(t: DateTime<Utc>) -> i64 {
    t.timestamp_nanos_opt().unwrap_or(if t.timestamp() < 0 {
        i64::MIN
    } else {
        i64::MAX
    })
}

pub(super) fn from_nanos(n: i64) -> DateTime<Utc> {
    DateTime::from_timestamp_nanos(n)
}

/// SQLite-backed [`JobStore`].
pub struct SqliteJobStore {
    path: PathBuf,
    writer: Mutex<Connection>,
    readers: Vec<Mutex<Connection>>,
    next_reader: AtomicUsize,
}

impl std::fmt::Debug for SqliteJobStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SqliteJobStore")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

fn lock(m: &Mutex<Connection>) -> MutexGuard<'_, Connection> {
    // A panic while holding the connection leaves SQLite consistent (an open transaction is
    // rolled back when its guard drops), so a poisoned lock is still usable.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl SqliteJobStore {
    /// Opens (creating if needed) the database at `path`, sets WAL mode, `synchronous=FULL` and
    /// a busy timeout, and creates or migrates the schema.
    ///
    /// # Errors
    /// [`StoreError::Database`] if the file cannot be opened, is not a database, or was written
    /// by a newer schema version; [`StoreError::Io`] if its folder cannot be created.
    pub fn open(path: &Path) -> Result<Self, StoreError> {
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)?;
        }
        let writer = Connection::open(path)?;
        writer.busy_timeout(BUSY_TIMEOUT)?;
        let mode: String = writer.query_row("PRAGMA journal_mode=WAL", [], |r| r.get(0))?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(StoreError::Database(format!(
                "could not enable wal mode (journal_mode is {mode})"
            )));
        }
        writer.pragma_update(None, "synchronous", "FULL")?;
        writer.pragma_update(None, "foreign_keys", "ON")?;
        migrate(&writer)?;
        let mut readers = Vec::with_capacity(READERS);
        for _ in 0..READERS {
            let r = Connection::open_with_flags(
                path,
                OpenFlags::SQLITE_OPEN_READ_ONLY
                    | OpenFlags::SQLITE_OPEN_NO_MUTEX
                    | OpenFlags::SQLITE_OPEN_URI,
            )?;
            r.busy_timeout(BUSY_TIMEOUT)?;
            readers.push(Mutex::new(r));
        }
        Ok(Self {
            path: path.to_path_buf(),
            writer: Mutex::new(writer),
            readers,
            next_reader: AtomicUsize::new(0),
        })
    }

    /// The database file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Caps the database at `max_pages` pages (`PRAGMA max_page_count` on the writer
    /// connection; SQLite never sets it below the current size) and returns the cap in force.
    /// A write that needs more pages fails as `SQLITE_FULL` ([`StoreError::DatabaseFull`]): a
    /// quota an operator may set, and how tests make the database report a full disk.
    pub fn limit_pages(&self, max_pages: u64) -> Result<u64, StoreError> {
        let conn = lock(&self.writer);
        let cap: i64 = conn.query_row(
            &format!("PRAGMA max_page_count = {}", max_pages.min(i64::MAX as u64)),
            [],
            |r| r.get(0),
        )?;
        Ok(cap as u64)
    }

    /// Pages the database has now.
    pub fn page_count(&self) -> Result<u64, StoreError> {
        let conn = lock(&self.writer);
        let n: i64 = conn.query_row("PRAGMA page_count", [], |r| r.get(0))?;
        Ok(n as u64)
    }

    /// A read-only connection: the first free one, else round robin.
    fn reader(&self) -> MutexGuard<'_, Connection> {
        for r in &self.readers {
            if let Ok(g) = r.try_lock() {
                return g;
            }
        }
        let i = self.next_reader.fetch_add(1, Ordering::Relaxed) % self.readers.len();
        lock(&self.readers[i])
    }

    /// Runs `f` in one immediate (write-locking) transaction and commits it.
    fn write<T>(
        &self,
        f: impl FnOnce(&Transaction<'_>) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut conn = lock(&self.writer);
        let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
        let out = f(&tx)?;
        tx.commit()?;
        Ok(out)
    }
}

fn migrate(conn: &Connection) -> Result<(), StoreError> {
    conn.execute_batch("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL);")?;
    let version: Option<i64> = conn
        .query_row("SELECT MAX(version) FROM schema_version", [], |r| r.get(0))
        .optional()?
        .flatten();
    match version {
        None => {
            conn.execute_batch(&format!(
                "BEGIN IMMEDIATE; {SCHEMA_V1} INSERT INTO schema_version (version) VALUES ({SCHEMA_VERSION}); COMMIT;"
            ))?;
        }
        Some(v) if v == SCHEMA_VERSION => {}
        Some(v) if v > SCHEMA_VERSION => {
            return Err(StoreError::Database(format!(
                "database schema version {v} is newer than this build supports ({SCHEMA_VERSION})"
            )))
        }
        Some(v) => {
            // No older versions exist yet; future migrations go here, one step per version.
            return Err(StoreError::Database(format!(
                "database schema version {v} has no migration to {SCHEMA_VERSION}"
            )));
        }
    }
    Ok(())
}

fn load_record(conn: &Connection, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
    let json: Option<String> = conn
        .query_row(
            "SELECT record FROM jobs WHERE id = ?1",
            [id.to_string()],
            |r| r.get(0),
        )
        .optional()?;
    json.map(|j| serde_json::from_str(&j).map_err(StoreError::from))
        .transpose()
}

fn insert_record(tx: &Transaction<'_>, job: &JobRecord) -> Result<(), StoreError> {
    tx.execute(
        "INSERT INTO jobs (id, status, method, created_at, finished_at, idempotency_key, request_hash, revision, record)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
        params![
            job.id.to_string(),
            job.status.as_str(),
            job.method,
            nanos(job.created_at),
            job.finished_at.map(nanos),
            job.idempotency_key,
            job.request_hash,
            job.revision as i64,
            serde_json::to_string(job)?,
        ],
    )?;
    Ok(())
}

/// Writes back a changed record (status, finished_at, revision and JSON).
fn update_record(tx: &Transaction<'_>, job: &JobRecord) -> Result<(), StoreError> {
    tx.execute(
        "UPDATE jobs SET status = ?2, finished_at = ?3, revision = ?4, record = ?5 WHERE id = ?1",
        params![
            job.id.to_string(),
            job.status.as_str(),
            job.finished_at.map(nanos),
            job.revision as i64,
            serde_json::to_string(job)?,
        ],
    )?;
    Ok(())
}

pub(super) fn encode_cursor(job: &JobRecord) -> String {
    base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(format!(
        "{}|{}",
        nanos(job.created_at),
        job.id
    ))
}

pub(super) fn decode_cursor(cursor: &str) -> Result<(i64, String), StoreError> {
    let bad = || StoreError::InvalidCursor(cursor.to_string());
    let bytes = base64::engine::general_purpose::URL_SAFE_NO_PAD
        .decode(cursor)
        .map_err(|_| bad())?;
    let text = String::from_utf8(bytes).map_err(|_| bad())?;
    let (t, id) = text.split_once('|').ok_or_else(bad)?;
    let t: i64 = t.parse().map_err(|_| bad())?;
    let id = Uuid::parse_str(id).map_err(|_| bad())?;
    Ok((t, id.to_string()))
}

pub(super) fn conflict(job: &JobRecord, what: &'static str) -> StoreError {
    StoreError::Conflict {
        id: job.id,
        status: job.status,
        what,
    }
}

impl JobStore for SqliteJobStore {
    fn create_bounded(&self, job: &JobRecord, queue_len: u64) -> Result<CreateOutcome, StoreError> {
        self.write(|tx| {
            if let Some(key) = &job.idempotency_key {
                let seen: Option<(String, String)> = tx
                    .query_row(
                        "SELECT request_hash, job_id FROM idempotency_keys WHERE key = ?1",
                        [key],
                        |r| Ok((r.get(0)?, r.get(1)?)),
                    )
                    .optional()?;
                if let Some((hash, job_id)) = seen {
                    let existing = Uuid::parse_str(&job_id)
                        .map_err(|e| StoreError::Database(format!("bad job id in keys: {e}")))?;
                    if hash != job.request_hash {
                        return Err(StoreError::IdempotencyMismatch {
                            key: key.clone(),
                            existing,
                        });
                    }
                    if let Some(rec) = load_record(tx, existing)? {
                        return Ok(CreateOutcome::Existing(Box::new(rec)));
                    }
                    // The job was deleted by its owner: the key is free again.
                    tx.execute("DELETE FROM idempotency_keys WHERE key = ?1", [key])?;
                }
            }
            // Counted inside the write transaction: concurrent creates are serialized, so the
            // queue never holds more than `queue_len` jobs.
            if job.status == JobStatus::Enqueued && queue_len < u64::MAX {
                let enqueued: i64 = tx.query_row(
                    "SELECT COUNT(*) FROM jobs WHERE status = 'enqueued'",
                    [],
                    |r| r.get(0),
                )?;
                if enqueued.max(0) as u64 >= queue_len {
                    return Err(StoreError::QueueFull { limit: queue_len });
                }
            }
            if let Some(key) = &job.idempotency_key {
                // A key pruned from the key table may still sit on an old job row.
                tx.execute(
                    "UPDATE jobs SET idempotency_key = NULL WHERE idempotency_key = ?1",
                    [key],
                )?;
                tx.execute(
                    "INSERT INTO idempotency_keys (key, request_hash, job_id, created_at) VALUES (?1, ?2, ?3, ?4)",
                    params![key, job.request_hash, job.id.to_string(), nanos(job.created_at)],
                )?;
            }
            insert_record(tx, job)?;
            Ok(CreateOutcome::Created)
        })
    }

    fn job_of_key(&self, key: &str) -> Result<Option<Uuid>, StoreError> {
        let id: Option<String> = self
            .reader()
            .query_row(
                "SELECT job_id FROM idempotency_keys WHERE key = ?1",
                [key],
                |r| r.get(0),
            )
            .optional()?;
        id.map(|j| {
            Uuid::parse_str(&j)
                .map_err(|e| StoreError::Database(format!("bad job id in keys: {e}")))
        })
        .transpose()
    }

    fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        load_record(&self.reader(), id)
    }

    fn list(&self, filter: &ListFilter) -> Result<ListPage, StoreError> {
        let limit = match filter.limit {
            0 => DEFAULT_PAGE,
            n => n.min(MAX_PAGE),
        };
        let mut sql = String::from("SELECT record FROM jobs WHERE 1=1");
        let mut args: Vec<rusqlite::types::Value> = Vec::new();
        if let Some(s) = filter.status {
            args.push(s.as_str().to_string().into());
            sql.push_str(&format!(" AND status = ?{}", args.len()));
        }
        if let Some(m) = &filter.method {
            args.push(m.clone().into());
            sql.push_str(&format!(" AND method = ?{}", args.len()));
        }
        if let Some(t) = filter.created_after {
            args.push(nanos(t).into());
            sql.push_str(&format!(" AND created_at > ?{}", args.len()));
        }
        if let Some(t) = filter.created_before {
            args.push(nanos(t).into());
            sql.push_str(&format!(" AND created_at < ?{}", args.len()));
        }
        if let Some(c) = &filter.cursor {
            let (t, id) = decode_cursor(c)?;
            args.push(t.into());
            let ti = args.len();
            args.push(id.into());
            let ii = args.len();
            sql.push_str(&format!(
                " AND (created_at < ?{ti} OR (created_at = ?{ti} AND id < ?{ii}))"
            ));
        }
        args.push(((limit + 1) as i64).into());
        sql.push_str(&format!(
            " ORDER BY created_at DESC, id DESC LIMIT ?{}",
            args.len()
        ));
        let conn = self.reader();
        let mut stmt = conn.prepare_cached(&sql)?;
        let rows = stmt.query_map(rusqlite::params_from_iter(args), |r| r.get::<_, String>(0))?;
        let mut jobs = Vec::with_capacity(limit + 1);
        for row in rows {
            jobs.push(serde_json::from_str::<JobRecord>(&row?)?);
        }
        let next = if jobs.len() > limit {
            jobs.truncate(limit);
            jobs.last().map(encode_cursor)
        } else {
            None
        };
        Ok(ListPage { jobs, next })
    }

    fn claim_next(&self, now: DateTime<Utc>) -> Result<Option<JobRecord>, StoreError> {
        self.write(|tx| {
            let json: Option<String> = tx
                .query_row(
                    "SELECT record FROM jobs WHERE status = 'enqueued' ORDER BY created_at, id LIMIT 1",
                    [],
                    |r| r.get(0),
                )
                .optional()?;
            let Some(json) = json else { return Ok(None) };
            let mut job: JobRecord = serde_json::from_str(&json)?;
            job.status = JobStatus::Processing;
            job.started_at = Some(now);
            job.attempts += 1;
            job.progress = JobProgress::default();
            job.revision += 1;
            update_record(tx, &job)?;
            Ok(Some(job))
        })
    }

    fn update_progress(&self, id: Uuid, progress: &JobProgress) -> Result<(), StoreError> {
        self.write(|tx| {
            let mut job = load_record(tx, id)?.ok_or(StoreError::NotFound(id))?;
            if job.status != JobStatus::Processing || job.progress == *progress {
                return Ok(());
            }
            job.progress = progress.clone();
            job.revision += 1;
            update_record(tx, &job)
        })
    }

    fn finish(
        &self,
        id: Uuid,
        outcome: Finish,
        now: DateTime<Utc>,
    ) -> Result<JobRecord, StoreError> {
        self.write(|tx| {
            let mut job = load_record(tx, id)?.ok_or(StoreError::NotFound(id))?;
            if job.status.is_terminal() {
                return Err(conflict(&job, "finish a finished job"));
            }
            outcome.apply(&mut job, now);
            update_record(tx, &job)?;
            Ok(job)
        })
    }

    fn cancel_if_enqueued(&self, id: Uuid, now: DateTime<Utc>) -> Result<JobRecord, StoreError> {
        self.write(|tx| {
            let mut job = load_record(tx, id)?.ok_or(StoreError::NotFound(id))?;
            match job.status {
                JobStatus::Enqueued => {
                    job.status = JobStatus::Canceled;
                    job.finished_at = Some(now);
                    job.revision += 1;
                    update_record(tx, &job)?;
                    Ok(job)
                }
                JobStatus::Processing => Ok(job),
                _ => Err(conflict(&job, "cancel a finished job")),
            }
        })
    }

    fn recover(&self, max_attempts: u32, now: DateTime<Utc>) -> Result<Recovery, StoreError> {
        self.write(|tx| {
            let mut stmt = tx.prepare("SELECT record FROM jobs WHERE status = 'processing'")?;
            let records = stmt
                .query_map([], |r| r.get::<_, String>(0))?
                .collect::<Result<Vec<_>, _>>()?;
            drop(stmt);
            let mut out = Recovery::default();
            for json in records {
                let mut job: JobRecord = serde_json::from_str(&json)?;
                out.settle(&mut job, max_attempts, now);
                update_record(tx, &job)?;
            }
            Ok(out)
        })
    }

    fn requeue_stopped(
        &self,
        ids: &[Uuid],
        _now: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.write(|tx| {
            let mut out = Vec::with_capacity(ids.len());
            for &id in ids {
                let Some(mut job) = load_record(tx, id)? else {
                    continue;
                };
                if job.status != JobStatus::Processing {
                    continue;
                }
                job.status = JobStatus::Enqueued;
                job.progress = JobProgress::default();
                job.attempts = job.attempts.saturating_sub(1);
                job.revision += 1;
                update_record(tx, &job)?;
                out.push(job);
            }
            Ok(out)
        })
    }

    fn delete(&self, id: Uuid) -> Result<JobRecord, StoreError> {
        self.write(|tx| {
            let job = load_record(tx, id)?.ok_or(StoreError::NotFound(id))?;
            if !job.status.is_terminal() {
                return Err(conflict(&job, "delete an unfinished job"));
            }
            tx.execute("DELETE FROM jobs WHERE id = ?1", [id.to_string()])?;
            Ok(job)
        })
    }

    fn prune(
        &self,
        finished_before: DateTime<Utc>,
        keys_before: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.write(|tx| {
            let mut stmt = tx.prepare(
                "SELECT record FROM jobs WHERE finished_at IS NOT NULL AND finished_at < ?1
                 AND status IN ('succeeded', 'failed', 'canceled')",
            )?;
            let records = stmt
                .query_map([nanos(finished_before)], |r| r.get::<_, String>(0))?
                .collect::<Result<Vec<_>, _>>()?;
            drop(stmt);
            let mut removed = Vec::with_capacity(records.len());
            for json in records {
                let job: JobRecord = serde_json::from_str(&json)?;
                tx.execute("DELETE FROM jobs WHERE id = ?1", [job.id.to_string()])?;
                removed.push(job);
            }
            let cutoff = nanos(keys_before);
            tx.execute(
                "UPDATE jobs SET idempotency_key = NULL WHERE idempotency_key IN
                 (SELECT key FROM idempotency_keys WHERE created_at < ?1)",
                [cutoff],
            )?;
            tx.execute(
                "DELETE FROM idempotency_keys WHERE created_at < ?1",
                [cutoff],
            )?;
            Ok(removed)
        })
    }

    /// Takes the write lock and inserts [`PROBE_DB_BYTES`] into `idempotency_keys`, then rolls
    /// back: fails as busy while another writer holds the lock, and as full when the database
    /// cannot get the pages (a `max_page_count` cap, or no room to grow); commits nothing.
    fn probe(&self) -> Result<(), StoreError> {
        let mut conn = lock(&self.writer);
        let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
        tx.execute(
            "INSERT INTO idempotency_keys (key, request_hash, job_id, created_at)
             VALUES ('readyz-probe', zeroblob(?1), '', 0)",
            [PROBE_DB_BYTES],
        )?;
        tx.rollback()?;
        Ok(())
    }

    fn counts(&self) -> Result<StatusCounts, StoreError> {
        let conn = self.reader();
        let mut stmt = conn.prepare_cached("SELECT status, COUNT(*) FROM jobs GROUP BY status")?;
        let rows = stmt.query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, i64>(1)?)))?;
        let mut by_status = Vec::new();
        for row in rows {
            let (s, n) = row?;
            let status = JobStatus::parse(&s)
                .ok_or_else(|| StoreError::Database(format!("unknown status {s:?} in jobs")))?;
            by_status.push((status, n as u64));
        }
        by_status.sort_by_key(|(s, _)| *s as u8);
        let oldest: Option<i64> = conn.query_row(
            "SELECT MIN(created_at) FROM jobs WHERE status = 'enqueued'",
            [],
            |r| r.get(0),
        )?;
        Ok(StatusCounts {
            by_status,
            oldest_enqueued: oldest.map(from_nanos),
        })
    }
}
