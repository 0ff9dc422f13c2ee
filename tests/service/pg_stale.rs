//! Issue 17 part 2: a job attempt that lost its lease cannot replace a result another attempt
//! committed. Two ways to lose it:
//!
//! - in process, deterministic: replica A's job store answers every heartbeat "held" without
//!   renewing the lease (a replica that does not know it is cut off), and A's engine call waits
//!   until replica B has reclaimed the job after the lease ran out and committed attempt 2; then
//!   A completes, stores its outputs under `a1/` (counted), its finish is refused, and it deletes
//!   them; B's `a2/` files and the record are untouched;
//! - as processes: replica A is frozen (`SIGSTOP`) in the middle of a job, so its heartbeats stop;
//!   its lease runs out, replica B reclaims the job and commits it (attempt 2). A is then thawed
//!   (`SIGCONT`) and carries on with the job it no longer holds: the store refuses its finish (or
//!   its next heartbeat reports the lease lost), and it deletes whatever it wrote under its own
//!   attempt's folder. Attempt 2's files, read back from the S3 bucket, keep the size and SHA-256
//!   of the record; attempt 1 leaves nothing behind; A lives on and runs the next job.
//!
//! Needs the throw-away servers of `pg_server` and `s3_server` (ignored by default; CI runs
//! them).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use chrono::{DateTime, Utc};
use retex::service::model::{JobProgress, JobRecord};
use retex::service::store::postgres::PgJobStore;
use retex::service::store::{
    BlobStore, CreateOutcome, Finish, JobStore, Lease, ListFilter, ListPage, Recovery,
    StatusCounts, StoreError,
};
use sha2::Digest;
use uuid::Uuid;

use crate::pg_kill::{wait_busy, Blobs};
use crate::pg_server::fresh_url;
use crate::s3_server::fresh_bucket;
use crate::service_common::*;

fn signal(p: &ServeProcess, sig: i32) {
    // SAFETY: kill(2) on the child's pid; no memory is passed.
    let rc = unsafe { libc::kill(p.0.id() as i32, sig) };
    assert_eq!(rc, 0, "kill({sig})");
}

#[test]
#[ignore = "needs PostgreSQL binaries and moto[server] (python3 -m pip install 'moto[server]')"]
fn a_frozen_replica_past_its_lease_never_replaces_the_committed_result() {
    let url = fresh_url();
    let mut blobs = Blobs::S3(fresh_bucket(), Vec::new());
    let (a, base_a) = blobs.spawn(&url, 0);
    let r = submit(&base_a, &spot_parts(2048), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id: Uuid = r.json()["id"].as_str().unwrap().parse().unwrap();
    wait_busy(&base_a);
    signal(&a, libc::SIGSTOP);
    let frozen_at = Instant::now();

    // B starts only now, so the job can reach it only through A's expired lease.
    let (_b, base_b) = blobs.spawn(&url, 1);
    let doc = wait_for(&base_b, &id.to_string(), Duration::from_secs(300), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    assert_eq!(doc["attempts"], 2, "B ran it as the second attempt: {doc}");
    let committed = frozen_at.elapsed();

    signal(&a, libc::SIGCONT);
    let Blobs::S3(bucket, _) = &blobs else {
        unreachable!()
    };
    let spool = tempfile::tempdir().unwrap();
    let store = bucket.open(spool.path());
    let observer = PgJobStore::connect(&url, Duration::from_secs(30)).unwrap();
    let job = observer.get(id).unwrap().unwrap();
    assert!(!job.artifacts.is_empty());
    // A finishes its engine call and gives up (its finish refused, or its heartbeat answered
    // "lost"); give it time to, then check both attempts' folders.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let leftovers: Vec<String> = job
            .artifacts
            .iter()
            .map(|a| format!("jobs/{id}/outputs/a1/{}", a.name))
            .filter(|k| !matches!(store.len(k), Err(StoreError::BlobNotFound(_))))
            .collect();
        if leftovers.is_empty() && busy_free(&base_a) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "attempt 1 left {leftovers:?} (B committed {committed:?} after the freeze)"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let job_now = observer.get(id).unwrap().unwrap();
    assert_eq!(
        job_now.artifacts, job.artifacts,
        "the record did not change"
    );
    assert_eq!(job_now.attempts, 2);
    for art in &job.artifacts {
        assert!(
            art.key.starts_with(&format!("jobs/{id}/outputs/a2/")),
            "{}",
            art.key
        );
        let bytes = store.get(&art.key).unwrap();
        assert_eq!(bytes.len() as u64, art.size, "{}", art.key);
        let sha = hex::encode(sha2::Sha256::digest(&bytes));
        assert_eq!(sha, art.sha256, "{} was replaced", art.key);
    }
    // A is alive and still takes work.
    assert_eq!(get(&format!("{base_a}/healthz")).status, 200);
    let r = submit(&base_a, &spot_parts(64), &[]);
    assert_eq!(r.status, 202);
    let next = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&base_a, &next, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
}

/// Whether the replica runs no job now.
fn busy_free(base: &str) -> bool {
    crate::pg_kill::busy_workers(base) == 0
}

/// A job store that answers every heartbeat "held" without renewing the lease and hears no
/// change feed: a replica cut off from the database's view of its leases.
struct DeafLease(Arc<dyn JobStore>);

impl JobStore for DeafLease {
    fn create_bounded(&self, job: &JobRecord, queue_len: u64) -> Result<CreateOutcome, StoreError> {
        self.0.create_bounded(job, queue_len)
    }
    fn job_of_key(&self, key: &str) -> Result<Option<Uuid>, StoreError> {
        self.0.job_of_key(key)
    }
    fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        self.0.get(id)
    }
    fn list(&self, filter: &ListFilter) -> Result<ListPage, StoreError> {
        self.0.list(filter)
    }
    fn claim_next(&self, now: DateTime<Utc>) -> Result<Option<JobRecord>, StoreError> {
        self.0.claim_next(now)
    }
    fn update_progress(&self, id: Uuid, progress: &JobProgress) -> Result<(), StoreError> {
        self.0.update_progress(id, progress)
    }
    fn finish(
        &self,
        id: Uuid,
        outcome: Finish,
        now: DateTime<Utc>,
    ) -> Result<JobRecord, StoreError> {
        self.0.finish(id, outcome, now)
    }
    fn cancel_if_enqueued(&self, id: Uuid, now: DateTime<Utc>) -> Result<JobRecord, StoreError> {
        self.0.cancel_if_enqueued(id, now)
    }
    fn recover(&self, max_attempts: u32, now: DateTime<Utc>) -> Result<Recovery, StoreError> {
        self.0.recover(max_attempts, now)
    }
    fn requeue_stopped(
        &self,
        ids: &[Uuid],
        now: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.0.requeue_stopped(ids, now)
    }
    fn delete(&self, id: Uuid) -> Result<JobRecord, StoreError> {
        self.0.delete(id)
    }
    fn prune(
        &self,
        finished_before: DateTime<Utc>,
        keys_before: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.0.prune(finished_before, keys_before)
    }
    fn counts(&self) -> Result<StatusCounts, StoreError> {
        self.0.counts()
    }
    fn lease_duration(&self) -> Option<Duration> {
        self.0.lease_duration()
    }
    fn heartbeat(&self, _id: Uuid, _now: DateTime<Utc>) -> Result<Lease, StoreError> {
        Ok(Lease::Held {
            cancel_requested: false,
        })
    }
    fn reclaim_expired(
        &self,
        max_attempts: u32,
        now: DateTime<Utc>,
    ) -> Result<Recovery, StoreError> {
        self.0.reclaim_expired(max_attempts, now)
    }
}

/// A blob store that counts the create-only puts under keys containing `needle`.
struct CountingPuts {
    inner: Arc<dyn BlobStore>,
    needle: String,
    count: Arc<AtomicUsize>,
}

impl BlobStore for CountingPuts {
    fn put(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.inner.put(key, bytes)
    }
    fn put_new(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        let r = self.inner.put_new(key, bytes);
        if r.is_ok() && key.contains(&self.needle) {
            self.count.fetch_add(1, Ordering::SeqCst);
        }
        r
    }
    fn put_file(&self, key: &str, temp: &Path) -> Result<(), StoreError> {
        self.inner.put_file(key, temp)
    }
    fn get(&self, key: &str) -> Result<Vec<u8>, StoreError> {
        self.inner.get(key)
    }
    fn len(&self, key: &str) -> Result<u64, StoreError> {
        self.inner.len(key)
    }
    fn read_range(&self, key: &str, offset: u64, len: u64) -> Result<Vec<u8>, StoreError> {
        self.inner.read_range(key, offset, len)
    }
    fn delete_prefix(&self, prefix: &str) -> Result<(), StoreError> {
        self.inner.delete_prefix(prefix)
    }
    fn temp_dir(&self) -> PathBuf {
        self.inner.temp_dir()
    }
    fn sweep_temp(&self, older_than: Duration) -> Result<usize, StoreError> {
        self.inner.sweep_temp(older_than)
    }
}

#[test]
#[ignore = "needs PostgreSQL binaries and moto[server] (python3 -m pip install 'moto[server]')"]
fn an_attempt_unaware_of_its_lost_lease_stores_nothing_that_stays() {
    let url = fresh_url();
    let bucket = Arc::new(fresh_bucket());
    let spools = tempfile::tempdir().unwrap();
    let a1_puts = Arc::new(AtomicUsize::new(0));
    let config = |u: String| {
        move |c: &mut retex::service::config::ServeConfig| {
            c.database_url = Some(u);
            c.lease_secs = 3;
            c.workers = 1;
        }
    };
    let (bk, spool, count) = (bucket.clone(), spools.path().join("a"), a1_puts.clone());
    let a = TestServer::start_wrapped(config(url.clone()), move |jobs, _| {
        let jobs: Arc<dyn JobStore> = Arc::new(DeafLease(jobs));
        let blobs: Arc<dyn BlobStore> = Arc::new(CountingPuts {
            inner: Arc::new(bk.open(&spool)),
            needle: "/outputs/a1/".into(),
            count,
        });
        (jobs, blobs)
    });
    let (entered, release) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicBool::new(false)),
    );
    let (e, r) = (entered.clone(), release.clone());
    a.state
        .runner
        .set_engine_hook(Some(Arc::new(move |_job: &JobRecord| {
            e.store(true, Ordering::SeqCst);
            let until = Instant::now() + Duration::from_secs(180);
            while !r.load(Ordering::SeqCst) && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(20));
            }
        })));
    let resp = submit(&a.base, &spot_parts(64), &[]);
    assert_eq!(resp.status, 202, "{}", String::from_utf8_lossy(&resp.body));
    let id: Uuid = resp.json()["id"].as_str().unwrap().parse().unwrap();
    let start = Instant::now();
    while !entered.load(Ordering::SeqCst) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "A never started the job"
        );
        std::thread::sleep(Duration::from_millis(20));
    }

    // B reclaims the job once A's lease (3 s) ran out and commits it as attempt 2.
    let (bk, spool) = (bucket.clone(), spools.path().join("b"));
    let b = TestServer::start_wrapped(config(url.clone()), move |jobs, _| {
        (jobs, Arc::new(bk.open(&spool)) as Arc<dyn BlobStore>)
    });
    let doc = wait_for(&b.base, &id.to_string(), Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    assert_eq!(doc["attempts"], 2, "{doc}");
    let observer = PgJobStore::connect(&url, Duration::from_secs(30)).unwrap();
    let committed = observer.get(id).unwrap().unwrap();

    // A goes on: its engine call completes and it stores its outputs as attempt 1.
    release.store(true, Ordering::SeqCst);
    let store = bucket.open(&spools.path().join("check"));
    let leftover = |name: &str| {
        let key = format!("jobs/{id}/outputs/a1/{name}");
        !matches!(store.len(&key), Err(StoreError::BlobNotFound(_)))
    };
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let stored = a1_puts.load(Ordering::SeqCst);
        let left: Vec<&str> = committed
            .artifacts
            .iter()
            .map(|x| x.name.as_str())
            .filter(|n| leftover(n))
            .collect();
        if stored >= committed.artifacts.len() && left.is_empty() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "A stored {stored} of {} outputs under a1/, {left:?} left",
            committed.artifacts.len()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let now = observer.get(id).unwrap().unwrap();
    assert_eq!(now.artifacts, committed.artifacts, "the record changed");
    assert_eq!((now.attempts, now.status), (2, committed.status));
    for art in &committed.artifacts {
        assert!(art.key.contains("/outputs/a2/"), "{}", art.key);
        let bytes = store.get(&art.key).unwrap();
        let sha = hex::encode(sha2::Sha256::digest(&bytes));
        assert_eq!(sha, art.sha256, "{} was replaced", art.key);
    }
    // Served the same by both replicas.
    let ra = get(&format!("{}/v1/jobs/{id}/result", a.base)).body;
    let rb = get(&format!("{}/v1/jobs/{id}/result", b.base)).body;
    assert!(ra == rb && &ra[..4] == b"glTF");
}
