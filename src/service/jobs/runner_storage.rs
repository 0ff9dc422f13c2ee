//! Storage failures seen by the [`Runner`]: a job whose output write hit a full disk is not
//! failed (the disk, not the job, is at fault) but put back to the queue, its partial outputs
//! removed, and no job is claimed for `storage_retry` so a full disk does not spin jobs
//! through the workers. Failed store writes are remembered so `/readyz` can report them.

use std::time::Instant;

use chrono::Utc;
use uuid::Uuid;

use super::{locked, Runner, FINISH_ATTEMPTS};

impl Runner {
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
}
