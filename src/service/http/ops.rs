//! Operations: `GET /healthz` (the process answers), `GET /readyz` (the store answers and the
//! server is not shutting down), and the retention sweep that prunes finished jobs older than
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

/// Readiness: the job store answers and the server accepts work.
#[utoipa::path(get, path = "/readyz", tag = "operations", security(()),
    responses(
        (status = 200, description = "Ready", body = Object),
        (status = 503, description = "Shutting down or the store fails", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn readyz(State(state): State<AppState>) -> Result<Json<Value>, ApiError> {
    if *state.shutdown.borrow() {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "shutting-down",
            "Shutting down",
            "the server is draining",
        ));
    }
    let jobs = state.jobs.clone();
    let counts = blocking(move || jobs.counts()).await.map_err(|e| {
        ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "store-unavailable",
            "Store unavailable",
            e.problem.detail,
        )
    })?;
    let queued: u64 = counts
        .by_status
        .iter()
        .filter(|(s, _)| *s == crate::service::model::JobStatus::Enqueued)
        .map(|(_, n)| *n)
        .sum();
    Ok(Json(json!({
        "status": "ready",
        "queue_depth": queued,
        "busy_workers": state.runner.busy_workers(),
    })))
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
