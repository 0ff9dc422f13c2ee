//! Shared test fixtures: where the shared assets live.
#![allow(dead_code)]

use std::path::PathBuf;

/// The shared asset folder: `$RETEX_SHARED_ASSETS`, else `../shared/assets` next to the crate.
pub fn shared_assets_dir() -> PathBuf {
    if let Ok(dir) = std::env::var("RETEX_SHARED_ASSETS") {
        return PathBuf::from(dir);
    }
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/assets")
}

/// Path of a file under the shared asset folder; panics with a clear message when missing.
pub fn shared_asset(relative: &str) -> PathBuf {
    let p = shared_assets_dir().join(relative);
    assert!(p.exists(), "shared asset {} not found (set RETEX_SHARED_ASSETS)", p.display());
    p
}
