//! The files of an upload, by name: the only place ingest may read bytes from.
//!
//! A [`BlobSet`] maps relative names (`Fox.bin`, `textures/a.png`) to bytes. [`super::load`]
//! resolves glTF URIs (glTF 2.0 §2.8 "URIs") against it and never touches the filesystem.
//! [`BlobSet::from_path`] is the one helper that reads a .gltf/.glb and the files its URIs name
//! from disk (for the CLI and tests); it applies the same URI rules as the loader
//! ([`super::uri`]) so it never reads outside the main file's folder.

use std::collections::BTreeMap;
use std::path::Path;

use super::{glb, uri};

/// Named byte blobs: the main glTF/GLB file and the files it references.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BlobSet {
    blobs: BTreeMap<String, Vec<u8>>,
}

impl BlobSet {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds (or replaces) the blob `name`.
    pub fn insert(&mut self, name: impl Into<String>, bytes: Vec<u8>) {
        self.blobs.insert(name.into(), bytes);
    }

    /// The bytes of blob `name`, if present (exact name match).
    pub fn get(&self, name: &str) -> Option<&[u8]> {
        self.blobs.get(name).map(Vec::as_slice)
    }

    /// All names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.blobs.keys().map(String::as_str)
    }

    /// Sum of all blob sizes in bytes.
    pub fn total_bytes(&self) -> u64 {
        self.blobs.values().map(|b| b.len() as u64).sum()
    }

    /// Reads a .glb/.gltf from disk: the main file plus the files its buffer and image URIs
    /// name relative to its folder (percent-decoded; only relative paths that stay inside the
    /// folder; data: URIs skipped; missing or unreadable referenced files simply not added).
    /// Returns (main name, set). A GLB's JSON chunk is scanned for external URIs too.
    ///
    /// # Errors
    /// Only when the main file cannot be read.
    pub fn from_path(path: &Path) -> std::io::Result<(String, BlobSet)> {
        let main_bytes = std::fs::read(path)?;
        let main_name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| {
                std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name")
            })?;
        let folder = path.parent().unwrap_or_else(|| Path::new("."));
        let canonical_folder = std::fs::canonicalize(folder).ok();
        let mut set = BlobSet::new();
        for name in referenced_names(&main_bytes) {
            if name == main_name || set.get(&name).is_some() {
                continue;
            }
            let file = folder.join(&name);
            // Symlinks must not lead outside the folder either.
            if let (Some(root), Ok(real)) = (&canonical_folder, std::fs::canonicalize(&file)) {
                if !real.starts_with(root) {
                    continue;
                }
            }
            if let Ok(bytes) = std::fs::read(&file) {
                set.insert(name, bytes);
            }
        }
        set.insert(main_name.clone(), main_bytes);
        Ok((main_name, set))
    }
}

/// The in-folder file names that a glTF/GLB's buffers and images refer to; anything malformed
/// or forbidden is skipped (the loader reports it).
fn referenced_names(main: &[u8]) -> Vec<String> {
    let json_bytes = if glb::is_glb(main) {
        match glb::parse(main) {
            Ok(g) => g.json,
            Err(_) => return Vec::new(),
        }
    } else {
        main
    };
    let Ok(json) = serde_json::from_slice::<serde_json::Value>(json_bytes) else {
        return Vec::new();
    };
    let mut names = Vec::new();
    for array in ["buffers", "images"] {
        let Some(items) = json.get(array).and_then(|v| v.as_array()) else {
            continue;
        };
        for (i, item) in items.iter().enumerate() {
            let Some(u) = item.get("uri").and_then(|v| v.as_str()) else {
                continue;
            };
            if uri::is_data_uri(u) {
                continue;
            }
            if let Ok(name) = uri::relative_name("", u, &format!("{array}[{i}]")) {
                names.push(name);
            }
        }
    }
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn insert_get_names_total() {
        let mut s = BlobSet::new();
        s.insert("b.bin", vec![1, 2, 3]);
        s.insert("a.gltf", vec![0; 10]);
        assert_eq!(s.get("b.bin"), Some(&[1u8, 2, 3][..]));
        assert_eq!(s.get("c"), None);
        assert_eq!(s.names().collect::<Vec<_>>(), ["a.gltf", "b.bin"]);
        assert_eq!(s.total_bytes(), 13);
    }

    #[test]
    fn referenced_names_skip_data_and_forbidden() {
        let json = br#"{"buffers":[{"uri":"a%20b.bin"},{"uri":"data:,x"},{"uri":"../x.bin"},{"uri":"http://e/x"}],
                        "images":[{"uri":"tex/c.png"}]}"#;
        assert_eq!(referenced_names(json), ["a b.bin", "tex/c.png"]);
    }
}
