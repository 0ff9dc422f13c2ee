//! A throw-away PostgreSQL server for the tests of the PostgreSQL job store (issue 17): one
//! per test binary, started on first use with `initdb` + `postgres` in a temp dir, listening
//! on a unix socket only (no TCP port to collide with); each test gets a fresh database.
//!
//! PostgreSQL refuses to run as root, so as root the server runs as `nobody` (`runuser`). It is
//! started through a small `sh` keeper whose stdin is a pipe held by this process: when the
//! test binary exits, however it exits, the pipe closes, the keeper's `read` returns, and it
//! stops the server (SIGINT, fast shutdown) and removes the temp dir. No server outlives the
//! tests.
//!
//! The binaries are looked up in `RETEX_PG_BIN`, then `PATH`, then Debian's
//! `/usr/lib/postgresql/<version>/bin` (newest first). Absent binaries are a test FAILURE, not a
//! skip: the tests using this helper are `#[ignore]`d with a reason so that a plain
//! `cargo test` on a machine without PostgreSQL passes, and CI (`--include-ignored`, after
//! `.ci/run` installed Debian's `postgresql`) runs them.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// The running server.
pub struct PgServer {
    bin: PathBuf,
    socket_dir: PathBuf,
    /// The keeper's stdin: dropping (or exiting) stops the server.
    _keeper: Mutex<Child>,
}

const PORT: u16 = 5432;

fn find_bin() -> Option<PathBuf> {
    let has_all = |d: &Path| {
        ["initdb", "postgres", "psql"]
            .iter()
            .all(|b| d.join(b).exists())
    };
    if let Some(d) = std::env::var_os("RETEX_PG_BIN") {
        return Some(PathBuf::from(d)).filter(|d| has_all(d));
    }
    // Debian's own directory first: /usr/bin/psql is a wrapper, the others are not on PATH.
    let mut debian: Vec<PathBuf> = std::fs::read_dir("/usr/lib/postgresql")
        .map(|r| r.flatten().map(|e| e.path().join("bin")).collect())
        .unwrap_or_default();
    debian.sort_by_key(|p| {
        std::cmp::Reverse(
            p.parent()
                .and_then(|v| v.file_name()?.to_str()?.parse::<u32>().ok())
                .unwrap_or(0),
        )
    });
    let path: Vec<PathBuf> = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect())
        .unwrap_or_default();
    debian.into_iter().chain(path).find(|d| has_all(d))
}

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions.
    unsafe { libc::geteuid() == 0 }
}

/// `program args…`, as `nobody` when we are root.
fn command(program: &Path) -> Command {
    if is_root() {
        let mut c = Command::new("runuser");
        c.args(["-u", "nobody", "--"]).arg(program);
        c
    } else {
        Command::new(program)
    }
}

fn start() -> PgServer {
    let bin = find_bin().unwrap_or_else(|| {
        panic!(
            "PostgreSQL binaries not found (RETEX_PG_BIN, PATH, /usr/lib/postgresql/*/bin): \
             install them (apt-get install -y postgresql; .ci/run does)"
        )
    });
    let dir = std::env::temp_dir().join(format!("retex-pg-{}", uuid::Uuid::new_v4()));
    std::fs::create_dir_all(&dir).unwrap();
    if is_root() {
        let ok = Command::new("chown")
            .args(["nobody:nogroup"])
            .arg(&dir)
            .status()
            .unwrap()
            .success();
        assert!(ok, "chown {}", dir.display());
    }
    let data = dir.join("data");
    let out = command(&bin.join("initdb"))
        .arg("-D")
        .arg(&data)
        .args([
            "-U",
            "postgres",
            "-A",
            "trust",
            "--locale=C",
            "-E",
            "UTF8",
            "--no-sync",
        ])
        .output()
        .expect("run initdb");
    assert!(
        out.status.success(),
        "initdb failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let script = format!(
        "'{postgres}' -D '{data}' -k '{dir}' -p {PORT} -c listen_addresses= -c fsync=off \
         -c max_connections=300 -c shared_buffers=16MB >'{dir}/log' 2>&1 & pid=$!; \
         read _eof; kill -INT $pid; wait $pid; rm -rf '{dir}'",
        postgres = bin.join("postgres").display(),
        data = data.display(),
        dir = dir.display(),
    );
    let keeper = command(Path::new("sh"))
        .args(["-c", &script])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the postgres keeper");
    let server = PgServer {
        bin,
        socket_dir: dir.clone(),
        _keeper: Mutex::new(keeper),
    };
    let t = Instant::now();
    loop {
        if server.psql("postgres", "SELECT 1").is_ok() {
            return server;
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "postgres did not start within 30 s; log: {}",
            std::fs::read_to_string(dir.join("log")).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

impl PgServer {
    /// Runs one SQL command with `psql` as the superuser; its output, or the error text.
    pub fn psql(&self, db: &str, sql: &str) -> Result<String, String> {
        let out = Command::new(self.bin.join("psql"))
            .arg("-h")
            .arg(&self.socket_dir)
            .args(["-p", &PORT.to_string(), "-U", "postgres", "-d", db])
            .args(["-v", "ON_ERROR_STOP=1", "-Atc", sql])
            .stdin(Stdio::null())
            .output()
            .map_err(|e| e.to_string())?;
        if out.status.success() {
            Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
        } else {
            Err(String::from_utf8_lossy(&out.stderr).to_string())
        }
    }

    /// A fresh, empty database; its connection string (unix socket).
    pub fn fresh_database(&self) -> String {
        static N: AtomicUsize = AtomicUsize::new(0);
        let name = format!(
            "t{}_{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        );
        self.psql("postgres", &format!("CREATE DATABASE {name}"))
            .unwrap_or_else(|e| panic!("create database {name}: {e}"));
        self.url(&name)
    }

    /// The connection string of database `db`.
    pub fn url(&self, db: &str) -> String {
        format!(
            "host={} port={PORT} user=postgres dbname={db}",
            self.socket_dir.display()
        )
    }
}

/// The shared server of this test binary, started on first use.
pub fn server() -> &'static PgServer {
    static SERVER: OnceLock<PgServer> = OnceLock::new();
    SERVER.get_or_init(start)
}

/// A fresh database on the shared server.
pub fn fresh_url() -> String {
    server().fresh_database()
}
