//! The networked [`BlobStore`] (issue 17 part 2): blobs in an S3 bucket, a Google Cloud Storage
//! bucket, an Azure container or a local folder, through the `object_store` crate, so that
//! several `retex serve` replicas on different machines share uploads and results.
//!
//! `--blob-url` picks the backend by scheme: `s3://bucket/prefix` (endpoint, region and
//! credentials from the usual `AWS_*` variables, e.g. `AWS_ENDPOINT_URL`, `AWS_REGION`,
//! `AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_ALLOW_HTTP=true` for a plain-HTTP endpoint),
//! `gs://bucket/prefix` (`GOOGLE_*`), `az://container/prefix` (`AZURE_*`) or
//! `file:///absolute/folder`. A blob key `jobs/<id>/…` is the object `<prefix>/jobs/<id>/…`.
//!
//! - Writes of a whole object are atomic on every backend (an object appears complete or not at
//!   all); [`BlobStore::put_new`] is a conditional put (`PutMode::Create`: `If-None-Match: *` on
//!   S3, `ifGenerationMatch=0` on GCS, `If-None-Match` on Azure, a no-replace link locally), so
//!   a job attempt that lost its lease cannot replace a result another attempt committed.
//! - Uploads are streamed to a local spool folder first ([`super::spool`]) and sent by
//!   [`BlobStore::put_file`]: in one request up to [`MULTIPART_FROM`] bytes, else as a multipart
//!   upload of [`PART_BYTES`] parts.
//! - Retention: [`BlobStore::delete_prefix`] lists the job's objects and deletes them in batches.
//!
//! [`BlobStore`] is synchronous (its callers are blocking threads); every call runs on this
//! store's own two-thread tokio runtime and the caller waits on a channel, so it works from any
//! thread. Requests are retried by `object_store`'s own retry policy (exponential backoff on
//! 5xx, timeouts and connection errors).

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use futures_util::StreamExt;
use object_store::aws::AmazonS3Builder;
use object_store::azure::MicrosoftAzureBuilder;
use object_store::gcp::GoogleCloudStorageBuilder;
use object_store::local::LocalFileSystem;
use object_store::memory::InMemory;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload, WriteMultipart};
use tokio::runtime::Runtime;

use super::fs::validate_key;
use super::spool::Spool;
use super::{BlobStore, StoreError};

/// Uploads larger than this go up as a multipart upload.
pub const MULTIPART_FROM: u64 = 32 << 20;
/// Part size of a multipart upload (S3's minimum is 5 MiB).
pub const PART_BYTES: usize = 16 << 20;

/// The URL schemes `--blob-url` accepts.
pub const SCHEMES: &[&str] = &["s3", "s3a", "gs", "az", "azure", "abfs", "abfss", "file"];

/// [`BlobStore`] on an `object_store` backend.
#[derive(Debug)]
pub struct ObjectBlobStore {
    store: Arc<dyn ObjectStore>,
    /// Path prefix inside the bucket (no leading or trailing `/`; empty for the root).
    prefix: String,
    spool: Spool,
    /// Runs the async client; `None` only while dropping.
    runtime: Option<Runtime>,
    /// What the store is, for messages (`s3://bucket/prefix`).
    url: String,
}

/// Splits `scheme://authority/path` into its scheme and the path after the authority (without
/// slashes at either end).
///
/// # Errors
/// A message naming what is wrong.
pub fn split_url(url: &str) -> Result<(&str, &str), String> {
    let (scheme, rest) = url
        .split_once("://")
        .ok_or_else(|| format!("{url:?} is not a URL (scheme://…)"))?;
    if !SCHEMES.contains(&scheme) {
        return Err(format!(
            "scheme {scheme:?} is not one of {}",
            SCHEMES.join(", ")
        ));
    }
    if scheme == "file" {
        if !rest.starts_with('/') {
            return Err("a file:// URL needs an absolute path (file:///folder)".into());
        }
        return Ok((scheme, ""));
    }
    let (bucket, path) = rest.split_once('/').unwrap_or((rest, ""));
    if bucket.is_empty() {
        return Err(format!("{url:?} names no bucket or container"));
    }
    Ok((scheme, path.trim_matches('/')))
}

fn object_error(key: &str) -> impl Fn(object_store::Error) -> StoreError + '_ {
    move |e| match e {
        object_store::Error::NotFound { .. } => StoreError::BlobNotFound(key.to_string()),
        object_store::Error::AlreadyExists { .. } | object_store::Error::Precondition { .. } => {
            StoreError::BlobExists(key.to_string())
        }
        other => StoreError::ObjectStore(other.to_string()),
    }
}

impl ObjectBlobStore {
    /// Opens the store a `--blob-url` names, configured from this process's environment, with
    /// `spool_root` as the local folder for uploads in flight (see [`super::spool`]). Nothing
    /// is sent yet (the readiness probe is the first request).
    ///
    /// # Errors
    /// [`StoreError::ObjectStore`] for a URL or configuration the backend refuses,
    /// [`StoreError::Io`] if the spool folder cannot be made.
    pub fn open(url: &str, spool_root: &Path) -> Result<Self, StoreError> {
        Self::open_with(url, spool_root, &[])
    }

    /// As [`ObjectBlobStore::open`], with `options` (named as the environment variables are,
    /// e.g. `AWS_ENDPOINT_URL`) applied over the environment's.
    ///
    /// # Errors
    /// As [`ObjectBlobStore::open`]; an option the backend does not know is an error.
    pub fn open_with(
        url: &str,
        spool_root: &Path,
        options: &[(&str, &str)],
    ) -> Result<Self, StoreError> {
        let bad = |e: String| StoreError::ObjectStore(format!("blob_url {url:?}: {e}"));
        let (scheme, prefix) = split_url(url).map_err(bad)?;
        let unknown = |k: &str| bad(format!("unknown option {k}"));
        let store: Arc<dyn ObjectStore> = match scheme {
            "s3" | "s3a" => {
                let mut b = AmazonS3Builder::from_env().with_url(url);
                for (k, v) in options {
                    b = b.with_config(k.to_ascii_lowercase().parse().map_err(|_| unknown(k))?, *v);
                }
                Arc::new(b.build().map_err(|e| bad(e.to_string()))?)
            }
            "gs" => {
                let mut b = GoogleCloudStorageBuilder::from_env().with_url(url);
                for (k, v) in options {
                    b = b.with_config(k.to_ascii_lowercase().parse().map_err(|_| unknown(k))?, *v);
                }
                Arc::new(b.build().map_err(|e| bad(e.to_string()))?)
            }
            "file" => {
                let folder = PathBuf::from(&url["file://".len()..]);
                std::fs::create_dir_all(&folder)?;
                Arc::new(LocalFileSystem::new_with_prefix(&folder).map_err(|e| bad(e.to_string()))?)
            }
            _ => {
                let mut b = MicrosoftAzureBuilder::from_env().with_url(url);
                for (k, v) in options {
                    b = b.with_config(k.to_ascii_lowercase().parse().map_err(|_| unknown(k))?, *v);
                }
                Arc::new(b.build().map_err(|e| bad(e.to_string()))?)
            }
        };
        Self::with_store(store, prefix, spool_root, url)
    }

    /// An in-memory store (tests: the backend-independent behaviour without a server).
    ///
    /// # Errors
    /// [`StoreError::Io`] if the spool folder cannot be made.
    pub fn in_memory(spool_root: &Path) -> Result<Self, StoreError> {
        Self::with_store(Arc::new(InMemory::new()), "", spool_root, "memory://")
    }

    fn with_store(
        store: Arc<dyn ObjectStore>,
        prefix: &str,
        spool_root: &Path,
        url: &str,
    ) -> Result<Self, StoreError> {
        std::fs::create_dir_all(spool_root)?;
        let spool = Spool::open(&std::fs::canonicalize(spool_root)?)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("retex-blobs")
            .enable_all()
            .build()?;
        Ok(Self {
            store,
            prefix: prefix.to_string(),
            spool,
            runtime: Some(runtime),
            url: url.to_string(),
        })
    }

    /// Where the store is (its URL).
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Runs `fut` on the store's runtime and waits for it (from any thread).
    fn block<T: Send + 'static>(
        &self,
        fut: impl std::future::Future<Output = Result<T, StoreError>> + Send + 'static,
    ) -> Result<T, StoreError> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let rt = self.runtime.as_ref().expect("runtime lives until drop");
        rt.spawn(async move {
            let _ = tx.send(fut.await);
        });
        rx.recv()
            .map_err(|_| StoreError::ObjectStore("the object store task was lost".into()))?
    }

    /// The object path of a (validated) key.
    fn path(&self, key: &str) -> Result<ObjectPath, StoreError> {
        validate_key(key)?;
        Ok(self.raw_path(key))
    }

    fn raw_path(&self, key: &str) -> ObjectPath {
        if self.prefix.is_empty() {
            ObjectPath::from(key)
        } else {
            ObjectPath::from(format!("{}/{key}", self.prefix))
        }
    }

    fn put_mode(&self, key: &str, bytes: &[u8], mode: PutMode) -> Result<(), StoreError> {
        let path = self.path(key)?;
        let (store, key) = (self.store.clone(), key.to_string());
        let payload = PutPayload::from(bytes.to_vec());
        self.block(async move {
            let opts = PutOptions {
                mode,
                ..Default::default()
            };
            store
                .put_opts(&path, payload, opts)
                .await
                .map_err(object_error(&key))?;
            Ok(())
        })
    }

    /// Sends a spooled file as a multipart upload, reading it [`PART_BYTES`] at a time.
    async fn upload_parts(
        store: Arc<dyn ObjectStore>,
        path: ObjectPath,
        file: PathBuf,
        key: String,
    ) -> Result<(), StoreError> {
        use tokio::io::AsyncReadExt;
        let upload = store
            .put_multipart(&path)
            .await
            .map_err(object_error(&key))?;
        let mut writer = WriteMultipart::new_with_chunk_size(upload, PART_BYTES);
        let mut f = tokio::fs::File::open(&file).await?;
        let mut buf = vec![0u8; PART_BYTES];
        loop {
            let n = f.read(&mut buf).await?;
            if n == 0 {
                break;
            }
            writer
                .wait_for_capacity(4)
                .await
                .map_err(object_error(&key))?;
            writer.write(&buf[..n]);
        }
        writer.finish().await.map_err(object_error(&key))?;
        Ok(())
    }

    /// The object paths under `prefix` (see [`BlobStore::delete_prefix`] for its meaning).
    fn matching(&self, prefix: &str) -> Result<Vec<ObjectPath>, StoreError> {
        let bad = || StoreError::InvalidKey(prefix.to_string());
        if prefix.is_empty() || prefix.starts_with('/') {
            return Err(bad());
        }
        let (dir, partial) = match prefix.strip_suffix('/') {
            Some(dir) => (dir, None),
            None => match prefix.rsplit_once('/') {
                Some((dir, last)) => (dir, Some(last)),
                None => ("", Some(prefix)),
            },
        };
        if !dir.is_empty() {
            validate_key(dir).map_err(|_| bad())?;
        }
        if let Some(last) = partial.filter(|l| !l.is_empty()) {
            validate_key(last).map_err(|_| bad())?;
        }
        let listed = match (dir.is_empty(), self.prefix.is_empty()) {
            (true, true) => None,
            (true, false) => Some(ObjectPath::from(self.prefix.as_str())),
            (false, _) => Some(self.raw_path(dir)),
        };
        let wanted = match (&listed, partial) {
            (Some(p), Some(last)) => format!("{p}/{last}"),
            (None, Some(last)) => last.to_string(),
            (Some(p), None) => format!("{p}/"),
            (None, None) => String::new(),
        };
        let store = self.store.clone();
        self.block(async move {
            let mut found = Vec::new();
            let mut listing = store.list(listed.as_ref());
            while let Some(meta) = listing.next().await {
                let meta = meta.map_err(object_error(""))?;
                if meta.location.as_ref().starts_with(&wanted) {
                    found.push(meta.location);
                }
            }
            Ok(found)
        })
    }
}

impl Drop for ObjectBlobStore {
    fn drop(&mut self) {
        // Dropping a runtime from async code panics; shutting it down in the background does not.
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

impl BlobStore for ObjectBlobStore {
    fn put(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.put_mode(key, bytes, PutMode::Overwrite)
    }

    fn put_new(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.put_mode(key, bytes, PutMode::Create)
    }

    /// Sends the spooled file (one request, or a multipart upload from [`MULTIPART_FROM`]
    /// bytes) and removes it once stored; on failure it stays for the caller to remove.
    fn put_file(&self, key: &str, temp: &Path) -> Result<(), StoreError> {
        let path = self.path(key)?;
        let real = self.spool.check_temp(temp)?;
        let size = std::fs::metadata(&real)?.len();
        if size < MULTIPART_FROM {
            let bytes = std::fs::read(&real)?;
            self.put_mode(key, &bytes, PutMode::Overwrite)?;
        } else {
            let (store, file, k) = (self.store.clone(), real.clone(), key.to_string());
            self.block(Self::upload_parts(store, path, file, k))?;
        }
        std::fs::remove_file(&real)?;
        Ok(())
    }

    fn get(&self, key: &str) -> Result<Vec<u8>, StoreError> {
        let path = self.path(key)?;
        let (store, key) = (self.store.clone(), key.to_string());
        self.block(async move {
            let got = store.get(&path).await.map_err(object_error(&key))?;
            let bytes = got.bytes().await.map_err(object_error(&key))?;
            Ok(bytes.to_vec())
        })
    }

    fn len(&self, key: &str) -> Result<u64, StoreError> {
        let path = self.path(key)?;
        let (store, key) = (self.store.clone(), key.to_string());
        self.block(async move {
            let meta = store.head(&path).await.map_err(object_error(&key))?;
            Ok(meta.size)
        })
    }

    /// Up to `len` bytes from `offset`: fewer when the object ends first, none from its end on.
    fn read_range(&self, key: &str, offset: u64, len: u64) -> Result<Vec<u8>, StoreError> {
        let size = self.len(key)?;
        let start = offset.min(size);
        let range: Range<u64> = start..start + len.min(size - start);
        if range.is_empty() {
            return Ok(Vec::new());
        }
        let path = self.path(key)?;
        let (store, key) = (self.store.clone(), key.to_string());
        self.block(async move {
            let bytes = store
                .get_range(&path, range)
                .await
                .map_err(object_error(&key))?;
            Ok(bytes.to_vec())
        })
    }

    /// Lists the objects under `prefix` and deletes them (`jobs/<id>/` is a job's folder;
    /// without the trailing slash it is a string prefix, as on the file system store).
    fn delete_prefix(&self, prefix: &str) -> Result<(), StoreError> {
        let doomed = self.matching(prefix)?;
        if doomed.is_empty() {
            return Ok(());
        }
        let store = self.store.clone();
        self.block(async move {
            let paths = futures_util::stream::iter(doomed.into_iter().map(Ok)).boxed();
            let mut deleted = store.delete_stream(paths);
            while let Some(r) = deleted.next().await {
                match r {
                    Ok(_) | Err(object_store::Error::NotFound { .. }) => {}
                    Err(e) => return Err(StoreError::ObjectStore(e.to_string())),
                }
            }
            Ok(())
        })
    }

    fn temp_dir(&self) -> PathBuf {
        self.spool.dir().to_path_buf()
    }

    fn sweep_temp(&self, older_than: Duration) -> Result<usize, StoreError> {
        self.spool.sweep(older_than)
    }
}

#[cfg(test)]
mod tests {
    use super::split_url;

    #[test]
    fn urls_split_into_scheme_and_prefix() {
        assert_eq!(split_url("s3://b/p/q/").unwrap(), ("s3", "p/q"));
        assert_eq!(split_url("s3://b").unwrap(), ("s3", ""));
        assert_eq!(split_url("gs://b/x").unwrap(), ("gs", "x"));
        assert_eq!(split_url("file:///srv/blobs").unwrap(), ("file", ""));
        assert!(split_url("file://relative").is_err());
        assert!(split_url("ftp://b/x").is_err());
        assert!(split_url("s3:///x").is_err());
        assert!(split_url("bucket/x").is_err());
    }
}
