//! Serving connections: hyper's HTTP/1 server driven directly (instead of `axum::serve`) so a
//! slow, idle or greedy client cannot hold the server.
//!
//! - **Header timeout** (`header_timeout_secs`): a request head must arrive complete within
//!   this time, counted from the accept for a connection's first request and from the first
//!   byte for the next ones; otherwise the connection is closed (a half-sent header no longer
//!   holds a socket forever).
//! - **Idle timeout** (`idle_timeout_secs`): a kept-alive connection with no request in flight
//!   and no byte received for this long is closed.
//! - **Connection cap** (`max_connections`): a connection beyond it is answered at once with
//!   `503` problem+json (`/problems/too-many-connections`, `Retry-After`) and closed, so the
//!   sockets the server holds stay bounded and `/healthz` answers again as soon as slots free.
//! - **Per-client cap** (`max_connections_per_client`, off by default): a connection from a peer
//!   address that already holds this many is answered `503`
//!   (`/problems/too-many-client-connections`, `Retry-After`) and closed, so one client cannot
//!   take every slot of the global cap. Off by default because behind a reverse proxy or a load
//!   balancer every client has the proxy's address.
//! - **Drain**: while the server drains ([`serve`]'s `draining`), open connections close after
//!   their current request and new ones are served one request each (keep-alive off), so
//!   `/readyz` keeps answering (`503 shutting-down`) until `stop`.
//!
//! A request in flight (handler running or response streaming) is bounded by the body timeouts
//! of the router (`body_timeout_secs`, `upload_timeout_secs`), not by these.

use std::convert::Infallible;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::Router;
use hyper::body::Incoming;
use hyper::server::conn::http1;
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Notify, Semaphore};
use tokio::time::Instant;
use tower::ServiceExt;

use crate::service::config::ServeConfig;

/// Most refused connections lingering at once (each reads what the client sent for up to
/// [`REFUSAL_LINGER`] so the client reads the 503 instead of a reset); beyond, refused
/// sockets are closed straight away.
const REFUSALS: usize = 64;
/// How long a refused connection is drained before it is closed.
const REFUSAL_LINGER: Duration = Duration::from_secs(1);

/// The connection limits of the configuration.
#[derive(Clone, Copy, Debug)]
pub struct ConnLimits {
    /// Time to receive a complete request head.
    pub header_timeout: Duration,
    /// Time a connection may sit idle between requests.
    pub idle_timeout: Duration,
    /// Most connections served at once.
    pub max_connections: usize,
    /// Most connections served at once per peer IP address; 0 = no per-client cap.
    pub max_connections_per_client: usize,
}

impl ConnLimits {
    /// The limits `config` names.
    pub fn from_config(config: &ServeConfig) -> Self {
        Self {
            header_timeout: Duration::from_secs(config.header_timeout_secs),
            idle_timeout: Duration::from_secs(config.idle_timeout_secs),
            max_connections: config.max_connections,
            max_connections_per_client: config.max_connections_per_client,
        }
    }
}

/// Where a connection is in its life: waiting for (or reading) a request head since, idle
/// since, or serving requests.
#[derive(Clone, Copy)]
enum Phase {
    Head(Instant),
    Idle(Instant),
    Busy(usize),
}

/// The phase of one connection, updated by its reads and by its requests' start and end.
struct Tracker {
    phase: Mutex<Phase>,
    changed: Notify,
}

impl Tracker {
    fn new() -> Arc<Self> {
        Arc::new(Self {
            phase: Mutex::new(Phase::Head(Instant::now())),
            changed: Notify::new(),
        })
    }

    fn update(&self, f: impl FnOnce(Phase) -> Phase) {
        let mut p = self.phase.lock().unwrap_or_else(|e| e.into_inner());
        *p = f(*p);
        drop(p);
        self.changed.notify_one();
    }

    /// Bytes arrived: an idle connection starts reading a request head.
    fn on_read(&self) {
        let idle = matches!(
            *self.phase.lock().unwrap_or_else(|e| e.into_inner()),
            Phase::Idle(_)
        );
        if idle {
            self.update(|p| match p {
                Phase::Idle(_) => Phase::Head(Instant::now()),
                other => other,
            });
        }
    }

    /// A request reached the router; the returned guard ends it when dropped (with the
    /// response body, once hyper has sent it).
    fn begin(self: &Arc<Self>) -> InFlight {
        self.update(|p| match p {
            Phase::Busy(n) => Phase::Busy(n + 1),
            _ => Phase::Busy(1),
        });
        InFlight(self.clone())
    }

    /// Resolves when the connection overstays its phase; names the timeout.
    async fn overstayed(&self, limits: ConnLimits) -> &'static str {
        loop {
            let phase = *self.phase.lock().unwrap_or_else(|e| e.into_inner());
            let deadline = match phase {
                Phase::Head(t) => Some((t + limits.header_timeout, "header_timeout_secs")),
                Phase::Idle(t) => Some((t + limits.idle_timeout, "idle_timeout_secs")),
                Phase::Busy(_) => None,
            };
            match deadline {
                None => self.changed.notified().await,
                Some((at, _)) if at > Instant::now() => {
                    tokio::select! {
                        _ = tokio::time::sleep_until(at) => {}
                        _ = self.changed.notified() => {}
                    }
                }
                Some((_, which)) => return which,
            }
        }
    }
}

/// One request in flight on a connection.
struct InFlight(Arc<Tracker>);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.update(|p| match p {
            Phase::Busy(n) if n > 1 => Phase::Busy(n - 1),
            _ => Phase::Idle(Instant::now()),
        });
    }
}

/// A socket that reports received bytes to its [`Tracker`].
struct Watched {
    io: TcpStream,
    tracker: Arc<Tracker>,
}

impl AsyncRead for Watched {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.io).poll_read(cx, buf);
        if matches!(polled, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            self.tracker.on_read();
        }
        polled
    }
}

impl AsyncWrite for Watched {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.io).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

/// A response body that keeps its request counted as in flight until hyper drops it.
struct Tracked {
    body: Body,
    _in_flight: InFlight,
}

impl http_body::Body for Tracked {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}

/// The 503 a connection beyond the cap gets.
fn refusal(max_connections: usize) -> Vec<u8> {
    refusal_answer(
        "too-many-connections",
        "Too many connections",
        format!("the server holds {max_connections} connections; try again shortly"),
        "max_connections",
        max_connections,
    )
}

/// The 503 a connection beyond the per-client cap gets.
fn client_refusal(per_client: usize) -> Vec<u8> {
    refusal_answer(
        "too-many-client-connections",
        "Too many connections from this client",
        format!("this address holds {per_client} connections already; reuse them (keep-alive) or close one"),
        "max_connections_per_client",
        per_client,
    )
}

/// A whole `503` HTTP/1.1 answer with a problem+json body and `Retry-After: 1`.
fn refusal_answer(kind: &str, title: &str, detail: String, limit: &str, value: usize) -> Vec<u8> {
    let body = serde_json::json!({
        "type": format!("/problems/{kind}"),
        "title": title,
        "status": 503,
        "detail": detail,
        "limit": {"name": limit, "value": value},
    })
    .to_string();
    format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: {}\r\nretry-after: 1\r\nconnection: close\r\ncontent-length: {}\r\n\r\n{body}",
        super::problem::PROBLEM_JSON,
        body.len()
    )
    .into_bytes()
}

/// Connections held per peer address (for `max_connections_per_client`).
#[derive(Default)]
struct Clients(Mutex<std::collections::HashMap<std::net::IpAddr, usize>>);

/// One connection counted against its peer address; uncounted when dropped.
struct ClientSlot {
    clients: Arc<Clients>,
    ip: std::net::IpAddr,
}

impl Clients {
    /// Counts a connection from `ip`, unless it holds `cap` already (`None`).
    fn take(self: &Arc<Self>, ip: std::net::IpAddr, cap: usize) -> Option<ClientSlot> {
        let mut held = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let n = held.entry(ip).or_insert(0);
        if *n >= cap {
            return None;
        }
        *n += 1;
        Some(ClientSlot {
            clients: self.clone(),
            ip,
        })
    }
}

impl Drop for ClientSlot {
    fn drop(&mut self) {
        let mut held = self.clients.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = held.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                held.remove(&self.ip);
            }
        }
    }
}

/// Answers a connection beyond the cap with the 503 and closes it, after reading what the
/// client sent (briefly, and only for [`REFUSALS`] sockets at once).
fn refuse(stream: TcpStream, answer: Arc<[u8]>, lingering: &Arc<Semaphore>) {
    // The send buffer of a fresh socket is empty: the short answer goes out without waiting.
    let _ = stream.try_write(&answer);
    let Ok(permit) = lingering.clone().try_acquire_owned() else {
        return;
    };
    tokio::spawn(async move {
        let mut stream = stream;
        let _ = stream.shutdown().await;
        let mut sink = [0u8; 4096];
        let _ = tokio::time::timeout(REFUSAL_LINGER, async {
            while matches!(stream.read(&mut sink).await, Ok(n) if n > 0) {}
        })
        .await;
        drop(permit);
    });
}

/// Serves one connection until it ends, overstays a timeout, or (once draining) finishes its
/// current request.
async fn serve_one(
    stream: TcpStream,
    app: Router,
    limits: ConnLimits,
    mut draining: watch::Receiver<bool>,
) {
    let tracker = Tracker::new();
    let io = TokioIo::new(Watched {
        io: stream,
        tracker: tracker.clone(),
    });
    let requests = tracker.clone();
    let service = hyper::service::service_fn(move |req: hyper::Request<Incoming>| {
        let in_flight = requests.begin();
        let app = app.clone();
        async move {
            let resp = match app.oneshot(req.map(Body::new)).await {
                Ok(r) => r,
                Err(never) => match never {},
            };
            Ok::<_, Infallible>(resp.map(|body| Tracked {
                body,
                _in_flight: in_flight,
            }))
        }
    });
    let mut already_draining = *draining.borrow();
    let conn = http1::Builder::new()
        .keep_alive(!already_draining)
        .serve_connection(io, service);
    tokio::pin!(conn);
    let overstayed = tracker.overstayed(limits);
    tokio::pin!(overstayed);
    loop {
        tokio::select! {
            r = conn.as_mut() => {
                if let Err(e) = r {
                    tracing::debug!(error = %e, "connection ended with an error");
                }
                return;
            }
            which = &mut overstayed => {
                tracing::debug!(timeout = which, "closing a connection that overstayed");
                return;
            }
            _ = draining.wait_for(|d| *d), if !already_draining => {
                already_draining = true;
                conn.as_mut().graceful_shutdown();
            }
        }
    }
}

/// Accepts and serves connections on `listener` until `stop`, then waits for the open ones to
/// end. From `draining` on, connections close after their current request.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: ConnLimits,
    draining: watch::Receiver<bool>,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let lingering = Arc::new(Semaphore::new(REFUSALS));
    let answer: Arc<[u8]> = refusal(limits.max_connections).into();
    let client_answer: Arc<[u8]> = client_refusal(limits.max_connections_per_client).into();
    let clients = Arc::new(Clients::default());
    loop {
        let accepted = tokio::select! {
            accepted = listener.accept() => accepted,
            _ = stop.wait_for(|s| *s) => break,
        };
        let (stream, peer) = match accepted {
            Ok(pair) => pair,
            Err(e) => {
                // Out of file descriptors, or a connection reset before the accept: wait a
                // little rather than spin.
                tracing::warn!(error = %e, "accept failed");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let client = match limits.max_connections_per_client {
            0 => None,
            cap => match clients.take(peer.ip(), cap) {
                Some(slot) => Some(slot),
                None => {
                    tracing::debug!(%peer, cap, "connection refused: per-client cap reached");
                    refuse(stream, client_answer.clone(), &lingering);
                    continue;
                }
            },
        };
        let Ok(slot) = slots.clone().try_acquire_owned() else {
            tracing::debug!(
                max_connections = limits.max_connections,
                "connection refused: cap reached"
            );
            refuse(stream, answer.clone(), &lingering);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let (app, draining) = (app.clone(), draining.clone());
        tokio::spawn(async move {
            serve_one(stream, app, limits, draining).await;
            drop((slot, client));
        });
    }
    drop(listener);
    let all = u32::try_from(limits.max_connections).unwrap_or(u32::MAX);
    let _ = slots.acquire_many(all).await;
    Ok(())
}
