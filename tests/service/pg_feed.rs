//! The PostgreSQL change feed (issue 17, part 1: LISTEN/NOTIFY wakes idle workers; progress
//! stored at a bounded rate so any replica serves polls and streams). Store handles hear the
//! changes other handles commit, never their own, and a cancel request arrives as one; a worker
//! replica that polls only once an hour still starts a job submitted through the API replica
//! (only the notification can wake it), and the API replica's event stream follows that job
//! while it runs on the worker.
//!
//! All need the throw-away server of `pg_server` (ignored by default; CI runs them).

use std::sync::mpsc;
use std::time::Duration;

use chrono::Utc;
use retex::service::model::JobStatus;
use retex::service::store::postgres::PgJobStore;
use retex::service::store::{JobChange, JobStore};

use crate::pg_replicas::{job, spawn_role};
use crate::pg_server::fresh_url;
use crate::service_common::*;

const WAIT: Duration = Duration::from_secs(20);

/// The next change on `rx` for `id`, skipping others.
fn next_for(rx: &mpsc::Receiver<JobChange>, id: uuid::Uuid) -> JobChange {
    loop {
        let c = rx.recv_timeout(WAIT).expect("a change within 20 s");
        if c.id == id {
            return c;
        }
    }
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn each_replica_hears_the_others_changes_and_never_its_own() {
    let url = fresh_url();
    let lease = Duration::from_secs(30);
    let a = PgJobStore::connect(&url, lease).unwrap();
    let b = PgJobStore::connect(&url, lease).unwrap();
    let (to_a, heard_by_a) = mpsc::channel();
    let (to_b, heard_by_b) = mpsc::channel();
    assert!(a.watch_changes(Box::new(move |c| {
        let _ = to_a.send(c);
    })));
    assert!(b.watch_changes(Box::new(move |c| {
        let _ = to_b.send(c);
    })));

    // A enqueues: B hears it (this is what wakes B's idle worker).
    let j = job(Utc::now());
    a.create(&j).unwrap();
    let c = next_for(&heard_by_b, j.id);
    assert_eq!(
        (c.status, c.revision, c.cancel_requested),
        (JobStatus::Enqueued, 1, false)
    );

    // B claims: A hears it.
    let claimed = b.claim_next(Utc::now()).unwrap().expect("B claims the job");
    let c = next_for(&heard_by_a, j.id);
    assert_eq!(
        (c.status, c.revision),
        (JobStatus::Processing, claimed.revision)
    );

    // A requests a cancel of the job B runs: B hears it as a cancel request. Notifications come
    // in commit order, so had B heard its own claim it would come before this one.
    a.cancel_if_enqueued(j.id, Utc::now()).unwrap();
    let c = next_for(&heard_by_b, j.id);
    assert_eq!(
        c.status,
        JobStatus::Processing,
        "B's own claim was not echoed back to B"
    );
    assert!(c.cancel_requested, "{c:?}");

    // B records the cancel and A hears the terminal state.
    let done = b
        .finish(j.id, retex::service::store::Finish::Canceled, Utc::now())
        .unwrap();
    let c = next_for(&heard_by_a, j.id);
    assert_eq!((c.status, c.revision), (JobStatus::Canceled, done.revision));
    // A's own cancel request was not echoed to A either: the next change A heard was B's finish,
    // and nothing else is pending for it.
    assert!(heard_by_a.recv_timeout(Duration::from_millis(500)).is_err());
}

#[test]
#[ignore = "needs PostgreSQL binaries (initdb, postgres, psql)"]
fn a_worker_that_polls_hourly_is_woken_by_the_api_replica_and_streamed_from_it() {
    let url = fresh_url();
    let data = tempfile::tempdir().unwrap();
    let (_api, api) = spawn_role(data.path(), &url, "api", &[]);
    // Polling once an hour: only a notification can make this worker claim within the test.
    let (_worker, _) = spawn_role(data.path(), &url, "worker", &["--poll-secs", "3600"]);
    for round in 0..2 {
        let r = submit(&api, &spot_parts(4096), &[]);
        assert_eq!(r.status, 202, "{}", String::from_utf8_lossy(&r.body));
        let id = r.json()["id"].as_str().unwrap().to_string();
        // The API replica's stream of a job that runs on the worker replica.
        let url = format!("{api}/v1/jobs/{id}/events");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(read_events(&url, None));
        });
        // Without the notification the job would wait an hour: fail instead of hanging.
        let events = rx
            .recv_timeout(Duration::from_secs(120))
            .expect("the job ran on the worker and the stream ended with `done` within 120 s");
        let statuses: Vec<&str> = events
            .iter()
            .map(|(_, _, d)| d["status"].as_str().unwrap())
            .collect();
        assert!(
            statuses.contains(&"processing"),
            "round {round}: {events:?}"
        );
        let (name, _, last) = events.last().unwrap();
        assert_eq!(
            (name.as_str(), &last["status"]),
            ("done", &"succeeded".into())
        );
        let revisions: Vec<u64> = events.iter().map(|e| e.1).collect();
        assert!(
            revisions.windows(2).all(|w| w[0] < w[1]),
            "revisions increase: {revisions:?}"
        );
        let doc = get(&format!("{api}/v1/jobs/{id}")).json();
        assert_eq!(
            (doc["status"].as_str(), doc["attempts"].as_u64()),
            (Some("succeeded"), Some(1))
        );
    }
}
