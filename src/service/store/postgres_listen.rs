//! The change feed of [`super::PgJobStore`] (issue 17, part 1: "LISTEN/NOTIFY to wake idle
//! workers"): every job write of a store handle sends `pg_notify(CHANNEL, payload)` inside its
//! transaction (PostgreSQL delivers it at commit, and never for a rolled-back transaction); each
//! replica keeps one extra connection that `LISTEN`s on the channel and hands the changes that
//! other handles made to the runner's [`ChangeSink`].
//!
//! Payload: the JSON of [`Note`], i.e. the writer's lease-owner id (so a replica skips its own
//! changes, which its runner already knows) and a [`JobChange`] (id, status, revision, stored
//! progress, whether a cancel was requested). PostgreSQL limits a payload to 8,000 bytes; a
//! change whose progress stage name would not fit is sent without the stage name.
//!
//! Delivery is best effort by design: while the listening connection is down (server restart,
//! network) changes are missed, and the feed reconnects every [`RECONNECT`]. Nothing depends on
//! it for correctness: idle workers still poll the queue every `poll_secs`, cancels still travel
//! with the lease heartbeat, and event streams re-read the store when they fall behind. The
//! reconnect delay is this module's choice (plumbing, no source).

use std::time::Duration;

use futures_util::StreamExt;
use tokio_postgres::{AsyncMessage, NoTls};

use super::super::{ChangeSink, JobChange};
use crate::service::model::{JobProgress, JobRecord};

/// The notification channel of job changes.
pub const CHANNEL: &str = "retex_jobs";
/// Wait before reconnecting a lost listening connection.
const RECONNECT: Duration = Duration::from_secs(1);
/// Largest payload PostgreSQL accepts (its limit is 8,000 bytes).
const MAX_PAYLOAD: usize = 7_900;

/// One notification's payload.
#[derive(serde::Serialize, serde::Deserialize)]
struct Note {
    /// Lease-owner id of the store handle that made the change.
    origin: String,
    /// The change.
    change: JobChange,
}

/// The payload announcing `job` as written by `origin`.
pub fn payload(job: &JobRecord, origin: &str, cancel_requested: bool) -> String {
    let mut note = Note {
        origin: origin.to_string(),
        change: JobChange {
            id: job.id,
            status: job.status,
            revision: job.revision,
            progress: job.progress.clone(),
            cancel_requested,
        },
    };
    let text = serde_json::to_string(&note).unwrap_or_default();
    if text.len() <= MAX_PAYLOAD {
        return text;
    }
    note.change.progress = JobProgress {
        stage: String::new(),
        ..job.progress.clone()
    };
    serde_json::to_string(&note).unwrap_or_default()
}

/// The change in `payload` unless `own` made it (or it does not parse: a newer replica's format).
fn foreign_change(payload: &str, own: &str) -> Option<JobChange> {
    let note: Note = serde_json::from_str(payload).ok()?;
    (note.origin != own).then_some(note.change)
}

/// Listens on [`CHANNEL`] with its own connection from `config` and forever hands the changes
/// not made by `own` to `sink`, reconnecting after [`RECONNECT`] when the connection fails. Runs
/// on the store's runtime until the store is dropped. `ready` gets a message once the first
/// `LISTEN` is in place (every change committed after that is delivered while the connection
/// lives).
pub async fn feed(
    config: tokio_postgres::Config,
    own: String,
    sink: ChangeSink,
    ready: std::sync::mpsc::SyncSender<()>,
) {
    let mut failures = 0u32;
    let mut ready = Some(ready);
    loop {
        match listen_once(&config, &own, &sink, &mut ready).await {
            Ok(()) => failures = 0,
            Err(e) => {
                failures += 1;
                // The first failure and then one in sixty, so a long outage does not flood logs.
                if failures % 60 == 1 {
                    tracing::warn!(error = %e, "job change feed: connection lost; reconnecting");
                }
            }
        }
        tokio::time::sleep(RECONNECT).await;
    }
}

/// One listening connection's life: connects, `LISTEN`s, relays until the connection ends.
async fn listen_once(
    config: &tokio_postgres::Config,
    own: &str,
    sink: &ChangeSink,
    ready: &mut Option<std::sync::mpsc::SyncSender<()>>,
) -> Result<(), tokio_postgres::Error> {
    let (client, mut connection) = config.connect(NoTls).await?;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<Result<String, _>>();
    // The connection object performs the I/O: it must be polled for `LISTEN` to complete and for
    // notifications to arrive.
    let driver = tokio::spawn(async move {
        let mut messages = futures_util::stream::poll_fn(move |cx| connection.poll_message(cx));
        while let Some(m) = messages.next().await {
            match m {
                Ok(AsyncMessage::Notification(n)) => {
                    if tx.send(Ok(n.payload().to_string())).is_err() {
                        return;
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    let _ = tx.send(Err(e));
                    return;
                }
            }
        }
    });
    let listened = client.batch_execute(&format!("LISTEN {CHANNEL}")).await;
    let result = match listened {
        Ok(()) => loop {
            if let Some(r) = ready.take() {
                let _ = r.try_send(());
            }
            match rx.recv().await {
                Some(Ok(payload)) => {
                    if let Some(change) = foreign_change(&payload, own) {
                        sink(change);
                    }
                }
                Some(Err(e)) => break Err(e),
                None => break Ok(()),
            }
        },
        Err(e) => Err(e),
    };
    driver.abort();
    drop(client);
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::model::{JobInputs, JobStatus, ModelFiles};

    fn job(stage: &str) -> JobRecord {
        JobRecord {
            id: uuid::Uuid::now_v7(),
            status: JobStatus::Processing,
            method: "project".into(),
            progress: JobProgress {
                stage: stage.into(),
                fraction: 0.5,
                stages_done: 1,
                stages_total: 4,
            },
            created_at: chrono::Utc::now(),
            started_at: None,
            finished_at: None,
            error: None,
            report: None,
            attempts: 1,
            idempotency_key: None,
            owner: None,
            request_hash: "h".into(),
            inputs: JobInputs {
                source: None,
                target: ModelFiles::default(),
                source_base: None,
                constraints: "c".into(),
                pattern: None,
            },
            artifacts: vec![],
            revision: 7,
        }
    }

    #[test]
    fn a_payload_round_trips_and_own_changes_are_skipped() {
        let j = job("project");
        let p = payload(&j, "replica-a", true);
        let c = foreign_change(&p, "replica-b").expect("another replica's change");
        assert_eq!((c.id, c.status, c.revision), (j.id, j.status, 7));
        assert_eq!(c.progress, j.progress);
        assert!(c.cancel_requested);
        assert!(
            foreign_change(&p, "replica-a").is_none(),
            "own change skipped"
        );
        assert!(foreign_change("not json", "x").is_none());
    }

    #[test]
    fn an_oversized_stage_name_is_dropped_to_fit_the_payload_limit() {
        let j = job(&"s".repeat(10_000));
        let p = payload(&j, "a", false);
        assert!(p.len() <= MAX_PAYLOAD, "{}", p.len());
        let c = foreign_change(&p, "b").unwrap();
        assert_eq!(
            (c.progress.stage.as_str(), c.progress.stages_total),
            ("", 4)
        );
    }
}
