//! A throw-away S3 endpoint for the object blob store's tests (issue 17 part 4): moto's server
//! (`python3 -m moto.server`, PyPI `moto[server]`) on a loopback port, one per test binary,
//! started on first use; each test gets a fresh bucket.
//!
//! As with `pg_server`, the server runs under a small `sh` keeper whose stdin is a pipe held by
//! this process, so it stops when the test binary exits, however it exits. A missing moto is a
//! test FAILURE, not a skip: the tests are `#[ignore]`d with a reason so that a plain
//! `cargo test` passes without it, and CI (`--include-ignored`, after `.ci/run` pip-installed
//! `moto[server]`) runs them.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use retex::service::store::object::ObjectBlobStore;

/// The running server.
pub struct S3Server {
    endpoint: String,
    _keeper: Mutex<Child>,
}

/// One test's bucket on the server.
pub struct S3Bucket {
    /// `s3://<bucket>/retex`.
    pub url: String,
    /// The environment a `retex serve` needs to reach it (`AWS_*`).
    pub env: Vec<(String, String)>,
}

impl S3Bucket {
    /// Opens an [`ObjectBlobStore`] on the bucket (configured explicitly, not through this
    /// process's environment), spooling under `spool`.
    pub fn open(&self, spool: &Path) -> ObjectBlobStore {
        let options: Vec<(&str, &str)> = self
            .env
            .iter()
            .map(|(k, v)| (k.as_str(), v.as_str()))
            .collect();
        ObjectBlobStore::open_with(&self.url, spool, &options).expect("open the S3 blob store")
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn start() -> S3Server {
    let has_moto = Command::new("python3")
        .args(["-c", "import moto.server, flask"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        has_moto,
        "moto's S3 server not found: python3 -m pip install 'moto[server]' (.ci/run does)"
    );
    let port = free_port();
    let log = std::env::temp_dir().join(format!("retex-moto-{port}.log"));
    let script = format!(
        "python3 -m moto.server -H 127.0.0.1 -p {port} >'{log}' 2>&1 & pid=$!; \
         read _eof; kill $pid; wait $pid",
        log = log.display()
    );
    let keeper = Command::new("sh")
        .args(["-c", &script])
        .stdin(Stdio::piped())
        .spawn()
        .expect("start the moto keeper");
    let endpoint = format!("http://127.0.0.1:{port}");
    let start = Instant::now();
    loop {
        let up = crate::service_common::agent()
            .get(&format!("{endpoint}/"))
            .call()
            .is_ok_and(|r| r.status().as_u16() == 200);
        if up {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "moto did not answer on {endpoint} within 60 s: {}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    S3Server {
        endpoint,
        _keeper: Mutex::new(keeper),
    }
}

fn server() -> &'static S3Server {
    static SERVER: OnceLock<S3Server> = OnceLock::new();
    SERVER.get_or_init(start)
}

/// A new, empty bucket on the test server.
pub fn fresh_bucket() -> S3Bucket {
    static N: AtomicUsize = AtomicUsize::new(0);
    let s = server();
    let name = format!(
        "retex-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    );
    let r = crate::service_common::agent()
        .put(&format!("{}/{name}", s.endpoint))
        .send_empty()
        .expect("create bucket");
    assert_eq!(r.status().as_u16(), 200, "creating bucket {name}");
    let env = [
        ("AWS_ENDPOINT_URL", s.endpoint.as_str()),
        ("AWS_ALLOW_HTTP", "true"),
        ("AWS_REGION", "us-east-1"),
        ("AWS_ACCESS_KEY_ID", "retex-test"),
        ("AWS_SECRET_ACCESS_KEY", "retex-test"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    S3Bucket {
        url: format!("s3://{name}/retex"),
        env,
    }
}
