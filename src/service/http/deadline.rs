//! The overall upload deadline (`upload_timeout_secs`): a request body must be received
//! completely within this time from the request's start, however steadily the client trickles
//! it (the per-read `body_timeout_secs` only catches a client that goes silent). Past the
//! deadline the body yields [`UploadDeadline`], which the submission answers as `408
//! /problems/upload-timeout` naming the limit.

use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::{Request, State};
use axum::middleware::Next;
use axum::response::Response;
use http_body::Frame;
use tokio::time::Sleep;

use super::AppState;

/// The request body was still arriving when the upload deadline passed.
#[derive(Debug, thiserror::Error)]
#[error("the request body was not received within {0} s")]
pub struct UploadDeadline(pub u64);

/// A body that fails with [`UploadDeadline`] once its deadline passes.
struct DeadlineBody {
    body: Body,
    sleep: Pin<Box<Sleep>>,
    secs: u64,
}

impl http_body::Body for DeadlineBody {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        if self.body.is_end_stream() {
            return Poll::Ready(None);
        }
        if self.sleep.as_mut().poll(cx).is_ready() {
            return Poll::Ready(Some(Err(axum::Error::new(UploadDeadline(self.secs)))));
        }
        Pin::new(&mut self.body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}

/// Middleware: puts every request body under the upload deadline.
pub async fn upload_deadline(
    State(state): State<AppState>,
    request: Request,
    next: Next,
) -> Response {
    let secs = state.config.upload_timeout_secs;
    if http_body::Body::is_end_stream(request.body()) {
        return next.run(request).await;
    }
    let request = request.map(|body| {
        Body::new(DeadlineBody {
            body,
            sleep: Box::pin(tokio::time::sleep(Duration::from_secs(secs))),
            secs,
        })
    });
    next.run(request).await
}

/// Whether `e` (or an error in its source chain) is the upload deadline; returns its seconds.
pub fn upload_deadline_of(e: &(dyn std::error::Error + 'static)) -> Option<u64> {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if let Some(d) = err.downcast_ref::<UploadDeadline>() {
            return Some(d.0);
        }
        cur = err.source();
    }
    None
}
