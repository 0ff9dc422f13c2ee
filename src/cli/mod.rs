//! Subcommands of the `retex` binary (`src/main.rs` parses the arguments and calls these).

pub mod bench;
pub mod bench_atlas;
pub mod bench_correlation;
pub mod bench_detail;
pub mod bench_elastiface;
pub mod bench_geometry;
pub mod bench_meshmatch;
pub mod bench_meshmatch_pairs;
pub mod bench_pattern;
pub mod inspect;
pub mod preview;
#[cfg(feature = "service")]
pub mod serve;
pub mod transfer;

use std::path::Path;

/// Checks, before any model is read, that `out` can be written: its folder exists, is a folder
/// and accepts a new file, and `out` is not itself a folder. Warns on stderr when the extension
/// is none of `extensions` (lowercase, without the dot), e.g. `["glb", "gltf"]`.
pub fn check_output(out: &Path, extensions: &[&str]) -> Result<(), String> {
    let shown = out.display();
    let folder = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    match std::fs::metadata(folder) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(format!(
                "--out {shown}: {} is not a folder",
                folder.display()
            ))
        }
        Err(e) => {
            return Err(format!(
            "--out {shown}: the folder {} does not exist or cannot be read ({e}); create it first",
            folder.display()
        ))
        }
    }
    if out.is_dir() {
        return Err(format!("--out {shown} is a folder; give a file name"));
    }
    // Writable: create (and remove) a probe file beside the output.
    let probe = folder.join(format!(".retex-write-check-{}", std::process::id()));
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(e) => {
            return Err(format!(
                "--out {shown}: cannot write into the folder {} ({e})",
                folder.display()
            ))
        }
    }
    let ext = out
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    if !ext.as_deref().is_some_and(|e| extensions.contains(&e)) {
        let expected = extensions
            .iter()
            .map(|e| format!(".{e}"))
            .collect::<Vec<_>>()
            .join(" or ");
        eprintln!("warning: --out {shown} does not end in {expected} (it is written anyway)");
    }
    Ok(())
}
