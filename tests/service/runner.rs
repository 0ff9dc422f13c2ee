//! The job runner on a real SQLite store and blob folder: a job on Spot (`tests/data`) succeeds
//! and its GLB loads; bad constraints fail naming the field; the engine runs only on engine
//! threads; a panic fails one job and the runner keeps working; a processing job is canceled
//! promptly (about a second; asserted within a generous 5 s); at most `workers` jobs run;
//! shutdown re-enqueues a running job without counting the attempt.
#![cfg(feature = "service")]

use crate::common;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use chrono::Utc;
use retex::engine::asset::{load, BlobSet, IngestLimits};
use retex::service::jobs::runner::{on_engine_thread, Runner, RunnerConfig};
use retex::service::model::{JobInputs, JobProgress, JobRecord, JobStatus, ModelFiles};
use retex::service::store::fs::FsBlobStore;
use retex::service::store::sqlite::SqliteJobStore;
use retex::service::store::{BlobStore, CreateOutcome, JobStore};
use sha2::{Digest, Sha256};
use uuid::Uuid;

const SPOT: &str = "src_spot_keenan/spot_textured_derived.glb";

struct Env {
    dir: PathBuf,
    jobs: Arc<SqliteJobStore>,
    blobs: Arc<FsBlobStore>,
}

impl Drop for Env {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn env() -> Env {
    let dir = std::env::temp_dir().join(format!("retex-runner-{}", Uuid::new_v4()));
    let jobs = Arc::new(SqliteJobStore::open(&dir.join("jobs.sqlite")).unwrap());
    let blobs = Arc::new(FsBlobStore::open(&dir.join("data")).unwrap());
    Env { dir, jobs, blobs }
}

fn config(workers: usize) -> RunnerConfig {
    RunnerConfig {
        workers,
        max_attempts: 3,
        limits: IngestLimits::default(),
        max_texture_size: 8192,
        progress_interval: Duration::from_millis(50),
        ..RunnerConfig::default()
    }
}

fn start(env: &Env, workers: usize) -> Arc<Runner> {
    Runner::start(config(workers), env.jobs.clone(), env.blobs.clone()).unwrap()
}

/// Stores a model's files the way the HTTP layer does and returns their blob keys.
fn store_model(blobs: &FsBlobStore, id: Uuid, side: &str, path: &Path) -> ModelFiles {
    let (main, set) = BlobSet::from_path(path).unwrap();
    let mut files = Vec::new();
    for name in set.names() {
        let key = format!("jobs/{id}/inputs/{side}/{name}");
        blobs.put(&key, set.get(name).unwrap()).unwrap();
        files.push((name.to_string(), key));
    }
    ModelFiles { main, files }
}

/// Writes the inputs and an enqueued record, as `POST /v1/jobs` would, and wakes the runner.
fn submit(env: &Env, runner: &Runner, asset: &str, constraints: &str) -> Uuid {
    let id = Uuid::now_v7();
    let path = common::test_data(asset);
    let source = store_model(&env.blobs, id, "source", &path);
    let target = store_model(&env.blobs, id, "target", &path);
    let ckey = format!("jobs/{id}/inputs/constraints.json");
    env.blobs.put(&ckey, constraints.as_bytes()).unwrap();
    let job = JobRecord {
        id,
        status: JobStatus::Enqueued,
        method: "project".into(),
        progress: JobProgress::default(),
        created_at: Utc::now(),
        started_at: None,
        finished_at: None,
        error: None,
        report: None,
        attempts: 0,
        idempotency_key: None,
        owner: None,
        request_hash: hex::encode(Sha256::digest(constraints.as_bytes())),
        inputs: JobInputs {
            source: Some(source),
            target,
            source_base: None,
            constraints: ckey,
            pattern: None,
        },
        artifacts: vec![],
        revision: 1,
    };
    assert_eq!(env.jobs.create(&job).unwrap(), CreateOutcome::Created);
    runner.notify();
    id
}

async fn wait_until(
    env: &Env,
    id: Uuid,
    timeout: Duration,
    what: &str,
    pred: impl Fn(&JobRecord) -> bool,
) -> JobRecord {
    let end = Instant::now() + timeout;
    loop {
        let j = env.jobs.get(id).unwrap().unwrap();
        if pred(&j) {
            return j;
        }
        assert!(
            Instant::now() < end,
            "job {id} not {what} within {timeout:?}: {j:?}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Polls `cond` until it holds; fails after `timeout`.
async fn eventually(what: &str, timeout: Duration, cond: impl Fn() -> bool) {
    let end = Instant::now() + timeout;
    while !cond() {
        assert!(Instant::now() < end, "{what}: not within {timeout:?}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

async fn wait_terminal(env: &Env, id: Uuid) -> JobRecord {
    wait_until(env, id, Duration::from_secs(300), "finished", |j| {
        j.status.is_terminal()
    })
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_succeeds_on_an_engine_thread_and_its_glb_loads() {
    let env = env();
    let runner = start(&env, 2);
    let seen: Arc<Mutex<Vec<(bool, String)>>> = Arc::default();
    let s = seen.clone();
    runner.set_engine_hook(Some(Arc::new(move |_job: &JobRecord| {
        let name = std::thread::current().name().unwrap_or("").to_string();
        s.lock().unwrap().push((on_engine_thread(), name));
    })));
    let mut events = runner.subscribe();
    assert!(
        !on_engine_thread(),
        "a tokio thread is not an engine thread"
    );

    let id = submit(
        &env,
        &runner,
        SPOT,
        r#"{"version":1,"output":{"texture_size":256}}"#,
    );
    let job = wait_terminal(&env, id).await;
    assert_eq!(job.status, JobStatus::Succeeded, "{:?}", job.error);
    assert_eq!(job.attempts, 1);
    assert_eq!(job.progress.fraction, 1.0);
    assert!(job.finished_at >= job.started_at && job.started_at.is_some());
    assert!(job.report.as_ref().unwrap().get("timings").is_some());

    let seen = seen.lock().unwrap().clone();
    assert_eq!(seen.len(), 1);
    assert!(seen[0].0, "the engine ran off the engine pool: {seen:?}");
    assert!(seen[0].1.starts_with("retex-engine-"), "{seen:?}");

    // Results: the model first, every artifact stored with its size and hash.
    assert_eq!(job.artifacts[0].name, "result.glb");
    assert_eq!(job.artifacts[0].media_type, "model/gltf-binary");
    assert!(job.artifacts.iter().any(|a| a.name == "report.json"));
    for a in &job.artifacts {
        assert_eq!(a.key, format!("jobs/{id}/outputs/a1/{}", a.name));
        let bytes = env.blobs.get(&a.key).unwrap();
        assert_eq!(bytes.len() as u64, a.size);
        assert_eq!(hex::encode(Sha256::digest(&bytes)), a.sha256);
    }
    let glb = env.blobs.get(&job.artifacts[0].key).unwrap();
    let mut set = BlobSet::new();
    set.insert("result.glb", glb);
    let asset = load("result.glb", &set, &IngestLimits::default()).expect("result loads");
    assert!(
        !asset.images.is_empty(),
        "the result carries the baked texture"
    );

    // Events: processing first, the terminal status last, revisions never decrease.
    // The store commits the terminal state just before the runner broadcasts it: read events
    // until the terminal one (or a timeout), not only those already sent.
    let mut got = Vec::new();
    while let Ok(Ok(e)) = tokio::time::timeout(Duration::from_secs(10), events.recv()).await {
        if e.id == id {
            let done = e.status.is_terminal();
            got.push(e);
            if done {
                break;
            }
        }
    }
    assert_eq!(got.first().map(|e| e.status), Some(JobStatus::Processing));
    assert_eq!(got.last().map(|e| e.status), Some(JobStatus::Succeeded));
    assert_eq!(got.last().unwrap().revision, job.revision);
    assert!(got.windows(2).all(|w| w[0].revision <= w[1].revision));

    let stages = runner.stage_durations();
    assert!(stages.iter().any(|(s, _)| s == "load"), "{stages:?}");
    assert!(stages.iter().all(|(_, t)| *t >= 0.0));
    assert!(runner.stage_durations().is_empty(), "durations are drained");
    eventually("the worker is free", Duration::from_secs(5), || {
        runner.busy_workers() == 0
    })
    .await;
    runner.shutdown(Duration::from_secs(1)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_constraints_fail_with_a_problem_naming_the_field() {
    let env = env();
    let runner = start(&env, 1);
    let bad_type = submit(
        &env,
        &runner,
        SPOT,
        r#"{"version":1,"output":{"texture_size":"large"}}"#,
    );
    let unknown = submit(&env, &runner, SPOT, r#"{"version":1,"outptu":{}}"#);
    // Every method id has a built-in method now: an id that is not one.
    let not_impl = submit(&env, &runner, SPOT, r#"{"version":1,"method":"detial"}"#);

    let j = wait_terminal(&env, bad_type).await;
    assert_eq!(j.status, JobStatus::Failed);
    let e = j.error.unwrap();
    assert_eq!(e.kind, "/problems/invalid-constraints");
    assert_eq!(e.status, 422);
    assert_eq!(e.field.as_deref(), Some("constraints.output.texture_size"));

    let e = wait_terminal(&env, unknown).await.error.unwrap();
    assert_eq!(e.kind, "/problems/invalid-constraints");
    assert!(e.detail.contains("outptu"), "{e:?}");

    let e = wait_terminal(&env, not_impl).await.error.unwrap();
    assert_eq!(e.kind, "/problems/invalid-constraints");
    assert!(e.detail.contains("detial"), "{e:?}");

    runner.shutdown(Duration::from_secs(1)).await;

    // The output texture cap is configurable; a refusal names the field and the limit.
    let env2 = self::env();
    let mut cfg = config(1);
    cfg.max_texture_size = 1024;
    let runner = Runner::start(cfg, env2.jobs.clone(), env2.blobs.clone()).unwrap();
    let capped = submit(
        &env2,
        &runner,
        SPOT,
        r#"{"version":1,"output":{"texture_size":2048}}"#,
    );
    let e = wait_terminal(&env2, capped).await.error.unwrap();
    assert_eq!(e.field.as_deref(), Some("constraints.output.texture_size"));
    assert_eq!(
        e.limit,
        Some(serde_json::json!({"name": "max_texture_size", "value": 1024}))
    );
    assert_eq!(e.status, 422);
    runner.shutdown(Duration::from_secs(1)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_panic_fails_the_job_and_the_runner_lives_on() {
    let env = env();
    let runner = start(&env, 1);
    let id = submit(
        &env,
        &runner,
        SPOT,
        r#"{"version":1,"output":{"texture_size":64}}"#,
    );
    let first = wait_terminal(&env, id).await;
    assert_eq!(first.status, JobStatus::Succeeded, "{:?}", first.error);

    runner.set_engine_hook(Some(Arc::new(|_job: &JobRecord| {
        panic!("boom in the engine");
    })));
    let boom = submit(
        &env,
        &runner,
        SPOT,
        r#"{"version":1,"output":{"texture_size":64}}"#,
    );
    let j = wait_terminal(&env, boom).await;
    assert_eq!(j.status, JobStatus::Failed);
    let e = j.error.unwrap();
    assert_eq!(e.status, 500);
    assert!(e.detail.contains("boom in the engine"), "{e:?}");

    // The same pool still runs jobs.
    runner.set_engine_hook(None);
    let after = submit(
        &env,
        &runner,
        SPOT,
        r#"{"version":1,"output":{"texture_size":64}}"#,
    );
    let j = wait_terminal(&env, after).await;
    assert_eq!(j.status, JobStatus::Succeeded, "{:?}", j.error);
    eventually("the worker is free", Duration::from_secs(5), || {
        runner.busy_workers() == 0
    })
    .await;
    runner.shutdown(Duration::from_secs(1)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_worker_cancel_is_prompt_then_shutdown_requeues() {
    let env = env();
    let runner = start(&env, 1);
    let slow = r#"{"version":1,"output":{"texture_size":8192}}"#;
    let a = submit(&env, &runner, SPOT, slow);
    let b = submit(&env, &runner, SPOT, slow);

    // Wait until A is inside the engine (a stage has started).
    wait_until(&env, a, Duration::from_secs(60), "processing", |j| {
        j.status == JobStatus::Processing
    })
    .await;
    let end = Instant::now() + Duration::from_secs(60);
    while runner.progress(a).is_none_or(|p| p.stage.is_empty()) {
        assert!(Instant::now() < end, "no engine progress for job {a}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    // Only one worker: B waits.
    assert_eq!(runner.busy_workers(), 1);
    assert_eq!(
        env.jobs.get(b).unwrap().unwrap().status,
        JobStatus::Enqueued
    );

    let asked = Instant::now();
    assert!(runner.cancel(a), "A is running here");
    // Latency bounds are generous (seconds): the machine may be busy with other tests.
    let j = wait_until(&env, a, Duration::from_secs(5), "canceled", |j| {
        j.status.is_terminal()
    })
    .await;
    let took = asked.elapsed();
    assert_eq!(j.status, JobStatus::Canceled, "{:?}", j.error);
    assert!(took < Duration::from_secs(5), "cancel took {took:?}");
    assert!(
        runner.progress(a).is_none(),
        "no live progress for a canceled job"
    );

    // B starts next (so A's engine call ended and freed the single worker); shutdown with a
    // short deadline puts B back in the queue.
    wait_until(&env, b, Duration::from_secs(30), "processing", |j| {
        j.status == JobStatus::Processing
    })
    .await;
    let stop = Instant::now();
    runner.shutdown(Duration::from_millis(300)).await;
    // Deadline (0.3 s), plus at most the grace the engine gets to reach a cancel check (5 s),
    // with room for a busy machine.
    let took = stop.elapsed();
    assert!(took < Duration::from_secs(10), "shutdown took {took:?}");
    let j = env.jobs.get(b).unwrap().unwrap();
    assert_eq!(j.status, JobStatus::Enqueued, "{j:?}");
    assert_eq!(j.attempts, 0, "a graceful stop gives the attempt back");
    assert!(j.artifacts.is_empty());
    // A stopped runner claims nothing.
    runner.notify();
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(
        env.jobs.get(b).unwrap().unwrap().status,
        JobStatus::Enqueued
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn start_recovers_a_job_left_processing_by_a_crash() {
    let env = env();
    // A stopped runner only serves to `submit`; the "crashed process" claims the job directly
    // and dies without finishing it.
    let stopped = Runner::start(config(1), env.jobs.clone(), env.blobs.clone()).unwrap();
    stopped.shutdown(Duration::from_millis(10)).await;
    let id = submit(
        &env,
        &stopped,
        SPOT,
        r#"{"version":1,"output":{"texture_size":64}}"#,
    );
    let claimed = env.jobs.claim_next(Utc::now()).unwrap().unwrap();
    assert_eq!((claimed.id, claimed.attempts), (id, 1));

    // Restart: the job goes back to the queue and runs to the end.
    let runner = start(&env, 1);
    let j = wait_terminal(&env, id).await;
    assert_eq!(j.status, JobStatus::Succeeded, "{:?}", j.error);
    assert_eq!(j.attempts, 2, "one crashed start plus the recovered one");
    runner.shutdown(Duration::from_secs(1)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graceful_restarts_do_not_count_as_crash_attempts() {
    let env = env();
    let id = {
        let runner = start(&env, 1);
        // The engine call waits a second: longer than the shutdown deadline below.
        runner.set_engine_hook(Some(Arc::new(|_| {
            std::thread::sleep(Duration::from_secs(1))
        })));
        let id = submit(
            &env,
            &runner,
            SPOT,
            r#"{"version":1,"output":{"texture_size":64}}"#,
        );
        wait_until(&env, id, Duration::from_secs(60), "processing", |j| {
            j.status == JobStatus::Processing
        })
        .await;
        runner.shutdown(Duration::from_millis(50)).await;
        id
    };
    // Two rolling restarts (max_attempts is 3)...
    for restart in 1..=2 {
        let j = env.jobs.get(id).unwrap().unwrap();
        assert_eq!(j.status, JobStatus::Enqueued, "restart {restart}: {j:?}");
        assert_eq!(j.attempts, 0, "a graceful stop is not an attempt: {j:?}");
        let runner = start(&env, 1);
        runner.set_engine_hook(Some(Arc::new(|_| {
            std::thread::sleep(Duration::from_secs(1))
        })));
        runner.notify();
        wait_until(&env, id, Duration::from_secs(60), "processing", |j| {
            j.status == JobStatus::Processing
        })
        .await;
        runner.shutdown(Duration::from_millis(50)).await;
    }
    // ... then a crash: the "crashed process" claims the job and dies.
    let claimed = env.jobs.claim_next(Utc::now()).unwrap().unwrap();
    assert_eq!(claimed.id, id);
    // The job is recovered and runs to the end, not failed with too-many-attempts.
    let runner = start(&env, 1);
    let j = wait_terminal(&env, id).await;
    assert_eq!(j.status, JobStatus::Succeeded, "{:?}", j.error);
    assert_eq!(j.attempts, 2, "one crashed start plus the recovered one");
    runner.shutdown(Duration::from_secs(1)).await;
}
