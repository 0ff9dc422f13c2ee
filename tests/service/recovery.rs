//! Crash recovery and graceful shutdown of the real binary: `retex serve` runs as a child
//! process on port 0; jobs are submitted; the process is killed with SIGKILL mid-job and
//! restarted on the same data directory. Every job must end `succeeded` (or `failed` with a
//! reason), none lost or duplicated, and results must download. Then SIGTERM stops the server
//! cleanly within its deadline.

use crate::common;

use std::path::Path;
use std::time::{Duration, Instant};

use crate::service_common::*;

/// Kills the child when a test fails, so no server outlives it.
/// Starts `retex serve` on port 0 and returns the child and its base URL.
fn spawn_server(data: &Path) -> (ServeProcess, String) {
    spawn_serve(data, &["--workers", "1", "--shutdown-secs", "10"], "warn")
}

#[test]
fn kill_9_mid_job_then_restart_loses_and_duplicates_nothing() {
    let data = tempfile::tempdir().unwrap();
    let (mut child, base) = spawn_server(data.path());
    let mut ids = Vec::new();
    for size in [8192, 512, 256, 128] {
        let r = submit(&base, &spot_parts(size), &[]);
        assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
        ids.push(r.json()["id"].as_str().unwrap().to_string());
    }
    // Kill while the first job is processing.
    wait_for(&base, &ids[0], Duration::from_secs(60), |s| s != "enqueued");
    std::thread::sleep(Duration::from_millis(300));
    child.0.kill().unwrap(); // SIGKILL
    child.0.wait().unwrap();

    let (mut child, base) = spawn_server(data.path());
    for id in &ids {
        let doc = wait_for(&base, id, Duration::from_secs(180), terminal);
        match doc["status"].as_str().unwrap() {
            "succeeded" => {
                let r = get(&format!("{base}/v1/jobs/{id}/result"));
                assert_eq!(r.status, 200);
                assert_eq!(&r.body[..4], b"glTF");
            }
            "failed" => assert!(doc["error"]["detail"].is_string(), "{doc}"),
            other => panic!("job {id} ended {other}: {doc}"),
        }
    }
    assert!(
        get(&format!("{base}/v1/jobs/{}", ids[0])).json()["attempts"]
            .as_u64()
            .unwrap()
            >= 2,
        "the interrupted job ran again"
    );
    let list = get(&format!("{base}/v1/jobs?limit=100")).json();
    let mut listed: Vec<String> = list["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap().to_string())
        .collect();
    listed.sort();
    let mut expected = ids.clone();
    expected.sort();
    assert_eq!(listed, expected, "no job lost or duplicated");
    common::assert_validator_clean(
        &get(&format!("{base}/v1/jobs/{}/result", ids[3])).body,
        "service_recovery_spot.glb",
    );

    // SIGTERM: a clean exit within the deadline.
    let t = Instant::now();
    // SAFETY: sending a signal to our own child process.
    let rc = unsafe { libc::kill(child.0.id() as i32, libc::SIGTERM) };
    assert_eq!(rc, 0);
    loop {
        if let Some(status) = child.0.try_wait().unwrap() {
            assert!(status.success(), "exit status {status}");
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(15),
            "no exit after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}
