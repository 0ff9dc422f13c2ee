//! Storage failures, continued (issue 9, item 5): a disk that fills while an upload is spooled
//! (507, no OS text, no temp file left), a database that cannot grow (SQLite `SQLITE_FULL`
//! through `PRAGMA max_page_count`: 507), a job whose end the store refuses (retried without a
//! restart, and recorded as `result-not-stored` when it never can be), and `/readyz` following a
//! live probe: not ready while the fault lasts, ready again once it clears.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use chrono::{DateTime, Utc};
use retex::service::jobs::runner::FINISH_SLOW_ROUNDS;
use retex::service::model::{JobProgress, JobRecord};
use retex::service::store::sqlite::SqliteJobStore;
use retex::service::store::{
    BlobStore, CreateOutcome, Finish, JobStore, ListFilter, ListPage, Recovery, StatusCounts,
    StoreError,
};
use uuid::Uuid;

use crate::service_common::*;
use crate::storage_faults::{assert_no_os_text, full_disk_server, wait_ready, wait_readyz};

/// Files left in the blob store's temp folder (its lock file aside).
fn temp_files(s: &TestServer) -> Vec<String> {
    let dir = s.state.blobs.temp_dir();
    std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn an_upload_spooled_onto_a_full_disk_is_507_and_leaves_no_temp_file() {
    let (s, full, refused) = full_disk_server(&["upload"], |c| c.storage_retry_secs = 60);
    let r = submit(&s.base, &spot_parts(16), &[]);
    let p = r.problem(507);
    assert_eq!(p["type"], "/problems/insufficient-storage", "{p}");
    assert!(r.header("retry-after").is_some(), "{:?}", r.headers);
    assert_no_os_text(&r);
    assert!(
        refused.load(Ordering::SeqCst) > 0,
        "the spool never hit the full disk"
    );
    assert_eq!(
        temp_files(&s),
        Vec::<String>::new(),
        "partial upload left behind"
    );
    let list = get(&format!("{}/v1/jobs", s.base)).json();
    assert_eq!(list["jobs"].as_array().unwrap().len(), 0, "{list}");
    // Space again: the same upload is accepted.
    full.store(false, Ordering::SeqCst);
    assert_eq!(submit(&s.base, &spot_parts(16), &[]).status, 202);
}

#[test]
fn a_zip_unpacked_onto_a_full_disk_is_507_not_an_invalid_zip() {
    // The zip part is spooled; its entries fill the disk as they are extracted.
    let (s, _, refused) = full_disk_server(&["-zip-"], |c| c.storage_retry_secs = 60);
    let mut parts = spot_parts(16);
    let mut zip_bytes = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut zip_bytes);
        z.start_file("spot.glb", zip::write::SimpleFileOptions::default())
            .unwrap();
        std::io::Write::write_all(&mut z, &parts[0].2).unwrap();
        z.finish().unwrap();
    }
    parts[0] = ("source", "spot.zip", zip_bytes.into_inner());
    let r = submit(&s.base, &parts, &[]);
    let p = r.problem(507);
    assert_eq!(p["type"], "/problems/insufficient-storage", "{p}");
    assert_no_os_text(&r);
    assert!(refused.load(Ordering::SeqCst) > 0);
    assert_eq!(
        temp_files(&s),
        Vec::<String>::new(),
        "partial upload left behind"
    );
}

#[test]
fn a_database_that_cannot_grow_is_507_and_readyz_recovers_when_it_can() {
    // The server's job store is a second store on the same file whose writer is capped at the
    // database's current size: SQLite answers SQLITE_FULL as on a full disk.
    let dir: Arc<Mutex<PathBuf>> = Arc::default();
    let capped: Arc<Mutex<Option<Arc<SqliteJobStore>>>> = Arc::default();
    let (d, c) = (dir.clone(), capped.clone());
    let s = TestServer::start_wrapped(
        move |cfg| {
            cfg.storage_retry_secs = 60;
            *d.lock().unwrap() = cfg.db_path();
        },
        move |_, blobs| {
            let store = Arc::new(SqliteJobStore::open(&dir.lock().unwrap()).unwrap());
            *c.lock().unwrap() = Some(store.clone());
            (store as Arc<dyn JobStore>, blobs)
        },
    );
    let store = capped.lock().unwrap().clone().unwrap();
    assert_eq!(get(&format!("{}/readyz", s.base)).status, 200);
    let pages = store.page_count().unwrap();
    assert_eq!(store.limit_pages(pages).unwrap(), pages);
    // The probe asks for pages the database cannot get (on its next run: at most 2 s).
    let p = wait_readyz(&s.base, 503, Duration::from_secs(10)).problem(503);
    assert_eq!(p["type"], "/problems/storage-failing", "{p}");
    // Jobs fill the pages there are; the first that needs one more is refused.
    let mut accepted = 0;
    let full = loop {
        let r = submit(&s.base, &spot_parts(16), &[]);
        if r.status != 202 {
            break r;
        }
        accepted += 1;
        assert!(accepted < 40, "the capped database never filled");
    };
    let p = full.problem(507);
    assert_eq!(p["type"], "/problems/insufficient-storage", "{p}");
    assert!(full.header("retry-after").is_some(), "{:?}", full.headers);
    assert_no_os_text(&full);
    let p = get(&format!("{}/readyz", s.base)).problem(503);
    assert_eq!(p["type"], "/problems/storage-failing", "{p}");
    // Room again: ready on a later poll (storage_retry_secs is 60: no time window), and the
    // refused upload is accepted.
    store.limit_pages(1 << 30).unwrap();
    wait_ready(&s.base, Duration::from_secs(10));
    assert_eq!(submit(&s.base, &spot_parts(16), &[]).status, 202);
}

#[test]
fn readyz_follows_a_live_probe_of_the_blob_store() {
    let (s, full, _) = full_disk_server(&["health"], |c| c.storage_retry_secs = 60);
    let p = get(&format!("{}/readyz", s.base)).problem(503);
    assert_eq!(p["type"], "/problems/storage-failing", "{p}");
    assert!(p.get("limit").is_none(), "{p}");
    full.store(false, Ordering::SeqCst);
    wait_ready(&s.base, Duration::from_secs(10));
    // And not ready again once the disk fills again (within the probe interval).
    full.store(true, Ordering::SeqCst);
    let p = wait_readyz(&s.base, 503, Duration::from_secs(10)).problem(503);
    assert_eq!(p["type"], "/problems/storage-failing", "{p}");
}

/// A job store whose `finish` is refused (a database I/O error, not a full disk) while `fail`
/// is set, or always for successes when `successes_only` is set.
struct RefusingFinish {
    inner: Arc<dyn JobStore>,
    fail: Arc<AtomicBool>,
    successes_only: bool,
    refused: Arc<AtomicUsize>,
}

impl JobStore for RefusingFinish {
    fn create_bounded(&self, job: &JobRecord, queue_len: u64) -> Result<CreateOutcome, StoreError> {
        self.inner.create_bounded(job, queue_len)
    }
    fn job_of_key(&self, key: &str) -> Result<Option<Uuid>, StoreError> {
        self.inner.job_of_key(key)
    }
    fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        self.inner.get(id)
    }
    fn list(&self, filter: &ListFilter) -> Result<ListPage, StoreError> {
        self.inner.list(filter)
    }
    fn claim_next(&self, now: DateTime<Utc>) -> Result<Option<JobRecord>, StoreError> {
        self.inner.claim_next(now)
    }
    fn update_progress(&self, id: Uuid, progress: &JobProgress) -> Result<(), StoreError> {
        self.inner.update_progress(id, progress)
    }
    fn finish(
        &self,
        id: Uuid,
        outcome: Finish,
        now: DateTime<Utc>,
    ) -> Result<JobRecord, StoreError> {
        let refuse = if self.successes_only {
            matches!(outcome, Finish::Succeeded { .. })
        } else {
            self.fail.load(Ordering::SeqCst)
        };
        if refuse {
            self.refused.fetch_add(1, Ordering::SeqCst);
            return Err(StoreError::Database("disk I/O error".into()));
        }
        self.inner.finish(id, outcome, now)
    }
    fn cancel_if_enqueued(&self, id: Uuid, now: DateTime<Utc>) -> Result<JobRecord, StoreError> {
        self.inner.cancel_if_enqueued(id, now)
    }
    fn recover(&self, max_attempts: u32, now: DateTime<Utc>) -> Result<Recovery, StoreError> {
        self.inner.recover(max_attempts, now)
    }
    fn requeue_stopped(
        &self,
        ids: &[Uuid],
        now: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.inner.requeue_stopped(ids, now)
    }
    fn delete(&self, id: Uuid) -> Result<JobRecord, StoreError> {
        self.inner.delete(id)
    }
    fn prune(
        &self,
        finished_before: DateTime<Utc>,
        keys_before: DateTime<Utc>,
    ) -> Result<Vec<JobRecord>, StoreError> {
        self.inner.prune(finished_before, keys_before)
    }
    fn counts(&self) -> Result<StatusCounts, StoreError> {
        self.inner.counts()
    }
}

fn refusing_server(successes_only: bool) -> (TestServer, Arc<AtomicBool>, Arc<AtomicUsize>) {
    let fail = Arc::new(AtomicBool::new(true));
    let refused = Arc::new(AtomicUsize::new(0));
    let (f, r) = (fail.clone(), refused.clone());
    let s = TestServer::start_wrapped(
        |c| {
            c.workers = 1;
            c.storage_retry_secs = 1;
        },
        move |jobs, blobs| {
            let wrapped: Arc<dyn JobStore> = Arc::new(RefusingFinish {
                inner: jobs,
                fail: f,
                successes_only,
                refused: r,
            });
            (wrapped, blobs as Arc<dyn BlobStore>)
        },
    );
    (s, fail, refused)
}

#[test]
fn a_job_whose_end_the_store_refuses_is_recorded_once_it_can_be_without_a_restart() {
    let (s, fail, refused) = refusing_server(false);
    let r = submit(&s.base, &spot_parts(16), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    // Past the four quick tries: the old runner gave up here and left the job processing.
    let end = Instant::now() + Duration::from_secs(120);
    while refused.load(Ordering::SeqCst) < 6 {
        assert!(Instant::now() < end, "the job never tried to finish");
        std::thread::sleep(Duration::from_millis(50));
    }
    let doc = get(&format!("{}/v1/jobs/{id}", s.base)).json();
    assert_eq!(doc["status"], "processing", "{doc}");
    fail.store(false, Ordering::SeqCst);
    let doc = wait_for(&s.base, &id, Duration::from_secs(30), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
    assert_eq!(doc["attempts"], 1, "{doc}");
    assert_eq!(get(&format!("{}/v1/jobs/{id}/result", s.base)).status, 200);
    // The worker is free again: the next job runs.
    let r = submit(&s.base, &spot_parts(16), &[]);
    let next = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&s.base, &next, Duration::from_secs(60), terminal);
    assert_eq!(doc["status"], "succeeded", "{doc}");
}

#[test]
fn a_success_that_can_never_be_stored_ends_failed_with_a_stable_type() {
    let (s, _, refused) = refusing_server(true);
    let r = submit(&s.base, &spot_parts(16), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let doc = wait_for(&s.base, &id, Duration::from_secs(90), terminal);
    assert_eq!(doc["status"], "failed", "{doc}");
    assert_eq!(doc["error"]["type"], "/problems/result-not-stored", "{doc}");
    let detail = doc["error"]["detail"]
        .as_str()
        .unwrap()
        .to_ascii_lowercase();
    assert!(!detail.contains("i/o error"), "raw store text: {detail}");
    // Four quick tries, then one more round per storage_retry_secs until the switch.
    let tries = refused.load(Ordering::SeqCst);
    assert_eq!(tries, 4 * (1 + FINISH_SLOW_ROUNDS as usize), "{tries}");
}
