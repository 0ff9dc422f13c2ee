//! Robustness of the service (issue 9): the queue limit holds under concurrent submissions,
//! an Idempotency-Key replay wins over a full queue, a stalled upload gets 408, the retention
//! sweep removes partial uploads a crash left behind.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use retex::service::jobs::runner::EngineHook;

use crate::service_common::*;

fn id_of(r: &Resp) -> String {
    match r.json()["id"].as_str() {
        Some(id) => id.to_string(),
        None => panic!("{}: {}", r.status, String::from_utf8_lossy(&r.body)),
    }
}

/// A server with one worker whose engine calls wait until the returned flag is set, and one
/// job already holding that worker: every job accepted from now on stays enqueued.
fn blocked_server(queue_len: u64) -> (TestServer, Arc<AtomicBool>) {
    let s = TestServer::start(|c| {
        c.workers = 1;
        c.queue_len = queue_len;
    });
    let release = Arc::new(AtomicBool::new(false));
    let r = release.clone();
    let hook: EngineHook = Arc::new(move |_| {
        while !r.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(10));
        }
    });
    s.state.runner.set_engine_hook(Some(hook));
    let first = id_of(&submit(&s.base, &spot_parts(64), &[]));
    wait_for(&s.base, &first, Duration::from_secs(60), |st| {
        st == "processing"
    });
    (s, release)
}

#[test]
fn concurrent_submissions_never_overshoot_queue_len() {
    let (s, release) = blocked_server(2);
    let parts = spot_parts(64);
    let answers: Vec<Resp> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..12)
            .map(|_| scope.spawn(|| submit(&s.base, &parts, &[])))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let accepted = answers.iter().filter(|r| r.status == 202).count();
    for r in answers.iter().filter(|r| r.status != 202) {
        let p = r.problem(503);
        assert_eq!(p["type"], "/problems/queue-full", "{p}");
        assert_eq!(p["limit"]["name"], "queue_len", "{p}");
        assert_eq!(p["limit"]["value"], 2, "{p}");
        assert!(r.header("retry-after").is_some());
    }
    assert!(accepted <= 2, "{accepted} of 12 accepted with queue_len 2");
    let enqueued = get(&format!("{}/v1/jobs?status=enqueued", s.base)).json();
    assert!(
        enqueued["jobs"].as_array().unwrap().len() <= 2,
        "{enqueued}"
    );
    release.store(true, Ordering::SeqCst);
}

#[test]
fn idempotent_replay_wins_over_a_full_queue() {
    let (s, release) = blocked_server(1);
    let key = [("Idempotency-Key", "retry-after-lost-202")];
    let first = submit(&s.base, &spot_parts(64), &key);
    assert_eq!(
        first.status,
        202,
        "{}",
        String::from_utf8_lossy(&first.body)
    );
    // The queue is full now.
    submit(&s.base, &spot_parts(64), &[]).problem(503);
    // The client never saw the 202 and retries with the same key: its job, not 503.
    let again = submit(&s.base, &spot_parts(64), &key);
    assert_eq!(
        again.status,
        200,
        "{}",
        String::from_utf8_lossy(&again.body)
    );
    assert_eq!(id_of(&again), id_of(&first));
    release.store(true, Ordering::SeqCst);
}

#[test]
fn a_stalled_upload_is_408_body_timeout() {
    use std::io::{Read, Write};
    let s = TestServer::start(|c| c.body_timeout_secs = 1);
    let addr = s.base.trim_start_matches("http://");
    let mut tcp = std::net::TcpStream::connect(addr).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let boundary = "stalledBoundary";
    let head = format!(
        "POST /v1/jobs HTTP/1.1\r\nHost: {addr}\r\nContent-Type: multipart/form-data; boundary={boundary}\r\nContent-Length: 100000\r\n\r\n"
    );
    let part = format!(
        "--{boundary}\r\nContent-Disposition: form-data; name=\"target\"; filename=\"t.glb\"\r\nContent-Type: application/octet-stream\r\n\r\nglTF some bytes"
    );
    tcp.write_all(head.as_bytes()).unwrap();
    tcp.write_all(part.as_bytes()).unwrap();
    tcp.flush().unwrap();
    // Then nothing: the server gives up after body_timeout_secs.
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match tcp.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                answer.extend_from_slice(&buf[..n]);
                let text = String::from_utf8_lossy(&answer);
                if let Some((_, body)) = text.split_once("\r\n\r\n") {
                    if body.contains('}') {
                        break;
                    }
                }
            }
            Err(e) => panic!("no answer: {e}; got {:?}", String::from_utf8_lossy(&answer)),
        }
    }
    let text = String::from_utf8_lossy(&answer);
    assert!(text.starts_with("HTTP/1.1 408"), "{text}");
    assert!(
        text.to_ascii_lowercase()
            .contains("content-type: application/problem+json"),
        "{text}"
    );
    assert!(text.contains("/problems/body-timeout"), "{text}");
    assert!(text.contains("body_timeout_secs"), "{text}");
}

#[test]
fn the_retention_sweep_removes_stale_partial_uploads() {
    let s = TestServer::start(|c| c.prune_interval_secs = 1);
    let tmp = s.state.blobs.temp_dir();
    // A crash left these behind (the start-up sweep has already run).
    let stale = tmp.join("upload-left-by-a-crash");
    std::fs::write(&stale, b"partial").unwrap();
    let two_hours_ago = std::time::SystemTime::now() - Duration::from_secs(2 * 3600);
    std::fs::File::options()
        .write(true)
        .open(&stale)
        .unwrap()
        .set_modified(two_hours_ago)
        .unwrap();
    let fresh = tmp.join("upload-in-flight");
    std::fs::write(&fresh, b"streaming").unwrap();
    let end = std::time::Instant::now() + Duration::from_secs(20);
    while stale.exists() {
        assert!(
            std::time::Instant::now() < end,
            "stale upload still there after 20 s"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(fresh.exists(), "a fresh upload file is not swept");
}

#[test]
fn blank_tokens_refuse_a_non_loopback_address() {
    use retex::service::config::ServeConfig;
    let env = |tokens: &'static str, addr: &'static str| {
        move |k: &str| match k {
            "RETEX_TOKENS" => Some(tokens.to_string()),
            "RETEX_ADDR" => Some(addr.to_string()),
            _ => None,
        }
    };
    // Set but blank, on every interface: an open server by mistake; refused with a clear error.
    for blank in ["", " ", " , ,"] {
        let mut c = ServeConfig::default();
        c.apply_env(env(blank, "0.0.0.0:8080")).unwrap();
        let e = c.validate().unwrap_err().to_string();
        assert!(
            e.contains("RETEX_TOKENS") && e.contains("0.0.0.0:8080"),
            "{e}"
        );
    }
    // On loopback it starts (open, with a warning in the log).
    let mut c = ServeConfig::default();
    c.apply_env(env(" ", "127.0.0.1:8080")).unwrap();
    c.validate().unwrap();
    // Real tokens anywhere, or RETEX_TOKENS unset, are fine.
    let mut c = ServeConfig::default();
    c.apply_env(env("abcdefgh", "0.0.0.0:8080")).unwrap();
    c.validate().unwrap();
    let mut c = ServeConfig::default();
    c.apply_env(|k| (k == "RETEX_ADDR").then(|| "0.0.0.0:8080".to_string()))
        .unwrap();
    c.validate().unwrap();
}
