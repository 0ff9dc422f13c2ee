//! `GET /v1/events`: one Server-Sent Events stream (WHATWG HTML §9.2) of every job's changes,
//! for a live job list (issue 16: "live progress bar and stage name (SSE, falling back to
//! polling)") without one stream per row.
//!
//! Every caller sees every job (the job list is not filtered by owner either), so the stream
//! carries every change the runner broadcasts ([`crate::service::jobs::runner::JobEvent`]: a job
//! claimed, its progress, its end, a cancellation or submission announced by the HTTP layer).
//! Events:
//! - `ready` (data `{}`) once, first, so a client knows the stream is open;
//! - `job`, data a [`JobEventDoc`], at most one per job and status per batch (so every status a
//!   job passes through is sent, in order, and progress within a status is coalesced);
//! - `resync` (data `{}`) when this stream fell behind the broadcast channel and missed changes:
//!   the client reloads the list.
//!
//! Rate: changes are gathered for [`BATCH`] after the first one arrives and sent together, each
//! job in each status only at its newest revision, so a stream sends at most one batch per
//! [`BATCH`] (and at most four events per job in it) however
//! many jobs run and however often their progress ticks (the runner itself sends progress at
//! most every `progress_interval_ms`). [`BATCH`] = 250 ms is a choice for a progress bar a person
//! watches (four updates a second), not from a source. Keep-alive comments every
//! [`super::events::KEEP_ALIVE`]; the stream ends when the server shuts down.

use std::collections::HashMap;
use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::stream::{self, Stream};
use tokio::sync::broadcast::error::RecvError;
use uuid::Uuid;

use super::doc::JobEventDoc;
use super::events::{doc, KEEP_ALIVE};
use super::AppState;
use crate::service::jobs::runner::JobEvent;
use crate::service::model::JobStatus;

/// How long changes are gathered before a batch is sent.
pub const BATCH: Duration = Duration::from_millis(250);

/// Changes gathered for the next batch, in first-seen order, the newest revision per job and
/// status.
#[derive(Default)]
struct Batch {
    order: Vec<(Uuid, JobStatus)>,
    latest: HashMap<(Uuid, JobStatus), JobEventDoc>,
    resync: bool,
}

impl Batch {
    fn add(&mut self, ev: JobEvent) {
        let key = (ev.id, ev.status);
        let d = doc(ev.id, ev.status, &ev.progress, ev.revision);
        match self.latest.get(&key) {
            // An older revision never replaces a newer one.
            Some(old) if old.revision > d.revision => {}
            Some(_) => {
                self.latest.insert(key, d);
            }
            None => {
                self.order.push(key);
                self.latest.insert(key, d);
            }
        }
    }

    fn is_empty(&self) -> bool {
        self.order.is_empty() && !self.resync
    }

    fn drain(&mut self) -> Vec<Event> {
        let mut out = Vec::with_capacity(self.order.len() + 1);
        if std::mem::take(&mut self.resync) {
            out.push(Event::default().event("resync").data("{}"));
        }
        for key in self.order.drain(..) {
            if let Some(d) = self.latest.remove(&key) {
                out.push(
                    Event::default()
                        .event("job")
                        .json_data(&d)
                        .unwrap_or_else(|_| Event::default().comment("serialization failed")),
                );
            }
        }
        out
    }
}

struct ListCursor {
    state: AppState,
    rx: tokio::sync::broadcast::Receiver<JobEvent>,
    queue: std::collections::VecDeque<Event>,
    ended: bool,
}

impl ListCursor {
    /// Waits for one message; `false` when the stream must end.
    async fn receive(&mut self, batch: &mut Batch) -> bool {
        let mut shutdown = self.state.shutdown.clone();
        if *shutdown.borrow() {
            return false;
        }
        tokio::select! {
            _ = shutdown.changed() => false,
            msg = self.rx.recv() => match msg {
                Ok(ev) => {
                    batch.add(ev);
                    true
                }
                Err(RecvError::Lagged(_)) => {
                    batch.resync = true;
                    true
                }
                Err(RecvError::Closed) => false,
            },
        }
    }

    /// Gathers one batch: the first change, then whatever arrives within [`BATCH`].
    async fn gather(&mut self) {
        let mut batch = Batch::default();
        if !self.receive(&mut batch).await {
            self.ended = true;
            return;
        }
        let until = tokio::time::Instant::now() + BATCH;
        loop {
            match tokio::time::timeout_at(until, self.receive(&mut batch)).await {
                Ok(true) => {}
                Ok(false) => {
                    self.ended = true;
                    break;
                }
                Err(_) => break,
            }
        }
        if !batch.is_empty() {
            self.queue.extend(batch.drain());
        }
    }

    async fn next(mut self) -> Option<(Result<Event, Infallible>, Self)> {
        loop {
            if let Some(ev) = self.queue.pop_front() {
                return Some((Ok(ev), self));
            }
            if self.ended {
                return None;
            }
            self.gather().await;
        }
    }
}

/// Stream every job's changes.
#[utoipa::path(get, path = "/v1/events", tag = "jobs",
    responses(
        (status = 200, description = "`text/event-stream`: one `ready` event, then `job` events (data a JobEventDoc; at most one per job and status every 250 ms) and `resync` events (changes were missed: reload the list); keep-alive comments every 15 s",
         content_type = "text/event-stream", body = JobEventDoc),
        (status = 401, description = "Tokens are configured and none valid was sent", body = super::doc::ProblemSchema, content_type = "application/problem+json"),
    ))]
pub async fn job_stream(
    State(state): State<AppState>,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let rx = state.runner.subscribe();
    let mut queue = std::collections::VecDeque::new();
    queue.push_back(Event::default().event("ready").data("{}"));
    let cursor = ListCursor {
        state,
        rx,
        queue,
        ended: false,
    };
    Sse::new(stream::unfold(cursor, ListCursor::next))
        .keep_alive(KeepAlive::new().interval(KEEP_ALIVE))
}
