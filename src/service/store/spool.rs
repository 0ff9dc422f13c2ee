//! The local spool folder of a blob store: where uploads are streamed before
//! [`super::BlobStore::put_file`] takes them, and where the file-system store writes a blob
//! before renaming it into place.
//!
//! The folder is `<root>/tmp`. Every store holds a shared `flock` on `<root>/tmp.lock` for its
//! life. At open a store first tries the lock exclusively: when it gets it, no other store is
//! using the folder, so every file already there was left by a dead writer and is removed (then
//! the lock is turned shared); otherwise only files older than an hour are removed. (Holding the
//! exclusive lock for life, as before, was wrong: once its holder died, the next store to open
//! got the lock and removed the in-flight files of stores opened beside the dead one, a failure
//! the three-replica kill test caught.) Shared by [`super::fs::FsBlobStore`] and
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

/// `flock(operation)` on `file`; whether it succeeded.
fn flock(file: &File, operation: libc::c_int) -> bool {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a file descriptor `file` owns; no memory is passed.
    unsafe { libc::flock(file.as_raw_fd(), operation) == 0 }
}

/// Fsyncs a folder, making the entries added to or removed from it durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

impl Spool {
    /// Opens (creating) `<root>/tmp` and sweeps it: every file when no other store holds the
    /// lock, else those older than [`STALE_TEMP`]; then holds the lock shared. `root` must
    /// exist.
    ///
    /// # Errors
    /// [`StoreError::Io`] if the folder cannot be created.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        let dir = root.join("tmp");
        fs::create_dir_all(&dir)?;
        let lock = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(root.join("tmp.lock"))?;
        sync_dir(root)?;
        let sole_user = flock(&lock, libc::LOCK_EX | libc::LOCK_NB);
        let spool = Self {
            dir,
            _lock: Some(Arc::new(lock)),
        };
        let swept = spool.sweep(if sole_user {
            Duration::ZERO
        } else {
            STALE_TEMP
        });
        // Shared from now on (converts the exclusive lock; waits only while another store
        // sweeps at its own open).
        if let Some(lock) = &spool._lock {
            flock(lock, libc::LOCK_SH);
        }
        swept?;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A store opened after the first one has closed must not remove the in-flight files of a
    /// store still open beside it (the lock's first holder is gone, but the folder is in use).
    #[test]
    fn a_store_opened_after_the_first_closes_keeps_the_live_stores_files() {
        let root = tempfile::tempdir().unwrap();
        let first = Spool::open(root.path()).unwrap();
        let second = Spool::open(root.path()).unwrap();
        let in_flight = second.new_temp();
        fs::write(&in_flight, b"half a blob").unwrap();
        drop(first);
        let third = Spool::open(root.path()).unwrap();
        assert!(in_flight.exists(), "the live store's temp file was swept");
        drop((second, third));
        // With every store closed, the next one removes what they left.
        let fourth = Spool::open(root.path()).unwrap();
        assert!(!in_flight.exists(), "a dead writer's temp file was kept");
        drop(fourth);
    }
}
