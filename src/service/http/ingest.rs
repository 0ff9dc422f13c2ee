//! Multipart ingest of `POST /v1/jobs`: parts are streamed to temporary files (in the blob
//! store's temp folder, so accepting them is a rename) under a per-part cap, hashed for
//! Idempotency-Key checks, grouped into models (one GLB; a .gltf plus its files as further parts
//! named by their filenames; or one zip of them), and validated before anything is accepted:
//! the constraints parse, each model loads under the ingest limits (on a blocking thread, never
//! a tokio worker), the texture size is within the configured maximum.

use std::collections::HashSet;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::Arc;

use axum::extract::multipart::{Field, Multipart, MultipartError};
use axum::http::StatusCode;
use sha2::{Digest, Sha256};

use super::problem::ApiError;
use crate::engine::asset::constraints::{Constraints, MAX_CONSTRAINTS_BYTES};
use crate::engine::methods::{InputUse, Registry};
use crate::engine::pipeline::checked_method;
use crate::service::config::ServeConfig;
use crate::service::problem_table::{texture_size_problem, transfer_problem};
use crate::service::store::BlobStore;

mod checks;

use checks::{check_pattern, validate_model};

/// The multipart parts a submission may have.
const PARTS: [&str; 5] = ["source", "target", "constraints", "pattern", "source_base"];

/// The constraints of a submission without a `constraints` part.
const DEFAULT_CONSTRAINTS: &[u8] = br#"{"version": 1}"#;

/// One uploaded file, already on disk.
#[derive(Debug, Clone)]
pub struct UploadFile {
    /// Name inside the model's file set (the part's filename, or the zip entry's path).
    pub name: String,
    /// The temporary file.
    pub path: PathBuf,
}

/// A model of the upload: its main file and every file of it.
#[derive(Debug, Clone)]
pub struct UploadModel {
    /// Name of the main .glb/.gltf.
    pub main: String,
    /// Files, the main one included.
    pub files: Vec<UploadFile>,
}

/// A complete, validated submission, still in temporary files.
#[derive(Debug)]
pub struct Upload {
    /// The source model (absent for methods that do not read one).
    pub source: Option<UploadModel>,
    /// The target.
    pub target: UploadModel,
    /// The smooth base of the source, if given and read by the method.
    pub source_base: Option<UploadModel>,
    /// The constraints document, verbatim (`{"version": 1}` when the part was left out).
    pub constraints_bytes: Vec<u8>,
    /// The parsed constraints.
    pub constraints: Constraints,
    /// The pattern image, if given.
    pub pattern: Option<UploadFile>,
    /// Hex SHA-256 over every part (name, filename, content).
    pub request_hash: String,
    /// Owns the temporary files; dropping it deletes whatever was not moved into the store.
    pub _temp: TempFiles,
}

/// Temporary files of one upload, directly inside the blob store's temp folder (so the store
/// can take them by rename), created through [`BlobStore::create_temp`]; those still there when
/// this is dropped are deleted.
pub struct TempFiles {
    blobs: Arc<dyn BlobStore>,
    dir: PathBuf,
    prefix: String,
    made: std::sync::Mutex<Vec<PathBuf>>,
}

impl std::fmt::Debug for TempFiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TempFiles")
            .field("dir", &self.dir)
            .field("prefix", &self.prefix)
            .finish_non_exhaustive()
    }
}

impl TempFiles {
    fn new(blobs: Arc<dyn BlobStore>) -> Self {
        Self {
            dir: blobs.temp_dir(),
            blobs,
            prefix: format!("upload-{}", uuid::Uuid::new_v4().simple()),
            made: Default::default(),
        }
    }

    /// Creates a new file (removed on drop unless moved away) and a writer into it.
    fn create(&self, tag: &str) -> Result<(PathBuf, Box<dyn Write + Send>), ApiError> {
        let p = self.dir.join(format!("{}-{tag}", self.prefix));
        if let Ok(mut m) = self.made.lock() {
            m.push(p.clone());
        }
        let file = self.blobs.create_temp(&p).map_err(ApiError::io)?;
        Ok((p, file))
    }
}

impl Drop for TempFiles {
    fn drop(&mut self) {
        if let Ok(m) = self.made.lock() {
            for p in m.iter() {
                let _ = std::fs::remove_file(p);
            }
        }
    }
}

fn multipart_error(e: MultipartError, config: &ServeConfig) -> ApiError {
    let status = e.status();
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        return ApiError::too_large("body", "max_body_bytes", config.max_body_bytes);
    }
    if let Some(secs) = super::deadline::upload_deadline_of(&e) {
        return ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            "upload-timeout",
            "Upload timeout",
            format!("the request body was not received within {secs} s"),
        )
        .limit("upload_timeout_secs", secs);
    }
    if is_timeout(&e) {
        return ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            "body-timeout",
            "Request body timeout",
            format!("the client sent nothing for {} s", config.body_timeout_secs),
        )
        .limit("body_timeout_secs", config.body_timeout_secs);
    }
    ApiError::bad_request("invalid-multipart", "body", e.body_text())
}

/// Whether a body error was caused by the request body timeout: the error of
/// `RequestBodyTimeoutLayer` ([`tower_http::timeout::TimeoutError`]) or an I/O time-out,
/// anywhere in the source chain (the multipart parser wraps it as "failed to read stream").
fn is_timeout(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if err.is::<tower_http::timeout::TimeoutError>()
            || err.is::<tokio::time::error::Elapsed>()
            || err
                .downcast_ref::<std::io::Error>()
                .is_some_and(|io| io.kind() == std::io::ErrorKind::TimedOut)
        {
            return true;
        }
        cur = err.source();
    }
    false
}

/// Checks a part's filename: a relative path of normal segments.
fn check_name(part: &str, name: &str) -> Result<(), ApiError> {
    let bad = name.is_empty()
        || name.starts_with('/')
        || name.contains('\\')
        || name.contains('\0')
        || name
            .split('/')
            .any(|s| s.is_empty() || s == "." || s == "..");
    if bad {
        return Err(ApiError::bad_request(
            "invalid-filename",
            part,
            format!("file name {name:?} must be a relative path without '..'"),
        ));
    }
    Ok(())
}

/// Streams one part into `file`, hashing it; refuses more than `cap` bytes. A failed write
/// (a full disk) is [`ApiError::io`]: 507 without the OS text.
async fn save_part(
    field: &mut Field<'_>,
    mut file: Box<dyn Write + Send>,
    part: &str,
    cap: u64,
    config: &ServeConfig,
) -> Result<(u64, [u8; 32]), ApiError> {
    let mut hasher = Sha256::new();
    let mut len = 0u64;
    while let Some(chunk) = field
        .chunk()
        .await
        .map_err(|e| multipart_error(e, config))?
    {
        len += chunk.len() as u64;
        if len > cap {
            let limit = if part == "constraints" {
                "max_constraints_bytes"
            } else {
                "max_part_bytes"
            };
            return Err(ApiError::too_large(part, limit, cap));
        }
        hasher.update(&chunk);
        // Small synchronous writes into the page cache; the fsync happens when the blob store
        // takes the file.
        file.write_all(&chunk).map_err(ApiError::io)?;
    }
    file.flush().map_err(ApiError::io)?;
    Ok((len, hasher.finalize().into()))
}

/// The parts of a multipart body as received, before grouping and validation.
#[derive(Default)]
struct Received {
    source: Vec<UploadFile>,
    target: Vec<UploadFile>,
    source_base: Vec<UploadFile>,
    constraints: Option<PathBuf>,
    pattern: Option<UploadFile>,
}

impl Received {
    fn add(&mut self, part: &str, file: UploadFile) -> Result<(), ApiError> {
        let twice = |what: &str| {
            Err(ApiError::bad_request(
                "duplicate-part",
                what,
                format!("{what} given twice"),
            ))
        };
        match part {
            "source" => self.source.push(file),
            "target" => self.target.push(file),
            "source_base" => self.source_base.push(file),
            "constraints" if self.constraints.is_some() => return twice(part),
            "constraints" => self.constraints = Some(file.path),
            _ if self.pattern.is_some() => return twice(part),
            _ => self.pattern = Some(file),
        }
        Ok(())
    }
}

/// Reads the whole multipart body into temporary files and validates it: the constraints parse,
/// the method is implemented and its params pass its check, the parts it needs are there, and
/// every model and image loads under the limits.
pub async fn read_upload(
    multipart: Multipart,
    config: &ServeConfig,
    registry: &Registry,
    blobs: Arc<dyn BlobStore>,
) -> Result<Upload, ApiError> {
    std::fs::create_dir_all(blobs.temp_dir()).map_err(ApiError::io)?;
    let temp = std::sync::Arc::new(TempFiles::new(blobs));
    let mut request = Sha256::new();
    let received = receive_parts(multipart, config, &temp, &mut request).await?;
    let constraints_bytes = match &received.constraints {
        Some(path) => std::fs::read(path).map_err(ApiError::io)?,
        None => DEFAULT_CONSTRAINTS.to_vec(),
    };
    let parsed =
        Constraints::from_json(&constraints_bytes).map_err(|e| ApiError::constraints(&e))?;
    if parsed.output.texture_size > config.max_texture_size {
        return Err(ApiError::from_problem(texture_size_problem(
            parsed.output.texture_size,
            config.max_texture_size,
        )));
    }
    let method = checked_method(registry, &parsed, &config.limits)
        .map_err(|e| ApiError::from_problem(transfer_problem(&e)))?;
    let spec = method.inputs();
    let missing = |part: &str| {
        ApiError::bad_request(
            "missing-part",
            part,
            format!(
                "the multipart body has no {part:?} part (method {} needs it)",
                parsed.method.as_str()
            ),
        )
    };
    if received.target.is_empty() {
        return Err(missing("target"));
    }
    let wanted =
        |given: bool, used: InputUse, part: &str| used.reads(given).ok_or_else(|| missing(part));
    let use_source = wanted(!received.source.is_empty(), spec.source, "source")?;
    let use_base = wanted(
        !received.source_base.is_empty(),
        spec.source_base,
        "source_base",
    )?;
    let use_pattern = wanted(received.pattern.is_some(), spec.pattern, "pattern")?;

    let work = temp.clone();
    let cfg = config.clone();
    let job_constraints = parsed.clone();
    let extra = method.extra_images(&parsed);
    let pattern = received.pattern.filter(|_| use_pattern);
    let pattern_check = pattern.clone();
    let (source_files, target_files, base_files) = (
        Some(received.source).filter(|_| use_source),
        received.target,
        Some(received.source_base).filter(|_| use_base),
    );
    let validated = tokio::task::spawn_blocking(move || -> Result<_, ApiError> {
        let group = |side: &str, files: Option<Vec<UploadFile>>| {
            files.map(|f| assemble(side, f, &work, &cfg)).transpose()
        };
        let source = group("source", source_files)?;
        let target = assemble("target", target_files, &work, &cfg)?;
        let base = group("source_base", base_files)?;
        let pattern_demand = match &pattern_check {
            Some(p) => Some(check_pattern(&p.path, &cfg)?),
            None => None,
        };
        // The models load under the limits, in parallel (the loader itself uses rayon).
        let check = |side: &str, m: &Option<UploadModel>| {
            m.as_ref()
                .map(|m| validate_model(side, m, &cfg, &extra))
                .transpose()
        };
        let (a, (b, c)) = rayon::join(
            || check("source", &source),
            || {
                rayon::join(
                    || validate_model("target", &target, &cfg, &extra),
                    || check("source_base", &base),
                )
            },
        );
        let (a, b, c) = (a?, b?, c?);
        checks::job_budget(
            [a.as_ref(), Some(&b), c.as_ref(), pattern_demand.as_ref()],
            method,
            &job_constraints,
            &cfg,
        )?;
        Ok((source, target, base))
    })
    .await
    .map_err(ApiError::internal)??;
    Ok(Upload {
        source: validated.0,
        target: validated.1,
        source_base: validated.2,
        constraints_bytes,
        constraints: parsed,
        pattern,
        request_hash: hex::encode(request.finalize()),
        _temp: std::sync::Arc::try_unwrap(temp)
            .map_err(|_| ApiError::internal("temp files still shared"))?,
    })
}

/// Streams every part to a temporary file under its cap, hashing names and contents.
async fn receive_parts(
    mut multipart: Multipart,
    config: &ServeConfig,
    temp: &TempFiles,
    request: &mut Sha256,
) -> Result<Received, ApiError> {
    let mut received = Received::default();
    let mut count = 0usize;
    while let Some(mut field) = multipart
        .next_field()
        .await
        .map_err(|e| multipart_error(e, config))?
    {
        let part = field.name().unwrap_or_default().to_string();
        if !PARTS.contains(&part.as_str()) {
            return Err(ApiError::bad_request(
                "unknown-part",
                &part,
                format!(
                    "unknown part {part:?}: expected one of {}",
                    PARTS.join(", ")
                ),
            ));
        }
        count += 1;
        if count > 3 * config.max_files + 2 {
            return Err(ApiError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                "too-many-files",
                "Too many files",
                format!("more than {} files per model", config.max_files),
            )
            .field(part)
            .limit("max_files", config.max_files as u64));
        }
        let name = field
            .file_name()
            .map(str::to_string)
            .unwrap_or_else(|| part.clone());
        check_name(&part, &name)?;
        let (path, file) = temp.create(&format!("part-{count}"))?;
        let cap = if part == "constraints" {
            MAX_CONSTRAINTS_BYTES as u64
        } else {
            config.max_part_bytes
        };
        let (_, digest) = save_part(&mut field, file, &part, cap, config).await?;
        for piece in [part.as_bytes(), &[0], name.as_bytes(), &[0], &digest] {
            request.update(piece);
        }
        received.add(&part, UploadFile { name, path })?;
    }
    Ok(received)
}

fn is_zip(file: &UploadFile) -> bool {
    if file.name.to_ascii_lowercase().ends_with(".zip") {
        return true;
    }
    let mut magic = [0u8; 4];
    std::fs::File::open(&file.path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok()
        && magic == *b"PK\x03\x04"
}

fn is_main(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    lower.ends_with(".glb") || lower.ends_with(".gltf")
}

/// Groups the parts of one side into a model: unpacks a zip, finds the main file and makes
/// every name relative to the main file's folder.
fn assemble(
    side: &str,
    mut files: Vec<UploadFile>,
    temp: &TempFiles,
    config: &ServeConfig,
) -> Result<UploadModel, ApiError> {
    if files.len() == 1 && is_zip(&files[0]) {
        files = unzip(side, &files[0], temp, config)?;
    }
    if files.len() > config.max_files {
        return Err(ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too-many-files",
            "Too many files",
            format!(
                "{side} has {} files, over max_files = {}",
                files.len(),
                config.max_files
            ),
        )
        .field(side)
        .limit("max_files", config.max_files as u64));
    }
    let mains: Vec<&UploadFile> = files.iter().filter(|f| is_main(&f.name)).collect();
    let main = match (mains.as_slice(), files.as_slice()) {
        ([one], _) => one.name.clone(),
        ([], [only]) => only.name.clone(),
        ([], _) => {
            return Err(ApiError::bad_request(
                "no-main-file",
                side,
                format!("{side} has several files but no .glb or .gltf among them"),
            ))
        }
        (many, _) => {
            return Err(ApiError::bad_request(
                "ambiguous-main-file",
                side,
                format!(
                    "{side} has {} .glb/.gltf files; send one model per side",
                    many.len()
                ),
            ))
        }
    };
    let mut seen = HashSet::new();
    for f in &files {
        if !seen.insert(f.name.clone()) {
            return Err(ApiError::bad_request(
                "duplicate-file",
                side,
                format!("{side} has two files named {:?}", f.name),
            ));
        }
    }
    // URIs resolve against the main file's folder: names become relative to it.
    let prefix = match main.rfind('/') {
        Some(i) => main[..=i].to_string(),
        None => String::new(),
    };
    let files = files
        .into_iter()
        .filter_map(|f| {
            let rel = f.name.strip_prefix(&prefix)?.to_string();
            Some(UploadFile {
                name: rel,
                path: f.path,
            })
        })
        .collect();
    Ok(UploadModel {
        main: main[prefix.len()..].to_string(),
        files,
    })
}

/// Extracts a zip's files (no directories, no paths leaving the archive) under the caps.
fn unzip(
    side: &str,
    zip_file: &UploadFile,
    temp: &TempFiles,
    config: &ServeConfig,
) -> Result<Vec<UploadFile>, ApiError> {
    let bad = |detail: String| {
        ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-zip",
            "Invalid zip",
            detail,
        )
        .field(side)
    };
    let reader = std::fs::File::open(&zip_file.path).map_err(ApiError::io)?;
    let mut archive = zip::ZipArchive::new(reader).map_err(|e| bad(format!("{side}: {e}")))?;
    if archive.len() > config.max_files {
        return Err(ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too-many-files",
            "Too many files",
            format!(
                "{side} zip has {} entries, over max_files = {}",
                archive.len(),
                config.max_files
            ),
        )
        .field(side)
        .limit("max_files", config.max_files as u64));
    }
    let mut out = Vec::new();
    let mut total = 0u64;
    for i in 0..archive.len() {
        let mut entry = archive
            .by_index(i)
            .map_err(|e| bad(format!("{side}: entry {i}: {e}")))?;
        if entry.is_dir() {
            continue;
        }
        let Some(rel) = entry.enclosed_name() else {
            return Err(ApiError::bad_request(
                "invalid-filename",
                side,
                format!("zip entry {:?} leaves the archive", entry.name()),
            ));
        };
        let name = rel.to_string_lossy().replace('\\', "/");
        check_name(side, &name)?;
        let (path, mut file) = temp.create(&format!("{side}-zip-{i}"))?;
        // Never trust the declared size: copy at most cap + 1 bytes.
        let copied = std::io::copy(&mut (&mut entry).take(config.max_part_bytes + 1), &mut file)
            .map_err(|e| {
                if crate::service::store::is_full(&e) {
                    // The archive is fine, the server's disk is not.
                    ApiError::io(e)
                } else {
                    bad(format!("{side}: {name}: {e}"))
                }
            })?;
        if copied > config.max_part_bytes {
            return Err(ApiError::too_large(
                side,
                "max_part_bytes",
                config.max_part_bytes,
            ));
        }
        total += copied;
        if total > config.limits.max_input_bytes {
            return Err(ApiError::too_large(
                side,
                "max_input_bytes",
                config.limits.max_input_bytes,
            ));
        }
        out.push(UploadFile { name, path });
    }
    Ok(out)
}

/// A blob key segment for a file name: `[A-Za-z0-9._-]` only, not starting with a dot,
/// unique within `taken`.
pub fn safe_key_name(name: &str, index: usize, taken: &mut HashSet<String>) -> String {
    let mut s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() || s.starts_with('.') {
        s.insert(0, '_');
    }
    if !taken.insert(s.clone()) {
        s = format!("{index}-{s}");
        taken.insert(s.clone());
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_checked_and_made_safe() {
        assert!(check_name("source", "textures/a.png").is_ok());
        for bad in ["../x.bin", "/etc/passwd", "a/../../b", "a\\b", ""] {
            assert!(check_name("source", bad).is_err(), "{bad}");
        }
        let mut taken = HashSet::new();
        assert_eq!(safe_key_name("Fox.bin", 0, &mut taken), "Fox.bin");
        assert_eq!(safe_key_name("tex/a b.png", 1, &mut taken), "tex_a_b.png");
        assert_eq!(safe_key_name("tex_a b.png", 2, &mut taken), "2-tex_a_b.png");
        assert_eq!(safe_key_name("..", 3, &mut taken), "_..");
    }
}
