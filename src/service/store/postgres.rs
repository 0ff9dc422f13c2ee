//! The networked [`JobStore`] (issue 17, part 1): one PostgreSQL database shared by several
//! `retex serve` replicas.
//!
//! Layout as in [`super::sqlite`]: one row of `jobs` per job (indexed columns plus the full
//! [`JobRecord`] as JSON text in `record`, times as nanoseconds since the epoch, `id` compared
//! byte-wise with `COLLATE "C"` so pages order exactly as SQLite's), idempotency keys in
//! `idempotency_keys`, the version in `schema_version`. Three columns exist only here:
//! `lease_owner` (the store handle that claimed the job: a fresh UUID per [`PgJobStore`]),
//! `lease_until` (nanoseconds) and `cancel_requested`.
//!
//! Semantics per trait method are SQLite's, plus those of several replicas:
//! - `claim_next` takes the oldest enqueued row with `SELECT … FOR UPDATE SKIP LOCKED` (two
//!   replicas never wait on, or both take, one job) and sets the lease to `now + lease`;
//!   [`JobStore::heartbeat`] renews it while the job runs and reports `cancel_requested`.
//! - `cancel_if_enqueued` on a processing job sets `cancel_requested` (the record itself is
//!   unchanged, as in SQLite): the replica running the job sees it at its next heartbeat.
//! - `recover` (start-up) re-enqueues processing jobs whose lease expired or that this handle
//!   holds; the live leases of other replicas are left alone. [`JobStore::reclaim_expired`]
//!   does the same for expired leases only and is what the runner calls every tick; both fail a
//!   job at `max_attempts` like SQLite.
//! - `finish`, `update_progress` and `requeue_stopped` of a processing job act only for the
//!   lease holder: a replica that lost its lease cannot overwrite the outcome of the attempt
//!   that replaced it (`finish` answers [`StoreError::Conflict`]).
//! - `create_bounded` takes a transaction-scoped advisory lock, so the queue-length check and
//!   the idempotency-key lookup are serialized across replicas as SQLite's single writer is.
//! - Migrations run at open under a session advisory lock, so replicas starting together
//!   create the schema once.
//! - Every write of a job also sends `pg_notify` on the channel `retex_jobs` in the same
//!   transaction (with the writer's owner id, so a handle skips its own), and
//!   [`JobStore::watch_changes`] keeps one extra connection `LISTEN`ing on it (`postgres_listen.rs`):
//!   idle workers wake when another replica enqueues, a cancel reaches the running job at once,
//!   and every replica's event streams follow jobs that run elsewhere. Progress reaches the
//!   store (and so the feed) at most every 500 ms per job (the runner's bounded rate).
//!
//! Client: `tokio-postgres` pooled by `deadpool-postgres`, driven on a small tokio runtime that
//! the store owns (two threads). The trait is synchronous: each method spawns its query onto
//! that runtime and waits on a channel. This is safe from `spawn_blocking` threads, from plain
//! threads (tests) and even from async code (the runner's start-up `recover`), where the sync
//! `postgres` crate would panic with a nested `block_on`. The runtime is shut down in the
//! background on drop, which is also allowed inside async code.
//!
//! Constants not from any paper (this is plumbing): pool of 8 connections, 5 s to get or open
//! a connection (then [`StoreError::Busy`]), lease 30 s by default (`--lease-secs`).

use std::future::Future;
use std::time::Duration;

use chrono::{DateTime, Utc};
use deadpool_postgres::{Manager, ManagerConfig, Pool, RecyclingMethod};
use tokio_postgres::types::ToSql;
use tokio_postgres::{GenericClient, NoTls, Transaction};
use uuid::Uuid;

use super::sqlite::{
    conflict, decode_cursor, encode_cursor, from_nanos, nanos, DEFAULT_PAGE, MAX_PAGE,
};
use super::{
    ChangeSink, CreateOutcome, Finish, JobStore, Lease, ListFilter, ListPage, Recovery,
    StatusCounts, StoreError,
};
use crate::service::model::{JobProgress, JobRecord, JobStatus};

#[path = "postgres_listen.rs"]
mod listen;

/// What a [`PgJobStore::write`] closure returns: its transaction's work.
type TxFuture<'t, T> = std::pin::Pin<Box<dyn Future<Output = Result<T, StoreError>> + Send + 't>>;

/// Schema version this code writes.
const SCHEMA_VERSION: i32 = 1;
/// Connections in the pool.
const POOL_SIZE: usize = 8;
/// Longest wait for a pooled or new connection.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// Default lease of a claim.
pub const DEFAULT_LEASE: Duration = Duration::from_secs(30);
/// Advisory lock key of the migrations (session) ("retexmig").
const MIGRATE_LOCK: i64 = 0x7265_7465_786d_6967;
/// Advisory lock key serializing `create_bounded` (transaction) ("retexnew").
const CREATE_LOCK: i64 = 0x7265_7465_786e_6577;

const SCHEMA_V1: &str = r#"
CREATE TABLE IF NOT EXISTS jobs (
    id               TEXT COLLATE "C" PRIMARY KEY NOT NULL,
    status           TEXT NOT NULL,
    method           TEXT NOT NULL,
    created_at       BIGINT NOT NULL,
    finished_at      BIGINT,
    idempotency_key  TEXT UNIQUE,
    request_hash     TEXT NOT NULL,
    revision         BIGINT NOT NULL,
    record           TEXT NOT NULL,
    lease_owner      TEXT,
    lease_until      BIGINT,
    cancel_requested BOOLEAN NOT NULL DEFAULT FALSE
);
CREATE INDEX IF NOT EXISTS jobs_created ON jobs (created_at DESC, id DESC);
CREATE INDEX IF NOT EXISTS jobs_status_created ON jobs (status, created_at, id);
CREATE INDEX IF NOT EXISTS jobs_finished ON jobs (finished_at) WHERE finished_at IS NOT NULL;
CREATE INDEX IF NOT EXISTS jobs_lease ON jobs (lease_until) WHERE status = 'processing';
CREATE TABLE IF NOT EXISTS idempotency_keys (
    key          TEXT PRIMARY KEY NOT NULL,
    request_hash TEXT NOT NULL,
    job_id       TEXT NOT NULL,
    created_at   BIGINT NOT NULL
);
CREATE INDEX IF NOT EXISTS idempotency_keys_created ON idempotency_keys (created_at);
"#;

fn db_error(e: tokio_postgres::Error) -> StoreError {
    match e.as_db_error() {
        Some(d) => {
            let text = format!("{}: {}", d.code().code(), d.message());
            match d.code().code() {
                // disk_full, insufficient_resources
                "53100" | "53000" => StoreError::DatabaseFull(text),
                // lock_not_available, serialization_failure, deadlock_detected,
                // too_many_connections, cannot_connect_now
                "55P03" | "40001" | "40P01" | "53300" | "57P03" => StoreError::Busy(text),
                _ => StoreError::Database(text),
            }
        }
        None => StoreError::Database(e.to_string()),
    }
}

fn pool_error(e: deadpool_postgres::PoolError) -> StoreError {
    match e {
        deadpool_postgres::PoolError::Backend(e) => db_error(e),
        deadpool_postgres::PoolError::Timeout(_) => {
            StoreError::Busy(format!("no database connection within {CONNECT_TIMEOUT:?}"))
        }
        e => StoreError::Database(e.to_string()),
    }
}

fn json_error(e: serde_json::Error) -> StoreError {
    StoreError::Database(format!("job record json: {e}"))
}

/// PostgreSQL-backed [`JobStore`]; one per replica (each has its own lease owner id).
pub struct PgJobStore {
    runtime: Option<tokio::runtime::Runtime>,
    /// The connection settings (the change feed opens its own connection with them).
    config: tokio_postgres::Config,
    pool: Pool,
    owner: String,
    lease: Duration,
}

impl std::fmt::Debug for PgJobStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PgJobStore")
            .field("owner", &self.owner)
            .field("lease", &self.lease)
            .finish_non_exhaustive()
    }
}

impl Drop for PgJobStore {
    fn drop(&mut self) {
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

impl PgJobStore {
    /// Connects to `url` (`postgres://user:pass@host:port/db`, or `key=value` pairs; a unix
    /// socket as `host=/run/postgresql`), runs the migrations under an advisory lock, and
    /// returns a store whose claims hold a lease of `lease`.
    ///
    /// # Errors
    /// [`StoreError::Database`] for a malformed URL, an unreachable server, or a database
    /// written by a newer schema version.
    pub fn connect(url: &str, lease: Duration) -> Result<Self, StoreError> {
        let mut config: tokio_postgres::Config = url
            .parse()
            .map_err(|e| StoreError::Database(format!("database url: {e}")))?;
        if config.get_connect_timeout().is_none() {
            config.connect_timeout(CONNECT_TIMEOUT);
        }
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("retex-pg")
            .enable_all()
            .build()?;
        let manager = Manager::from_config(
            config.clone(),
            NoTls,
            ManagerConfig {
                recycling_method: RecyclingMethod::Fast,
            },
        );
        let pool = {
            let _enter = runtime.enter();
            Pool::builder(manager)
                .max_size(POOL_SIZE)
                .runtime(deadpool_postgres::Runtime::Tokio1)
                .wait_timeout(Some(CONNECT_TIMEOUT))
                .create_timeout(Some(CONNECT_TIMEOUT))
                .build()
                .map_err(|e| StoreError::Database(format!("database pool: {e}")))?
        };
        let store = Self {
            runtime: Some(runtime),
            config,
            pool,
            owner: Uuid::new_v4().to_string(),
            lease: lease.max(Duration::from_secs(1)),
        };
        let pool = store.pool.clone();
        store.block(async move { migrate(&pool).await })?;
        Ok(store)
    }

    /// This handle's lease owner id.
    pub fn owner(&self) -> &str {
        &self.owner
    }

    /// Runs `fut` on the store's runtime and waits for it (see the module docs).
    fn block<T: Send + 'static>(
        &self,
        fut: impl Future<Output = Result<T, StoreError>> + Send + 'static,
    ) -> Result<T, StoreError> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let rt = self.runtime.as_ref().expect("runtime lives until drop");
        rt.spawn(async move {
            let _ = tx.send(fut.await);
        });
        rx.recv()
            .map_err(|_| StoreError::Database("the database task was lost".into()))?
    }

    /// Runs `f` in one transaction on a pooled connection and commits it when `f` succeeds (an
    /// error rolls it back), on the store's runtime.
    fn write<T, F>(&self, f: F) -> Result<T, StoreError>
    where
        T: Send + 'static,
        F: for<'t> FnOnce(&'t Transaction<'t>) -> TxFuture<'t, T> + Send + 'static,
    {
        let pool = self.pool.clone();
        self.block(async move {
            let mut c = pool.get().await.map_err(pool_error)?;
            let tx = c.transaction().await.map_err(db_error)?;
            let out = f(&tx).await?;
            tx.commit().await.map_err(db_error)?;
            Ok(out)
        })
    }

    fn lease_until(&self, now: DateTime<Utc>) -> i64 {
        let lease = chrono::Duration::from_std(self.lease).unwrap_or(chrono::Duration::MAX);
        nanos(now.checked_add_signed(lease).unwrap_or(now))
    }

    /// Re-enqueues (or fails) the processing jobs that `expired_only` or this owner selects.
    fn requeue_processing(
        &self,
        max_attempts: u32,
        now: DateTime<Utc>,
        expired_only: bool,
    ) -> Result<Recovery, StoreError> {
        let owner = self.owner.clone();
        self.write(move |tx| {
            Box::pin(async move {
                // Owner "" matches no handle: only expired leases.
                let selected = if expired_only { "" } else { owner.as_str() };
                let rows = tx
                    .query(
                        "SELECT record FROM jobs WHERE status = 'processing'
                     AND (lease_until IS NULL OR lease_until < $1 OR lease_owner = $2)
                     ORDER BY created_at, id FOR UPDATE SKIP LOCKED",
                        &[&nanos(now), &selected],
                    )
                    .await
                    .map_err(db_error)?;
                let mut out = Recovery::default();
                for row in rows {
                    let mut job: JobRecord =
                        serde_json::from_str(row.get::<_, &str>(0)).map_err(json_error)?;
                    out.settle(&mut job, max_attempts, now);
                    update_record(tx, &job, &owner).await?;
                }
                Ok(out)
            })
        })
    }
}

async fn migrate(pool: &Pool) -> Result<(), StoreError> {
    let c = pool.get().await.map_err(pool_error)?;
    c.execute("SELECT pg_advisory_lock($1)", &[&MIGRATE_LOCK])
        .await
        .map_err(db_error)?;
    let result = migrate_locked(&c).await;
    let unlock = c
        .execute("SELECT pg_advisory_unlock($1)", &[&MIGRATE_LOCK])
        .await
        .map_err(db_error);
    result.and(unlock.map(|_| ()))
}

async fn migrate_locked(c: &tokio_postgres::Client) -> Result<(), StoreError> {
    c.batch_execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
        .await
        .map_err(db_error)?;
    let version: Option<i32> = c
        .query_one("SELECT MAX(version) FROM schema_version", &[])
        .await
        .map_err(db_error)?
        .get(0);
    match version {
        None => c
            .batch_execute(&format!(
                "BEGIN; {SCHEMA_V1} INSERT INTO schema_version (version) VALUES ({SCHEMA_VERSION}); COMMIT;"
            ))
            .await
            .map_err(db_error),
        Some(v) if v == SCHEMA_VERSION => Ok(()),
        Some(v) if v > SCHEMA_VERSION => Err(StoreError::Database(format!(
            "database schema version {v} is newer than this build supports ({SCHEMA_VERSION})"
        ))),
        Some(v) => Err(StoreError::Database(format!(
            "database schema version {v} has no migration to {SCHEMA_VERSION}"
        ))),
    }
}

/// The record, with `FOR UPDATE` when `lock`, and its lease owner.
async fn load<C: GenericClient + Sync>(
    c: &C,
    id: Uuid,
    lock: bool,
) -> Result<Option<(JobRecord, Option<String>)>, StoreError> {
    let sql = if lock {
        "SELECT record, lease_owner FROM jobs WHERE id = $1 FOR UPDATE"
    } else {
        "SELECT record, lease_owner FROM jobs WHERE id = $1"
    };
    let row = c
        .query_opt(sql, &[&id.to_string()])
        .await
        .map_err(db_error)?;
    row.map(|r| {
        let job = serde_json::from_str(r.get::<_, &str>(0)).map_err(json_error)?;
        Ok((job, r.get(1)))
    })
    .transpose()
}

/// Inserts a new job and announces it to the other replicas ([`notify`]) as `origin`.
async fn insert_record<C: GenericClient + Sync>(
    c: &C,
    job: &JobRecord,
    origin: &str,
) -> Result<(), StoreError> {
    let json = serde_json::to_string(job).map_err(json_error)?;
    c.execute(
        "INSERT INTO jobs (id, status, method, created_at, finished_at, idempotency_key, request_hash, revision, record)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9)",
        &[
            &job.id.to_string(),
            &job.status.as_str(),
            &job.method,
            &nanos(job.created_at),
            &job.finished_at.map(nanos),
            &job.idempotency_key,
            &job.request_hash,
            &(job.revision as i64),
            &json,
        ],
    )
    .await
    .map_err(db_error)?;
    notify(c, job, origin, false).await
}

/// Writes back a changed record; a job leaving `processing` drops its lease and cancel flag.
/// The change is announced to the other replicas ([`notify`]) as `origin`.
async fn update_record<C: GenericClient + Sync>(
    c: &C,
    job: &JobRecord,
    origin: &str,
) -> Result<(), StoreError> {
    let json = serde_json::to_string(job).map_err(json_error)?;
    c.execute(
        "UPDATE jobs SET status = $2, finished_at = $3, revision = $4, record = $5,
             lease_owner = CASE WHEN $2 = 'processing' THEN lease_owner END,
             lease_until = CASE WHEN $2 = 'processing' THEN lease_until END,
             cancel_requested = ($2 = 'processing' AND cancel_requested)
         WHERE id = $1",
        &[
            &job.id.to_string(),
            &job.status.as_str(),
            &job.finished_at.map(nanos),
            &(job.revision as i64),
            &json,
        ],
    )
    .await
    .map_err(db_error)?;
    notify(c, job, origin, false).await
}

/// Sends the change of `job` on [`listen::CHANNEL`] (delivered when the transaction commits;
/// PostgreSQL drops the notifications of a rolled-back one).
async fn notify<C: GenericClient + Sync>(
    c: &C,
    job: &JobRecord,
    origin: &str,
    cancel_requested: bool,
) -> Result<(), StoreError> {
    let payload = listen::payload(job, origin, cancel_requested);
    c.execute("SELECT pg_notify($1, $2)", &[&listen::CHANNEL, &payload])
        .await
        .map_err(db_error)?;
    Ok(())
}

fn parse_id(text: &str) -> Result<Uuid, StoreError> {
    Uuid::parse_str(text).map_err(|e| StoreError::Database(format!("bad job id in keys: {e}")))
}

/// Whether `holder` (the row's lease owner) lets `owner` act on a processing job.
fn holds(holder: &Option<String>, owner: &str) -> bool {
    holder.as_deref().is_none_or(|h| h == owner)
}

impl JobStore for PgJobStore {
    fn create_bounded(&self, job: &JobRecord, queue_len: u64) -> Result<CreateOutcome, StoreError> {
        let job = job.clone();
        let owner = self.owner.clone();
        self.write(move |tx| Box::pin(async move {
            tx.execute("SELECT pg_advisory_xact_lock($1)", &[&CREATE_LOCK])
                .await
                .map_err(db_error)?;
            if let Some(key) = &job.idempotency_key {
                let seen = tx
                    .query_opt(
                        "SELECT request_hash, job_id FROM idempotency_keys WHERE key = $1",
                        &[key],
                    )
                    .await
                    .map_err(db_error)?;
                if let Some(row) = seen {
                    let existing = parse_id(row.get(1))?;
                    if row.get::<_, &str>(0) != job.request_hash {
                        return Err(StoreError::IdempotencyMismatch {
                            key: key.clone(),
                            existing,
                        });
                    }
                    if let Some((rec, _)) = load(&*tx, existing, false).await? {
                        return Ok(CreateOutcome::Existing(Box::new(rec)));
                    }
                    tx.execute("DELETE FROM idempotency_keys WHERE key = $1", &[key])
                        .await
                        .map_err(db_error)?;
                }
            }
            if job.status == JobStatus::Enqueued && queue_len < u64::MAX {
                let enqueued: i64 = tx
                    .query_one("SELECT COUNT(*) FROM jobs WHERE status = 'enqueued'", &[])
                    .await
                    .map_err(db_error)?
                    .get(0);
                if enqueued.max(0) as u64 >= queue_len {
                    return Err(StoreError::QueueFull { limit: queue_len });
                }
            }
            if let Some(key) = &job.idempotency_key {
                tx.execute(
                    "UPDATE jobs SET idempotency_key = NULL WHERE idempotency_key = $1",
                    &[key],
                )
                .await
                .map_err(db_error)?;
                tx.execute(
                    "INSERT INTO idempotency_keys (key, request_hash, job_id, created_at) VALUES ($1, $2, $3, $4)",
                    &[key, &job.request_hash, &job.id.to_string(), &nanos(job.created_at)],
                )
                .await
                .map_err(db_error)?;
            }
            insert_record(tx, &job, &owner).await?;
            Ok(CreateOutcome::Created)
        }))
    }

    fn job_of_key(&self, key: &str) -> Result<Option<Uuid>, StoreError> {
        let pool = self.pool.clone();
        let key = key.to_string();
        self.block(async move {
            let c = pool.get().await.map_err(pool_error)?;
            let row = c
                .query_opt(
                    "SELECT job_id FROM idempotency_keys WHERE key = $1",
                    &[&key],
                )
                .await
                .map_err(db_error)?;
            row.map(|r| parse_id(r.get(0))).transpose()
        })
    }

    fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        let pool = self.pool.clone();
        self.block(async move {
            let c = pool.get().await.map_err(pool_error)?;
            Ok(load(&**c, id, false).await?.map(|(j, _)| j))
        })
    }

    fn list(&self, filter: &ListFilter) -> Result<ListPage, StoreError> {
        let limit = match filter.limit {
            0 => DEFAULT_PAGE,
            n => n.min(MAX_PAGE),
        };
        let mut sql = String::from("SELECT record FROM jobs WHERE TRUE");
        let mut args: Vec<Box<dyn ToSql + Sync + Send>> = Vec::new();
        if let Some(s) = filter.status {
            args.push(Box::new(s.as_str().to_string()));
            sql.push_str(&format!(" AND status = ${}", args.len()));
        }
        if let Some(m) = &filter.method {
            args.push(Box::new(m.clone()));
            sql.push_str(&format!(" AND method = ${}", args.len()));
        }
        if let Some(t) = filter.created_after {
            args.push(Box::new(nanos(t)));
            sql.push_str(&format!(" AND created_at > ${}", args.len()));
        }
        if let Some(t) = filter.created_before {
            args.push(Box::new(nanos(t)));
            sql.push_str(&format!(" AND created_at < ${}", args.len()));
        }
        if let Some(cursor) = &filter.cursor {
            let (t, id) = decode_cursor(cursor)?;
            args.push(Box::new(t));
            let ti = args.len();
            args.push(Box::new(id));
            let ii = args.len();
            sql.push_str(&format!(
                " AND (created_at < ${ti} OR (created_at = ${ti} AND id < ${ii}))"
            ));
        }
        args.push(Box::new((limit + 1) as i64));
        sql.push_str(&format!(
            " ORDER BY created_at DESC, id DESC LIMIT ${}",
            args.len()
        ));
        let pool = self.pool.clone();
        self.block(async move {
            let c = pool.get().await.map_err(pool_error)?;
            let params: Vec<&(dyn ToSql + Sync)> = args
                .iter()
                .map(|a| a.as_ref() as &(dyn ToSql + Sync))
                .collect();
            let rows = c.query(&sql, &params).await.map_err(db_error)?;
            let mut jobs = Vec::with_capacity(rows.len());
            for r in rows {
                jobs.push(
                    serde_json::from_str::<JobRecord>(r.get::<_, &str>(0)).map_err(json_error)?,
                );
            }
            let next = if jobs.len() > limit {
                jobs.truncate(limit);
                jobs.last().map(encode_cursor)
            } else {
                None
            };
            Ok(ListPage { jobs, next })
        })
    }

    fn claim_next(&self, now: DateTime<Utc>) -> Result<Option<JobRecord>, StoreError> {
        let owner = self.owner.clone();
        let until = self.lease_until(now);
        self.write(move |tx| {
            Box::pin(async move {
                let row = tx
                    .query_opt(
                        "SELECT record FROM jobs WHERE status = 'enqueued' ORDER BY created_at, id
                     LIMIT 1 FOR UPDATE SKIP LOCKED",
                        &[],
                    )
                    .await
                    .map_err(db_error)?;
                let Some(row) = row else { return Ok(None) };
                let mut job: JobRecord =
                    serde_json::from_str(row.get::<_, &str>(0)).map_err(json_error)?;
                job.status = JobStatus::Processing;
                job.started_at = Some(now);
                job.attempts += 1;
                job.progress = JobProgress::default();
                job.revision += 1;
                update_record(tx, &job, &owner).await?;
                tx.execute(
                    "UPDATE jobs SET lease_owner = $2, lease_until = $3, cancel_requested = FALSE
                 WHERE id = $1",
                    &[&job.id.to_string(), &owner, &until],
                )
                .await
                .map_err(db_error)?;
                Ok(Some(job))
            })
        })
    }

    fn update_progress(&self, id: Uuid, progress: &JobProgress) -> Result<(), StoreError> {
        let owner = self.owner.clone();
        let progress = progress.clone();
        self.write(move |tx| {
            Box::pin(async move {
                let (mut job, holder) = load(&*tx, id, true)
                    .await?
                    .ok_or(StoreError::NotFound(id))?;
                if job.status != JobStatus::Processing
                    || job.progress == progress
                    || !holds(&holder, &owner)
                {
                    return Ok(());
                }
                job.progress = progress;
                job.revision += 1;
                update_record(tx, &job, &owner).await?;
                Ok(())
            })
        })
    }

    fn finish(
        &self,
        id: Uuid,
        outcome: Finish,
        now: DateTime<Utc>,
    ) -> Result<JobRecord, StoreError> {
        let owner = self.owner.clone();
        self.write(move |tx| {
            Box::pin(async move {
                let (mut job, holder) = load(&*tx, id, true)
                    .await?
                    .ok_or(StoreError::NotFound(id))?;
                if job.status.is_terminal() {
                    return Err(conflict(&job, "finish a finished job"));
                }
                if job.status == JobStatus::Processing && !holds(&holder, &owner) {
                    return Err(conflict(&job, "finish a job leased by another replica"));
                }
                outcome.apply(&mut job, now);
                update_record(tx, &job, &owner).await?;
                Ok(job)
            })
        })
    }

    fn cancel_if_enqueued(&self, id: Uuid, now: DateTime<Utc>) -> Result<JobRecord, StoreError> {
        let owner = self.owner.clone();
        self.write(move |tx| {
            Box::pin(async move {
                let (mut job, _) = load(&*tx, id, true)
                    .await?
                    .ok_or(StoreError::NotFound(id))?;
                match job.status {
                    JobStatus::Enqueued => {
                        job.status = JobStatus::Canceled;
                        job.finished_at = Some(now);
                        job.revision += 1;
                        update_record(tx, &job, &owner).await?;
                    }
                    JobStatus::Processing => {
                        // The lease holder hears of it through the change feed at once, or
                        // sees the flag at its next heartbeat.
                        tx.execute(
                            "UPDATE jobs SET cancel_requested = TRUE WHERE id = $1",
                            &[&id.to_string()],
                        )
                        .await
                        .map_err(db_error)?;
                        notify(tx, &job, &owner, true).await?;
                    }
                    _ => return Err(conflict(&job, "cancel a finished job")),
                }
                Ok(job)
            })
        })
    }

    fn recover(&self, max_attempts: u32, now: DateTime<Utc>) -> Result<Recovery, StoreError> {
        self.requeue_processing(max_attempts, now, false)
    }

    fn requeue_stopped(
        &self,
        ids: &[Uuid],
        _now: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        let owner = self.owner.clone();
        let ids = ids.to_vec();
        self.write(move |tx| {
            Box::pin(async move {
                let mut out = Vec::with_capacity(ids.len());
                for id in ids {
                    let Some((mut job, holder)) = load(&*tx, id, true).await? else {
                        continue;
                    };
                    if job.status != JobStatus::Processing || !holds(&holder, &owner) {
                        continue;
                    }
                    job.status = JobStatus::Enqueued;
                    job.progress = JobProgress::default();
                    job.attempts = job.attempts.saturating_sub(1);
                    job.revision += 1;
                    update_record(tx, &job, &owner).await?;
                    out.push(job);
                }
                Ok(out)
            })
        })
    }

    fn delete(&self, id: Uuid) -> Result<JobRecord, StoreError> {
        self.write(move |tx| {
            Box::pin(async move {
                let (job, _) = load(&*tx, id, true)
                    .await?
                    .ok_or(StoreError::NotFound(id))?;
                if !job.status.is_terminal() {
                    return Err(conflict(&job, "delete an unfinished job"));
                }
                tx.execute("DELETE FROM jobs WHERE id = $1", &[&id.to_string()])
                    .await
                    .map_err(db_error)?;
                Ok(job)
            })
        })
    }

    fn prune(
        &self,
        finished_before: DateTime<Utc>,
        keys_before: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.write(move |tx| {
            Box::pin(async move {
                let rows = tx
                    .query(
                        "DELETE FROM jobs WHERE finished_at IS NOT NULL AND finished_at < $1
                     AND status IN ('succeeded', 'failed', 'canceled') RETURNING record",
                        &[&nanos(finished_before)],
                    )
                    .await
                    .map_err(db_error)?;
                let mut removed = Vec::with_capacity(rows.len());
                for r in rows {
                    removed.push(
                        serde_json::from_str::<JobRecord>(r.get::<_, &str>(0))
                            .map_err(json_error)?,
                    );
                }
                removed.sort_by_key(|j| (j.created_at, j.id));
                let cutoff = nanos(keys_before);
                tx.execute(
                    "UPDATE jobs SET idempotency_key = NULL WHERE idempotency_key IN
                 (SELECT key FROM idempotency_keys WHERE created_at < $1)",
                    &[&cutoff],
                )
                .await
                .map_err(db_error)?;
                tx.execute(
                    "DELETE FROM idempotency_keys WHERE created_at < $1",
                    &[&cutoff],
                )
                .await
                .map_err(db_error)?;
                Ok(removed)
            })
        })
    }

    fn counts(&self) -> Result<StatusCounts, StoreError> {
        let pool = self.pool.clone();
        self.block(async move {
            let c = pool.get().await.map_err(pool_error)?;
            let rows = c
                .query("SELECT status, COUNT(*) FROM jobs GROUP BY status", &[])
                .await
                .map_err(db_error)?;
            let mut by_status = Vec::new();
            for r in rows {
                let s: &str = r.get(0);
                let status = JobStatus::parse(s)
                    .ok_or_else(|| StoreError::Database(format!("unknown status {s:?} in jobs")))?;
                by_status.push((status, r.get::<_, i64>(1) as u64));
            }
            by_status.sort_by_key(|(s, _)| *s as u8);
            let oldest: Option<i64> = c
                .query_one(
                    "SELECT MIN(created_at) FROM jobs WHERE status = 'enqueued'",
                    &[],
                )
                .await
                .map_err(db_error)?
                .get(0);
            Ok(StatusCounts {
                by_status,
                oldest_enqueued: oldest.map(from_nanos),
            })
        })
    }

    fn lease_duration(&self) -> Option<Duration> {
        Some(self.lease)
    }

    fn heartbeat(&self, id: Uuid, now: DateTime<Utc>) -> Result<Lease, StoreError> {
        let pool = self.pool.clone();
        let owner = self.owner.clone();
        let until = self.lease_until(now);
        self.block(async move {
            let c = pool.get().await.map_err(pool_error)?;
            let row = c
                .query_opt(
                    "UPDATE jobs SET lease_until = $3
                     WHERE id = $1 AND status = 'processing' AND lease_owner = $2
                     RETURNING cancel_requested",
                    &[&id.to_string(), &owner, &until],
                )
                .await
                .map_err(db_error)?;
            Ok(match row {
                Some(r) => Lease::Held {
                    cancel_requested: r.get(0),
                },
                None => Lease::Lost,
            })
        })
    }

    fn reclaim_expired(
        &self,
        max_attempts: u32,
        now: DateTime<Utc>,
    ) -> Result<Recovery, StoreError> {
        self.requeue_processing(max_attempts, now, true)
    }

    /// Starts the change feed ([`listen`]) and waits up to the connect timeout for its first
    /// `LISTEN`, so that every change committed after this returns is delivered (a feed that is
    /// not up by then keeps trying in the background; polling covers the gap).
    fn watch_changes(&self, sink: ChangeSink) -> bool {
        let rt = self.runtime.as_ref().expect("runtime lives until drop");
        let (ready, listening) = std::sync::mpsc::sync_channel(1);
        rt.spawn(listen::feed(
            self.config.clone(),
            self.owner.clone(),
            sink,
            ready,
        ));
        if listening.recv_timeout(CONNECT_TIMEOUT * 2).is_err() {
            tracing::warn!("job change feed not listening yet; idle workers poll until it is");
        }
        true
    }
}
