//! The HTTP front of the job service (axum): routes under `/v1`, problem+json errors, bearer
//! auth, CORS, metrics, body limits and timeouts, tracing spans per request, and the server
//! life cycle ([`serve`]): open the store, start the runner (which recovers interrupted jobs),
//! bind, serve connections under their limits ([`conn`]), print the address, prune expired
//! jobs periodically, and on SIGTERM/SIGINT drain (readiness off, event streams end,
//! connections close after their request), let the runner finish or re-enqueue its jobs within
//! the deadline, then stop accepting.
//!
//! Handlers never run the engine or block: store and blob calls go through
//! [`blocking`] (`spawn_blocking`), and jobs run on the runner's own pool.

use std::sync::Arc;
use std::time::Duration;

use axum::extract::DefaultBodyLimit;
use axum::http::{StatusCode, Uri};
use axum::middleware;
use axum::response::IntoResponse;
use axum::routing::{get, post};
use axum::Router;
use tokio::sync::watch;
use tower_http::timeout::RequestBodyTimeoutLayer;
use tower_http::trace::TraceLayer;

use crate::engine::methods::Registry;
use crate::service::config::Role;
use crate::service::config::ServeConfig;
use crate::service::jobs::runner::{Runner, RunnerConfig};
use crate::service::store::fs::FsBlobStore;
use crate::service::store::object::ObjectBlobStore;
use crate::service::store::postgres::PgJobStore;
use crate::service::store::sqlite::SqliteJobStore;
use crate::service::store::{BlobStore, JobStore, StoreError};

pub mod auth;
pub mod caller;
pub mod conn;
pub mod dashboard;
pub mod deadline;
pub mod doc;
pub mod events;
pub mod files;
pub mod ingest;
pub mod job_stream;
pub mod jobs;
pub mod linger;
pub mod metrics;
pub mod openapi;
pub mod ops;
pub mod problem;

use problem::ApiError;

/// What every handler shares.
#[derive(Clone)]
pub struct AppState {
    /// The configuration.
    pub config: Arc<ServeConfig>,
    /// Job records.
    pub jobs: Arc<dyn JobStore>,
    /// Uploaded and produced files.
    pub blobs: Arc<dyn BlobStore>,
    /// The worker pool.
    pub runner: Arc<Runner>,
    /// The methods jobs may ask for (checked at submission).
    pub registry: Registry,
    /// Request counters.
    pub metrics: Arc<metrics::Metrics>,
    /// Becomes `true` when the server shuts down.
    pub shutdown: watch::Receiver<bool>,
}

/// Runs a store call on the blocking pool.
pub async fn blocking<T, F>(f: F) -> Result<T, ApiError>
where
    F: FnOnce() -> Result<T, StoreError> + Send + 'static,
    T: Send + 'static,
{
    match tokio::task::spawn_blocking(f).await {
        Ok(r) => r.map_err(ApiError::from),
        Err(e) => Err(ApiError::internal(format!("blocking task failed: {e}"))),
    }
}

async fn fallback(uri: Uri) -> ApiError {
    problem::from_status(
        StatusCode::NOT_FOUND,
        format!("no route for {}", uri.path()),
    )
}

/// Turns axum's plain-text rejections (bad path parameter, bad query, 405) into problems.
async fn problem_rejections(
    req: axum::extract::Request,
    next: middleware::Next,
) -> axum::response::Response {
    let resp = next.run(req).await;
    let status = resp.status();
    let is_problem = resp
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with(problem::PROBLEM_JSON));
    if (status.is_client_error() || status.is_server_error()) && !is_problem {
        let (parts, body) = resp.into_parts();
        let text = axum::body::to_bytes(body, 64 << 10)
            .await
            .unwrap_or_default();
        let mut out = problem::from_status(status, String::from_utf8_lossy(&text).into_owned())
            .into_response();
        for name in [
            axum::http::header::WWW_AUTHENTICATE,
            axum::http::header::ALLOW,
        ] {
            if let Some(v) = parts.headers.get(&name) {
                out.headers_mut().insert(name, v.clone());
            }
        }
        return out;
    }
    resp
}

/// The application with all routes and layers.
pub fn router(state: AppState) -> Router {
    let config = state.config.clone();
    // Role `worker` (issue 17) serves only the health endpoints and metrics.
    let worker_only = config.role == Role::Worker;
    let jobs_api = Router::new()
        .route(
            "/v1/jobs",
            // The body limit is enforced by `linger::SharedBody` inside the handler.
            post(jobs::submit)
                .layer(DefaultBodyLimit::disable())
                .get(jobs::list_jobs),
        )
        .route("/v1/jobs/{id}", get(jobs::get_job).delete(jobs::delete_job))
        .route("/v1/jobs/{id}/cancel", post(jobs::cancel_job))
        .route("/v1/jobs/{id}/result", get(files::result))
        .route("/v1/jobs/{id}/artifacts/{name}", get(files::artifact))
        .route("/v1/jobs/{id}/files/{name}", get(files::file))
        .route("/v1/events", get(job_stream::job_stream))
        .route("/v1/jobs/{id}/events", get(events::events))
        .route("/v1/openapi.json", get(openapi::openapi_json))
        .route("/v1/methods", get(dashboard::methods))
        .route("/v1/jobs/{id}/constraints", get(dashboard::constraints));
    let api = if worker_only { Router::new() } else { jobs_api }
        .route("/healthz", get(ops::healthz))
        .route("/readyz", get(ops::readyz))
        .route("/metrics", get(metrics::metrics))
        .route_layer(middleware::from_fn_with_state(
            state.clone(),
            metrics::track,
        ))
        .fallback(fallback)
        .layer(middleware::from_fn(problem_rejections))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            deadline::upload_deadline,
        ))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            auth::require_token,
        ))
        .layer(RequestBodyTimeoutLayer::new(Duration::from_secs(
            config.body_timeout_secs,
        )))
        .layer(auth::cors(&config.cors_origins))
        .layer(TraceLayer::new_for_http());
    // The dashboard's static files need no token (see `dashboard`).
    let pages = Router::new()
        .route("/", get(dashboard::index))
        .route("/dashboard/{*path}", get(dashboard::file))
        .layer(TraceLayer::new_for_http());
    if worker_only {
        return api.with_state(state);
    }
    pages.merge(api).with_state(state)
}

/// A running server (for tests and `retex serve`).
pub struct Server {
    /// The state its handlers share.
    pub state: AppState,
    /// Where it listens.
    pub addr: std::net::SocketAddr,
    shutdown_tx: watch::Sender<bool>,
    stop_tx: watch::Sender<bool>,
    handle: tokio::task::JoinHandle<std::io::Result<()>>,
}

/// Opens the store under `config.data_dir`, starts the runner and binds the listener, with the
/// built-in methods.
pub async fn start(config: ServeConfig) -> Result<Server, String> {
    start_with(config, Registry::builtin()).await
}

/// As [`start`], with the methods of `registry` (tests register extra methods this way).
pub async fn start_with(config: ServeConfig, registry: Registry) -> Result<Server, String> {
    start_with_stores(config, registry, |jobs, blobs| (jobs, blobs)).await
}

/// The stores a server uses: the job store and the blob store.
pub type Stores = (Arc<dyn JobStore>, Arc<dyn BlobStore>);

/// As [`start_with`], with the opened stores passed through `wrap` first (tests inject storage
/// faults, e.g. a full disk, with a wrapper).
pub async fn start_with_stores(
    config: ServeConfig,
    registry: Registry,
    wrap: impl FnOnce(Arc<dyn JobStore>, Arc<dyn BlobStore>) -> Stores,
) -> Result<Server, String> {
    config.validate().map_err(|e| e.to_string())?;
    std::fs::create_dir_all(&config.data_dir)
        .map_err(|e| format!("data dir {}: {e}", config.data_dir.display()))?;
    let jobs: Arc<dyn JobStore> = match config.database_url.clone() {
        // Connecting blocks (the store runs its own runtime), so it goes off the async thread.
        Some(url) => {
            let lease = Duration::from_secs(config.lease_secs);
            let store = tokio::task::spawn_blocking(move || PgJobStore::connect(&url, lease))
                .await
                .map_err(|e| e.to_string())?;
            Arc::new(store.map_err(|e| format!("database: {e}"))?)
        }
        None => Arc::new(SqliteJobStore::open(&config.db_path()).map_err(|e| e.to_string())?),
    };
    let blobs: Arc<dyn BlobStore> = match &config.blob_url {
        Some(url) => {
            let store = ObjectBlobStore::open(url, &config.blob_dir());
            Arc::new(store.map_err(|e| format!("blob store: {e}"))?)
        }
        None => Arc::new(FsBlobStore::open(&config.blob_dir()).map_err(|e| e.to_string())?),
    };
    let (jobs, blobs) = wrap(jobs, blobs);
    let runner = Runner::start(
        RunnerConfig {
            workers: config.workers,
            max_attempts: config.max_attempts,
            limits: config.limits.clone(),
            max_texture_size: config.max_texture_size,
            progress_interval: Duration::from_millis(config.progress_interval_ms),
            registry: registry.clone(),
            storage_retry: Duration::from_secs(config.storage_retry_secs),
            claim: config.role.runs_jobs(),
            poll: Duration::from_secs(config.poll_secs),
        },
        jobs.clone(),
        blobs.clone(),
    )
    .map_err(|e| format!("runner: {e}"))?;
    let listener = tokio::net::TcpListener::bind(config.addr)
        .await
        .map_err(|e| format!("bind {}: {e}", config.addr))?;
    let addr = listener.local_addr().map_err(|e| e.to_string())?;
    if config.tokens.is_empty() {
        tracing::warn!(
            %addr,
            "authentication is off: no bearer tokens configured (RETEX_TOKENS), every route is open"
        );
    }
    let (shutdown_tx, shutdown) = watch::channel(false);
    let state = AppState {
        config: Arc::new(config),
        jobs,
        blobs,
        runner,
        registry,
        metrics: Arc::default(),
        shutdown,
    };
    tokio::spawn(ops::retention_loop(state.clone()));
    let app = router(state.clone());
    let (stop_tx, stop) = watch::channel(false);
    let limits = conn::ConnLimits::from_config(&state.config);
    let handle = tokio::spawn(conn::serve(
        listener,
        app,
        limits,
        state.shutdown.clone(),
        stop,
    ));
    Ok(Server {
        state,
        addr,
        shutdown_tx,
        stop_tx,
        handle,
    })
}

impl Server {
    /// Graceful stop: drain (`/readyz` answers 503, event streams end, connections close
    /// after their current request, new ones get one request each), let the runner finish or
    /// re-enqueue its jobs within the deadline, then stop accepting and wait for the open
    /// requests with what is left of it (at least a second).
    pub async fn shutdown(self) {
        let deadline = Duration::from_secs(self.state.config.shutdown_secs);
        let started = std::time::Instant::now();
        let _ = self.shutdown_tx.send(true);
        self.state.runner.shutdown(deadline).await;
        let _ = self.stop_tx.send(true);
        let left = deadline.saturating_sub(started.elapsed());
        if tokio::time::timeout(left.max(Duration::from_secs(1)), self.handle)
            .await
            .is_err()
        {
            tracing::warn!("connections still open after the shutdown deadline");
        }
    }
}

/// Resolves on SIGTERM or SIGINT.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}
