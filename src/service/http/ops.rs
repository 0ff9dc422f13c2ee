//! Operations: `GET /healthz` (the process answers), `GET /readyz` (the server accepts work:
//! not draining, storage passing its live probe, disk space above `min_free_bytes`, queue not
//! full), and the retention sweep that prunes finished jobs older than
//! the TTL together with their files, and removes partial uploads a crash left in the blob
//! store's temp dir (untouched for an hour). Unfinished jobs are never pruned.

use std::time::Duration;

use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use chrono::Utc;
use serde_json::{json, Value};

use super::problem::ApiError;
use super::{blocking, AppState};

/// Liveness.
#[utoipa::path(get, path = "/healthz", tag = "operations", security(()),
    responses((status = 200, description = "The process is alive", body = Object)))]
pub async fn healthz() -> Json<Value> {
    Json(json!({"status": "ok"}))
}

/// Readiness: the server accepts work. Not ready (503, with `Retry-After`) while it drains,
/// while the storage fails its live probe (a blob write and a rolled-back database write, at
/// most every 2 s and at once after a failed write: a full disk, a locked or full database),
/// when the job store does not answer, when the data directory's free space is under
/// `min_free_bytes`, or when `queue_len` jobs are waiting. It keeps answering during a drain.
#[utoipa::path(get, path = "/readyz", tag = "operations", security(()),
    responses(
        (status = 200, description = "Ready", body = Object),
        (status = 503, description = "Not ready: `shutting-down`, `storage-failing`, `store-unavailable`, `low-disk-space` or `queue-full`", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn readyz(State(state): State<AppState>) -> Result<Json<Value>, ApiError> {
    let unready = |kind: &str, title: &str, detail: String| {
        ApiError::new(StatusCode::SERVICE_UNAVAILABLE, kind, title, detail).retry_after(5)
    };
    if *state.shutdown.borrow() {
        return Err(unready(
            "shutting-down",
            "Shutting down",
            "the server is draining".into(),
        ));
    }
    if !state.runner.storage_healthy().await {
        return Err(unready(
            "storage-failing",
            "Storage failing",
            "a probe write to the blob store or the job database failed just now (see the server log)".into(),
        ));
    }
    let jobs = state.jobs.clone();
    let counts = blocking(move || jobs.counts()).await.map_err(|_| {
        unready(
            "store-unavailable",
            "Store unavailable",
            "the job store does not answer (see the server log)".into(),
        )
    })?;
    let min_free = state.config.min_free_bytes;
    let free = free_bytes(&state.config.data_dir);
    if let Some(free) = free.filter(|f| *f < min_free) {
        return Err(unready(
            "low-disk-space",
            "Low disk space",
            format!("{free} bytes free in the data directory, under min_free_bytes"),
        )
        .limit("min_free_bytes", min_free));
    }
    let queued: u64 = counts
        .by_status
        .iter()
        .filter(|(s, _)| *s == crate::service::model::JobStatus::Enqueued)
        .map(|(_, n)| *n)
        .sum();
    let queue_len = state.config.queue_len;
    if queued >= queue_len {
        return Err(unready(
            "queue-full",
            "Queue full",
            format!("{queued} jobs are waiting"),
        )
        .limit("queue_len", queue_len));
    }
    Ok(Json(json!({
        "status": "ready",
        "queue_depth": queued,
        "busy_workers": state.runner.busy_workers(),
        "free_bytes": free,
    })))
}

/// Bytes available to the server on the file system of `dir` (`statvfs`), if known.
#[cfg(unix)]
pub fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: an all-zero statvfs is a valid value of this plain C struct.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `path` is NUL-terminated and outlives the call; `st` is a valid out-pointer.
    let rc = unsafe { libc::statvfs(path.as_ptr(), &mut st) };
    #[allow(clippy::unnecessary_cast)]
    (rc == 0).then(|| (st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
}

/// Free space is not checked off Unix.
#[cfg(not(unix))]
pub fn free_bytes(_dir: &std::path::Path) -> Option<u64> {
    None
}

/// One retention sweep: removes finished jobs older than the TTL and their blobs, and
/// Idempotency-Keys older than their retention. Returns how many jobs were removed.
pub fn prune_once(state: &AppState) -> Result<usize, crate::service::store::StoreError> {
    let now = Utc::now();
    let ttl = chrono::Duration::seconds(state.config.ttl_secs.min(i64::MAX as u64) as i64);
    let keys = chrono::Duration::seconds(state.config.idempotency_secs.min(i64::MAX as u64) as i64);
    let removed = state.jobs.prune(now - ttl, now - keys.max(ttl))?;
    for r in &removed {
        state.blobs.delete_prefix(&format!("jobs/{}/", r.id))?;
    }
    Ok(removed.len())
}

/// Temporary upload files untouched this long are leftovers of a crash.
pub const STALE_TEMP: Duration = Duration::from_secs(3600);

/// Runs [`prune_once`] and sweeps stale partial uploads from the blob store's temp dir every
/// `prune_interval_secs` until shutdown.
pub async fn retention_loop(state: AppState) {
    let mut shutdown = state.shutdown.clone();
    let period = Duration::from_secs(state.config.prune_interval_secs);
    loop {
        let s = state.clone();
        let swept =
            tokio::task::spawn_blocking(move || (prune_once(&s), s.blobs.sweep_temp(STALE_TEMP)))
                .await;
        if let Ok((pruned, temp)) = swept {
            match pruned {
                Ok(n) if n > 0 => tracing::info!(removed = n, "retention: pruned finished jobs"),
                Err(e) => tracing::warn!(error = %e, "retention sweep failed"),
                _ => {}
            }
            match temp {
                Ok(n) if n > 0 => {
                    tracing::info!(removed = n, "retention: removed stale partial uploads")
                }
                Err(e) => tracing::warn!(error = %e, "sweeping the upload temp dir failed"),
                _ => {}
            }
        }
        tokio::select! {
            _ = tokio::time::sleep(period) => {}
            _ = shutdown.changed() => return,
        }
    }
}
