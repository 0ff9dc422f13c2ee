//! Test support for the HTTP service: an in-process server on a real socket (port 0) with its
//! own data directory, a plain blocking HTTP client (ureq), multipart bodies built by hand the
//! way curl sends them, and polling helpers.
#![allow(dead_code)]

use std::io::BufRead;
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use retex::service::config::ServeConfig;
use retex::service::http::{self, AppState};

/// A response, fully read.
#[derive(Debug)]
pub struct Resp {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Resp {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| {
            panic!(
                "status {}: body is not json ({e}): {}",
                self.status,
                String::from_utf8_lossy(&self.body)
            )
        })
    }

    /// Asserts a problem+json body with this status and returns it.
    pub fn problem(&self, status: u16) -> serde_json::Value {
        assert_eq!(
            self.status,
            status,
            "expected {status}, got {}: {}",
            self.status,
            String::from_utf8_lossy(&self.body)
        );
        assert_eq!(
            self.header("content-type"),
            Some("application/problem+json"),
            "{:?}",
            self.headers
        );
        let p = self.json();
        assert!(p["type"].as_str().unwrap().starts_with("/problems/"), "{p}");
        assert_eq!(p["status"], status, "{p}");
        p
    }
}

pub fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(300)))
        .build()
        .into()
}

fn finish(r: Result<ureq::http::Response<ureq::Body>, ureq::Error>) -> Resp {
    let mut r = r.expect("http request");
    let status = r.status().as_u16();
    let headers = r
        .headers()
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_str().unwrap_or("").to_string()))
        .collect();
    let body = r
        .body_mut()
        .with_config()
        .limit(1 << 31)
        .read_to_vec()
        .unwrap_or_default();
    Resp {
        status,
        headers,
        body,
    }
}

/// A request with headers; `body` is sent with POST, nothing with GET/DELETE.
pub fn request(method: &str, url: &str, headers: &[(&str, &str)], body: Option<&[u8]>) -> Resp {
    let a = agent();
    match method {
        "GET" => {
            let mut r = a.get(url);
            for (k, v) in headers {
                r = r.header(*k, *v);
            }
            finish(r.call())
        }
        "DELETE" => {
            let mut r = a.delete(url);
            for (k, v) in headers {
                r = r.header(*k, *v);
            }
            finish(r.call())
        }
        "POST" => {
            let mut r = a.post(url);
            for (k, v) in headers {
                r = r.header(*k, *v);
            }
            finish(match body {
                Some(b) => r.send(b),
                None => r.send_empty(),
            })
        }
        m => panic!("method {m}"),
    }
}

pub fn get(url: &str) -> Resp {
    request("GET", url, &[], None)
}

/// One multipart part: (field name, filename, bytes).
pub type Part<'a> = (&'a str, &'a str, Vec<u8>);

/// Builds a multipart/form-data body like `curl -F name=@file`.
pub fn multipart(parts: &[Part<'_>]) -> (String, Vec<u8>) {
    let boundary = "------------------------retexTestBoundary7MA4YWxkTrZu0gW";
    let mut body = Vec::new();
    for (name, filename, bytes) in parts {
        body.extend_from_slice(format!("--{boundary}\r\n").as_bytes());
        body.extend_from_slice(
            format!("Content-Disposition: form-data; name=\"{name}\"; filename=\"{filename}\"\r\nContent-Type: application/octet-stream\r\n\r\n")
                .as_bytes(),
        );
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// POSTs a job; extra headers (Idempotency-Key, Authorization) optional.
pub fn submit(base: &str, parts: &[Part<'_>], headers: &[(&str, &str)]) -> Resp {
    let (ct, body) = multipart(parts);
    let mut h = vec![("Content-Type", ct.as_str())];
    h.extend_from_slice(headers);
    request("POST", &format!("{base}/v1/jobs"), &h, Some(&body))
}

pub fn constraints(texture_size: u32) -> Vec<u8> {
    format!(r#"{{"version": 1, "method": "project", "output": {{"texture_size": {texture_size}, "padding": 4}}}}"#)
        .into_bytes()
}

/// The bytes of a file of `tests/data`.
pub fn asset(relative: &str) -> Vec<u8> {
    let p = crate::common::test_data(relative);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Spot onto itself: a GLB source and target. At texture size 8192 the job runs for seconds
/// (about 15 s on the 2-core machine): the slow job of the cancel, queue and recovery tests.
pub fn spot_parts(texture_size: u32) -> Vec<Part<'static>> {
    let spot = asset("src_spot_keenan/spot_textured_derived.glb");
    vec![
        ("source", "spot.glb", spot.clone()),
        ("target", "spot.glb", spot),
        ("constraints", "constraints.json", constraints(texture_size)),
    ]
}

/// The parts of a .gltf and the files its URIs name, as curl would send them.
pub fn model_parts_from(main: &Path, part: &'static str) -> Vec<Part<'static>> {
    let (main_name, blobs) = retex::engine::asset::BlobSet::from_path(main).unwrap();
    let mut parts = Vec::new();
    for name in blobs.names() {
        let leaked: &'static str = Box::leak(name.to_string().into_boxed_str());
        parts.push((part, leaked, blobs.get(name).unwrap().to_vec()));
    }
    assert!(blobs.get(&main_name).is_some());
    parts
}

/// Polls the job until `done(status)` or the timeout; returns the last document.
pub fn wait_for(
    base: &str,
    id: &str,
    timeout: Duration,
    done: impl Fn(&str) -> bool,
) -> serde_json::Value {
    wait_for_with(base, id, &[], timeout, done)
}

/// [`wait_for`] with request headers (e.g. `Authorization`).
pub fn wait_for_with(
    base: &str,
    id: &str,
    headers: &[(&str, &str)],
    timeout: Duration,
    done: impl Fn(&str) -> bool,
) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let r = request("GET", &format!("{base}/v1/jobs/{id}"), headers, None);
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        let doc = r.json();
        if done(doc["status"].as_str().unwrap()) {
            return doc;
        }
        assert!(
            start.elapsed() < timeout,
            "job {id} still {} after {timeout:?}",
            doc["status"]
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Submits a job, waits up to 300 s for it to succeed, downloads the result and checks it with
/// the Khronos validator (named `name` in the report); returns the job document and the result.
pub fn run_job(base: &str, parts: &[Part<'_>], name: &str) -> (serde_json::Value, Vec<u8>) {
    let r = submit(base, parts, &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();
    let job = wait_for(base, &id, Duration::from_secs(300), terminal);
    assert_eq!(job["status"], "succeeded", "{job}");
    let result = get(&format!("{base}/v1/jobs/{id}/result"));
    assert_eq!(result.status, 200);
    crate::common::assert_validator_clean(&result.body, name);
    (job, result.body)
}

pub fn terminal(s: &str) -> bool {
    matches!(s, "succeeded" | "failed" | "canceled")
}

/// A server running in this process on its own runtime thread.
pub struct TestServer {
    pub base: String,
    pub state: AppState,
    pub data: tempfile::TempDir,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// A configuration for tests: port 0, a fresh data directory, 2 workers.
pub fn test_config(data: &Path) -> ServeConfig {
    ServeConfig {
        addr: "127.0.0.1:0".parse().unwrap(),
        data_dir: data.to_path_buf(),
        workers: 2,
        shutdown_secs: 5,
        ..ServeConfig::default()
    }
}

impl TestServer {
    pub fn start(edit: impl FnOnce(&mut ServeConfig)) -> TestServer {
        Self::start_with_registry(retex::engine::methods::Registry::builtin(), edit)
    }

    /// A server whose jobs may run the methods of `registry`.
    pub fn start_with_registry(
        registry: retex::engine::methods::Registry,
        edit: impl FnOnce(&mut ServeConfig),
    ) -> TestServer {
        Self::start_full(registry, edit, |jobs, blobs| (jobs, blobs))
    }

    /// A server whose stores are passed through `wrap` (to inject storage faults).
    pub fn start_wrapped(
        edit: impl FnOnce(&mut ServeConfig),
        wrap: impl FnOnce(
                std::sync::Arc<dyn retex::service::store::JobStore>,
                std::sync::Arc<dyn retex::service::store::BlobStore>,
            ) -> http::Stores
            + Send
            + 'static,
    ) -> TestServer {
        Self::start_full(retex::engine::methods::Registry::builtin(), edit, wrap)
    }

    fn start_full(
        registry: retex::engine::methods::Registry,
        edit: impl FnOnce(&mut ServeConfig),
        wrap: impl FnOnce(
                std::sync::Arc<dyn retex::service::store::JobStore>,
                std::sync::Arc<dyn retex::service::store::BlobStore>,
            ) -> http::Stores
            + Send
            + 'static,
    ) -> TestServer {
        let data = tempfile::tempdir().unwrap();
        let mut config = test_config(data.path());
        edit(&mut config);
        let (tx, rx) = mpsc::channel();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(async move {
                let server = http::start_with_stores(config, registry, wrap)
                    .await
                    .expect("server starts");
                tx.send((server.addr, server.state.clone())).unwrap();
                let _ = stop_rx.await;
                server.shutdown().await;
            });
        });
        let (addr, state) = rx.recv().expect("server address");
        TestServer {
            base: format!("http://{addr}"),
            state,
            data,
            stop: Some(stop_tx),
            thread: Some(thread),
        }
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Reads SSE events until a `done` event: (event name, id, data) triples.
pub fn read_events(
    url: &str,
    last_event_id: Option<&str>,
) -> Vec<(String, u64, serde_json::Value)> {
    let a = agent();
    let mut req = a.get(url).header("Accept", "text/event-stream");
    if let Some(l) = last_event_id {
        req = req.header("Last-Event-ID", l);
    }
    let mut resp = req.call().unwrap();
    assert_eq!(resp.status().as_u16(), 200);
    let reader = std::io::BufReader::new(resp.body_mut().as_reader());
    let (mut events, mut name, mut id, mut data) = (Vec::new(), String::new(), 0u64, String::new());
    for line in reader.lines() {
        let line = line.unwrap();
        if line.is_empty() {
            if !data.is_empty() {
                let v: serde_json::Value = serde_json::from_str(&data).unwrap();
                events.push((name.clone(), id, v));
                if name == "done" {
                    break;
                }
            }
            data.clear();
            continue;
        }
        if let Some(v) = line.strip_prefix("event:") {
            name = v.trim().to_string();
        } else if let Some(v) = line.strip_prefix("id:") {
            id = v.trim().parse().unwrap();
        } else if let Some(v) = line.strip_prefix("data:") {
            data.push_str(v.trim());
        }
    }
    events
}

/// A `retex serve` child process, killed (SIGKILL) and reaped when dropped.
pub struct ServeProcess(pub std::process::Child);

impl Drop for ServeProcess {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts the release binary as `retex serve --addr 127.0.0.1:0 --data-dir DATA ARGS…` with
/// `RETEX_LOG=log` and returns it with its base URL (read from its first stdout line).
pub fn spawn_serve(data: &Path, args: &[&str], log: &str) -> (ServeProcess, String) {
    spawn_serve_env(data, args, log, &[])
}

/// As [`spawn_serve`], with extra environment variables (e.g. `AWS_*` for an S3 blob store).
pub fn spawn_serve_env(
    data: &Path,
    args: &[&str],
    log: &str,
    env: &[(String, String)],
) -> (ServeProcess, String) {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_retex"))
        .args(["serve", "--addr", "127.0.0.1:0"])
        .arg("--data-dir")
        .arg(data)
        .args(args)
        .envs(env.iter().map(|(k, v)| (k, v)))
        .env("RETEX_LOG", log)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::inherit())
        .spawn()
        .expect("start retex serve");
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let base = line
        .trim()
        .strip_prefix("retex listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    (ServeProcess(child), base)
}
