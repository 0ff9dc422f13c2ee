//! `GET /metrics` in the Prometheus text exposition format (version 0.0.4): requests by route
//! template and status, request latency, queue depth, age of the oldest enqueued job, jobs by
//! status, busy workers, and per-stage duration histograms of the engine.
//!
//! Request counting is a middleware on the matched routes (the template, e.g.
//! `/v1/jobs/{id}`, never the concrete path, so label cardinality stays bounded); unmatched
//! requests are counted under `unmatched`.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::Mutex;
use std::time::Instant;

use axum::extract::{MatchedPath, Request, State};
use axum::http::{header, HeaderValue};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use chrono::Utc;

use super::problem::ApiError;
use super::{blocking, AppState};
use crate::service::model::JobStatus;

/// Upper bounds of the request latency histogram, seconds.
const REQUEST_BUCKETS: [f64; 10] = [0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.5, 1.0, 5.0];
/// Upper bounds of the stage duration histogram, seconds.
const STAGE_BUCKETS: [f64; 10] = [0.01, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 15.0, 60.0];

/// A cumulative histogram over fixed bounds.
#[derive(Default)]
struct Histogram {
    buckets: [u64; 10],
    count: u64,
    sum: f64,
}

impl Histogram {
    fn observe(&mut self, bounds: &[f64; 10], value: f64) {
        for (i, b) in bounds.iter().enumerate() {
            if value <= *b {
                self.buckets[i] += 1;
            }
        }
        self.count += 1;
        self.sum += value;
    }

    fn render(&self, out: &mut String, name: &str, labels: &str, bounds: &[f64; 10]) {
        for (i, b) in bounds.iter().enumerate() {
            let _ = writeln!(
                out,
                "{name}_bucket{{{labels},le=\"{b}\"}} {}",
                self.buckets[i]
            );
        }
        let _ = writeln!(out, "{name}_bucket{{{labels},le=\"+Inf\"}} {}", self.count);
        let _ = writeln!(out, "{name}_sum{{{labels}}} {}", self.sum);
        let _ = writeln!(out, "{name}_count{{{labels}}} {}", self.count);
    }
}

/// Request counters shared by all connections.
#[derive(Default)]
pub struct Metrics {
    /// (method, route, status) → count.
    requests: Mutex<BTreeMap<(String, String, u16), u64>>,
    /// route → latency histogram.
    latency: Mutex<BTreeMap<String, Histogram>>,
    /// stage → duration histogram (the runner hands each duration over once).
    stages: Mutex<BTreeMap<String, Histogram>>,
}

impl Metrics {
    fn record(&self, method: &str, route: &str, status: u16, secs: f64) {
        if let Ok(mut m) = self.requests.lock() {
            *m.entry((method.to_string(), route.to_string(), status))
                .or_default() += 1;
        }
        if let Ok(mut m) = self.latency.lock() {
            m.entry(route.to_string())
                .or_default()
                .observe(&REQUEST_BUCKETS, secs);
        }
    }
}

/// Middleware: counts the request under its route template.
pub async fn track(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", |m| m.as_str())
        .to_string();
    let method = req.method().as_str().to_string();
    let start = Instant::now();
    let resp = next.run(req).await;
    if resp
        .extensions()
        .get::<super::problem::StorageFailure>()
        .is_some()
    {
        state.runner.note_storage_failure();
    }
    state.metrics.record(
        &method,
        &route,
        resp.status().as_u16(),
        start.elapsed().as_secs_f64(),
    );
    resp
}

fn escape(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// Prometheus metrics.
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, description = "Prometheus text format 0.0.4", content_type = "text/plain", body = String)))]
pub async fn metrics(State(state): State<AppState>) -> Result<Response, ApiError> {
    let jobs = state.jobs.clone();
    let counts = blocking(move || jobs.counts()).await?;
    let mut out = String::with_capacity(4096);
    out.push_str(
        "# HELP retex_http_requests_total HTTP requests by method, route template and status.\n",
    );
    out.push_str("# TYPE retex_http_requests_total counter\n");
    if let Ok(m) = state.metrics.requests.lock() {
        for ((method, route, status), n) in m.iter() {
            let _ = writeln!(
                out,
                "retex_http_requests_total{{method=\"{method}\",route=\"{}\",status=\"{status}\"}} {n}",
                escape(route)
            );
        }
    }
    out.push_str("# HELP retex_http_request_duration_seconds Time to the response head, by route template.\n");
    out.push_str("# TYPE retex_http_request_duration_seconds histogram\n");
    if let Ok(m) = state.metrics.latency.lock() {
        for (route, h) in m.iter() {
            let labels = format!("route=\"{}\"", escape(route));
            h.render(
                &mut out,
                "retex_http_request_duration_seconds",
                &labels,
                &REQUEST_BUCKETS,
            );
        }
    }
    out.push_str("# HELP retex_jobs Jobs in the store by status.\n# TYPE retex_jobs gauge\n");
    for s in [
        JobStatus::Enqueued,
        JobStatus::Processing,
        JobStatus::Succeeded,
        JobStatus::Failed,
        JobStatus::Canceled,
    ] {
        let n: u64 = counts
            .by_status
            .iter()
            .filter(|(k, _)| *k == s)
            .map(|(_, n)| *n)
            .sum();
        let _ = writeln!(out, "retex_jobs{{status=\"{}\"}} {n}", s.as_str());
    }
    let depth: u64 = counts
        .by_status
        .iter()
        .filter(|(k, _)| *k == JobStatus::Enqueued)
        .map(|(_, n)| *n)
        .sum();
    out.push_str("# HELP retex_queue_depth Enqueued jobs.\n# TYPE retex_queue_depth gauge\n");
    let _ = writeln!(out, "retex_queue_depth {depth}");
    out.push_str("# HELP retex_queue_capacity Most enqueued jobs before 503.\n# TYPE retex_queue_capacity gauge\n");
    let _ = writeln!(out, "retex_queue_capacity {}", state.config.queue_len);
    let age = counts.oldest_enqueued.map_or(0.0, |t| {
        (Utc::now() - t).num_milliseconds().max(0) as f64 / 1e3
    });
    out.push_str("# HELP retex_queue_oldest_age_seconds Age of the oldest enqueued job.\n# TYPE retex_queue_oldest_age_seconds gauge\n");
    let _ = writeln!(out, "retex_queue_oldest_age_seconds {age}");
    out.push_str(
        "# HELP retex_workers_busy Workers running a job.\n# TYPE retex_workers_busy gauge\n",
    );
    let _ = writeln!(out, "retex_workers_busy {}", state.runner.busy_workers());
    out.push_str("# HELP retex_workers Size of the engine pool.\n# TYPE retex_workers gauge\n");
    let _ = writeln!(out, "retex_workers {}", state.config.workers);
    out.push_str(
        "# HELP retex_stage_duration_seconds Engine stage durations of finished stages.\n",
    );
    out.push_str("# TYPE retex_stage_duration_seconds histogram\n");
    if let Ok(mut m) = state.metrics.stages.lock() {
        for (stage, secs) in state.runner.stage_durations() {
            m.entry(stage).or_default().observe(&STAGE_BUCKETS, secs);
        }
        for (stage, h) in m.iter() {
            let labels = format!("stage=\"{}\"", escape(stage));
            h.render(
                &mut out,
                "retex_stage_duration_seconds",
                &labels,
                &STAGE_BUCKETS,
            );
        }
    }
    let mut resp = out.into_response();
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
    );
    Ok(resp)
}
