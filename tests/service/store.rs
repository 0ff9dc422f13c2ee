//! The stores: the job-store suite (state machine, pagination, atomic claims, recovery,
//! idempotency, retention) run on both `SqliteJobStore` and `PgJobStore` (module
//! `postgres_suite`, on a throw-away server), SQLite's durability across reopen, and the
//! file-system blob store's temp-file sweep (the blob-store suite is in `blob_store.rs`).
#![cfg(feature = "service")]

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;

use chrono::{DateTime, Duration, TimeZone, Utc};
use retex::service::model::{
    ArtifactRef, JobInputs, JobProgress, JobRecord, JobStatus, ModelFiles, Problem,
};
use retex::service::store::fs::FsBlobStore;
use retex::service::store::sqlite::SqliteJobStore;
use retex::service::store::{BlobStore, CreateOutcome, Finish, JobStore, ListFilter, StoreError};
use uuid::Uuid;

/// A fresh folder under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let p = std::env::temp_dir().join(format!("retex-{tag}-{}", Uuid::new_v4()));
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn t0() -> DateTime<Utc> {
    Utc.with_ymd_and_hms(2025, 1, 1, 12, 0, 0).unwrap()
}

fn job(created_at: DateTime<Utc>, method: &str) -> JobRecord {
    JobRecord {
        id: Uuid::now_v7(),
        status: JobStatus::Enqueued,
        method: method.to_string(),
        progress: JobProgress::default(),
        created_at,
        started_at: None,
        finished_at: None,
        error: None,
        report: None,
        attempts: 0,
        idempotency_key: None,
        owner: None,
        request_hash: "h0".into(),
        inputs: JobInputs {
            source: Some(ModelFiles {
                main: "a.glb".into(),
                files: vec![("a.glb".into(), "jobs/x/inputs/source/a.glb".into())],
            }),
            target: ModelFiles::default(),
            source_base: None,
            constraints: "jobs/x/inputs/constraints.json".into(),
            pattern: None,
        },
        artifacts: vec![],
        revision: 1,
    }
}

fn open(dir: &TempDir) -> SqliteJobStore {
    SqliteJobStore::open(&dir.0.join("jobs.sqlite")).unwrap()
}

fn success() -> Finish {
    Finish::Succeeded {
        artifacts: vec![ArtifactRef {
            name: "result.glb".into(),
            media_type: "model/gltf-binary".into(),
            key: "jobs/x/outputs/result.glb".into(),
            size: 3,
            sha256: "abc".into(),
        }],
        report: serde_json::json!({"coverage": 0.9}),
    }
}

fn create_get_round_trip_keeps_every_field(store: Arc<dyn JobStore>) {
    let mut j = job(t0(), "project");
    j.idempotency_key = Some("k1".into());
    j.report = Some(serde_json::json!({"a": [1, 2]}));
    assert_eq!(store.create(&j).unwrap(), CreateOutcome::Created);
    assert_eq!(store.get(j.id).unwrap().as_ref(), Some(&j));
    assert_eq!(store.get(Uuid::new_v4()).unwrap(), None);
    // A duplicate id is refused, not silently overwritten.
    let mut dup = j.clone();
    dup.idempotency_key = None;
    assert!(store.create(&dup).is_err());
}

fn pagination_covers_every_job_once_newest_first_with_filters(store: Arc<dyn JobStore>) {
    let mut all = Vec::new();
    for i in 0..57 {
        // Several jobs share a timestamp so the id tie-break matters.
        let j = job(
            t0() + Duration::seconds(i / 3),
            if i % 4 == 0 { "meshmatch" } else { "project" },
        );
        store.create(&j).unwrap();
        all.push(j);
    }
    // Fail some so the status filter has something to separate.
    for j in all.iter().step_by(5) {
        store
            .finish(j.id, Finish::Canceled, t0() + Duration::hours(1))
            .unwrap();
    }
    let mut expect: Vec<&JobRecord> = all.iter().collect();
    expect.sort_by_key(|j| std::cmp::Reverse((j.created_at, j.id)));

    let collect = |filter: ListFilter| -> Vec<JobRecord> {
        let mut out = Vec::new();
        let mut f = filter;
        let mut pages = 0;
        loop {
            let page = store.list(&f).unwrap();
            assert!(page.jobs.len() <= f.limit.max(1));
            out.extend(page.jobs);
            pages += 1;
            assert!(pages < 100, "pagination does not end");
            match page.next {
                Some(c) => f.cursor = Some(c),
                None => break,
            }
        }
        out
    };

    let got = collect(ListFilter {
        limit: 7,
        ..Default::default()
    });
    let ids: Vec<Uuid> = got.iter().map(|j| j.id).collect();
    let expect_ids: Vec<Uuid> = expect.iter().map(|j| j.id).collect();
    assert_eq!(ids, expect_ids, "all jobs exactly once, newest first");

    let project = collect(ListFilter {
        limit: 4,
        method: Some("project".into()),
        status: Some(JobStatus::Enqueued),
        ..Default::default()
    });
    let want: Vec<Uuid> = expect
        .iter()
        .filter(|j| {
            j.method == "project" && store.get(j.id).unwrap().unwrap().status == JobStatus::Enqueued
        })
        .map(|j| j.id)
        .collect();
    assert!(!want.is_empty());
    assert_eq!(project.iter().map(|j| j.id).collect::<Vec<_>>(), want);

    let after = t0() + Duration::seconds(5);
    let before = t0() + Duration::seconds(10);
    let window = collect(ListFilter {
        limit: 500,
        created_after: Some(after),
        created_before: Some(before),
        ..Default::default()
    });
    assert_eq!(window.len(), 4 * 3, "seconds 6..=9, three jobs each");
    assert!(window
        .iter()
        .all(|j| j.created_at > after && j.created_at < before));

    // A limit above the cap is clamped; a forged cursor is refused.
    assert_eq!(
        store
            .list(&ListFilter {
                limit: 10_000,
                ..Default::default()
            })
            .unwrap()
            .jobs
            .len(),
        57
    );
    assert!(matches!(
        store.list(&ListFilter {
            limit: 5,
            cursor: Some("not a cursor".into()),
            ..Default::default()
        }),
        Err(StoreError::InvalidCursor(_))
    ));
}

fn concurrent_claims_never_take_the_same_job(store: Arc<dyn JobStore>) {
    let n = 60;
    for i in 0..n {
        store
            .create(&job(t0() + Duration::milliseconds(i), "project"))
            .unwrap();
    }
    let threads: Vec<_> = (0..4)
        .map(|_| {
            let s = Arc::clone(&store);
            std::thread::spawn(move || {
                let mut mine = Vec::new();
                while let Some(j) = s.claim_next(Utc::now()).unwrap() {
                    assert_eq!(j.status, JobStatus::Processing);
                    assert_eq!(j.attempts, 1);
                    mine.push(j.id);
                }
                mine
            })
        })
        .collect();
    let mut seen = HashSet::new();
    let mut total = 0;
    for t in threads {
        for id in t.join().unwrap() {
            total += 1;
            assert!(seen.insert(id), "job {id} claimed twice");
        }
    }
    assert_eq!(total, n as usize);
    assert_eq!(store.claim_next(Utc::now()).unwrap(), None);
}

fn claim_takes_the_oldest_and_bumps_revision(store: Arc<dyn JobStore>) {
    let newer = job(t0() + Duration::seconds(1), "project");
    let older = job(t0(), "project");
    store.create(&newer).unwrap();
    store.create(&older).unwrap();
    let now = t0() + Duration::minutes(1);
    let c = store.claim_next(now).unwrap().unwrap();
    assert_eq!(c.id, older.id);
    assert_eq!(c.started_at, Some(now));
    assert_eq!(c.revision, older.revision + 1);
    assert_eq!(store.get(c.id).unwrap().unwrap(), c);
    let p = JobProgress {
        stage: "bake".into(),
        fraction: 0.5,
        stages_done: 3,
        stages_total: 6,
    };
    store.update_progress(c.id, &p).unwrap();
    let g = store.get(c.id).unwrap().unwrap();
    assert_eq!(g.progress, p);
    assert_eq!(g.revision, c.revision + 1);
    // Progress of an enqueued job is ignored.
    store.update_progress(newer.id, &p).unwrap();
    assert_eq!(store.get(newer.id).unwrap().unwrap(), newer);
}

fn terminal_states_never_change(store: Arc<dyn JobStore>) {
    let j = job(t0(), "project");
    store.create(&j).unwrap();
    store.claim_next(t0()).unwrap().unwrap();
    let done = store
        .finish(j.id, success(), t0() + Duration::seconds(3))
        .unwrap();
    assert_eq!(done.status, JobStatus::Succeeded);
    assert_eq!(done.progress.fraction, 1.0);
    let failed = Finish::Failed {
        error: Problem::default(),
        report: None,
    };
    for attempt in [failed, Finish::Canceled, success()] {
        assert!(matches!(
            store.finish(j.id, attempt, Utc::now()),
            Err(StoreError::Conflict {
                status: JobStatus::Succeeded,
                ..
            })
        ));
    }
    assert!(matches!(
        store.cancel_if_enqueued(j.id, Utc::now()),
        Err(StoreError::Conflict { .. })
    ));
    store
        .update_progress(
            j.id,
            &JobProgress {
                stage: "x".into(),
                ..Default::default()
            },
        )
        .unwrap();
    assert_eq!(store.get(j.id).unwrap().unwrap(), done, "nothing changed");
    assert!(matches!(
        store.finish(Uuid::new_v4(), Finish::Canceled, Utc::now()),
        Err(StoreError::NotFound(_))
    ));
}

fn finish_writes_status_results_and_time_together(store: Arc<dyn JobStore>) {
    let j = job(t0(), "project");
    store.create(&j).unwrap();
    let claimed = store.claim_next(t0()).unwrap().unwrap();
    let at = t0() + Duration::seconds(9);
    let f = store.finish(j.id, success(), at).unwrap();
    let g = store.get(j.id).unwrap().unwrap();
    assert_eq!(f, g);
    assert_eq!(g.finished_at, Some(at));
    assert_eq!(g.artifacts.len(), 1);
    assert_eq!(g.report, Some(serde_json::json!({"coverage": 0.9})));
    assert_eq!(g.revision, claimed.revision + 1);
    // Indexed columns follow the record: the job is listed under its new status only.
    let listed = |s| {
        store
            .list(&ListFilter {
                status: Some(s),
                limit: 10,
                ..Default::default()
            })
            .unwrap()
            .jobs
            .len()
    };
    assert_eq!(listed(JobStatus::Succeeded), 1);
    assert_eq!(listed(JobStatus::Processing), 0);
}

fn cancel_if_enqueued_cancels_only_enqueued_jobs(store: Arc<dyn JobStore>) {
    let a = job(t0(), "project");
    let b = job(t0() + Duration::seconds(1), "project");
    store.create(&a).unwrap();
    store.create(&b).unwrap();
    let running = store.claim_next(t0()).unwrap().unwrap();
    assert_eq!(running.id, a.id);
    let unchanged = store.cancel_if_enqueued(a.id, t0()).unwrap();
    assert_eq!(unchanged, running);
    let c = store.cancel_if_enqueued(b.id, t0()).unwrap();
    assert_eq!(c.status, JobStatus::Canceled);
    assert!(c.finished_at.is_some());
    assert_eq!(
        store.claim_next(t0()).unwrap(),
        None,
        "a canceled job is never claimed"
    );
}

fn recover_requeues_processing_jobs_and_fails_after_max_attempts(store: Arc<dyn JobStore>) {
    let j = job(t0(), "project");
    let other = job(t0() + Duration::seconds(1), "project");
    store.create(&j).unwrap();
    store.create(&other).unwrap();
    for attempt in 1..=3u32 {
        let c = store.claim_next(t0()).unwrap().unwrap();
        assert_eq!((c.id, c.attempts), (j.id, attempt));
        // "Crash" and restart.
        let r = store.recover(3, t0()).unwrap();
        if attempt < 3 {
            assert_eq!(r.requeued, vec![j.id]);
            assert!(r.failed.is_empty());
            let g = store.get(j.id).unwrap().unwrap();
            assert_eq!(g.status, JobStatus::Enqueued);
            assert_eq!(g.progress, JobProgress::default());
        } else {
            assert_eq!(r.failed, vec![j.id]);
            assert!(r.requeued.is_empty());
        }
    }
    let g = store.get(j.id).unwrap().unwrap();
    assert_eq!(g.status, JobStatus::Failed);
    assert_eq!(g.error.unwrap().kind, "/problems/too-many-attempts");
    // The enqueued job was never touched.
    assert_eq!(store.get(other.id).unwrap().unwrap(), other);
}

fn idempotency_key_same_hash_returns_job_different_hash_is_refused(store: Arc<dyn JobStore>) {
    let mut a = job(t0(), "project");
    a.idempotency_key = Some("key-1".into());
    a.request_hash = "hash-a".into();
    store.create(&a).unwrap();

    let mut replay = job(t0() + Duration::seconds(1), "project");
    replay.idempotency_key = Some("key-1".into());
    replay.request_hash = "hash-a".into();
    assert_eq!(
        store.create(&replay).unwrap(),
        CreateOutcome::Existing(Box::new(a.clone()))
    );
    assert_eq!(
        store.get(replay.id).unwrap(),
        None,
        "the replay inserted nothing"
    );

    let mut other = replay.clone();
    other.request_hash = "hash-b".into();
    match store.create(&other) {
        Err(StoreError::IdempotencyMismatch { key, existing }) => {
            assert_eq!((key.as_str(), existing), ("key-1", a.id));
        }
        r => panic!("expected a mismatch, got {r:?}"),
    }

    // Keys expire only through prune(keys_before); then the key may be reused.
    store
        .prune(t0() - Duration::days(1), t0() - Duration::hours(1))
        .unwrap();
    assert!(matches!(
        store.create(&other),
        Err(StoreError::IdempotencyMismatch { .. })
    ));
    store
        .prune(t0() - Duration::days(1), t0() + Duration::hours(1))
        .unwrap();
    assert_eq!(store.create(&other).unwrap(), CreateOutcome::Created);
    assert!(
        store.get(a.id).unwrap().is_some(),
        "pruning a key keeps its job"
    );
}

fn prune_removes_only_old_terminal_jobs(store: Arc<dyn JobStore>) {
    let old_done = job(t0(), "project");
    let new_done = job(t0() + Duration::seconds(1), "project");
    let old_running = job(t0() - Duration::days(30), "project");
    let old_enqueued = job(t0() - Duration::days(30) + Duration::seconds(1), "project");
    for j in [&old_done, &new_done, &old_running, &old_enqueued] {
        store.create(j).unwrap();
    }
    assert_eq!(store.claim_next(t0()).unwrap().unwrap().id, old_running.id);
    store
        .cancel_if_enqueued(old_done.id, t0() + Duration::days(1))
        .unwrap();
    store
        .cancel_if_enqueued(new_done.id, t0() + Duration::days(9))
        .unwrap();

    let removed = store.prune(t0() + Duration::days(8), t0()).unwrap();
    assert_eq!(
        removed.iter().map(|j| j.id).collect::<Vec<_>>(),
        vec![old_done.id]
    );
    assert_eq!(store.get(old_done.id).unwrap(), None);
    for j in [&new_done, &old_running, &old_enqueued] {
        assert!(store.get(j.id).unwrap().is_some(), "{} must stay", j.id);
    }
    // Even a cutoff far in the future never removes unfinished jobs.
    let removed = store.prune(t0() + Duration::days(1000), t0()).unwrap();
    assert_eq!(
        removed.iter().map(|j| j.id).collect::<Vec<_>>(),
        vec![new_done.id]
    );
    let counts = store.counts().unwrap();
    assert_eq!(
        counts.by_status,
        vec![(JobStatus::Enqueued, 1), (JobStatus::Processing, 1)]
    );
    assert_eq!(counts.oldest_enqueued, Some(old_enqueued.created_at));
}

fn delete_removes_finished_jobs_only(store: Arc<dyn JobStore>) {
    let j = job(t0(), "project");
    store.create(&j).unwrap();
    assert!(matches!(
        store.delete(j.id),
        Err(StoreError::Conflict { .. })
    ));
    store.cancel_if_enqueued(j.id, t0()).unwrap();
    assert_eq!(store.delete(j.id).unwrap().id, j.id);
    assert_eq!(store.get(j.id).unwrap(), None);
    assert!(matches!(store.delete(j.id), Err(StoreError::NotFound(_))));
}

#[test]
fn everything_survives_reopen() {
    let dir = TempDir::new("store");
    let (a, b) = (
        job(t0(), "project"),
        job(t0() + Duration::seconds(1), "project"),
    );
    let finished = {
        let store = open(&dir);
        store.create(&a).unwrap();
        store.create(&b).unwrap();
        store.claim_next(t0()).unwrap();
        store.finish(a.id, success(), t0()).unwrap()
    };
    let store = open(&dir);
    assert_eq!(store.get(a.id).unwrap().unwrap(), finished);
    assert_eq!(store.get(b.id).unwrap().unwrap(), b);
    drop(store);
    let store = open(&dir);
    assert_eq!(store.get(b.id).unwrap().unwrap(), b);
    drop(store);
    // The file is in WAL mode and the schema version row is not duplicated by reopening.
    let conn = rusqlite::Connection::open(dir.0.join("jobs.sqlite")).unwrap();
    let mode: String = conn
        .query_row("PRAGMA journal_mode", [], |r| r.get(0))
        .unwrap();
    assert_eq!(mode, "wal");
    let rows: i64 = conn
        .query_row("SELECT COUNT(*) FROM schema_version", [], |r| r.get(0))
        .unwrap();
    assert_eq!(rows, 1);
}

/// Instantiates the job-store suite above for one store: one `#[test]` per check, each on a
/// fresh store from `$open` (which returns a guard to keep alive and the store), each with the
/// attribute given (`#[ignore = …]` for PostgreSQL).
macro_rules! job_store_suite {
    ($open:expr, #[$attr:meta]) => {
        job_store_suite!(@each $open, $attr,
            create_get_round_trip_keeps_every_field,
            pagination_covers_every_job_once_newest_first_with_filters,
            concurrent_claims_never_take_the_same_job,
            claim_takes_the_oldest_and_bumps_revision,
            terminal_states_never_change,
            finish_writes_status_results_and_time_together,
            cancel_if_enqueued_cancels_only_enqueued_jobs,
            recover_requeues_processing_jobs_and_fails_after_max_attempts,
            idempotency_key_same_hash_returns_job_different_hash_is_refused,
            prune_removes_only_old_terminal_jobs,
            delete_removes_finished_jobs_only
        );
    };
    (@each $open:expr, $attr:meta, $($name:ident),*) => {
        $(
            #[test]
            #[$attr]
            fn $name() {
                let (_guard, store) = $open;
                super::$name(store);
            }
        )*
    };
}

/// The suite on the embedded SQLite store.
mod sqlite_suite {
    use super::*;

    fn open_sqlite() -> (TempDir, Arc<dyn JobStore>) {
        let dir = TempDir::new("store");
        let store: Arc<dyn JobStore> = Arc::new(open(&dir));
        (dir, store)
    }

    job_store_suite!(open_sqlite(), #[doc = "On SQLite."]);
}

/// The same suite on PostgreSQL: a fresh database of the test binary's throw-away server
/// (`pg_server`) per test.
mod postgres_suite {
    use super::*;
    use retex::service::store::postgres::{PgJobStore, DEFAULT_LEASE};

    fn open_pg() -> ((), Arc<dyn JobStore>) {
        let url = crate::pg_server::fresh_url();
        let store: Arc<dyn JobStore> = Arc::new(PgJobStore::connect(&url, DEFAULT_LEASE).unwrap());
        ((), store)
    }

    job_store_suite!(open_pg(), #[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]);
}

// ---------------------------------------------------------------- blobs

#[test]
fn temp_files_of_a_dead_writer_are_swept_at_open_but_not_a_live_ones() {
    let dir = TempDir::new("tmp-sweep");
    let first = FsBlobStore::open(&dir.0).unwrap();
    let left = first.temp_dir().join("put-left-by-a-crash");
    std::fs::write(&left, b"partial").unwrap();
    // A second store on the same folder while the first lives: the file may be in use.
    let second = FsBlobStore::open(&dir.0).unwrap();
    assert!(left.exists(), "a live writer's temp file was removed");
    drop(second);
    drop(first);
    // Reopened after the writer is gone (as after kill -9 and restart): nothing is left.
    let _again = FsBlobStore::open(&dir.0).unwrap();
    assert!(
        !left.exists(),
        "a dead writer's temp file survived the reopen"
    );
}
