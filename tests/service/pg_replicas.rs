//! Several replicas on one PostgreSQL database (issue 17, part 1). Two `PgJobStore` handles on
//! one database stand for two replicas (each has its own lease owner id): concurrent claims
//! from both never hand one job to two, an expired lease lets the other replica reclaim the job
//! (and only then: live leases are never stolen, not even by `recover`), a cancel recorded
//! through one is seen by the other's heartbeat, idempotency keys are shared, and replicas
//! starting together migrate the schema once. Then two real `retex serve` processes on one
//! database and one data directory run 10 jobs, each exactly once.
//!
//! All need the throw-away server of `pg_server` (ignored by default; CI runs them).

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use chrono::{DateTime, TimeZone, Utc};
use retex::service::model::{JobInputs, JobProgress, JobRecord, JobStatus, ModelFiles};
use retex::service::store::postgres::PgJobStore;
use retex::service::store::sqlite::SqliteJobStore;
use retex::service::store::{CreateOutcome, Finish, JobStore, Lease, StoreError};
use uuid::Uuid;

use crate::pg_server::fresh_url;
use crate::service_common::*;

const LEASE: Duration = Duration::from_secs(10);

fn t0() -> DateTime<Utc> {
    Utc.with_ymd_and_hms(2025, 1, 1, 12, 0, 0).unwrap()
}

fn secs(s: i64) -> chrono::Duration {
    chrono::Duration::seconds(s)
}

pub(crate) fn job(created_at: DateTime<Utc>) -> JobRecord {
    JobRecord {
        id: Uuid::now_v7(),
        status: JobStatus::Enqueued,
        method: "project".into(),
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
            source: None,
            target: ModelFiles::default(),
            source_base: None,
            constraints: "jobs/x/inputs/constraints.json".into(),
            pattern: None,
        },
        artifacts: vec![],
        revision: 1,
    }
}

/// Two replicas' store handles on one fresh database.
fn two_replicas() -> (Arc<PgJobStore>, Arc<PgJobStore>) {
    let url = fresh_url();
    let a = PgJobStore::connect(&url, LEASE).unwrap();
    let b = PgJobStore::connect(&url, LEASE).unwrap();
    assert_ne!(a.owner(), b.owner());
    (Arc::new(a), Arc::new(b))
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn two_replicas_hammering_claims_never_share_a_job() {
    let (a, b) = two_replicas();
    let n = 300;
    for i in 0..n {
        // Half through each replica.
        let s = if i % 2 == 0 { &a } else { &b };
        s.create(&job(t0() + chrono::Duration::milliseconds(i)))
            .unwrap();
    }
    let threads: Vec<_> = (0..8)
        .map(|t| {
            let s = Arc::clone(if t % 2 == 0 { &a } else { &b });
            std::thread::spawn(move || {
                let mut mine = Vec::new();
                while let Some(j) = s.claim_next(Utc::now()).unwrap() {
                    assert_eq!((j.status, j.attempts), (JobStatus::Processing, 1));
                    mine.push(j.id);
                }
                mine
            })
        })
        .collect();
    let mut seen = HashSet::new();
    let mut per_thread = Vec::new();
    for t in threads {
        let mine = t.join().unwrap();
        per_thread.push(mine.len());
        for id in mine {
            assert!(seen.insert(id), "job {id} claimed twice");
        }
    }
    assert_eq!(seen.len(), n as usize, "every job claimed once");
    // SKIP LOCKED lets claims proceed side by side: both replicas got work.
    let (even, odd): (usize, usize) = (
        per_thread.iter().step_by(2).sum(),
        per_thread.iter().skip(1).step_by(2).sum(),
    );
    assert!(even > 0 && odd > 0, "claims per replica: {even} / {odd}");
    assert_eq!(a.claim_next(Utc::now()).unwrap(), None);
    assert_eq!(b.claim_next(Utc::now()).unwrap(), None);
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn an_expired_lease_is_reclaimed_by_the_other_replica_a_live_one_never() {
    let (a, b) = two_replicas();
    let j = job(t0());
    a.create(&j).unwrap();
    let claimed = a.claim_next(t0()).unwrap().unwrap();
    assert_eq!(claimed.id, j.id);
    let lease = secs(LEASE.as_secs() as i64);

    // A live lease: neither B's start-up recovery nor its reclaim touches it.
    assert_eq!(b.recover(3, t0() + secs(1)).unwrap(), Default::default());
    assert_eq!(
        b.reclaim_expired(3, t0() + lease - secs(1)).unwrap(),
        Default::default()
    );
    // A's heartbeat at lease - 1 s pushes the expiry to 2 × lease - 1 s.
    assert_eq!(
        a.heartbeat(j.id, t0() + lease - secs(1)).unwrap(),
        Lease::Held {
            cancel_requested: false
        }
    );
    assert_eq!(
        b.reclaim_expired(3, t0() + lease + secs(1)).unwrap(),
        Default::default(),
        "the renewed lease still holds"
    );
    assert_eq!(b.get(j.id).unwrap().unwrap().status, JobStatus::Processing);

    // A dies (no more heartbeats): after the renewed lease runs out, B reclaims and runs it.
    let expired = t0() + lease + lease;
    let r = b.reclaim_expired(3, expired).unwrap();
    assert_eq!((r.requeued, r.failed), (vec![j.id], vec![]));
    let again = b.claim_next(expired).unwrap().unwrap();
    assert_eq!((again.id, again.attempts), (j.id, 2));
    // A's late heartbeat, progress and finish find the job gone from under it.
    assert_eq!(a.heartbeat(j.id, expired).unwrap(), Lease::Lost);
    a.update_progress(
        j.id,
        &JobProgress {
            stage: "zombie".into(),
            ..Default::default()
        },
    )
    .unwrap();
    assert_ne!(b.get(j.id).unwrap().unwrap().progress.stage, "zombie");
    assert!(matches!(
        a.finish(j.id, Finish::Canceled, expired),
        Err(StoreError::Conflict { .. })
    ));
    let done = b
        .finish(
            j.id,
            Finish::Succeeded {
                artifacts: vec![],
                report: serde_json::json!({}),
            },
            expired + secs(1),
        )
        .unwrap();
    assert_eq!((done.status, done.attempts), (JobStatus::Succeeded, 2));

    // The attempt cap holds across replicas: a job interrupted max_attempts times fails.
    let k = job(t0() + secs(1));
    a.create(&k).unwrap();
    let mut now = expired + secs(10);
    for attempt in 1..=2u32 {
        let c = [&a, &b][attempt as usize % 2]
            .claim_next(now)
            .unwrap()
            .unwrap();
        assert_eq!((c.id, c.attempts), (k.id, attempt));
        now = now + lease + secs(1);
        let r = [&b, &a][attempt as usize % 2]
            .reclaim_expired(2, now)
            .unwrap();
        if attempt < 2 {
            assert_eq!(r.requeued, vec![k.id]);
        } else {
            assert_eq!(r.failed, vec![k.id]);
        }
    }
    let failed = a.get(k.id).unwrap().unwrap();
    assert_eq!(failed.status, JobStatus::Failed);
    assert_eq!(failed.error.unwrap().kind, "/problems/too-many-attempts");
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn a_cancel_through_one_replica_reaches_the_runner_of_the_other() {
    let (a, b) = two_replicas();
    let j = job(t0());
    b.create(&j).unwrap();
    let running = a.claim_next(t0()).unwrap().unwrap();
    assert_eq!(
        a.heartbeat(j.id, t0()).unwrap(),
        Lease::Held {
            cancel_requested: false
        }
    );
    // B answers as SQLite does (the processing record, unchanged) and records the request.
    assert_eq!(b.cancel_if_enqueued(j.id, t0()).unwrap(), running);
    assert_eq!(
        a.heartbeat(j.id, t0() + secs(1)).unwrap(),
        Lease::Held {
            cancel_requested: true
        }
    );
    let done = a.finish(j.id, Finish::Canceled, t0() + secs(1)).unwrap();
    assert_eq!(b.get(j.id).unwrap().unwrap(), done);
    assert_eq!(a.heartbeat(j.id, t0() + secs(2)).unwrap(), Lease::Lost);
    // SQLite keeps its single-process behaviour: no lease, nothing to reclaim.
    let dir = tempfile::tempdir().unwrap();
    let s = SqliteJobStore::open(&dir.path().join("j.sqlite")).unwrap();
    assert_eq!(s.lease_duration(), None);
    assert_eq!(
        s.heartbeat(j.id, t0()).unwrap(),
        Lease::Held {
            cancel_requested: false
        }
    );
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn idempotency_keys_are_shared_and_migrations_run_once() {
    let url = fresh_url();
    // Four replicas start at once: the advisory lock lets one create the schema.
    let stores: Vec<PgJobStore> = (0..4)
        .map(|_| {
            let url = url.clone();
            std::thread::spawn(move || PgJobStore::connect(&url, LEASE).unwrap())
        })
        .collect::<Vec<_>>()
        .into_iter()
        .map(|t| t.join().unwrap())
        .collect();
    let db = url.rsplit("dbname=").next().unwrap();
    assert_eq!(
        crate::pg_server::server()
            .psql(db, "SELECT COUNT(*) FROM schema_version")
            .unwrap(),
        "1"
    );
    let (a, b) = (&stores[0], &stores[3]);
    let mut first = job(t0());
    first.idempotency_key = Some("k-shared".into());
    first.request_hash = "hash-a".into();
    assert_eq!(a.create(&first).unwrap(), CreateOutcome::Created);
    let mut replay = job(t0() + secs(1));
    replay.idempotency_key = Some("k-shared".into());
    replay.request_hash = "hash-a".into();
    assert_eq!(
        b.create(&replay).unwrap(),
        CreateOutcome::Existing(Box::new(first.clone()))
    );
    assert_eq!(b.job_of_key("k-shared").unwrap(), Some(first.id));
    replay.request_hash = "hash-b".into();
    assert!(matches!(
        b.create(&replay),
        Err(StoreError::IdempotencyMismatch { existing, .. }) if existing == first.id
    ));
    // Concurrent submissions with one key through all four replicas create one job.
    let mut same = job(t0() + secs(2));
    same.idempotency_key = Some("k-race".into());
    let created = std::thread::scope(|scope| {
        let hs: Vec<_> = stores
            .iter()
            .map(|s| {
                let mut mine = same.clone();
                mine.id = Uuid::now_v7();
                scope.spawn(move || s.create(&mine).unwrap())
            })
            .collect();
        hs.into_iter()
            .map(|h| h.join().unwrap())
            .filter(|o| *o == CreateOutcome::Created)
            .count()
    });
    assert_eq!(created, 1, "one job for one key across replicas");
}

fn spawn_replica(data: &Path, url: &str) -> (ServeProcess, String) {
    spawn_role(data, url, "all", &[])
}

/// One replica of `role` on the database `url` and the shared data directory, plus `extra` flags.
pub(crate) fn spawn_role(
    data: &Path,
    url: &str,
    role: &str,
    extra: &[&str],
) -> (ServeProcess, String) {
    let mut args = vec!["--workers", "1", "--role", role, "--database-url", url];
    args.extend(["--shutdown-secs", "5", "--memory-bytes", "0"]);
    args.extend(extra);
    spawn_serve(data, &args, "warn")
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn two_serve_processes_on_one_database_run_ten_jobs_once_each() {
    let url = fresh_url();
    let data = tempfile::tempdir().unwrap();
    let (_a, base_a) = spawn_replica(data.path(), &url);
    let (_b, base_b) = spawn_replica(data.path(), &url);
    let bases = [base_a.as_str(), base_b.as_str()];
    let mut ids = Vec::new();
    for i in 0..10 {
        let r = submit(bases[i % 2], &spot_parts(128), &[]);
        assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
        ids.push(r.json()["id"].as_str().unwrap().to_string());
    }
    for (i, id) in ids.iter().enumerate() {
        // Polled through the replica that did not accept it.
        let doc = wait_for(bases[(i + 1) % 2], id, Duration::from_secs(240), terminal);
        assert_eq!(doc["status"], "succeeded", "{doc}");
        assert_eq!(doc["attempts"], 1, "ran exactly once: {doc}");
        let r = get(&format!("{}/v1/jobs/{id}/result", bases[i % 2]));
        assert_eq!((r.status, &r.body[..4]), (200, &b"glTF"[..]));
    }
    for base in bases {
        let list = get(&format!("{base}/v1/jobs?limit=100")).json();
        let mut listed: Vec<String> = list["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| j["id"].as_str().unwrap().to_string())
            .collect();
        listed.sort();
        let mut expected = ids.clone();
        expected.sort();
        assert_eq!(listed, expected, "both replicas list the same 10 jobs");
    }
    crate::common::assert_validator_clean(
        &get(&format!("{base_b}/v1/jobs/{}/result", ids[0])).body,
        "service_pg_replicas_spot.glb",
    );
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn a_cancel_sent_to_the_api_replica_stops_the_job_on_the_worker() {
    let url = fresh_url();
    let data = tempfile::tempdir().unwrap();
    let (_api, api) = spawn_role(data.path(), &url, "api", &[]);
    let (_worker, worker) = spawn_role(data.path(), &url, "worker", &[]);
    // The worker serves no job routes.
    assert_eq!(get(&format!("{worker}/v1/jobs")).status, 404);
    // Spot at 8192² runs for seconds: long enough to cancel mid-job.
    let r = submit(&api, &spot_parts(8192), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    wait_for(&api, &id, Duration::from_secs(60), |s| s == "processing");
    let r = request("POST", &format!("{api}/v1/jobs/{id}/cancel"), &[], None);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    // The worker's heartbeat (every second at most) brings the request; it records the cancel.
    let doc = wait_for(&api, &id, Duration::from_secs(10), terminal);
    assert_eq!(doc["status"], "canceled", "{doc}");
    assert_eq!(doc["attempts"], 1);
}
