//! The embedded [`BlobStore`]: blobs are files under `<root>/blobs/<key>`, written atomically
//! (uploads are spooled in `<root>/tmp`, see [`super::spool`]).
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
use std::time::Duration;

use super::spool::{sync_dir, Spool};
use super::{BlobStore, StoreError};

/// File-system [`BlobStore`].
#[derive(Debug, Clone)]
pub struct FsBlobStore {
    blobs: PathBuf,
    spool: Spool,
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
        fs::create_dir_all(&blobs)?;
        let spool = Spool::open(&root)?;
        Ok(Self { blobs, spool })
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

    /// Writes `bytes` to a fresh temporary file and fsyncs it.
    fn write_temp(&self, bytes: &[u8]) -> Result<PathBuf, StoreError> {
        let temp = self.spool.new_temp();
        let written = (|| {
            let mut f = OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&temp)?;
            f.write_all(bytes)?;
            f.sync_all()
        })();
        match written {
            Ok(()) => Ok(temp),
            Err(e) => {
                let _ = fs::remove_file(&temp);
                Err(e.into())
            }
        }
    }
}

impl BlobStore for FsBlobStore {
    fn put(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        let dest = self.path_of(key)?;
        let temp = self.write_temp(bytes)?;
        let result = self.install(&temp, &dest);
        if result.is_err() {
            let _ = fs::remove_file(&temp);
        }
        result
    }

    /// A hard link from the synced temporary file: `link(2)` fails when the name exists, so of
    /// two writers exactly one creates the blob and neither can replace it.
    fn put_new(&self, key: &str, bytes: &[u8]) -> Result<(), StoreError> {
        let dest = self.path_of(key)?;
        let temp = self.write_temp(bytes)?;
        let result = self
            .ensure_parent(&dest)
            .and_then(|()| match fs::hard_link(&temp, &dest) {
                Ok(()) => Ok(sync_dir(dest.parent().unwrap_or(&self.blobs))?),
                Err(e) if e.kind() == ErrorKind::AlreadyExists => {
                    Err(StoreError::BlobExists(key.to_string()))
                }
                Err(e) => Err(e.into()),
            });
        let _ = fs::remove_file(&temp);
        result
    }

    fn put_file(&self, key: &str, temp: &Path) -> Result<(), StoreError> {
        let dest = self.path_of(key)?;
        let real = self.spool.check_temp(temp)?;
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
        self.spool.dir().to_path_buf()
    }

    fn sweep_temp(&self, older_than: Duration) -> Result<usize, StoreError> {
        self.spool.sweep(older_than)
    }
}
