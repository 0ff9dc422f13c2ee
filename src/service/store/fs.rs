//! The embedded [`BlobStore`]: blobs are files under `<root>/blobs/<key>`, written atomically.
//!
//! A write goes to a fresh file in `<root>/tmp` (same file system), is fsynced, renamed over its
//! final name, and the parent directory is fsynced, so after a crash a key holds either nothing,
//! the old bytes or the new bytes, never a torn file. Directories created on the way are fsynced
//! into their parents too. Keys are relative paths of segments made of `[A-Za-z0-9._-]`, without
//! empty, `.` or `..` segments and without a leading `/`; anything else is
//! [`StoreError::InvalidKey`], so a key can never name a file outside the root.

use std::fs::{self, File, OpenOptions};
use std::io::{ErrorKind, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use uuid::Uuid;

use super::{BlobStore, StoreError};

/// Temporary files older than this are removed by [`FsBlobStore::open`] when another process
/// may be using the same folder (left over by a crash).
const STALE_TEMP: Duration = Duration::from_secs(3600);

/// File-system [`BlobStore`].
#[derive(Debug, Clone)]
pub struct FsBlobStore {
    blobs: PathBuf,
    tmp: PathBuf,
    /// `<root>/tmp.lock`, held with an exclusive `flock` for the store's life when no other
    /// process holds it (then every file in `tmp` at open was left by a dead writer).
    _tmp_lock: Option<std::sync::Arc<File>>,
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

/// Checks a key and splits it into its segments.
fn segments(key: &str) -> Result<Vec<&str>, StoreError> {
    let bad = || StoreError::InvalidKey(key.to_string());
    if key.is_empty() || key.starts_with('/') || key.len() > 1024 {
        return Err(bad());
    }
    let segs: Vec<&str> = key.split('/').collect();
    for s in &segs {
        let charset_ok = s
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'));
        if s.is_empty() || *s == "." || *s == ".." || !charset_ok || s.len() > 255 {
            return Err(bad());
        }
    }
    Ok(segs)
}

/// Validates a blob key (see the module docs).
///
/// # Errors
/// [`StoreError::InvalidKey`] for anything but a safe relative path.
pub fn validate_key(key: &str) -> Result<(), StoreError> {
    segments(key).map(|_| ())
}

fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

fn not_found(key: &str) -> impl Fn(std::io::Error) -> StoreError + '_ {
    move |e| {
        if e.kind() == ErrorKind::NotFound {
            StoreError::BlobNotFound(key.to_string())
        } else {
            StoreError::Io(e)
        }
    }
}

impl FsBlobStore {
    /// Opens (creating if needed) a blob store rooted at `root`, and removes leftover temporary
    /// files: all of them when this store is the only one using the folder (it holds
    /// `<root>/tmp.lock`), else those older than an hour.
    ///
    /// # Errors
    /// [`StoreError::Io`] if the folders cannot be created.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        fs::create_dir_all(root)?;
        let root = fs::canonicalize(root)?;
        let blobs = root.join("blobs");
        let tmp = root.join("tmp");
        fs::create_dir_all(&blobs)?;
        fs::create_dir_all(&tmp)?;
        let lock = exclusive_lock(&root.join("tmp.lock"))?;
        sync_dir(&root)?;
        let sole_user = lock.is_some();
        let store = Self {
            blobs,
            tmp,
            _tmp_lock: lock.map(std::sync::Arc::new),
        };
        store.sweep_temp(if sole_user {
            Duration::ZERO
        } else {
            STALE_TEMP
        })?;
        Ok(store)
    }

    /// The file of a (valid) key.
    fn path_of(&self, key: &str) -> Result<PathBuf, StoreError> {
        let mut p = self.blobs.clone();
        for s in segments(key)? {
            p.push(s);
        }
        Ok(p)
    }

    /// Creates the parent folders of `file` under the blob root, fsyncing each new one into
    /// its parent.
    fn ensure_parent(&self, file: &Path) -> Result<(), StoreError> {
        let parent = file.parent().unwrap_or(&self.blobs);
        if parent.is_dir() {
            return Ok(());
        }
        let rel = parent
            .strip_prefix(&self.blobs)
            .map_err(|_| StoreError::InvalidKey(file.to_string_lossy().into_owned()))?;
        let mut dir = self.blobs.clone();
        for c in rel.components() {
            let up = dir.clone();
            dir.push(c);
            match fs::create_dir(&dir) {
                Ok(()) => sync_dir(&up)?,
                Err(e) if e.kind() == ErrorKind::AlreadyExists => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    /// Renames a synced temporary file into place and syncs the folder.
    fn install(&self, temp: &Path, dest: &Path) -> Result<(), StoreError> {
        self.ensure_parent(dest)?;
        fs::rename(temp, dest)?;
        sync_dir(dest.parent().unwrap_or(&self.blobs))?;
        Ok(())
    }

    fn new_temp(&self) -> PathBuf {
        self.tmp.join(format!("put-{}", Uuid::new_v4()))
    }
}

impl BlobStore for FsBlobStore {
    fn put(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        let dest = self.path_of(key)?;
        let temp = self.new_temp();
        let result = (|| {
            let mut f = OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&temp)?;
            f.write_all(bytes)?;
            f.sync_all()?;
            drop(f);
            self.install(&temp, &dest)
        })();
        if result.is_err() {
            let _ = fs::remove_file(&temp);
        }
        result
    }

    fn put_file(&self, key: &str, temp: &Path) -> Result<(), StoreError> {
        let dest = self.path_of(key)?;
        let real = fs::canonicalize(temp)?;
        if real.parent() != Some(self.tmp.as_path()) || !real.is_file() {
            return Err(StoreError::Io(std::io::Error::new(
                ErrorKind::InvalidInput,
                format!(
                    "{} is not a file directly inside the blob store's temp dir",
                    temp.display()
                ),
            )));
        }
        OpenOptions::new().write(true).open(&real)?.sync_all()?;
        self.install(&real, &dest)
    }

    fn get(&self, key: &str) -> Result<Vec<u8>, StoreError> {
        let path = self.path_of(key)?;
        fs::read(&path).map_err(not_found(key))
    }

    fn len(&self, key: &str) -> Result<u64, StoreError> {
        let path = self.path_of(key)?;
        let meta = fs::metadata(&path).map_err(not_found(key))?;
        if !meta.is_file() {
            return Err(StoreError::BlobNotFound(key.to_string()));
        }
        Ok(meta.len())
    }

    /// Reads up to `len` bytes from `offset`; fewer when the blob ends first (none when
    /// `offset` is at or past its end).
    fn read_range(&self, key: &str, offset: u64, len: u64) -> Result<Vec<u8>, StoreError> {
        let path = self.path_of(key)?;
        let mut f = File::open(&path).map_err(not_found(key))?;
        let size = f.metadata()?.len();
        let start = offset.min(size);
        let n = len.min(size - start);
        f.seek(SeekFrom::Start(start))?;
        let mut out = Vec::with_capacity(n as usize);
        f.take(n).read_to_end(&mut out)?;
        Ok(out)
    }

    /// Deletes every blob whose key starts with `prefix`. `jobs/<id>/` (with the trailing
    /// slash) removes that folder; `jobs/ab` also removes `jobs/abc/...` and `jobs/ab.bin`.
    fn delete_prefix(&self, prefix: &str) -> Result<(), StoreError> {
        let (dir_key, name_prefix) = match prefix.strip_suffix('/') {
            Some(dir) => (dir, None),
            None => match prefix.rsplit_once('/') {
                Some((dir, last)) => (dir, Some(last)),
                None => ("", Some(prefix)),
            },
        };
        let bad = || StoreError::InvalidKey(prefix.to_string());
        if prefix.is_empty() || prefix.starts_with('/') {
            return Err(bad());
        }
        let dir = if dir_key.is_empty() {
            self.blobs.clone()
        } else {
            self.path_of(dir_key).map_err(|_| bad())?
        };
        if let Some(last) = name_prefix {
            // The partial last segment must itself be a valid (possibly empty-free) segment.
            if !last.is_empty() {
                segments(last).map_err(|_| bad())?;
            }
        }
        let remove = |p: &Path| -> Result<(), StoreError> {
            let res = match fs::symlink_metadata(p) {
                Ok(m) if m.is_dir() => fs::remove_dir_all(p),
                Ok(_) => fs::remove_file(p),
                Err(e) => Err(e),
            };
            match res {
                Err(e) if e.kind() != ErrorKind::NotFound => Err(e.into()),
                _ => Ok(()),
            }
        };
        match name_prefix {
            None => remove(&dir)?,
            Some(last) => {
                let entries = match fs::read_dir(&dir) {
                    Ok(e) => e,
                    Err(e) if e.kind() == ErrorKind::NotFound => return Ok(()),
                    Err(e) => return Err(e.into()),
                };
                for entry in entries {
                    let entry = entry?;
                    if entry.file_name().to_string_lossy().starts_with(last) {
                        remove(&entry.path())?;
                    }
                }
            }
        }
        // Make the removal durable: sync the folder that lost entries.
        let changed = if dir.is_dir() {
            Some(dir.as_path())
        } else {
            dir.parent()
        };
        if let Some(d) = changed.filter(|p| p.starts_with(&self.blobs)) {
            sync_dir(d)?;
        }
        Ok(())
    }

    fn temp_dir(&self) -> PathBuf {
        self.tmp.clone()
    }

    fn sweep_temp(&self, older_than: Duration) -> Result<usize, StoreError> {
        let now = SystemTime::now();
        let mut removed = 0;
        for entry in fs::read_dir(&self.tmp)?.flatten() {
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
