//! The job runner: the one place that knows both the service and the engine (DESIGN.md
//! "Layout"). It claims enqueued jobs from the [`JobStore`], reads their inputs from the
//! [`BlobStore`], runs [`crate::engine::pipeline::transfer`] on a dedicated rayon pool under a
//! [`Control`], publishes progress, and stores the results.
//!
//! Threads: the engine never runs on a tokio thread. Each job is `spawn`ed onto the rayon pool
//! of a free worker slot (threads `retex-engine-<slot>-<i>`; one pool per slot, so a thread of
//! one job never steals another job's engine call) and awaited through a `tokio::sync::oneshot`, inside
//! `catch_unwind`: a panic fails that job with its message and the process lives on. Store calls
//! from async code go through `spawn_blocking`.
//!
//! Progress: while a job runs, its task samples `Control::progress` every
//! [`RunnerConfig::progress_interval`]; each change is broadcast as a [`JobEvent`] and written
//! to the store at most every [`DB_PROGRESS_INTERVAL`]. A [`JobEvent::revision`] is the
//! revision of the stored record the event is at or after (progress events between two store
//! writes share it).
//!
//! Durability order on success: the result model and every artifact are written under
//! deterministic, attempt-scoped keys (`jobs/<id>/outputs/a<attempt>/<name>`) with create-only
//! puts ([`BlobStore::put_new`]), then the job flips to `succeeded` in one transaction, so a
//! `kill -9` at any point leaves either a processing job (re-run after restart by
//! [`JobStore::recover`], as the next attempt, under its own keys) or a finished job whose files
//! exist. An attempt never writes over another's files: a replica that lost its lease and still
//! finishes its engine call writes under its own attempt's keys, the store refuses its finish,
//! and it deletes what it wrote; the committed attempt's files are untouched.
//!
//! Cancellation: [`Runner::cancel`] flips the job's Control and wakes the job's task, which
//! finishes the job as `canceled` in the store at once (clients never wait on the engine). The
//! engine stops at its next Control check (every long loop checks); until then the worker slot
//! stays taken, so at most `workers` engine calls ever run. Results of an engine call that
//! completes after the cancel are discarded. On [`Runner::shutdown`] the jobs still running
//! after the deadline are cancelled the same way but put back to `enqueued` instead (they run
//! again after restart); such a stop gives back the attempt, so rolling restarts never fail a
//! job with `too-many-attempts`; only crashes (a job found processing at start) count.
//!
//! Replicas (a store with [`JobStore::lease_duration`], i.e. PostgreSQL): while a job runs its
//! task renews the lease every third of the lease time (at most every second) with
//! [`JobStore::heartbeat`], which also brings a cancel sent through another replica (handled as
//! a local cancel); a lost lease (another replica reclaimed the job) stops the engine and
//! records nothing. Every dispatcher tick ([`RunnerConfig::poll`]) re-enqueues jobs whose lease
//! expired ([`JobStore::reclaim_expired`]). A store with a change feed
//! ([`JobStore::watch_changes`], PostgreSQL's `LISTEN`/`NOTIFY`) tells the runner what other
//! replicas commit: a job enqueued through another replica wakes an idle worker at once (the
//! tick stays as the fallback), a cancel reaches the running job without waiting for the next
//! heartbeat, and the status and stored progress of jobs running elsewhere reach this
//! process's event streams, so any replica serves SSE for any job. With [`RunnerConfig::claim`] off (role `api`) the runner
//! claims nothing and runs no recovery: it only relays events and cancels.

use std::cell::Cell;
use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use chrono::Utc;
use sha2::{Digest, Sha256};
use tokio::sync::{broadcast, oneshot, watch, Notify};
use uuid::Uuid;

use super::preview::{
    amend_report, combined_progress, render_previews, PreviewInput, INPUT_SIZE, INPUT_VIEWS,
    RESULT_SIZE, RESULT_VIEWS,
};
use crate::engine::asset::constraints::{Constraints, OutputFormat};
use crate::engine::asset::{BlobSet, IngestLimits};
use crate::engine::control::Control;
use crate::engine::methods::Registry;
use crate::engine::pipeline::{
    transfer_with, ImageInput, ModelInput, TransferError, TransferInput,
};
use crate::service::model::{ArtifactRef, JobProgress, JobRecord, JobStatus, ModelFiles, Problem};
use crate::service::problem_table::{
    constraints_problem, internal_problem, panic_problem, result_not_stored_problem,
    texture_size_problem, transfer_problem,
};
use crate::service::store::{BlobStore, Finish, JobChange, JobStore, Lease, StoreError};

/// Store writes of progress are at most this frequent per job.
pub const DB_PROGRESS_INTERVAL: Duration = Duration::from_millis(500);
/// How long a cancel for a job that is not running (yet) is remembered.
const EARLY_CANCEL_TTL: Duration = Duration::from_secs(30);
/// After the shutdown deadline, how long cancelled jobs get to stop.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);
/// Quick tries of storing a job's terminal state.
const FINISH_ATTEMPTS: u32 = 4;
/// Slow rounds (one per `storage_retry`) before a success that cannot be recorded is recorded
/// as a failure instead (see [`Runner::store_finish`]).
pub const FINISH_SLOW_ROUNDS: u32 = 5;
/// Capacity of the event channel (slow subscribers miss events and see `Lagged`).
const EVENT_CAPACITY: usize = 1024;

thread_local! {
    static ENGINE_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// Gives the calling engine thread a lower scheduling priority (nice +10) so that, with every
/// core busy on long jobs, the HTTP threads still answer polls promptly. On Linux `setpriority`
/// with `who = 0` applies to the calling thread only. Failure is harmless and ignored.
fn lower_thread_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: setpriority reads no memory of ours; it only changes the calling thread's nice value.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, 10);
    }
}

/// True when called on one of the runner's engine threads.
pub fn on_engine_thread() -> bool {
    ENGINE_THREAD.with(Cell::get)
}

/// Configuration of the [`Runner`].
#[derive(Clone, Debug)]
pub struct RunnerConfig {
    /// Engine threads and jobs run at once. Default: the number of cores.
    pub workers: usize,
    /// Starts of one job before recovery fails it instead of re-enqueueing. Default: 3.
    pub max_attempts: u32,
    /// Ingest limits of both models.
    pub limits: IngestLimits,
    /// Largest `output.texture_size` a job may ask for, in texels. Default: 8192.
    pub max_texture_size: u32,
    /// How often a running job's progress is sampled. Default: 100 ms.
    pub progress_interval: Duration,
    /// The methods jobs may run. Default: [`Registry::builtin`].
    pub registry: Registry,
    /// After a job's output write hit a full disk, how long no job is claimed (the job goes
    /// back to the queue). Default: 30 s.
    pub storage_retry: Duration,
    /// Claim and run jobs (roles `worker` and `all`); off for role `api`. Default: on.
    pub claim: bool,
    /// The dispatcher looks for work (and reclaims expired leases) at least this often even
    /// when nothing wakes it. Default: 1 s.
    pub poll: Duration,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            workers: std::thread::available_parallelism().map_or(2, |n| n.get()),
            max_attempts: 3,
            limits: IngestLimits::default(),
            max_texture_size: 8192,
            progress_interval: Duration::from_millis(100),
            registry: Registry::builtin(),
            storage_retry: Duration::from_secs(30),
            claim: true,
            poll: Duration::from_secs(1),
        }
    }
}

/// A change of a job's status or progress.
#[derive(Clone, Debug, serde::Serialize)]
pub struct JobEvent {
    /// The job.
    pub id: Uuid,
    /// Its status after the change.
    pub status: JobStatus,
    /// Its progress after the change.
    pub progress: JobProgress,
    /// The stored revision the event is at or after.
    pub revision: u64,
}

/// A job running here.
struct Running {
    control: Control,
    /// The preview stage's control (see [`super::preview`]).
    preview: Control,
    /// Cancel requested by a client: finish as canceled.
    client_cancel: AtomicBool,
    /// Stopped by shutdown: put back to enqueued.
    requeue: AtomicBool,
    /// Wakes the job's task when a client cancels.
    cancel_wake: Notify,
}

/// A test hook run on the engine thread right before the engine call (see
/// [`Runner::set_engine_hook`]).
#[doc(hidden)]
pub type EngineHook = Arc<dyn Fn(&JobRecord) + Send + Sync>;

/// How a job ended on the engine side.
enum Outcome {
    Succeeded {
        artifacts: Vec<ArtifactRef>,
        report: serde_json::Value,
        timings: Vec<(String, f64)>,
    },
    Failed(Problem),
    Canceled,
    /// Storing the outputs hit a full disk (the detail is for the log): not the job's fault.
    StorageFull(String),
}

/// Claims and runs jobs; see the module docs.
pub struct Runner {
    config: RunnerConfig,
    jobs: Arc<dyn JobStore>,
    blobs: Arc<dyn BlobStore>,
    /// One rayon pool per worker slot: a thread of one job that waits inside a parallel loop
    /// would otherwise steal another job's whole engine call and block its own job behind it.
    pools: Vec<(Arc<rayon::ThreadPool>, Arc<AtomicBool>)>,
    running: Mutex<HashMap<Uuid, Arc<Running>>>,
    early_cancels: Mutex<HashMap<Uuid, Instant>>,
    wake: Notify,
    busy: watch::Sender<usize>,
    events: broadcast::Sender<JobEvent>,
    stopping: AtomicBool,
    stage_times: Mutex<Vec<(String, f64)>>,
    hook: Mutex<Option<EngineHook>>,
    dispatcher: Mutex<Option<tokio::task::JoinHandle<()>>>,
    /// When storage last failed (see [`storage`]); no job is claimed for `storage_retry` after.
    storage_failed: Mutex<Option<Instant>>,
    /// The last storage probe of `/readyz` ([`Runner::storage_healthy`]).
    probed: Mutex<Option<storage::Probed>>,
}

#[path = "runner_storage.rs"]
mod storage;

impl std::fmt::Debug for Runner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Runner")
            .field("config", &self.config)
            .field("busy", &*self.busy.borrow())
            .finish_non_exhaustive()
    }
}

fn locked<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "non-string panic payload".to_string())
}

impl Runner {
    /// Builds one rayon pool per worker slot (threads `retex-engine-<slot>-<i>`), runs
    /// [`JobStore::recover`], and spawns the dispatcher task that claims jobs while fewer than
    /// `workers` run (woken by [`Runner::notify`] and by a periodic tick).
    ///
    /// # Errors
    /// When called outside a tokio runtime, when the pool cannot be built, or when recovery
    /// fails.
    pub fn start(
        config: RunnerConfig,
        jobs: Arc<dyn JobStore>,
        blobs: Arc<dyn BlobStore>,
    ) -> Result<Arc<Runner>, StoreError> {
        let handle = tokio::runtime::Handle::try_current().map_err(|_| {
            StoreError::Io(std::io::Error::other(
                "the runner must be started inside a tokio runtime",
            ))
        })?;
        let workers = config.workers.max(1);
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
        let mut pools = Vec::with_capacity(workers);
        for slot in 0..workers {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .thread_name(move |i| format!("retex-engine-{slot}-{i}"))
                .start_handler(|_| {
                    ENGINE_THREAD.with(|c| c.set(true));
                    lower_thread_priority();
                })
                .build()
                .map_err(|e| StoreError::Io(std::io::Error::other(format!("engine pool: {e}"))))?;
            pools.push((Arc::new(pool), Arc::new(AtomicBool::new(false))));
        }
        let recovery = if config.claim {
            jobs.recover(config.max_attempts, Utc::now())?
        } else {
            Default::default()
        };
        if !recovery.requeued.is_empty() || !recovery.failed.is_empty() {
            tracing::warn!(
                requeued = recovery.requeued.len(),
                failed = recovery.failed.len(),
                "recovered jobs interrupted by a previous stop"
            );
        }
        let runner = Arc::new(Runner {
            config: RunnerConfig { workers, ..config },
            jobs,
            blobs,
            pools,
            running: Mutex::new(HashMap::new()),
            early_cancels: Mutex::new(HashMap::new()),
            wake: Notify::new(),
            busy: watch::channel(0).0,
            events: broadcast::channel(EVENT_CAPACITY).0,
            stopping: AtomicBool::new(false),
            stage_times: Mutex::new(Vec::new()),
            hook: Mutex::new(None),
            dispatcher: Mutex::new(None),
            storage_failed: Mutex::new(None),
            probed: Mutex::new(None),
        });
        let weak = Arc::downgrade(&runner);
        let watched = runner.jobs.watch_changes(Box::new(move |change| {
            if let Some(r) = weak.upgrade() {
                r.on_remote_change(change);
            }
        }));
        if watched {
            tracing::info!("listening for job changes from other replicas");
        }
        let me = Arc::clone(&runner);
        let task = handle.spawn(async move { me.dispatch().await });
        *locked(&runner.dispatcher) = Some(task);
        Ok(runner)
    }

    /// Wakes the dispatcher: a job was enqueued.
    pub fn notify(&self) {
        self.wake.notify_one();
    }

    /// Requests cancellation of a processing job. True if it is running here (it stops within
    /// a second and ends `canceled`). False otherwise; the request is still remembered for
    /// 30 s, in case the job was claimed but has not registered yet.
    pub fn cancel(&self, id: Uuid) -> bool {
        if let Some(r) = locked(&self.running).get(&id) {
            r.client_cancel.store(true, Ordering::SeqCst);
            r.control.cancel();
            r.cancel_wake.notify_one();
            return true;
        }
        let mut early = locked(&self.early_cancels);
        early.retain(|_, at| at.elapsed() < EARLY_CANCEL_TTL);
        early.insert(id, Instant::now());
        false
    }

    /// Live progress of a job running here (`None` once a client canceled it: the stored
    /// record is then the truth).
    pub fn progress(&self, id: Uuid) -> Option<JobProgress> {
        let (control, preview) = {
            let running = locked(&self.running);
            let r = running.get(&id)?;
            if r.client_cancel.load(Ordering::SeqCst) {
                return None;
            }
            (r.control.clone(), r.preview.clone())
        };
        Some(combined_progress(control.progress(), preview.progress()))
    }

    /// A receiver of every status and progress change of every job from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<JobEvent> {
        self.events.subscribe()
    }

    /// Jobs running now.
    pub fn busy_workers(&self) -> usize {
        *self.busy.borrow()
    }

    /// The configured number of workers.
    pub fn workers(&self) -> usize {
        self.config.workers
    }

    /// Durations of the stages of jobs that succeeded since the last call, as
    /// (stage name, seconds), taken from the engine report's timings (`load`, `project`,
    /// `export`, ...). Draining: each duration is returned once, for a metrics histogram.
    pub fn stage_durations(&self) -> Vec<(String, f64)> {
        std::mem::take(&mut *locked(&self.stage_times))
    }

    /// Test hook: `hook` runs on the engine thread, inside the job's panic guard, right
    /// before the engine call of every job. Not part of the API.
    #[doc(hidden)]
    pub fn set_engine_hook(&self, hook: Option<EngineHook>) {
        *locked(&self.hook) = hook;
    }

    /// Graceful shutdown: stop claiming; wait up to `deadline` for running jobs; then cancel the
    /// rest and put them back to `enqueued` (they run again after restart).
    pub async fn shutdown(&self, deadline: Duration) {
        self.stopping.store(true, Ordering::SeqCst);
        self.wake.notify_one();
        let dispatcher = locked(&self.dispatcher).take();
        if let Some(d) = dispatcher {
            let _ = d.await;
        }
        let mut busy = self.busy.subscribe();
        if tokio::time::timeout(deadline, busy.wait_for(|n| *n == 0))
            .await
            .is_ok()
        {
            return;
        }
        let stopping: Vec<(Uuid, Arc<Running>)> = locked(&self.running)
            .iter()
            .map(|(id, r)| (*id, r.clone()))
            .collect();
        tracing::warn!(
            jobs = stopping.len(),
            "shutdown deadline passed: stopping running jobs to re-enqueue them"
        );
        for (_, r) in &stopping {
            r.requeue.store(true, Ordering::SeqCst);
            r.control.cancel();
        }
        if tokio::time::timeout(SHUTDOWN_GRACE, busy.wait_for(|n| *n == 0))
            .await
            .is_err()
        {
            tracing::error!("jobs did not stop within the grace period; re-enqueueing anyway");
        }
        let jobs = Arc::clone(&self.jobs);
        let ids: Vec<Uuid> = stopping.iter().map(|(id, _)| *id).collect();
        // A graceful stop does not count against `max_attempts` (only crashes do).
        let requeue = move || jobs.requeue_stopped(&ids, Utc::now());
        match tokio::task::spawn_blocking(requeue).await {
            Ok(Ok(records)) => {
                for j in records {
                    tracing::info!(id = %j.id, "job re-enqueued by shutdown");
                    self.emit(j.id, j.status, j.progress, j.revision);
                }
            }
            Ok(Err(e)) => tracing::error!(error = %e, "re-enqueueing jobs at shutdown failed"),
            Err(e) => tracing::error!(error = %e, "re-enqueueing jobs at shutdown panicked"),
        }
    }

    /// Broadcasts a change made outside the runner (a submission, the cancellation of a waiting
    /// job) to the event streams.
    pub fn announce(&self, record: &JobRecord) {
        self.emit(
            record.id,
            record.status,
            record.progress.clone(),
            record.revision,
        );
    }

    /// A change another replica committed ([`JobStore::watch_changes`]): an enqueued job wakes
    /// the dispatcher, a cancel request for a job running here cancels it as a client's
    /// would, and a job not running here has its change relayed to this process's event
    /// streams (a job running here already sends finer-grained events of its own).
    fn on_remote_change(&self, change: JobChange) {
        let here = locked(&self.running).contains_key(&change.id);
        if here && change.cancel_requested {
            tracing::info!(id = %change.id, "cancel requested through another replica");
            self.cancel(change.id);
        }
        if change.status == JobStatus::Enqueued && self.config.claim {
            self.wake.notify_one();
        }
        if !here {
            self.emit(change.id, change.status, change.progress, change.revision);
        }
    }

    fn emit(&self, id: Uuid, status: JobStatus, progress: JobProgress, revision: u64) {
        // No subscriber is not an error.
        let _ = self.events.send(JobEvent {
            id,
            status,
            progress,
            revision,
        });
    }

    /// Claims jobs while workers are free; sleeps until notified or the tick.
    async fn dispatch(self: Arc<Self>) {
        if !self.config.claim {
            return;
        }
        let leased = self.jobs.lease_duration().is_some();
        let mut last_reclaim: Option<Instant> = None;
        loop {
            if leased && last_reclaim.is_none_or(|t| t.elapsed() >= self.config.poll) {
                last_reclaim = Some(Instant::now());
                let (jobs, max) = (Arc::clone(&self.jobs), self.config.max_attempts);
                match tokio::task::spawn_blocking(move || jobs.reclaim_expired(max, Utc::now()))
                    .await
                {
                    Ok(Ok(r)) if !r.requeued.is_empty() || !r.failed.is_empty() => {
                        tracing::warn!(requeued = ?r.requeued, failed = ?r.failed, "reclaimed jobs whose lease expired");
                    }
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => tracing::warn!(error = %e, "reclaiming expired leases failed"),
                    Err(e) => tracing::warn!(error = %e, "reclaiming expired leases panicked"),
                }
            }
            while !self.stopping.load(Ordering::SeqCst)
                && self.busy_workers() < self.config.workers
                && !self.storage_paused()
            {
                let jobs = Arc::clone(&self.jobs);
                match tokio::task::spawn_blocking(move || jobs.claim_next(Utc::now())).await {
                    Ok(Ok(Some(job))) => self.launch(job),
                    Ok(Ok(None)) => break,
                    Ok(Err(e)) => {
                        tracing::error!(error = %e, "claiming a job failed");
                        break;
                    }
                    Err(e) => {
                        tracing::error!(error = %e, "claiming a job panicked");
                        break;
                    }
                }
            }
            if self.stopping.load(Ordering::SeqCst) {
                return;
            }
            tokio::select! {
                _ = self.wake.notified() => {}
                _ = tokio::time::sleep(self.config.poll) => {}
            }
        }
    }

    /// Registers a claimed job and spawns its task.
    fn launch(self: &Arc<Self>, job: JobRecord) {
        let running = Arc::new(Running {
            control: Control::new(),
            preview: Control::new(),
            client_cancel: AtomicBool::new(false),
            requeue: AtomicBool::new(false),
            cancel_wake: Notify::new(),
        });
        self.busy.send_modify(|n| *n += 1);
        locked(&self.running).insert(job.id, Arc::clone(&running));
        if locked(&self.early_cancels).remove(&job.id).is_some() {
            running.client_cancel.store(true, Ordering::SeqCst);
            running.control.cancel();
            running.cancel_wake.notify_one();
        }
        let me = Arc::clone(self);
        tokio::spawn(async move {
            let id = job.id;
            me.run(job, running).await;
            locked(&me.running).remove(&id);
            me.busy.send_modify(|n| *n -= 1);
            me.wake.notify_one();
        });
    }

    /// Runs one claimed job to its end.
    async fn run(&self, job: JobRecord, running: Arc<Running>) {
        let id = job.id;
        let span = tracing::info_span!("job", %id, method = %job.method, attempt = job.attempts);
        let _enter = span.enter();
        tracing::info!("job started");
        let control = running.control.clone();
        let preview = running.preview.clone();
        let mut revision = job.revision;
        self.emit(id, JobStatus::Processing, job.progress.clone(), revision);

        let (tx, mut rx) = oneshot::channel();
        let ctx = EngineCtx {
            blobs: Arc::clone(&self.blobs),
            limits: self.config.limits.clone(),
            max_texture_size: self.config.max_texture_size,
            registry: self.config.registry.clone(),
            hook: locked(&self.hook).clone(),
        };
        let engine_job = job.clone();
        let engine_control = control.clone();
        let preview_control = preview.clone();
        // A slot whose previous engine call has ended; there is one, because at most `workers`
        // jobs are busy and a job stays busy until its engine call returns.
        let (pool, in_use) = self
            .pools
            .iter()
            .find(|(_, in_use)| {
                in_use
                    .compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst)
                    .is_ok()
            })
            .cloned()
            .unwrap_or_else(|| self.pools[0].clone());
        pool.spawn(move || {
            let out = catch_unwind(AssertUnwindSafe(|| {
                execute(&ctx, &engine_job, &engine_control, &preview_control)
            }))
            .unwrap_or_else(|p| Outcome::Failed(panic_problem(&panic_message(p.as_ref()))));
            super::heap::release_freed_memory();
            in_use.store(false, Ordering::SeqCst);
            let _ = tx.send(out);
        });
        drop(_enter);

        let mut ticker = tokio::time::interval(self.config.progress_interval);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut last_sent = job.progress.clone();
        let mut last_stored = job.progress.clone();
        let mut last_store_at: Option<Instant> = None;
        let mut canceled = false;
        let mut lost = false;
        let lease = self.jobs.lease_duration();
        let beat = lease.map_or(Duration::from_secs(3600), |l| {
            (l / 3).clamp(Duration::from_millis(100), Duration::from_secs(1))
        });
        let mut heartbeat = tokio::time::interval(beat);
        heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let outcome = loop {
            tokio::select! {
                r = &mut rx => break r.unwrap_or_else(|_| {
                    Outcome::Failed(internal_problem("the engine worker was lost".into()))
                }),
                _ = running.cancel_wake.notified(), if !canceled => {
                    // The client sees `canceled` at once; the worker slot stays taken until the
                    // engine reaches its next cancel check and returns.
                    canceled = true;
                    self.store_finish(id, Finish::Canceled).await;
                }
                _ = heartbeat.tick(), if lease.is_some() && !canceled => {
                    let jobs = Arc::clone(&self.jobs);
                    match tokio::task::spawn_blocking(move || jobs.heartbeat(id, Utc::now())).await {
                        Ok(Ok(Lease::Held { cancel_requested: false })) => {}
                        Ok(Ok(Lease::Held { cancel_requested: true })) => {
                            tracing::info!(%id, "cancel requested through another replica");
                            running.client_cancel.store(true, Ordering::SeqCst);
                            control.cancel();
                            canceled = true;
                            self.store_finish(id, Finish::Canceled).await;
                        }
                        Ok(Ok(Lease::Lost)) => {
                            tracing::warn!(%id, "lease lost: another replica took the job; stopping it here");
                            control.cancel();
                            canceled = true;
                            lost = true;
                        }
                        Ok(Err(e)) => tracing::warn!(%id, error = %e, "renewing the lease failed"),
                        Err(e) => tracing::warn!(%id, error = %e, "renewing the lease panicked"),
                    }
                }
                _ = ticker.tick(), if !canceled => {
                    let p = combined_progress(control.progress(), preview.progress());
                    if p == last_sent {
                        continue;
                    }
                    last_sent = p.clone();
                    let due = last_store_at.is_none_or(|t| t.elapsed() >= DB_PROGRESS_INTERVAL);
                    if due && p != last_stored {
                        last_store_at = Some(Instant::now());
                        let jobs = Arc::clone(&self.jobs);
                        let stored = p.clone();
                        match tokio::task::spawn_blocking(move || jobs.update_progress(id, &stored)).await {
                            Ok(Ok(())) => {
                                revision += 1;
                                last_stored = p.clone();
                            }
                            Ok(Err(e)) => tracing::warn!(%id, error = %e, "storing progress failed"),
                            Err(e) => tracing::warn!(%id, error = %e, "storing progress panicked"),
                        }
                    }
                    self.emit(id, JobStatus::Processing, p, revision);
                }
            }
        };

        if canceled {
            if let Outcome::Succeeded { artifacts, .. } = &outcome {
                self.discard_outputs(id, artifacts).await;
            }
            let how = match &outcome {
                Outcome::Succeeded { .. } => "succeeded",
                Outcome::Failed(_) | Outcome::StorageFull(_) => "failed",
                Outcome::Canceled => "canceled",
            };
            tracing::info!(%id, engine = how, lost, "canceled job's engine call returned");
            return;
        }
        // A job faster than the progress interval never stored its stage counts: store the
        // final ones before finishing, so the document reports the stages that ran.
        let last = combined_progress(control.progress(), preview.progress());
        if last.stages_total != last_stored.stages_total && !matches!(outcome, Outcome::Canceled) {
            let jobs = Arc::clone(&self.jobs);
            match tokio::task::spawn_blocking(move || jobs.update_progress(id, &last)).await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => tracing::warn!(%id, error = %e, "storing final progress failed"),
                Err(e) => tracing::warn!(%id, error = %e, "storing final progress panicked"),
            }
        }
        let stored = match &outcome {
            Outcome::Succeeded { artifacts, .. } => artifacts.clone(),
            _ => Vec::new(),
        };
        let finish = match outcome {
            Outcome::StorageFull(detail) => {
                self.requeue_after_full_disk(id, &detail).await;
                return;
            }
            Outcome::Succeeded {
                artifacts,
                report,
                timings,
            } => {
                locked(&self.stage_times).extend(timings);
                Finish::Succeeded { artifacts, report }
            }
            Outcome::Failed(error) => Finish::Failed {
                error,
                report: None,
            },
            Outcome::Canceled => {
                if running.requeue.load(Ordering::SeqCst)
                    && !running.client_cancel.load(Ordering::SeqCst)
                {
                    // Left processing; `shutdown` re-enqueues it.
                    tracing::info!(%id, "job stopped by shutdown");
                    return;
                }
                Finish::Canceled
            }
        };
        if !self.store_finish(id, finish).await {
            self.discard_outputs(id, &stored).await;
        }
    }

    /// Moves the job to its terminal state in the store and announces it. A store that refuses
    /// the write [`FINISH_ATTEMPTS`] times in a row (with 100 ms × 4ⁿ backoff) is retried
    /// slowly: the worker slot stays taken (the job is not over), claims pause, and the finish is
    /// tried again every `storage_retry`; after [`FINISH_SLOW_ROUNDS`] such rounds a success
    /// that still cannot be recorded becomes a failure with the stable type
    /// `/problems/result-not-stored` (a smaller record; the outputs stay until the job is
    /// pruned), retried the same way. Only a shutdown ends the retries early: the job is then
    /// left processing and the next start's recovery re-runs it. Returns false when the store
    /// refused the ending for good (the job was already terminal, deleted, or leased by another
    /// replica): the caller's outputs belong to no record then.
    async fn store_finish(&self, id: Uuid, finish: Finish) -> bool {
        let mut finish = finish;
        let mut rounds = 0u32;
        loop {
            match self.try_finish(id, &finish).await {
                Some(stored) => return stored,
                None if self.stopping.load(Ordering::SeqCst) => {
                    tracing::warn!(%id, "stopping with the job's end unrecorded; recovery re-runs it");
                    return true;
                }
                None => {}
            }
            if rounds == FINISH_SLOW_ROUNDS && matches!(finish, Finish::Succeeded { .. }) {
                tracing::error!(%id, rounds, "the job's success cannot be recorded; failing it");
                finish = Finish::Failed {
                    error: result_not_stored_problem(),
                    report: None,
                };
            }
            self.note_storage_failure();
            tokio::time::sleep(self.config.storage_retry).await;
            rounds += 1;
        }
    }

    /// [`FINISH_ATTEMPTS`] quick tries of storing `finish`: `Some(true)` stored, `Some(false)`
    /// refused for good (a conflict or a missing job is not retried), `None` not settled.
    async fn try_finish(&self, id: Uuid, finish: &Finish) -> Option<bool> {
        let mut delay = Duration::from_millis(100);
        for attempt in 1..=FINISH_ATTEMPTS {
            let jobs = Arc::clone(&self.jobs);
            let f = finish.clone();
            match tokio::task::spawn_blocking(move || jobs.finish(id, f, Utc::now())).await {
                Ok(Ok(rec)) => {
                    tracing::info!(%id, status = rec.status.as_str(), "job finished");
                    self.emit(id, rec.status, rec.progress.clone(), rec.revision);
                    return Some(true);
                }
                Ok(Err(e @ (StoreError::Conflict { .. } | StoreError::NotFound(_)))) => {
                    tracing::warn!(%id, error = %e, "job not finished");
                    return Some(false);
                }
                Ok(Err(e)) => {
                    if e.is_storage_failure() {
                        self.note_storage_failure();
                    }
                    tracing::error!(%id, attempt, error = %e, "finishing the job failed")
                }
                Err(e) => tracing::error!(%id, attempt, error = %e, "finishing the job panicked"),
            }
            if attempt < FINISH_ATTEMPTS {
                tokio::time::sleep(delay).await;
                delay *= 4;
            }
        }
        None
    }
}

/// What the engine side of a job needs.
struct EngineCtx {
    blobs: Arc<dyn BlobStore>,
    limits: IngestLimits,
    max_texture_size: u32,
    registry: Registry,
    hook: Option<EngineHook>,
}

fn read_model(blobs: &dyn BlobStore, files: &ModelFiles) -> Result<BlobSet, StoreError> {
    let mut set = BlobSet::new();
    for (name, key) in &files.files {
        set.insert(name.clone(), blobs.get(key)?);
    }
    Ok(set)
}

/// The engine side of a job; runs on an engine thread.
fn execute(ctx: &EngineCtx, job: &JobRecord, control: &Control, preview: &Control) -> Outcome {
    if let Some(hook) = &ctx.hook {
        hook(job);
    }
    let read = |files: &Option<ModelFiles>| -> Result<Option<BlobSet>, StoreError> {
        files
            .as_ref()
            .map(|f| read_model(ctx.blobs.as_ref(), f))
            .transpose()
    };
    let inputs = (|| -> Result<_, StoreError> {
        let source = read(&job.inputs.source)?;
        let pattern = match &job.inputs.pattern {
            Some(key) => Some(ctx.blobs.get(key)?),
            None => None,
        };
        Ok((
            source,
            read_model(ctx.blobs.as_ref(), &job.inputs.target)?,
            read(&job.inputs.source_base)?,
            pattern,
            ctx.blobs.get(&job.inputs.constraints)?,
        ))
    })();
    let (source, target, source_base, pattern, constraints) = match inputs {
        Ok(i) => i,
        Err(e) => return Outcome::Failed(internal_problem(format!("reading the inputs: {e}"))),
    };
    let constraints = match Constraints::from_json(&constraints) {
        Ok(c) => c,
        Err(e) => return Outcome::Failed(constraints_problem(&e)),
    };
    if constraints.output.texture_size > ctx.max_texture_size {
        return Outcome::Failed(texture_size_problem(
            constraints.output.texture_size,
            ctx.max_texture_size,
        ));
    }
    let mut input = TransferInput::new(
        ModelInput {
            main: &job.inputs.target.main,
            blobs: &target,
        },
        constraints,
    )
    .with_limits(ctx.limits.clone());
    if let (Some(files), Some(blobs)) = (&job.inputs.source, &source) {
        input = input.with_source(ModelInput {
            main: &files.main,
            blobs,
        });
    }
    if let (Some(files), Some(blobs)) = (&job.inputs.source_base, &source_base) {
        input = input.with_source_base(ModelInput {
            main: &files.main,
            blobs,
        });
    }
    if let Some(bytes) = &pattern {
        input = input.with_pattern(ImageInput {
            name: "pattern",
            bytes,
        });
    }
    let out = match transfer_with(&ctx.registry, &input, control) {
        Ok(out) => out,
        Err(TransferError::Cancelled) => return Outcome::Canceled,
        Err(e) => return Outcome::Failed(transfer_problem(&e)),
    };
    drop(input);
    drop((source_base, pattern));
    if control.is_cancelled() {
        // Canceled after the engine's last check: the client already sees `canceled`.
        return Outcome::Canceled;
    }
    let (name, media_type) = match out.format {
        OutputFormat::Glb => ("result.glb", "model/gltf-binary"),
        OutputFormat::Gltf => ("result.gltf", "model/gltf+json"),
    };
    let mut result = BlobSet::new();
    // A copy: the blob set cannot give its bytes back, and the result is stored below.
    result.insert(name, out.model.clone());
    let mut models = vec![PreviewInput {
        artifact: "preview.png",
        stage: "preview: result",
        main: name,
        blobs: &result,
        views: RESULT_VIEWS,
        size: RESULT_SIZE,
    }];
    if let (Some(files), Some(blobs)) = (&job.inputs.source, &source) {
        models.push(PreviewInput {
            artifact: "source_preview.png",
            stage: "preview: source",
            main: &files.main,
            blobs,
            views: INPUT_VIEWS,
            size: INPUT_SIZE,
        });
    }
    models.push(PreviewInput {
        artifact: "target_preview.png",
        stage: "preview: target",
        main: &job.inputs.target.main,
        blobs: &target,
        views: INPUT_VIEWS,
        size: INPUT_SIZE,
    });
    let Some(previews) = render_previews(&models, &ctx.limits, preview, || control.is_cancelled())
    else {
        return Outcome::Canceled;
    };
    drop(models);
    drop((source, target, result));
    let mut report = serde_json::to_value(&out.report).unwrap_or_default();
    amend_report(&mut report, preview, &previews.warnings);
    let mut files: Vec<(String, String, Vec<u8>)> = Vec::with_capacity(out.artifacts.len() + 4);
    files.push((name.into(), media_type.into(), out.model));
    for a in out.artifacts {
        let bytes = if a.name == "report.json" {
            serde_json::to_vec_pretty(&report).unwrap_or(a.bytes)
        } else {
            a.bytes
        };
        files.push((a.name, a.media_type, bytes));
    }
    for (name, png) in previews.files {
        files.push((name, "image/png".into(), png));
    }
    let mut artifacts = Vec::with_capacity(files.len());
    for (name, media_type, bytes) in files {
        let key = format!("{}{name}", outputs_prefix(job));
        if let Err(e) = put_output(ctx.blobs.as_ref(), &key, &bytes) {
            if e.is_storage_full() {
                return Outcome::StorageFull(format!("storing {name}: {e}"));
            }
            tracing::error!(id = %job.id, error = %e, "storing {name} failed");
            return Outcome::Failed(internal_problem(format!(
                "storing {name} failed; the details are in the server log"
            )));
        }
        artifacts.push(ArtifactRef {
            name,
            media_type,
            key,
            size: bytes.len() as u64,
            sha256: hex::encode(Sha256::digest(&bytes)),
        });
    }
    let timings = out
        .report
        .timings
        .iter()
        .chain(&preview.timings())
        .map(|t| (t.stage.clone(), t.ms / 1e3))
        .collect();
    Outcome::Succeeded {
        artifacts,
        report,
        timings,
    }
}

/// The folder of this attempt's outputs: `jobs/<id>/outputs/a<attempt>/`.
pub fn outputs_prefix(job: &JobRecord) -> String {
    format!("jobs/{}/outputs/a{}/", job.id, job.attempts)
}

/// Stores one output with a create-only put. The same bytes already there (the same attempt
/// number after a graceful stop gave the attempt back) are accepted; other bytes are an error,
/// never overwritten.
fn put_output(blobs: &dyn BlobStore, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
    match blobs.put_new(key, bytes) {
        Err(StoreError::BlobExists(k)) => match blobs.get(key) {
            Ok(stored) if stored == bytes => Ok(()),
            _ => Err(StoreError::BlobExists(k)),
        },
        other => other,
    }
}
