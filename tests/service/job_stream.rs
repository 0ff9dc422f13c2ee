//! Issue 16: the dashboard's live job list reads one list-level event stream, `GET /v1/events`,
//! instead of polling: it delivers a submitted job's announcement, its progress and its terminal
//! status, in batches with at most one event per job each; with tokens configured it needs one.

use std::io::{BufRead, BufReader};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::service_common::*;

/// One SSE event: name and data (`None` for a batch boundary is not visible on the wire, so
/// the reader reports events one by one).
type Ev = (String, serde_json::Value);

/// Opens `/v1/events` on a thread and forwards its events until `stop(event)` holds; the first
/// event (`ready`) is awaited before returning, so nothing submitted afterwards is missed.
fn open_stream(
    base: &str,
    headers: Vec<(String, String)>,
    stop: impl Fn(&Ev) -> bool + Send + 'static,
) -> (mpsc::Receiver<Ev>, std::thread::JoinHandle<()>) {
    let url = format!("{base}/v1/events");
    let (tx, rx) = mpsc::channel();
    let handle = std::thread::spawn(move || {
        let a = agent();
        let mut req = a.get(&url).header("Accept", "text/event-stream");
        for (k, v) in &headers {
            req = req.header(k, v);
        }
        let mut resp = req.call().unwrap();
        assert_eq!(resp.status().as_u16(), 200);
        let ct = resp
            .headers()
            .get("content-type")
            .unwrap()
            .to_str()
            .unwrap();
        assert!(ct.starts_with("text/event-stream"), "{ct}");
        let reader = BufReader::new(resp.body_mut().as_reader());
        let (mut name, mut data) = (String::new(), String::new());
        for line in reader.lines() {
            let Ok(line) = line else { return };
            if line.is_empty() {
                if !data.is_empty() {
                    let ev = (name.clone(), serde_json::from_str(&data).unwrap());
                    let end = stop(&ev);
                    if tx.send(ev).is_err() || end {
                        return;
                    }
                }
                data.clear();
                name.clear();
            } else if let Some(v) = line.strip_prefix("event:") {
                name = v.trim().to_string();
            } else if let Some(v) = line.strip_prefix("data:") {
                data.push_str(v.trim());
            }
        }
    });
    let first = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("a ready event");
    assert_eq!(first.0, "ready", "{first:?}");
    (rx, handle)
}

#[test]
fn the_list_stream_delivers_a_jobs_progress_and_its_end() {
    let s = TestServer::start(|c| c.progress_interval_ms = 20);
    let (rx, handle) = open_stream(&s.base, Vec::new(), |(name, d)| {
        name == "job" && terminal(d["status"].as_str().unwrap_or(""))
    });
    let r = submit(&s.base, &spot_parts(2048), &[]);
    assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
    let id = r.json()["id"].as_str().unwrap().to_string();

    let start = Instant::now();
    let mut mine: Vec<serde_json::Value> = Vec::new();
    loop {
        let left = Duration::from_secs(180).saturating_sub(start.elapsed());
        let (name, d) = rx.recv_timeout(left).expect("the stream ends the job");
        assert!(name == "job" || name == "resync", "{name}");
        if name == "job" && d["id"] == id.as_str() {
            let end = terminal(d["status"].as_str().unwrap());
            mine.push(d);
            if end {
                break;
            }
        }
    }
    handle.join().unwrap();
    let statuses: Vec<&str> = mine.iter().map(|d| d["status"].as_str().unwrap()).collect();
    // The submission is announced, the run is followed, the end is sent.
    assert_eq!(statuses.first(), Some(&"enqueued"), "{statuses:?}");
    assert_eq!(statuses.last(), Some(&"succeeded"), "{statuses:?}");
    let running: Vec<f64> = mine
        .iter()
        .filter(|d| d["status"] == "processing")
        .map(|d| d["progress"]["fraction"].as_f64().unwrap())
        .collect();
    // At least one update between the start and the end (the job takes about a second; one
    // batch every 250 ms).
    assert!(
        running.iter().any(|f| *f > 0.0 && *f < 1.0),
        "intermediate progress: {running:?}"
    );
    assert!(
        running.windows(2).all(|w| w[0] <= w[1]),
        "progress only grows: {running:?}"
    );
    let revisions: Vec<u64> = mine
        .iter()
        .map(|d| d["revision"].as_u64().unwrap())
        .collect();
    assert!(revisions.windows(2).all(|w| w[0] <= w[1]), "{revisions:?}");
    let last = mine.last().unwrap();
    assert_eq!(last["progress"]["fraction"], 1.0, "{last}");
    // Batched: the runner reports every 20 ms, the stream at most one event per job per 250 ms.
    let secs = start.elapsed().as_secs_f64();
    assert!(
        (mine.len() as f64) <= secs / 0.25 + 3.0,
        "{} events in {secs:.1} s",
        mine.len()
    );
}

#[test]
fn the_list_stream_needs_a_token_when_tokens_are_configured() {
    let s = TestServer::start(|c| c.tokens = vec!["read:list-secret".into()]);
    let r = request(
        "GET",
        &format!("{}/v1/events", s.base),
        &[("Accept", "text/event-stream")],
        None,
    );
    let p = r.problem(401);
    assert!(r.header("www-authenticate").is_some(), "{p}");
    let (_rx, _handle) = open_stream(
        &s.base,
        vec![("Authorization".into(), "Bearer list-secret".into())],
        |_| true,
    );
}
