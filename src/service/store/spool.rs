//! The local spool folder of a blob store: where uploads are streamed before
//! [`super::BlobStore::put_file`] takes them, and where the file-system store writes a blob
//! before renaming it into place.
//!
//! The folder is `<root>/tmp`. The first store to open it holds `<root>/tmp.lock` (an exclusive
//! `flock`) for its life; a store that gets the lock knows every file already in the folder was
//! left by a dead writer and removes them all, while a store opened beside a live one only
//! removes files older than an hour. Shared by [`super::fs::FsBlobStore`] and
//! [`super::object::ObjectBlobStore`] (whose spool is local even when its blobs are not).

use std::fs::{self, File, OpenOptions};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use uuid::Uuid;

use super::StoreError;

/// Temporary files older than this are removed at open when another process may be using the
/// same folder (left over by a crash).
pub const STALE_TEMP: Duration = Duration::from_secs(3600);

/// A blob store's temporary folder.
#[derive(Debug, Clone)]
pub struct Spool {
    dir: PathBuf,
    /// `<root>/tmp.lock`, held while no other process holds it.
    _lock: Option<Arc<File>>,
}

/// Takes an exclusive, non-blocking `flock` on `path` (created if needed); `None` when another
/// open file holds it.
fn exclusive_lock(path: &Path) -> std::io::Result<Option<File>> {
    use std::os::fd::AsRawFd;
    let file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(path)?;
    // SAFETY: flock on a file descriptor this function owns; no memory is passed.
    let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    Ok((rc == 0).then_some(file))
}

/// Fsyncs a folder, making the entries added to or removed from it durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

impl Spool {
    /// Opens (creating) `<root>/tmp` and sweeps it: every file when this is the only store
    /// using it, else those older than [`STALE_TEMP`]. `root` must exist.
    ///
    /// # Errors
    /// [`StoreError::Io`] if the folder cannot be created.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        let dir = root.join("tmp");
        fs::create_dir_all(&dir)?;
        let lock = exclusive_lock(&root.join("tmp.lock"))?;
        sync_dir(root)?;
        let sole_user = lock.is_some();
        let spool = Self {
            dir,
            _lock: lock.map(Arc::new),
        };
        spool.sweep(if sole_user {
            Duration::ZERO
        } else {
            STALE_TEMP
        })?;
        Ok(spool)
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// A fresh, unused file name in the folder.
    pub fn new_temp(&self) -> PathBuf {
        self.dir.join(format!("put-{}", Uuid::new_v4()))
    }

    /// Checks that `temp` is a file directly inside the folder and returns its real path.
    ///
    /// # Errors
    /// [`StoreError::Io`] (`InvalidInput`) for any other path.
    pub fn check_temp(&self, temp: &Path) -> Result<PathBuf, StoreError> {
        let real = fs::canonicalize(temp)?;
        if real.parent() != Some(self.dir.as_path()) || !real.is_file() {
            return Err(StoreError::Io(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "{} is not a file directly inside the blob store's temp dir",
                    temp.display()
                ),
            )));
        }
        Ok(real)
    }

    /// Removes files not modified for `older_than` (all of them for zero); returns how many.
    ///
    /// # Errors
    /// [`StoreError::Io`] if the folder cannot be read.
    pub fn sweep(&self, older_than: Duration) -> Result<usize, StoreError> {
        let now = SystemTime::now();
        let mut removed = 0;
        for entry in fs::read_dir(&self.dir)?.flatten() {
            let old = older_than.is_zero()
                || entry
                    .metadata()
                    .ok()
                    .filter(|m| m.is_file())
                    .and_then(|m| m.modified().ok())
                    .and_then(|t| now.duration_since(t).ok())
                    .is_some_and(|age| age > older_than);
            if old && fs::remove_file(entry.path()).is_ok() {
                removed += 1;
            }
        }
        Ok(removed)
    }
}
