//! Storage failures seen by the [`Runner`]: a job whose output write hit a full disk is not
//! failed (the disk, not the job, is at fault) but put back to the queue, its partial outputs
//! removed, and no job is claimed for `storage_retry` so a full disk does not spin jobs
//! through the workers. Outputs of an attempt whose finish the store refused are deleted
//! ([`Runner::discard_outputs`]).
//!
//! `/readyz` asks [`Runner::storage_healthy`], a live probe rather than a time window: one
//! blob write ([`crate::service::store::BlobStore::probe`]) and one rolled-back database write ([`crate::service::store::JobStore::probe`]),
//! run at most every [`PROBE_EVERY`] and cached in between, and re-run at once after a failure
//! was noted, so readiness turns false on the next poll after a failed write and true again on
//! the first poll after the fault has cleared. [`PROBE_EVERY`] is not from a paper: a probe
//! is an fsynced 4 KiB file and a 16 KiB rolled-back insert, cheap at one per 2 s even when
//! a load balancer polls several times a second.

use std::time::Instant;

use chrono::Utc;
use uuid::Uuid;

use super::{locked, Runner, FINISH_ATTEMPTS};
use crate::service::model::ArtifactRef;
use crate::service::store::StoreError;

/// The storage probe behind `/readyz` runs at most this often (unless a failure was noted).
pub const PROBE_EVERY: std::time::Duration = std::time::Duration::from_secs(2);

/// The last storage probe: when, and whether it passed.
#[derive(Clone, Copy, Debug)]
pub(super) struct Probed {
    at: Instant,
    ok: bool,
}

impl Runner {
    /// Whether the storage takes writes now (see the module docs): the cached probe when it is
    /// younger than [`PROBE_EVERY`] and no failure was noted since, else a new probe.
    pub async fn storage_healthy(&self) -> bool {
        let failed = *locked(&self.storage_failed);
        let cached = *locked(&self.probed);
        if let Some(p) = cached {
            let failed_since = failed.is_some_and(|f| f > p.at);
            if p.at.elapsed() < PROBE_EVERY && !failed_since {
                return p.ok;
            }
        }
        let (jobs, blobs) = (self.jobs.clone(), self.blobs.clone());
        let probe = move || blobs.probe().and_then(|()| jobs.probe());
        let at = Instant::now();
        let ok = match tokio::task::spawn_blocking(probe).await {
            Ok(Ok(())) => true,
            Ok(Err(e)) => {
                tracing::warn!(error = %e, "storage probe failed: not ready");
                false
            }
            Err(e) => {
                tracing::error!(error = %e, "storage probe panicked");
                false
            }
        };
        if cached.is_some_and(|p| !p.ok) && ok {
            tracing::info!("storage probe passed again: ready");
        }
        *locked(&self.probed) = Some(Probed { at, ok });
        ok
    }

    /// Records a failure of the storage: claims pause for `storage_retry`, and
    /// [`Runner::storage_failing`] is true for as long.
    pub fn note_storage_failure(&self) {
        *locked(&self.storage_failed) = Some(Instant::now());
    }

    /// Whether storage failed within the last `storage_retry`.
    pub fn storage_failing(&self) -> bool {
        locked(&self.storage_failed).is_some_and(|t| t.elapsed() < self.config.storage_retry)
    }

    /// Whether the dispatcher holds off claiming after a storage failure.
    pub(super) fn storage_paused(&self) -> bool {
        self.storage_failing()
    }

    /// Puts a job whose outputs could not be stored for lack of space back to the queue
    /// (without counting the attempt) and removes what it stored.
    pub(super) async fn requeue_after_full_disk(&self, id: Uuid, detail: &str) {
        tracing::error!(%id, detail, "disk full while storing the job's outputs; re-enqueueing it");
        self.note_storage_failure();
        let mut delay = std::time::Duration::from_millis(100);
        for attempt in 1..=FINISH_ATTEMPTS {
            let (jobs, blobs) = (self.jobs.clone(), self.blobs.clone());
            let requeue = move || {
                let _ = blobs.delete_prefix(&format!("jobs/{id}/outputs/"));
                jobs.requeue_stopped(&[id], Utc::now())
            };
            match tokio::task::spawn_blocking(requeue).await {
                Ok(Ok(records)) => {
                    for j in records {
                        self.emit(j.id, j.status, j.progress, j.revision);
                    }
                    return;
                }
                Ok(Err(e)) => tracing::error!(%id, attempt, error = %e, "re-enqueueing failed"),
                Err(e) => tracing::error!(%id, attempt, error = %e, "re-enqueueing panicked"),
            }
            tokio::time::sleep(delay).await;
            delay *= 4;
        }
    }

    /// Deletes the outputs an attempt stored that no record points at (its finish was refused:
    /// the job was canceled, deleted or reclaimed by another replica meanwhile). Only this
    /// attempt's folder goes; a failure is logged (the files then go with the job).
    pub(super) async fn discard_outputs(&self, id: Uuid, artifacts: &[ArtifactRef]) {
        let mut folders: Vec<String> = artifacts
            .iter()
            .filter_map(|a| a.key.rsplit_once('/').map(|(dir, _)| format!("{dir}/")))
            .collect();
        folders.dedup();
        if folders.is_empty() {
            return;
        }
        let blobs = self.blobs.clone();
        let delete = move || -> Result<(), StoreError> {
            folders.iter().try_for_each(|f| blobs.delete_prefix(f))
        };
        match tokio::task::spawn_blocking(delete).await {
            Ok(Ok(())) => {
                tracing::info!(%id, "discarded the outputs of a finish the store refused")
            }
            Ok(Err(e)) => tracing::warn!(%id, error = %e, "discarding unrecorded outputs failed"),
            Err(e) => tracing::warn!(%id, error = %e, "discarding unrecorded outputs panicked"),
        }
    }
}
