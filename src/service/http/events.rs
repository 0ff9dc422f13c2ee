//! `GET /v1/jobs/{id}/events`: Server-Sent Events (WHATWG HTML §9.2) of one job.
//!
//! The stream starts with the job's current state, then sends one event per change the runner
//! broadcasts (status or progress). Event ids are the job's revisions, so they increase; a
//! client reconnecting with `Last-Event-ID: n` receives only revisions after `n` (plus the
//! terminal event, which is always sent so the stream can end). Non-terminal events are named
//! `progress`, the last one `done`; the data is a [`JobEventDoc`]. Comments keep idle
//! connections open through proxies, and every stream ends when the server shuts down.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::stream::{self, Stream};
use tokio::sync::broadcast::error::RecvError;
use uuid::Uuid;

use super::doc::{JobEventDoc, ProgressDoc, StageCount};
use super::jobs::JobId;
use super::problem::ApiError;
use super::{blocking, AppState};
use crate::service::jobs::runner::JobEvent;
use crate::service::model::{JobProgress, JobRecord, JobStatus};

/// Interval of keep-alive comments.
pub const KEEP_ALIVE: Duration = Duration::from_secs(15);

pub(crate) fn doc(id: Uuid, status: JobStatus, p: &JobProgress, revision: u64) -> JobEventDoc {
    JobEventDoc {
        id,
        status,
        progress: ProgressDoc {
            stage: p.stage.clone(),
            fraction: p.fraction.clamp(0.0, 1.0),
            stages: StageCount {
                done: p.stages_done,
                total: p.stages_total,
            },
        },
        revision,
    }
}

fn to_event(d: &JobEventDoc) -> Event {
    let name = if d.status.is_terminal() {
        "done"
    } else {
        "progress"
    };
    Event::default()
        .id(d.revision.to_string())
        .event(name)
        .json_data(d)
        .unwrap_or_else(|_| Event::default().comment("serialization failed"))
}

struct Cursor {
    state: AppState,
    id: Uuid,
    rx: tokio::sync::broadcast::Receiver<JobEvent>,
    /// An event to send before waiting (the initial state, or a reload after lag).
    pending: Option<JobEventDoc>,
    /// Revision of the last event sent (or the client's `Last-Event-ID`).
    last: Option<u64>,
    done: bool,
}

fn from_record(r: &JobRecord) -> JobEventDoc {
    doc(r.id, r.status, &r.progress, r.revision)
}

impl Cursor {
    /// Emits `d` if it is news (or terminal); returns the event.
    fn take(&mut self, d: JobEventDoc) -> Option<Event> {
        if self.last.is_some_and(|l| d.revision <= l) && !d.status.is_terminal() {
            return None;
        }
        self.last = Some(self.last.map_or(d.revision, |l| l.max(d.revision)));
        self.done = d.status.is_terminal();
        Some(to_event(&d))
    }

    async fn next(mut self) -> Option<(Result<Event, Infallible>, Self)> {
        loop {
            if self.done {
                return None;
            }
            if let Some(d) = self.pending.take() {
                if let Some(ev) = self.take(d) {
                    return Some((Ok(ev), self));
                }
                continue;
            }
            let mut shutdown = self.state.shutdown.clone();
            if *shutdown.borrow() {
                return None;
            }
            tokio::select! {
                _ = shutdown.changed() => return None,
                msg = self.rx.recv() => match msg {
                    Ok(ev) if ev.id == self.id => {
                        let d = doc(ev.id, ev.status, &ev.progress, ev.revision);
                        if let Some(e) = self.take(d) {
                            return Some((Ok(e), self));
                        }
                    }
                    Ok(_) => {}
                    Err(RecvError::Lagged(_)) => {
                        // Missed events: the store has the latest state.
                        let (jobs, id) = (self.state.jobs.clone(), self.id);
                        match blocking(move || jobs.get(id)).await {
                            Ok(Some(r)) => self.pending = Some(from_record(&r)),
                            _ => return None,
                        }
                    }
                    Err(RecvError::Closed) => return None,
                },
            }
        }
    }
}

/// Stream a job's progress.
#[utoipa::path(get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id"),
           ("Last-Event-ID" = Option<String>, Header, description = "Resume after this revision")),
    responses(
        (status = 200, description = "`text/event-stream`: `progress` events, then one `done` event; data is a JobEventDoc",
         content_type = "text/event-stream", body = JobEventDoc),
        (status = 400, description = "Malformed job id (not a UUID)", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn events(
    State(state): State<AppState>,
    JobId(id): JobId,
    headers: HeaderMap,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let last = headers
        .get("last-event-id")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    // Subscribe before reading the store so no change falls between the two.
    let rx = state.runner.subscribe();
    let jobs = state.jobs.clone();
    let record = blocking(move || jobs.get(id))
        .await?
        .ok_or_else(|| ApiError::job_not_found(id))?;
    // Without Last-Event-ID the current state is sent first.
    let initial = from_record(&record);
    let cursor = Cursor {
        state,
        id,
        rx,
        pending: Some(initial),
        last,
        done: false,
    };
    let stream = stream::unfold(cursor, Cursor::next);
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(KEEP_ALIVE)))
}
