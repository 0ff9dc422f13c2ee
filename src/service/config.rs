//! Configuration of `retex serve`: defaults that serve on a fresh machine, an optional TOML file,
//! environment variables (`RETEX_*`) and command-line flags, applied in that order (later wins).
//!
//! Every limit has a name (`max_body_bytes`, `max_part_bytes`, `max_texture_size`, ...) that the
//! service repeats in the `limit` of a refusal, so an operator can find the knob to turn.
//! Durations in the TOML file and in env vars are whole seconds.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::engine::asset::IngestLimits;

#[path = "config_fit.rs"]
mod fit;

pub use fit::MIN_JOB_BYTES;

/// Everything `retex serve` can be told.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServeConfig {
    /// Listen address. Default `127.0.0.1:8080` (env `RETEX_ADDR`).
    pub addr: SocketAddr,
    /// Data directory: `jobs.sqlite3` and `blobs/` live here. Default `./retex-data`
    /// (env `RETEX_DATA_DIR`).
    pub data_dir: PathBuf,
    /// Jobs that run at once (size of the engine pool). Default: number of cores
    /// (env `RETEX_WORKERS`).
    pub workers: usize,
    /// Most enqueued jobs; a submission beyond it gets 503. Default 64 (env `RETEX_QUEUE_LEN`).
    pub queue_len: u64,
    /// Times a job may be started (crash recovery re-runs count). Default 3.
    pub max_attempts: u32,
    /// Bearer tokens; empty means no authentication (env `RETEX_TOKENS`, comma separated).
    /// A `read:`, `submit:` or `admin:` prefix names the token's scope (the prefix is not part
    /// of the token the client sends); a token without one is an admin token.
    pub tokens: Vec<String>,
    /// Origins allowed by CORS, e.g. `https://dashboard.example`; empty allows none
    /// (env `RETEX_CORS_ORIGINS`, comma separated; `*` allows any).
    pub cors_origins: Vec<String>,
    /// Seconds a finished job and its files are kept. Default 7 days (env `RETEX_TTL_SECS`).
    pub ttl_secs: u64,
    /// Seconds between retention sweeps. Default 600.
    pub prune_interval_secs: u64,
    /// Seconds an Idempotency-Key is remembered (at least 24 h). Default 86400.
    pub idempotency_secs: u64,
    /// Seconds a client may stay silent while sending a request body. Default 30
    /// (env `RETEX_BODY_TIMEOUT_SECS`).
    pub body_timeout_secs: u64,
    /// Seconds a client may take to send a request head: from the accept for a connection's
    /// first request, from its first byte for later ones. Default 10
    /// (env `RETEX_HEADER_TIMEOUT_SECS`).
    pub header_timeout_secs: u64,
    /// Seconds a kept-alive connection may sit idle between requests. Default 60
    /// (env `RETEX_IDLE_TIMEOUT_SECS`).
    pub idle_timeout_secs: u64,
    /// Seconds a whole request body may take to arrive, however steadily it trickles.
    /// Default 3600 (env `RETEX_UPLOAD_TIMEOUT_SECS`).
    pub upload_timeout_secs: u64,
    /// Most client connections at once; one beyond gets 503 `too-many-connections` and is
    /// closed. Default 512, well under the usual limit of 1024 open files
    /// (env `RETEX_MAX_CONNECTIONS`).
    pub max_connections: usize,
    /// Most connections at once from one peer IP address; one beyond gets 503
    /// `too-many-client-connections` and is closed. Default 0 = no per-client cap (behind a
    /// reverse proxy every client has the proxy's address) (env
    /// `RETEX_MAX_CONNECTIONS_PER_CLIENT`).
    pub max_connections_per_client: usize,
    /// Free bytes the data directory's file system must keep: below, `/readyz` answers 503
    /// `low-disk-space`. Default 512 MiB (env `RETEX_MIN_FREE_BYTES`).
    pub min_free_bytes: u64,
    /// Seconds after a storage failure (a full disk, a failing database write) during which
    /// no job is claimed (`/readyz` follows a live probe instead); a job whose outputs hit a
    /// full disk goes back to the queue, and a job whose end the store refuses is retried this
    /// often. Default 30.
    pub storage_retry_secs: u64,
    /// Seconds granted on SIGTERM/SIGINT to running jobs and open connections. Default 20
    /// (env `RETEX_SHUTDOWN_SECS`).
    pub shutdown_secs: u64,
    /// Milliseconds between progress snapshots of a running job. Default 250.
    pub progress_interval_ms: u64,
    /// Largest request body in bytes. Default 1 GiB (env `RETEX_MAX_BODY_BYTES`).
    pub max_body_bytes: u64,
    /// Largest single multipart part (a file, after zip extraction) in bytes. Default 512 MiB
    /// (env `RETEX_MAX_PART_BYTES`).
    pub max_part_bytes: u64,
    /// Most files in one model (parts plus zip entries). Default 256.
    pub max_files: usize,
    /// Largest `output.texture_size` a job may ask for. Default 8192
    /// (env `RETEX_MAX_TEXTURE_SIZE`).
    pub max_texture_size: u32,
    /// Limits applied when validating uploads and when the job loads them again
    /// (`max_triangles`, `max_image_pixels`, `max_decoded_image_bytes`, `max_method_bytes`, ...).
    pub limits: IngestLimits,
    /// Memory the jobs may use together, in bytes; `0` = no cap. Unset (the default), `retex
    /// serve` takes it from the machine ([`crate::service::memory`]: the cgroup limit or
    /// MemTotal, less 512 MiB for the server); the library ([`ServeConfig::default`], tests)
    /// never detects it, so unset there means no cap. [`ServeConfig::fit_workers`] lowers
    /// `workers` so that workers × the worst case of one job ([`ServeConfig::job_memory_bytes`])
    /// fits, and lowers the per-job limits when not even one job fits
    /// (env `RETEX_MEMORY_BYTES`).
    pub memory_bytes: Option<u64>,
    /// JSON log lines instead of text (env `RETEX_LOG_JSON=1`).
    pub log_json: bool,
    /// PostgreSQL job store shared by replicas, e.g. `postgres://retex:pw@db:5432/retex`
    /// (or `host=/run/postgresql user=retex dbname=retex`); unset (the default): the embedded
    /// SQLite file under `data_dir` (env `RETEX_DATABASE_URL`). Blobs stay under `data_dir`
    /// unless `blob_url` is set; replicas must then share that folder.
    pub database_url: Option<String>,
    /// Object store for uploads and results shared by replicas: `s3://bucket/prefix`,
    /// `gs://bucket/prefix`, `az://container/prefix` or `file:///folder`, with endpoint,
    /// region and credentials from the usual `AWS_*` / `GOOGLE_*` / `AZURE_*` variables; unset
    /// (the default): files under `data_dir` (env `RETEX_BLOB_URL`). Uploads are still spooled
    /// under `data_dir` before they are sent.
    pub blob_url: Option<String>,
    /// What this process does: `api` (routes, no runner), `worker` (runner, health endpoints
    /// and metrics only) or `all` (the default) (env `RETEX_ROLE`).
    pub role: Role,
    /// Seconds a claimed job's lease lasts without a heartbeat (PostgreSQL only): after a
    /// replica dies, its jobs run again elsewhere this long later. Default 30
    /// (env `RETEX_LEASE_SECS`).
    pub lease_secs: u64,
    /// Seconds between an idle worker's looks for enqueued jobs when nothing wakes it: a job
    /// submitted to this process, or (PostgreSQL) a change notification from another replica
    /// (`LISTEN`/`NOTIFY`), wakes it at once; the look also reclaims expired leases. Default 1
    /// (env `RETEX_POLL_SECS`).
    pub poll_secs: u64,
    /// `RETEX_TOKENS` was set but names no token (empty or blank): a server meant to need
    /// tokens would start open. [`ServeConfig::validate`] refuses that unless the address is
    /// loopback.
    #[serde(skip)]
    pub tokens_blank: bool,
}

impl Default for ServeConfig {
    fn default() -> Self {
        Self {
            addr: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data_dir: PathBuf::from("./retex-data"),
            workers: std::thread::available_parallelism().map_or(2, |n| n.get()),
            queue_len: 64,
            max_attempts: 3,
            tokens: Vec::new(),
            cors_origins: Vec::new(),
            ttl_secs: 7 * 24 * 3600,
            prune_interval_secs: 600,
            idempotency_secs: 24 * 3600,
            body_timeout_secs: 30,
            header_timeout_secs: 10,
            idle_timeout_secs: 60,
            upload_timeout_secs: 3600,
            max_connections: 512,
            max_connections_per_client: 0,
            min_free_bytes: 512 << 20,
            storage_retry_secs: 30,
            shutdown_secs: 20,
            progress_interval_ms: 250,
            max_body_bytes: 1 << 30,
            max_part_bytes: 512 << 20,
            max_files: 256,
            max_texture_size: 8192,
            limits: IngestLimits::default(),
            memory_bytes: None,
            log_json: false,
            database_url: None,
            blob_url: None,
            role: Role::All,
            lease_secs: 30,
            poll_secs: 1,
            tokens_blank: false,
        }
    }
}

/// What a `retex serve` process does (issue 17).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// The HTTP API only: accepts, lists and cancels jobs; runs none.
    Api,
    /// Runs jobs; serves only `/healthz`, `/readyz` and `/metrics`.
    Worker,
    /// Both (the single-process default).
    #[default]
    All,
}

impl Role {
    /// Whether this role claims and runs jobs.
    pub fn runs_jobs(self) -> bool {
        self != Role::Api
    }
}

impl std::str::FromStr for Role {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "api" => Ok(Role::Api),
            "worker" => Ok(Role::Worker),
            "all" => Ok(Role::All),
            other => Err(format!("unknown role {other:?} (api, worker or all)")),
        }
    }
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The TOML file could not be read.
    #[error("config file {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The TOML file does not parse or has unknown keys.
    #[error("config file {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// An environment variable with a bad value.
    #[error("environment variable {name}: {message}")]
    Env {
        /// The variable.
        name: &'static str,
        /// Why.
        message: String,
    },
    /// A value outside its range.
    #[error("{field}: {message}")]
    Invalid {
        /// The setting.
        field: &'static str,
        /// Why.
        message: String,
    },
}

impl ServeConfig {
    /// Parses a TOML document (unknown keys are errors); missing keys keep their defaults.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let config: ServeConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Reads a TOML file.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml(&text, path)
    }

    /// Applies `RETEX_*` variables read through `get` (the process environment in production,
    /// a map in tests).
    pub fn apply_env(&mut self, get: impl Fn(&str) -> Option<String>) -> Result<(), ConfigError> {
        fn parse<T: std::str::FromStr>(name: &'static str, v: &str) -> Result<T, ConfigError>
        where
            T::Err: std::fmt::Display,
        {
            v.trim().parse().map_err(|e: T::Err| ConfigError::Env {
                name,
                message: format!("{v:?}: {e}"),
            })
        }
        let list = |v: String| -> Vec<String> {
            v.split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(String::from)
                .collect()
        };
        if let Some(v) = get("RETEX_ADDR") {
            self.addr = parse("RETEX_ADDR", &v)?;
        }
        if let Some(v) = get("RETEX_DATA_DIR") {
            self.data_dir = PathBuf::from(v);
        }
        if let Some(v) = get("RETEX_WORKERS") {
            self.workers = parse("RETEX_WORKERS", &v)?;
        }
        if let Some(v) = get("RETEX_QUEUE_LEN") {
            self.queue_len = parse("RETEX_QUEUE_LEN", &v)?;
        }
        if let Some(v) = get("RETEX_TOKENS") {
            self.tokens = list(v);
            self.tokens_blank = self.tokens.is_empty();
        }
        if let Some(v) = get("RETEX_CORS_ORIGINS") {
            self.cors_origins = list(v);
        }
        if let Some(v) = get("RETEX_TTL_SECS") {
            self.ttl_secs = parse("RETEX_TTL_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_BODY_TIMEOUT_SECS") {
            self.body_timeout_secs = parse("RETEX_BODY_TIMEOUT_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_HEADER_TIMEOUT_SECS") {
            self.header_timeout_secs = parse("RETEX_HEADER_TIMEOUT_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_IDLE_TIMEOUT_SECS") {
            self.idle_timeout_secs = parse("RETEX_IDLE_TIMEOUT_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_UPLOAD_TIMEOUT_SECS") {
            self.upload_timeout_secs = parse("RETEX_UPLOAD_TIMEOUT_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_MAX_CONNECTIONS") {
            self.max_connections = parse("RETEX_MAX_CONNECTIONS", &v)?;
        }
        if let Some(v) = get("RETEX_MAX_CONNECTIONS_PER_CLIENT") {
            self.max_connections_per_client = parse("RETEX_MAX_CONNECTIONS_PER_CLIENT", &v)?;
        }
        if let Some(v) = get("RETEX_MIN_FREE_BYTES") {
            self.min_free_bytes = parse("RETEX_MIN_FREE_BYTES", &v)?;
        }
        if let Some(v) = get("RETEX_SHUTDOWN_SECS") {
            self.shutdown_secs = parse("RETEX_SHUTDOWN_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_MAX_BODY_BYTES") {
            self.max_body_bytes = parse("RETEX_MAX_BODY_BYTES", &v)?;
        }
        if let Some(v) = get("RETEX_MAX_PART_BYTES") {
            self.max_part_bytes = parse("RETEX_MAX_PART_BYTES", &v)?;
        }
        if let Some(v) = get("RETEX_MAX_TEXTURE_SIZE") {
            self.max_texture_size = parse("RETEX_MAX_TEXTURE_SIZE", &v)?;
        }
        if let Some(v) = get("RETEX_MAX_TRIANGLES") {
            self.limits.max_triangles = parse("RETEX_MAX_TRIANGLES", &v)?;
        }
        if let Some(v) = get("RETEX_MEMORY_BYTES") {
            self.memory_bytes = Some(parse("RETEX_MEMORY_BYTES", &v)?);
        }
        if let Some(v) = get("RETEX_DATABASE_URL") {
            self.database_url = Some(v.trim().to_string()).filter(|v| !v.is_empty());
        }
        if let Some(v) = get("RETEX_BLOB_URL") {
            self.blob_url = Some(v.trim().to_string()).filter(|v| !v.is_empty());
        }
        if let Some(v) = get("RETEX_ROLE") {
            self.role = parse("RETEX_ROLE", &v)?;
        }
        if let Some(v) = get("RETEX_LEASE_SECS") {
            self.lease_secs = parse("RETEX_LEASE_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_POLL_SECS") {
            self.poll_secs = parse("RETEX_POLL_SECS", &v)?;
        }
        if let Some(v) = get("RETEX_LOG_JSON") {
            self.log_json = matches!(v.trim(), "1" | "true" | "yes");
        }
        Ok(())
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let bad = |field, message: &str| {
            Err(ConfigError::Invalid {
                field,
                message: message.to_string(),
            })
        };
        if self.workers == 0 {
            return bad("workers", "must be at least 1");
        }
        if self.queue_len == 0 {
            return bad("queue_len", "must be at least 1");
        }
        if self.max_attempts == 0 {
            return bad("max_attempts", "must be at least 1");
        }
        if !(16..=8192).contains(&self.max_texture_size) {
            return bad("max_texture_size", "must be within 16..=8192");
        }
        if self.max_part_bytes == 0 || self.max_body_bytes == 0 {
            return bad("max_body_bytes", "body and part limits must be positive");
        }
        for (field, secs) in [
            ("body_timeout_secs", self.body_timeout_secs),
            ("header_timeout_secs", self.header_timeout_secs),
            ("idle_timeout_secs", self.idle_timeout_secs),
            ("upload_timeout_secs", self.upload_timeout_secs),
            ("storage_retry_secs", self.storage_retry_secs),
        ] {
            if !(1..=30 * 24 * 3600).contains(&secs) {
                return bad(field, "must be within 1..=2592000 seconds");
            }
        }
        if !(1..=1_000_000).contains(&self.max_connections) {
            return bad("max_connections", "must be within 1..=1000000");
        }
        if self.max_connections_per_client > self.max_connections {
            return bad(
                "max_connections_per_client",
                "must be at most max_connections (0 = no per-client cap)",
            );
        }
        if self.idempotency_secs < 24 * 3600 {
            return bad("idempotency_secs", "keys are kept at least 24 h (86400)");
        }
        if let Some(url) = &self.database_url {
            if !(url.starts_with("postgres://")
                || url.starts_with("postgresql://")
                || url.contains("host="))
            {
                return bad(
                    "database_url",
                    "must be a PostgreSQL URL (postgres://…) or key=value connection string",
                );
            }
        }
        if let Some(url) = &self.blob_url {
            if let Err(why) = crate::service::store::object::split_url(url) {
                return bad("blob_url", &why);
            }
        }
        if self.database_url.is_none() && self.role != Role::All {
            return bad(
                "role",
                "api and worker roles share jobs through PostgreSQL: set database_url",
            );
        }
        if !(3..=3600).contains(&self.lease_secs) {
            return bad("lease_secs", "must be within 3..=3600");
        }
        if !(1..=3600).contains(&self.poll_secs) {
            return bad("poll_secs", "must be within 1..=3600");
        }
        if self.prune_interval_secs == 0 || self.progress_interval_ms == 0 {
            return bad("prune_interval_secs", "intervals must be positive");
        }
        if self
            .tokens
            .iter()
            .any(|t| crate::service::http::auth::scoped(t).1.len() < 8)
        {
            return bad("tokens", "each token needs at least 8 characters");
        }
        if self.tokens_blank && self.tokens.is_empty() && !self.addr.ip().is_loopback() {
            return Err(ConfigError::Invalid {
                field: "tokens",
                message: format!(
                    "RETEX_TOKENS is set but names no token: refusing to serve {} without authentication; set a token (8+ characters) or unset RETEX_TOKENS",
                    self.addr
                ),
            });
        }
        Ok(())
    }

    /// Time-to-live of finished jobs.
    pub fn ttl(&self) -> Duration {
        Duration::from_secs(self.ttl_secs)
    }

    /// Path of the SQLite job database.
    pub fn db_path(&self) -> PathBuf {
        self.data_dir.join("jobs.sqlite3")
    }

    /// Root of the blob store.
    pub fn blob_dir(&self) -> PathBuf {
        self.data_dir.join("blobs")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn defaults_are_valid_and_env_overrides() {
        let mut c = ServeConfig::default();
        c.validate().unwrap();
        let env: HashMap<&str, &str> = [
            ("RETEX_ADDR", "0.0.0.0:9000"),
            ("RETEX_TOKENS", "abcdefgh, ijklmnopq ,"),
            ("RETEX_MAX_TRIANGLES", "1000"),
        ]
        .into();
        c.apply_env(|k| env.get(k).map(|v| v.to_string())).unwrap();
        assert_eq!(c.addr.port(), 9000);
        assert_eq!(c.tokens, ["abcdefgh", "ijklmnopq"]);
        assert_eq!(c.limits.max_triangles, 1000);
        let e = c
            .apply_env(|k| (k == "RETEX_WORKERS").then(|| "many".to_string()))
            .unwrap_err();
        assert!(e.to_string().contains("RETEX_WORKERS"), "{e}");
    }

    #[test]
    fn database_url_and_role_from_env_and_toml() {
        let mut c = ServeConfig::default();
        assert_eq!((c.database_url.as_deref(), c.role), (None, Role::All));
        let env: HashMap<&str, &str> = [
            ("RETEX_DATABASE_URL", "postgres://retex@db/retex"),
            ("RETEX_ROLE", "worker"),
            ("RETEX_POLL_SECS", "60"),
        ]
        .into();
        c.apply_env(|k| env.get(k).map(|v| v.to_string())).unwrap();
        assert_eq!(c.database_url.as_deref(), Some("postgres://retex@db/retex"));
        assert_eq!(c.poll_secs, 60);
        assert!(!c.role.runs_jobs() || c.role == Role::Worker);
        c.validate().unwrap();
        let mut never = c.clone();
        never.poll_secs = 0;
        assert!(never.validate().is_err(), "poll_secs 0 would spin");
        assert!(c
            .apply_env(|k| (k == "RETEX_ROLE").then(|| "boss".to_string()))
            .is_err());
        let p = Path::new("x.toml");
        let c = ServeConfig::from_toml("role = \"api\"\ndatabase_url = \"host=/tmp user=x\"\n", p)
            .unwrap();
        assert_eq!(c.role, Role::Api);
        assert!(!c.role.runs_jobs());
        // A role without a shared database would split one process's jobs: refused.
        assert!(ServeConfig::from_toml("role = \"worker\"\n", p).is_err());
        assert!(ServeConfig::from_toml("database_url = \"mysql://x\"\n", p).is_err());
    }

    #[test]
    fn blob_url_from_env_and_toml_and_checked() {
        let mut c = ServeConfig::default();
        assert_eq!(c.blob_url, None);
        c.apply_env(|k| (k == "RETEX_BLOB_URL").then(|| " s3://farm/retex ".to_string()))
            .unwrap();
        assert_eq!(c.blob_url.as_deref(), Some("s3://farm/retex"));
        c.validate().unwrap();
        let p = Path::new("x.toml");
        let c = ServeConfig::from_toml("blob_url = \"file:///srv/blobs\"\n", p).unwrap();
        assert_eq!(c.blob_url.as_deref(), Some("file:///srv/blobs"));
        for bad in ["ftp://x/y", "s3:///y", "file://relative", "bucket"] {
            let e = ServeConfig::from_toml(&format!("blob_url = {bad:?}\n"), p).unwrap_err();
            assert!(e.to_string().contains("blob_url"), "{bad}: {e}");
        }
    }

    #[test]
    fn toml_rejects_unknown_keys_and_bad_ranges() {
        let p = Path::new("x.toml");
        let c = ServeConfig::from_toml("workers = 3\n[limits]\nmax_triangles = 5\n", p).unwrap();
        assert_eq!((c.workers, c.limits.max_triangles), (3, 5));
        assert!(ServeConfig::from_toml("wrkers = 3", p).is_err());
        assert!(ServeConfig::from_toml("workers = 0", p).is_err());
        assert!(ServeConfig::from_toml("max_texture_size = 9000", p).is_err());
    }
}
