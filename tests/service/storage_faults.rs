//! Storage failures (issue 9, item 5), injected with a blob-store wrapper that answers ENOSPC
//! and with a second SQLite connection that holds the write lock: a full disk is 507
//! `insufficient-storage` without OS text, a locked database is 503 `store-busy` with
//! `Retry-After`, a job whose outputs hit a full disk goes back to the queue and succeeds once
//! space is back, and `/readyz` is not ready on a storage failure, low free space, a full
//! queue, or while draining (and keeps answering then). More in `storage_live`.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use retex::service::jobs::runner::EngineHook;
use retex::service::store::{BlobStore, StoreError};

use crate::service_common::*;

/// ENOSPC, as the kernel reports it.
pub fn enospc() -> std::io::Error {
    std::io::Error::from_raw_os_error(28)
}

/// A blob store whose writes of keys (and spooled upload files) whose name contains one of
/// `needles` fail with ENOSPC while `full` is set. The `/readyz` probe writes the key
/// `health/probe` (needle `health`); uploads are spooled to `upload-<uuid>-part-<n>` (needle
/// `upload`).
pub struct FullDisk {
    pub inner: Arc<dyn BlobStore>,
    pub full: Arc<AtomicBool>,
    pub needles: &'static [&'static str],
    pub refused: Arc<AtomicUsize>,
}

impl FullDisk {
    fn hit(&self, name: &str) -> bool {
        self.full.load(Ordering::SeqCst) && self.needles.iter().any(|n| name.contains(n))
    }

    fn check(&self, key: &str) -> Result<(), StoreError> {
        if self.hit(key) {
            self.refused.fetch_add(1, Ordering::SeqCst);
            return Err(StoreError::Io(enospc()));
        }
        Ok(())
    }
}

/// A spooled upload file on a disk that fills up: the first `room` bytes are written, then
/// every write fails with ENOSPC (as a real full disk does part-way through a file).
struct FillingFile {
    file: Box<dyn std::io::Write + Send>,
    room: usize,
    refused: Arc<AtomicUsize>,
}

impl std::io::Write for FillingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.room == 0 {
            self.refused.fetch_add(1, Ordering::SeqCst);
            return Err(enospc());
        }
        let n = buf.len().min(self.room);
        let n = self.file.write(&buf[..n])?;
        self.room -= n;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl BlobStore for FullDisk {
    fn put(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.check(key)?;
        self.inner.put(key, bytes)
    }
    fn put_new(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.check(key)?;
        self.inner.put_new(key, bytes)
    }
    fn put_file(&self, key: &str, temp: &Path) -> Result<(), StoreError> {
        self.check(key)?;
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
    fn create_temp(&self, path: &Path) -> std::io::Result<Box<dyn std::io::Write + Send>> {
        let file = self.inner.create_temp(path)?;
        let name = path.file_name().unwrap_or_default().to_string_lossy();
        if !self.hit(&name) {
            return Ok(file);
        }
        Ok(Box::new(FillingFile {
            file,
            room: 8 << 10,
            refused: self.refused.clone(),
        }))
    }
}

/// A server whose blob writes under keys containing one of `needles` fail while the flag is
/// set.
pub fn full_disk_server(
    needles: &'static [&'static str],
    edit: impl FnOnce(&mut retex::service::config::ServeConfig),
) -> (TestServer, Arc<AtomicBool>, Arc<AtomicUsize>) {
    let full = Arc::new(AtomicBool::new(true));
    let refused = Arc::new(AtomicUsize::new(0));
    let (f, r) = (full.clone(), refused.clone());
    let s = TestServer::start_wrapped(edit, move |jobs, blobs| {
        let wrapped: Arc<dyn BlobStore> = Arc::new(FullDisk {
            inner: blobs,
            full: f,
            needles,
            refused: r,
        });
        (jobs, wrapped)
    });
    (s, full, refused)
}

pub fn assert_no_os_text(r: &Resp) {
    let body = String::from_utf8_lossy(&r.body).to_ascii_lowercase();
    for raw in ["no space left", "os error", "database is locked", "sqlite"] {
        assert!(!body.contains(raw), "raw text {raw:?} in {body}");
    }
}

#[test]
fn a_full_disk_at_submission_is_507_without_os_text_and_readyz_turns_unready() {
    // A full disk fails every write: the inputs and the readiness probe.
    let (s, full, refused) =
        full_disk_server(&["/inputs/", "health"], |c| c.storage_retry_secs = 60);
    full.store(false, Ordering::SeqCst);
    assert_eq!(get(&format!("{}/readyz", s.base)).status, 200);
    full.store(true, Ordering::SeqCst);
    let r = submit(&s.base, &spot_parts(16), &[]);
    let p = r.problem(507);
    assert_eq!(p["type"], "/problems/insufficient-storage", "{p}");
    assert!(r.header("retry-after").is_some(), "{:?}", r.headers);
    assert_no_os_text(&r);
    assert!(refused.load(Ordering::SeqCst) > 0);
    let ready = get(&format!("{}/readyz", s.base));
    let p = ready.problem(503);
    assert_eq!(p["type"], "/problems/storage-failing", "{p}");
    assert!(ready.header("retry-after").is_some());
    // Nothing of the refused job is left behind.
    full.store(false, Ordering::SeqCst);
    let list = get(&format!("{}/v1/jobs", s.base)).json();
    assert_eq!(list["jobs"].as_array().unwrap().len(), 0, "{list}");
}

#[test]
fn a_job_whose_outputs_hit_a_full_disk_is_requeued_and_succeeds_later() {
    let (s, full, refused) = full_disk_server(&["/outputs/"], |c| {
        c.storage_retry_secs = 1;
        c.workers = 1;
    });
    let r = submit(&s.base, &spot_parts(16), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let end = Instant::now() + Duration::from_secs(120);
    while refused.load(Ordering::SeqCst) < 2 {
        let doc = get(&format!("{}/v1/jobs/{id}", s.base)).json();
        assert!(!terminal(doc["status"].as_str().unwrap()), "{doc}");
        assert!(
            Instant::now() < end,
            "the job never reached its output write"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // Tried twice (once per storage_retry_secs), never failed; then the disk has space again.
    let doc = get(&format!("{}/v1/jobs/{id}", s.base)).json();
    assert!(!terminal(doc["status"].as_str().unwrap()), "{doc}");
    full.store(false, Ordering::SeqCst);
    let doc = wait_for(&s.base, &id, Duration::from_secs(120), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    // A full disk is not the job's fault: only the start that succeeded counts.
    assert_eq!(doc["attempts"], 1, "{doc}");
    assert_eq!(get(&format!("{}/v1/jobs/{id}/result", s.base)).status, 200);
}

#[test]
fn a_locked_database_is_503_store_busy_with_retry_after() {
    let s = TestServer::start(|c| c.storage_retry_secs = 60);
    let db = s.state.config.db_path();
    let other = rusqlite::Connection::open(&db).unwrap();
    other.execute_batch("BEGIN IMMEDIATE;").unwrap();
    let id = "0190c5a0-0000-7000-8000-000000000000";
    let r = request("DELETE", &format!("{}/v1/jobs/{id}", s.base), &[], None);
    let p = r.problem(503);
    assert_eq!(p["type"], "/problems/store-busy", "{p}");
    assert_eq!(r.header("retry-after"), Some("1"));
    assert_no_os_text(&r);
    // While the lock is held the readiness probe cannot write either.
    let p = get(&format!("{}/readyz", s.base)).problem(503);
    assert_eq!(p["type"], "/problems/storage-failing", "{p}");
    other.execute_batch("COMMIT;").unwrap();
    // The lock is gone: the same call answers normally again, and so does /readyz (its probe
    // is live, not a time window after the failure: storage_retry_secs is 60 here).
    request("DELETE", &format!("{}/v1/jobs/{id}", s.base), &[], None).problem(404);
    wait_ready(&s.base, Duration::from_secs(10));
}

/// Polls `/readyz` until it answers 200 (it probes the storage at most every 2 s).
pub fn wait_ready(base: &str, timeout: Duration) {
    wait_readyz(base, 200, timeout);
}

/// Polls `/readyz` until it answers `status`; returns that answer.
pub fn wait_readyz(base: &str, status: u16, timeout: Duration) -> Resp {
    let end = Instant::now() + timeout;
    loop {
        let r = get(&format!("{base}/readyz"));
        if r.status == status {
            return r;
        }
        assert!(
            Instant::now() < end,
            "/readyz still {}: {}",
            r.status,
            String::from_utf8_lossy(&r.body)
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn readyz_is_not_ready_on_low_free_space() {
    let s = TestServer::start(|c| c.min_free_bytes = u64::MAX);
    let p = get(&format!("{}/readyz", s.base)).problem(503);
    assert_eq!(p["type"], "/problems/low-disk-space", "{p}");
    assert_eq!(p["limit"]["name"], "min_free_bytes", "{p}");
    let s = TestServer::start(|c| c.min_free_bytes = 1);
    let ok = get(&format!("{}/readyz", s.base));
    assert_eq!(ok.status, 200);
    assert!(ok.json()["free_bytes"].as_u64().unwrap() > 0);
}

/// One worker held by a hook until the flag is set, and the job holding it.
fn held_server(
    edit: impl FnOnce(&mut retex::service::config::ServeConfig),
) -> (TestServer, Arc<AtomicBool>) {
    let s = TestServer::start(|c| {
        c.workers = 1;
        edit(c);
    });
    let release = Arc::new(AtomicBool::new(false));
    let r = release.clone();
    let hook: EngineHook = Arc::new(move |_| {
        while !r.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(10));
        }
    });
    s.state.runner.set_engine_hook(Some(hook));
    let first = submit(&s.base, &spot_parts(16), &[]);
    assert_eq!(first.status, 202);
    let id = first.json()["id"].as_str().unwrap().to_string();
    wait_for(&s.base, &id, Duration::from_secs(60), |st| {
        st == "processing"
    });
    (s, release)
}

#[test]
fn readyz_is_not_ready_while_the_queue_is_full() {
    let (s, release) = held_server(|c| c.queue_len = 1);
    assert_eq!(get(&format!("{}/readyz", s.base)).status, 200);
    assert_eq!(submit(&s.base, &spot_parts(16), &[]).status, 202);
    let p = get(&format!("{}/readyz", s.base)).problem(503);
    assert_eq!(p["type"], "/problems/queue-full", "{p}");
    release.store(true, Ordering::SeqCst);
}

#[test]
fn readyz_answers_not_ready_during_the_drain() {
    let (s, release) = held_server(|c| c.shutdown_secs = 10);
    let base = s.base.clone();
    // Shutting down waits for the held job: the drain lasts until it is released.
    let stopper = std::thread::spawn(move || drop(s));
    let end = Instant::now() + Duration::from_secs(8);
    let seen = loop {
        let r = std::panic::catch_unwind(|| get(&format!("{base}/readyz")));
        if let Ok(r) = r {
            if r.status == 503 {
                break r;
            }
        }
        assert!(
            Instant::now() < end,
            "/readyz never answered 503 during the drain"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let p = seen.problem(503);
    assert_eq!(p["type"], "/problems/shutting-down", "{p}");
    // Still answering a moment later: the drain keeps the listener open.
    std::thread::sleep(Duration::from_millis(200));
    get(&format!("{base}/readyz")).problem(503);
    release.store(true, Ordering::SeqCst);
    stopper.join().unwrap();
}
