//! The blob-store suite (issue 17 parts 2 and 4): the same checks on every [`BlobStore`]: the
//! embedded `FsBlobStore`, the object store on a local folder (`file://`) and in memory, and on
//! S3 (moto's server, started by the tests; ignored by default, CI runs it). Round trips,
//! ranges, spooled uploads (one request and multipart), key validation, prefix deletion
//! (retention) and the create-only put that keeps a committed result from being replaced,
//! also under concurrent writers (not on moto, whose check is not atomic).
#![cfg(feature = "service")]

use std::sync::{Arc, Barrier};

use retex::service::store::fs::FsBlobStore;
use retex::service::store::object::{ObjectBlobStore, MULTIPART_FROM};
use retex::service::store::{BlobStore, StoreError};

fn data(n: usize, seed: u32) -> Vec<u8> {
    (0..n as u32)
        .map(|i| (i.wrapping_mul(2_654_435_761).wrapping_add(seed) >> 13) as u8)
        .collect()
}

fn missing<T: std::fmt::Debug>(r: Result<T, StoreError>) -> bool {
    matches!(r, Err(StoreError::BlobNotFound(_)))
}

fn put_get_len_range_and_overwrite(blobs: Arc<dyn BlobStore>) {
    let d = data(10_000, 1);
    let key = "jobs/a/inputs/source/Fox.bin";
    blobs.put(key, &d).unwrap();
    assert_eq!(blobs.get(key).unwrap(), d);
    assert_eq!(blobs.len(key).unwrap(), 10_000);
    assert_eq!(blobs.read_range(key, 100, 50).unwrap(), &d[100..150]);
    assert_eq!(blobs.read_range(key, 9_990, 50).unwrap(), &d[9_990..]);
    assert!(blobs.read_range(key, 20_000, 5).unwrap().is_empty());
    assert!(blobs.read_range(key, 10_000, 5).unwrap().is_empty());
    blobs.put(key, b"new").unwrap();
    assert_eq!(blobs.get(key).unwrap(), b"new");
    assert_eq!(std::fs::read_dir(blobs.temp_dir()).unwrap().count(), 0);
    assert!(missing(blobs.get("jobs/a/missing")));
    assert!(missing(blobs.len("jobs/a/missing")));
    assert!(missing(blobs.read_range("jobs/a/missing", 0, 1)));
    blobs.probe().unwrap();
}

fn put_file_sends_a_spooled_file_and_removes_it(blobs: Arc<dyn BlobStore>) {
    let temp = blobs.temp_dir().join("upload-1");
    std::fs::write(&temp, b"streamed").unwrap();
    blobs.put_file("jobs/b/inputs/target/t.glb", &temp).unwrap();
    assert!(!temp.exists());
    assert_eq!(
        blobs.get("jobs/b/inputs/target/t.glb").unwrap(),
        b"streamed"
    );
    // A file outside the spool folder is refused and left alone.
    let outside = blobs.temp_dir().parent().unwrap().join("outside");
    std::fs::write(&outside, b"x").unwrap();
    assert!(blobs.put_file("jobs/b/x", &outside).is_err());
    assert!(outside.exists());
    std::fs::remove_file(&outside).unwrap();
}

/// Above the multipart threshold of the object store (one request below it): the bytes come
/// back whole and in order.
fn a_large_upload_round_trips(blobs: Arc<dyn BlobStore>) {
    let big = data(MULTIPART_FROM as usize + (5 << 20) + 123, 7);
    let temp = blobs.temp_dir().join("upload-big");
    std::fs::write(&temp, &big).unwrap();
    blobs
        .put_file("jobs/c/inputs/source/big.bin", &temp)
        .unwrap();
    assert_eq!(
        blobs.len("jobs/c/inputs/source/big.bin").unwrap(),
        big.len() as u64
    );
    let back = blobs.get("jobs/c/inputs/source/big.bin").unwrap();
    assert!(back == big, "the multipart upload came back different");
    let mid = MULTIPART_FROM - 10;
    assert_eq!(
        blobs
            .read_range("jobs/c/inputs/source/big.bin", mid, 20)
            .unwrap(),
        &big[mid as usize..mid as usize + 20]
    );
}

fn bad_keys_are_refused(blobs: Arc<dyn BlobStore>) {
    for key in [
        "../x", "/abs", "a//b", "", "a/../b", "a/./b", "a/", "a b", "a\\b", "ä", "..", "a/b\0",
    ] {
        let refused = |r: Result<(), StoreError>| matches!(r, Err(StoreError::InvalidKey(_)));
        assert!(refused(blobs.put(key, b"x")), "{key:?} must be refused");
        assert!(refused(blobs.put_new(key, b"x")), "{key:?} must be refused");
        assert!(
            matches!(blobs.get(key), Err(StoreError::InvalidKey(_))),
            "{key:?}"
        );
    }
    blobs.put("ok/A-z_0.9", b"x").unwrap();
}

fn delete_prefix_removes_a_job_folder_only(blobs: Arc<dyn BlobStore>) {
    blobs.put("jobs/j1/inputs/a.glb", b"1").unwrap();
    blobs.put("jobs/j1/outputs/a1/result.glb", b"2").unwrap();
    blobs.put("jobs/j10/outputs/a1/result.glb", b"3").unwrap();
    blobs.put("jobs/j2/outputs/a1/result.glb", b"4").unwrap();
    blobs.delete_prefix("jobs/j1/").unwrap();
    assert!(missing(blobs.get("jobs/j1/inputs/a.glb")));
    assert!(missing(blobs.get("jobs/j1/outputs/a1/result.glb")));
    assert_eq!(blobs.get("jobs/j10/outputs/a1/result.glb").unwrap(), b"3");
    // A prefix without the trailing slash is a string prefix.
    blobs.delete_prefix("jobs/j1").unwrap();
    assert!(missing(blobs.get("jobs/j10/outputs/a1/result.glb")));
    assert_eq!(blobs.get("jobs/j2/outputs/a1/result.glb").unwrap(), b"4");
    // One attempt's folder only.
    blobs.put("jobs/j2/outputs/a2/result.glb", b"5").unwrap();
    blobs.delete_prefix("jobs/j2/outputs/a2/").unwrap();
    assert!(missing(blobs.get("jobs/j2/outputs/a2/result.glb")));
    assert_eq!(blobs.get("jobs/j2/outputs/a1/result.glb").unwrap(), b"4");
    // Deleting what is not there is fine; escaping the root is not.
    blobs.delete_prefix("jobs/nothing/").unwrap();
    for bad in ["../", "/", ""] {
        assert!(
            matches!(blobs.delete_prefix(bad), Err(StoreError::InvalidKey(_))),
            "{bad:?}"
        );
    }
}

fn put_new_creates_once_and_never_replaces(blobs: Arc<dyn BlobStore>) {
    let key = "jobs/k/outputs/a1/result.glb";
    blobs.put_new(key, b"first").unwrap();
    assert!(matches!(
        blobs.put_new(key, b"second"),
        Err(StoreError::BlobExists(_))
    ));
    assert_eq!(blobs.get(key).unwrap(), b"first");
    assert_eq!(std::fs::read_dir(blobs.temp_dir()).unwrap().count(), 0);
}

/// Eight writers race for one key: exactly one wins and its bytes are what is stored. Not run
/// on moto: its S3 server checks `If-None-Match` and then stores, without a lock, on a
/// threaded server (`moto/s3/responses.py`, moto 5.2), so two racing puts can both succeed
/// there; S3 itself, GCS, Azure and MinIO decide the condition atomically.
fn racing_create_only_puts_have_one_winner(blobs: Arc<dyn BlobStore>) {
    let key = "jobs/k/outputs/a2/result.glb";
    let start = Arc::new(Barrier::new(8));
    let handles: Vec<_> = (0..8u32)
        .map(|i| {
            let (blobs, start) = (blobs.clone(), start.clone());
            std::thread::spawn(move || {
                let mine = data(200_000, i);
                start.wait();
                (blobs.put_new(key, &mine), mine)
            })
        })
        .collect();
    let results: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
    let winners: Vec<&Vec<u8>> = results
        .iter()
        .filter(|(r, _)| r.is_ok())
        .map(|(_, d)| d)
        .collect();
    assert_eq!(winners.len(), 1, "exactly one create-only put succeeds");
    for (r, _) in &results {
        assert!(
            r.is_ok() || matches!(r, Err(StoreError::BlobExists(_))),
            "{r:?}"
        );
    }
    assert!(
        blobs.get(key).unwrap() == *winners[0],
        "the winner's bytes are stored"
    );
}

/// Instantiates the suite for one store (`$open` returns a guard to keep alive and the store).
macro_rules! blob_store_suite {
    ($open:expr, #[$attr:meta]) => {
        blob_store_suite!(@each $open, $attr,
            put_get_len_range_and_overwrite,
            put_file_sends_a_spooled_file_and_removes_it,
            a_large_upload_round_trips,
            bad_keys_are_refused,
            delete_prefix_removes_a_job_folder_only,
            put_new_creates_once_and_never_replaces,
            racing_create_only_puts_have_one_winner
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

fn spool() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

fn arc(store: impl BlobStore) -> Arc<dyn BlobStore> {
    Arc::new(store)
}

mod fs_suite {
    use super::*;
    fn open() -> (tempfile::TempDir, Arc<dyn BlobStore>) {
        let dir = spool();
        let store = arc(FsBlobStore::open(dir.path()).unwrap());
        (dir, store)
    }
    blob_store_suite!(open(), #[doc = "On the file-system store."]);
}

mod object_file_suite {
    use super::*;
    fn open() -> (tempfile::TempDir, Arc<dyn BlobStore>) {
        let dir = spool();
        let url = format!("file://{}", dir.path().join("bucket").display());
        let store = arc(ObjectBlobStore::open(&url, &dir.path().join("spool")).unwrap());
        (dir, store)
    }
    blob_store_suite!(open(), #[doc = "On object_store's local file system."]);
}

mod object_memory_suite {
    use super::*;
    fn open() -> (tempfile::TempDir, Arc<dyn BlobStore>) {
        let dir = spool();
        let store = arc(ObjectBlobStore::in_memory(dir.path()).unwrap());
        (dir, store)
    }
    blob_store_suite!(open(), #[doc = "On object_store's in-memory store."]);
}

mod s3_suite {
    use super::*;
    fn open() -> (tempfile::TempDir, Arc<dyn BlobStore>) {
        let dir = spool();
        let store = arc(crate::s3_server::fresh_bucket().open(dir.path()));
        (dir, store)
    }
    // Without the race (see `racing_create_only_puts_have_one_winner`).
    blob_store_suite!(@each open(), ignore = "needs moto[server] (python3 -m pip install 'moto[server]')",
        put_get_len_range_and_overwrite,
        put_file_sends_a_spooled_file_and_removes_it,
        a_large_upload_round_trips,
        bad_keys_are_refused,
        delete_prefix_removes_a_job_folder_only,
        put_new_creates_once_and_never_replaces
    );
}

/// Two stores on prefixes of one bucket never see or delete each other's blobs.
#[test]
#[ignore = "needs moto[server] (python3 -m pip install 'moto[server]')"]
fn an_object_store_prefix_scopes_every_operation() {
    let dir = spool();
    let bucket = crate::s3_server::fresh_bucket();
    let a = bucket.open(&dir.path().join("a"));
    let name = bucket.url.strip_suffix("/retex").unwrap();
    let on = |url: String| crate::s3_server::S3Bucket {
        url,
        env: bucket.env.clone(),
    };
    let b = on(format!("{name}/other")).open(&dir.path().join("b"));
    let root = on(name.to_string()).open(&dir.path().join("root"));
    a.put("jobs/x/r", b"a").unwrap();
    b.put("jobs/x/r", b"b").unwrap();
    // The prefix is where the objects are.
    assert_eq!(root.get("retex/jobs/x/r").unwrap(), b"a");
    assert_eq!(root.get("other/jobs/x/r").unwrap(), b"b");
    assert!(missing(root.get("jobs/x/r")));
    a.delete_prefix("jobs/").unwrap();
    assert!(missing(a.get("jobs/x/r")));
    assert_eq!(b.get("jobs/x/r").unwrap(), b"b");
    b.delete_prefix("j").unwrap();
    assert!(missing(b.get("jobs/x/r")));
}

/// Retention on S3: deleting a job through the API and the TTL sweep remove every object of
/// that job (inputs and outputs) and nothing of another job.
#[test]
#[ignore = "needs moto[server] (python3 -m pip install 'moto[server]')"]
fn deleting_and_pruning_jobs_removes_their_objects_from_the_bucket() {
    use crate::service_common::*;
    let bucket = Arc::new(crate::s3_server::fresh_bucket());
    let spools = spool();
    let (bk, dir) = (bucket.clone(), spools.path().join("server"));
    let s = TestServer::start_wrapped(
        |c| c.ttl_secs = 1,
        move |jobs, _| (jobs, Arc::new(bk.open(&dir)) as Arc<dyn BlobStore>),
    );
    let store = bucket.open(&spools.path().join("check"));
    let ids: Vec<String> = (0..3)
        .map(|_| {
            let r = submit(&s.base, &spot_parts(64), &[]);
            assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
            r.json()["id"].as_str().unwrap().to_string()
        })
        .collect();
    let mut keys = Vec::new();
    for id in &ids {
        let doc = wait_for(&s.base, id, std::time::Duration::from_secs(120), terminal);
        assert_eq!(doc["status"], "succeeded", "{doc}");
        let job = s.state.jobs.get(id.parse().unwrap()).unwrap().unwrap();
        let mut mine: Vec<String> = job.artifacts.iter().map(|a| a.key.clone()).collect();
        mine.push(job.inputs.constraints.clone());
        mine.push(format!(
            "jobs/{id}/inputs/target/{}",
            job.inputs.target.main
        ));
        for k in &mine {
            assert!(store.len(k).is_ok(), "{k} is in the bucket");
        }
        keys.push(mine);
    }
    let gone = |ks: &[String]| ks.iter().all(|k| missing(store.len(k)));
    let del = request(
        "DELETE",
        &format!("{}/v1/jobs/{}", s.base, ids[0]),
        &[],
        None,
    );
    assert!(del.status == 204 || del.status == 200, "{}", del.status);
    assert!(gone(&keys[0]), "the deleted job's objects are gone");
    assert!(!gone(&keys[1]) && !gone(&keys[2]));
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let removed = retex::service::http::ops::prune_once(&s.state).unwrap();
    assert_eq!(removed, 2);
    assert!(
        gone(&keys[1]) && gone(&keys[2]),
        "pruned jobs' objects are gone"
    );
}
