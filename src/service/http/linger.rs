//! Request bodies that can still be drained after a rejection, so the client reads the answer.
//!
//! When a handler answers (413 for a part over `max_part_bytes`, 503 for a full queue, ...)
//! before the request body has been read to its end, hyper closes the connection with unread
//! bytes in the socket buffer; the kernel then resets it, and a client still writing its body
//! (ureq, curl without `Expect: 100-continue`, most scripts) sees `Broken pipe` instead of the
//! problem document. Like nginx's lingering close, the submit handler reads and discards what is
//! left of a rejected body, within [`LINGER_BYTES`] and [`LINGER_TIME`], before answering.
//!
//! A client that sent `Expect: 100-continue` with a `Content-Length` over the limit is answered
//! without reading anything: hyper only sends `100 Continue` when the body is first read, so
//! that client never sends the body and reads the 413 cleanly.
//!
//! The body limit (`max_body_bytes`) is enforced here rather than by axum's `DefaultBodyLimit`
//! so that the body outlives the multipart parser that hit the limit.

use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::{Body, BodyDataStream, Bytes};
use axum::http::{header, HeaderMap};
use futures_util::{Stream, StreamExt};

/// Most bytes read and discarded after a rejection.
pub const LINGER_BYTES: u64 = 32 << 20;
/// Longest time spent discarding after a rejection.
pub const LINGER_TIME: Duration = Duration::from_secs(10);

/// A request body shared between the multipart parser and the handler.
#[derive(Clone)]
pub struct SharedBody {
    inner: Arc<Mutex<BodyDataStream>>,
    over_limit: Arc<AtomicBool>,
    started: Arc<AtomicBool>,
}

/// The parser's view of a [`SharedBody`]: yields at most `limit` bytes, then an error.
struct LimitedView {
    body: SharedBody,
    seen: u64,
    limit: u64,
}

/// The body passed `max_body_bytes`.
#[derive(Debug, thiserror::Error)]
#[error("request body exceeds {0} bytes")]
pub struct BodyTooLarge(u64);

impl Stream for LimitedView {
    type Item = Result<Bytes, axum::Error>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        if self.body.over_limit.load(Ordering::Relaxed) {
            return Poll::Ready(None);
        }
        self.body.started.store(true, Ordering::Relaxed);
        let polled = match self.body.inner.lock() {
            Ok(mut s) => s.poll_next_unpin(cx),
            Err(_) => return Poll::Ready(None),
        };
        if let Poll::Ready(Some(Ok(chunk))) = &polled {
            self.seen += chunk.len() as u64;
            if self.seen > self.limit {
                self.body.over_limit.store(true, Ordering::Relaxed);
                return Poll::Ready(Some(Err(axum::Error::new(BodyTooLarge(self.limit)))));
            }
        }
        polled
    }
}

impl SharedBody {
    /// Takes `body`; returns the shared handle and a body for the parser limited to `limit`.
    pub fn new(body: Body, limit: u64) -> (Self, Body) {
        let shared = Self {
            inner: Arc::new(Mutex::new(body.into_data_stream())),
            over_limit: Arc::new(AtomicBool::new(false)),
            started: Arc::new(AtomicBool::new(false)),
        };
        let view = LimitedView {
            body: shared.clone(),
            seen: 0,
            limit,
        };
        (shared, Body::from_stream(view))
    }

    /// Whether the parser's view passed its limit.
    pub fn over_limit(&self) -> bool {
        self.over_limit.load(Ordering::Relaxed)
    }

    /// Reads and discards the rest of the body, within [`LINGER_BYTES`] and [`LINGER_TIME`].
    /// Returns the number of bytes discarded.
    pub async fn drain(&self) -> u64 {
        let mut discarded = 0u64;
        let work = async {
            loop {
                let next = std::future::poll_fn(|cx| match self.inner.lock() {
                    Ok(mut s) => s.poll_next_unpin(cx),
                    Err(_) => Poll::Ready(None),
                })
                .await;
                match next {
                    Some(Ok(chunk)) => {
                        discarded += chunk.len() as u64;
                        if discarded > LINGER_BYTES {
                            break;
                        }
                    }
                    _ => break,
                }
            }
        };
        let _ = tokio::time::timeout(LINGER_TIME, work).await;
        discarded
    }
}

/// The declared `Content-Length`, if any and valid.
pub fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)?
        .to_str()
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// Whether the client waits for `100 Continue` before sending its body.
fn expects_continue(headers: &HeaderMap) -> bool {
    headers
        .get(header::EXPECT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.eq_ignore_ascii_case("100-continue"))
}

impl SharedBody {
    /// Whether a rejection should drain the body first: not when the client still waits for
    /// `100 Continue` (nothing was read, so it has sent nothing), nor when the declared rest is
    /// beyond what lingering reads anyway.
    pub fn worth_draining(&self, headers: &HeaderMap, limit: u64) -> bool {
        if expects_continue(headers) && !self.started.load(Ordering::Relaxed) {
            return false;
        }
        match content_length(headers) {
            Some(n) => n <= limit.saturating_add(LINGER_BYTES),
            None => true,
        }
    }
}

/// Reads and discards a whole request body that was rejected before anything read it (401 or
/// 403 from authentication), when the client declared a length of at most [`LINGER_BYTES`] and
/// does not wait for `100 Continue`; within [`LINGER_TIME`]. Returns the bytes discarded.
pub async fn drain_unread(headers: &HeaderMap, body: Body) -> u64 {
    let small = content_length(headers).is_some_and(|n| n > 0 && n <= LINGER_BYTES);
    if !small || expects_continue(headers) {
        return 0;
    }
    let mut stream = body.into_data_stream();
    let mut discarded = 0u64;
    let work = async {
        while let Some(Ok(chunk)) = stream.next().await {
            discarded += chunk.len() as u64;
            if discarded > LINGER_BYTES {
                break;
            }
        }
    };
    let _ = tokio::time::timeout(LINGER_TIME, work).await;
    discarded
}
