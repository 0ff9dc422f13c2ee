//! Issue 17, part 4: three `retex serve` replicas on one database run 30 jobs while one replica
//! is `kill -9`'d in the middle of a job and another is restarted (SIGTERM, then started again).
//! The killed replica is the one that claimed a slow job submitted first (about 15 s), so the
//! kill always interrupts a running attempt.
//! Every job succeeds exactly once visibly: the job the killed replica held goes back to the
//! queue once its lease expires (measured through the change feed, against the lease time) and
//! runs again elsewhere (attempt 2), the restarted replica gives its job back without spending
//! an attempt (attempt 1), and every result is served identically by every live replica.
//!
//! Twice: with blobs in one shared data directory, and with blobs in an S3 bucket (moto), each
//! replica on its own data directory (no shared disk at all); there every stored artifact is
//! also read back from the bucket and checked against the size and SHA-256 its record holds,
//! under the folder of the attempt that committed it (nothing lost, nothing overwritten).
//!
//! Needs the throw-away servers of `pg_server` and `s3_server` (ignored by default; CI runs
//! them).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use chrono::{DateTime, Utc};
use retex::service::model::JobStatus;
use retex::service::store::postgres::PgJobStore;
use retex::service::store::JobStore;
use sha2::Digest;
use uuid::Uuid;

use crate::pg_server::fresh_url;
use crate::s3_server::{fresh_bucket, S3Bucket};
use crate::service_common::*;

pub(crate) const LEASE_SECS: u64 = 5;
const JOBS: usize = 30;

/// `retex_workers_busy` of a replica's `/metrics`.
pub(crate) fn busy_workers(base: &str) -> u64 {
    let text = String::from_utf8(get(&format!("{base}/metrics")).body).unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix("retex_workers_busy "))
        .and_then(|v| v.trim().parse().ok())
        .expect("retex_workers_busy in /metrics")
}

/// Waits (up to a minute) until `base` runs a job.
pub(crate) fn wait_busy(base: &str) {
    let start = Instant::now();
    while busy_workers(base) == 0 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "{base} never ran a job"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits (up to a minute) until one of `replicas` runs a job; returns its index.
fn wait_any_busy(replicas: &[(ServeProcess, String)]) -> usize {
    let start = Instant::now();
    loop {
        if let Some(i) = replicas.iter().position(|(_, base)| busy_workers(base) > 0) {
            return i;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no replica ran a job"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Sends SIGTERM and waits for the process to exit.
fn terminate(p: &mut ServeProcess) {
    // SAFETY: kill(2) on the child's pid; no memory is passed.
    let rc = unsafe { libc::kill(p.0.id() as i32, libc::SIGTERM) };
    assert_eq!(rc, 0);
    let status = p.0.wait().unwrap();
    assert!(status.success(), "graceful stop exits 0: {status:?}");
}

/// Where the replicas keep blobs.
pub(crate) enum Blobs {
    /// One data directory shared by all replicas.
    SharedDir(tempfile::TempDir),
    /// An S3 bucket; each replica on its own data directory.
    S3(S3Bucket, Vec<tempfile::TempDir>),
}

impl Blobs {
    /// Starts replica `i` (role all, one worker, a short lease).
    pub(crate) fn spawn(&mut self, url: &str, i: usize) -> (ServeProcess, String) {
        let lease = LEASE_SECS.to_string();
        let mut args = vec!["--workers", "1", "--role", "all", "--database-url", url];
        args.extend(["--shutdown-secs", "5", "--memory-bytes", "0"]);
        args.extend(["--lease-secs", lease.as_str()]);
        match self {
            Blobs::SharedDir(dir) => spawn_serve(dir.path(), &args, "warn"),
            Blobs::S3(bucket, dirs) => {
                while dirs.len() <= i {
                    dirs.push(tempfile::tempdir().unwrap());
                }
                args.extend(["--blob-url", bucket.url.as_str()]);
                spawn_serve_env(dirs[i].path(), &args, "warn", &bucket.env)
            }
        }
    }
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn three_replicas_thirty_jobs_one_killed_mid_job_one_restarted() {
    let dir = tempfile::tempdir().unwrap();
    kill_and_restart(Blobs::SharedDir(dir));
}

#[test]
#[ignore = "needs PostgreSQL binaries and moto[server] (python3 -m pip install 'moto[server]')"]
fn three_replicas_on_s3_thirty_jobs_one_killed_mid_job_one_restarted() {
    kill_and_restart(Blobs::S3(fresh_bucket(), Vec::new()));
}

fn kill_and_restart(mut blobs: Blobs) {
    let url = fresh_url();
    let mut replicas: Vec<(ServeProcess, String)> = (0..3).map(|i| blobs.spawn(&url, i)).collect();
    // An observer on the same database records when each job goes back to the queue.
    let observer = PgJobStore::connect(&url, Duration::from_secs(30)).unwrap();
    let requeued: Arc<Mutex<HashMap<Uuid, DateTime<Utc>>>> = Arc::default();
    let seen = Arc::clone(&requeued);
    let last_status: Mutex<HashMap<Uuid, JobStatus>> = Mutex::default();
    assert!(observer.watch_changes(Box::new(move |c| {
        let mut last = last_status.lock().unwrap();
        if last.insert(c.id, c.status) == Some(JobStatus::Processing)
            && c.status == JobStatus::Enqueued
        {
            seen.lock().unwrap().entry(c.id).or_insert_with(Utc::now);
        }
    })));

    // A slow job first, alone in the queue: the replica that claims it is the one killed, so
    // the kill lands mid-job for certain (a short job could end between the gauge read and the
    // kill, and then no attempt would be interrupted).
    let slow = submit(&replicas[0].1, &spot_parts(8192), &[]);
    assert_eq!(slow.status, 202, "{}", String::from_utf8_lossy(&slow.body));
    let slow_id: Uuid = slow.json()["id"].as_str().unwrap().parse().unwrap();
    let victim = wait_any_busy(&replicas);
    let mut ids = vec![slow_id];
    for i in 0..JOBS {
        let r = submit(&replicas[i % 3].1, &spot_parts(1024), &[]);
        assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
        ids.push(r.json()["id"].as_str().unwrap().parse::<Uuid>().unwrap());
    }

    // kill -9 the victim while it runs the slow job (about 15 s long).
    let doc = get(&format!("{}/v1/jobs/{slow_id}", replicas[victim].1)).json();
    assert_eq!(doc["status"], "processing", "{doc}");
    replicas[victim].0 .0.kill().unwrap();
    replicas[victim].0 .0.wait().unwrap();
    let killed_at = Utc::now();
    // Restart another replica (graceful stop while it runs a job: the job goes back to the
    // queue).
    let restarted = (victim + 1) % 3;
    let other = (victim + 2) % 3;
    wait_busy(&replicas[restarted].1);
    terminate(&mut replicas[restarted].0);
    replicas[restarted] = blobs.spawn(&url, restarted);
    let live = [replicas[other].1.clone(), replicas[restarted].1.clone()];

    let mut attempts = HashMap::new();
    for (i, id) in ids.iter().enumerate() {
        let doc = wait_for(
            &live[i % 2],
            &id.to_string(),
            Duration::from_secs(300),
            terminal,
        );
        assert_eq!(doc["status"], "succeeded", "{doc}");
        attempts.insert(*id, doc["attempts"].as_u64().unwrap());
        let a = get(&format!("{}/v1/jobs/{id}/result", live[0])).body;
        let b = get(&format!("{}/v1/jobs/{id}/result", live[1])).body;
        assert_eq!(&a[..4], b"glTF");
        assert!(a == b, "job {id}: both replicas serve the same result");
    }

    // Exactly one job, the slow one, was interrupted by the crash: it ran a second time. The job of the
    // gracefully stopped replica gave its attempt back.
    let twice: Vec<&Uuid> = attempts
        .iter()
        .filter(|(_, n)| **n == 2)
        .map(|(id, _)| id)
        .collect();
    assert_eq!(twice, [&slow_id], "attempts: {attempts:?}");
    assert!(attempts.values().all(|n| *n <= 2), "{attempts:?}");
    let crashed = slow_id;
    let back = requeued.lock().unwrap()[&crashed];
    let waited = (back - killed_at).to_std().unwrap_or_default();
    // Reclaimed once its lease ran out: within the lease plus one poll tick (1 s) and the
    // observer's delivery (generous 2 s).
    assert!(
        waited <= Duration::from_secs(LEASE_SECS + 3),
        "the crashed job went back to the queue {waited:?} after the kill (lease {LEASE_SECS} s)"
    );
    // Every list shows the 30 jobs and the slow one succeeded, nothing else.
    let list = get(&format!("{}/v1/jobs?limit=100", live[0])).json();
    let jobs = list["jobs"].as_array().unwrap();
    assert_eq!(jobs.len(), JOBS + 1);
    assert!(jobs.iter().all(|j| j["status"] == "succeeded"), "{list}");

    // Every artifact is in the bucket under its committing attempt's folder, as recorded.
    if let Blobs::S3(bucket, _) = &blobs {
        let spool = tempfile::tempdir().unwrap();
        let store = bucket.open(spool.path());
        for id in &ids {
            let job = observer.get(*id).unwrap().unwrap();
            for a in &job.artifacts {
                let folder = format!("jobs/{id}/outputs/a{}/", job.attempts);
                assert!(a.key.starts_with(&folder), "{} not under {folder}", a.key);
                let bytes = retex::service::store::BlobStore::get(&store, &a.key).unwrap();
                assert_eq!(bytes.len() as u64, a.size, "{}", a.key);
                let sha = sha2::Sha256::digest(&bytes);
                assert_eq!(hex::encode(sha), a.sha256, "{} was overwritten", a.key);
            }
        }
    }
}
