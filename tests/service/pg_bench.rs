//! Issue 17's benchmark (ignored, `bench_` so `.ci/run` skips it; run by hand with
//! `cargo test --release --test service pg_bench -- --ignored --nocapture`): claim latency
//! (enqueue → running, `started_at − created_at` of the job document) and the throughput of
//! trivial jobs with 1, 2 and 3 worker replicas behind one API replica on one PostgreSQL
//! database. Prints the README table's rows.

use std::time::{Duration, Instant};

use retex::engine::rng::SplitMix64;

use crate::pg_replicas::spawn_role;
use crate::pg_server::fresh_url;
use crate::service_common::*;

/// Jobs submitted one at a time for the latency figures.
const LATENCY_JOBS: usize = 20;
/// Jobs submitted at once for the throughput figure.
const BURST_JOBS: usize = 30;

fn millis(doc: &serde_json::Value, field: &str) -> i64 {
    let t = doc[field]
        .as_str()
        .unwrap_or_else(|| panic!("{field} in {doc}"));
    chrono::DateTime::parse_from_rfc3339(t)
        .unwrap()
        .timestamp_millis()
}

fn percentile(sorted: &[i64], p: f64) -> i64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

#[test]
#[ignore = "benchmark; needs PostgreSQL binaries"]
fn bench_pg_claim_latency_and_throughput() {
    // Trivial jobs: Spot onto Spot at 64².
    let parts = spot_parts(64);
    for workers in 1..=3 {
        let url = fresh_url();
        let data = tempfile::tempdir().unwrap();
        let (_api, api) = spawn_role(data.path(), &url, "api", &[]);
        let _workers: Vec<_> = (0..workers)
            .map(|_| spawn_role(data.path(), &url, "worker", &[]))
            .collect();
        let mut rng = SplitMix64::new(workers as u64);
        let mut latency = Vec::new();
        for _ in 0..LATENCY_JOBS {
            // A random phase against the workers' poll tick.
            std::thread::sleep(Duration::from_millis((rng.unit_f64() * 1000.0) as u64));
            let r = submit(&api, &parts, &[]);
            assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
            let id = r.json()["id"].as_str().unwrap().to_string();
            let doc = wait_for(&api, &id, Duration::from_secs(60), terminal);
            assert_eq!(doc["status"], "succeeded", "{doc}");
            latency.push(millis(&doc, "started_at") - millis(&doc, "created_at"));
        }
        latency.sort_unstable();
        let start = Instant::now();
        let ids: Vec<String> = (0..BURST_JOBS)
            .map(|_| {
                let r = submit(&api, &parts, &[]);
                assert_eq!(r.status, 202);
                r.json()["id"].as_str().unwrap().to_string()
            })
            .collect();
        for id in &ids {
            let doc = wait_for(&api, id, Duration::from_secs(120), terminal);
            assert_eq!(doc["status"], "succeeded", "{doc}");
        }
        let secs = start.elapsed().as_secs_f64();
        println!(
            "| 1 `api` + {workers} `worker` | {} ms | {} ms | {} ms | {:.1} jobs/s ({BURST_JOBS} in {secs:.1} s) |",
            percentile(&latency, 0.5),
            percentile(&latency, 0.9),
            latency[latency.len() - 1],
            BURST_JOBS as f64 / secs,
        );
    }
}

/// Status polls on the API replica while two worker replicas are saturated (Spot at 8192², six
/// jobs: two running, four queued): `wrk -t2 -c32 -d15s --latency` on `GET /v1/jobs/{id}`
/// (Debian's `wrk`). Prints wrk's report.
#[test]
#[ignore = "benchmark; needs PostgreSQL binaries and wrk"]
fn bench_pg_polls_with_saturated_workers() {
    let url = fresh_url();
    let data = tempfile::tempdir().unwrap();
    let (_api, api) = spawn_role(data.path(), &url, "api", &[]);
    let workers: Vec<_> = (0..2)
        .map(|_| spawn_role(data.path(), &url, "worker", &[]))
        .collect();
    let parts = spot_parts(8192);
    let ids: Vec<String> = (0..6)
        .map(|_| {
            let r = submit(&api, &parts, &[]);
            assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
            r.json()["id"].as_str().unwrap().to_string()
        })
        .collect();
    for (_, base) in &workers {
        crate::pg_kill::wait_busy(base);
    }
    let out = std::process::Command::new("wrk")
        .args(["-t2", "-c32", "-d15s", "--latency"])
        .arg(format!("{api}/v1/jobs/{}", ids[0]))
        .output()
        .expect("run wrk (apt-get install wrk)");
    assert!(out.status.success());
    let report = String::from_utf8_lossy(&out.stdout);
    println!("{report}");
    let busy: u64 = workers
        .iter()
        .map(|(_, b)| crate::pg_kill::busy_workers(b))
        .sum();
    assert_eq!(busy, 2, "both workers stayed busy during the measurement");
}
