//! `retex serve`: the HTTP job service. Settings come from defaults, then `--config FILE`
//! (TOML), then `RETEX_*` environment variables, then these flags; when none of them sets
//! `memory_bytes`, it is taken from the machine ([`retex::service::memory`]) and the workers
//! and per-job limits are fitted into it (`ServeConfig::fit_workers`). On start it prints
//! `retex listening on http://ADDR` to stdout (tests start it on port 0 and read the address);
//! SIGTERM or SIGINT shut it down gracefully.

use std::io::Write;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use clap::Args;
use retex::service::config::ServeConfig;
use retex::service::http;
use retex::service::memory;

/// Flags of `retex serve` (each overrides the config file and the environment).
#[derive(Args, Debug, Default)]
pub struct ServeArgs {
    /// TOML config file (see deploy/retex.example.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Listen address [env RETEX_ADDR; default 127.0.0.1:8080].
    #[arg(long)]
    pub addr: Option<SocketAddr>,
    /// Data directory for jobs.sqlite3 and blobs/ [env RETEX_DATA_DIR; default ./retex-data].
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Jobs that run at once [env RETEX_WORKERS; default: cores].
    #[arg(long)]
    pub workers: Option<usize>,
    /// Most enqueued jobs before 503 [env RETEX_QUEUE_LEN; default 64].
    #[arg(long)]
    pub queue_len: Option<u64>,
    /// Bearer tokens, comma separated [env RETEX_TOKENS; default none = no auth].
    #[arg(long, value_delimiter = ',')]
    pub tokens: Option<Vec<String>>,
    /// CORS origins, comma separated [env RETEX_CORS_ORIGINS].
    #[arg(long, value_delimiter = ',')]
    pub cors_origins: Option<Vec<String>>,
    /// Seconds finished jobs are kept [env RETEX_TTL_SECS; default 604800].
    #[arg(long)]
    pub ttl_secs: Option<u64>,
    /// Seconds between retention sweeps [default 600].
    #[arg(long)]
    pub prune_interval_secs: Option<u64>,
    /// Seconds a client may stay silent while uploading [env RETEX_BODY_TIMEOUT_SECS; default 30].
    #[arg(long)]
    pub body_timeout_secs: Option<u64>,
    /// Seconds a client may take to send a request head [env RETEX_HEADER_TIMEOUT_SECS; default 10].
    #[arg(long)]
    pub header_timeout_secs: Option<u64>,
    /// Seconds a kept-alive connection may sit idle [env RETEX_IDLE_TIMEOUT_SECS; default 60].
    #[arg(long)]
    pub idle_timeout_secs: Option<u64>,
    /// Seconds a whole request body may take [env RETEX_UPLOAD_TIMEOUT_SECS; default 3600].
    #[arg(long)]
    pub upload_timeout_secs: Option<u64>,
    /// Most client connections at once [env RETEX_MAX_CONNECTIONS; default 512].
    #[arg(long)]
    pub max_connections: Option<usize>,
    /// Most connections from one IP address [env RETEX_MAX_CONNECTIONS_PER_CLIENT; default 0 =
    /// no per-client cap].
    #[arg(long)]
    pub max_connections_per_client: Option<usize>,
    /// Free bytes below which /readyz is not ready [env RETEX_MIN_FREE_BYTES; default 512 MiB].
    #[arg(long)]
    pub min_free_bytes: Option<u64>,
    /// Seconds claims pause after a storage failure [default 30].
    #[arg(long)]
    pub storage_retry_secs: Option<u64>,
    /// Seconds granted to jobs and connections on shutdown [env RETEX_SHUTDOWN_SECS; default 20].
    #[arg(long)]
    pub shutdown_secs: Option<u64>,
    /// Largest request body in bytes [env RETEX_MAX_BODY_BYTES; default 1 GiB].
    #[arg(long)]
    pub max_body_bytes: Option<u64>,
    /// Largest multipart part in bytes [env RETEX_MAX_PART_BYTES; default 512 MiB].
    #[arg(long)]
    pub max_part_bytes: Option<u64>,
    /// Largest output.texture_size [env RETEX_MAX_TEXTURE_SIZE; default 8192].
    #[arg(long)]
    pub max_texture_size: Option<u32>,
    /// Most triangles per job, counting every mesh instance [env RETEX_MAX_TRIANGLES;
    /// default 20,000,000].
    #[arg(long)]
    pub max_triangles: Option<u64>,
    /// Memory the jobs may use together; workers (and, below one job, the per-job limits) are
    /// lowered to fit their worst case; 0 = no cap [env RETEX_MEMORY_BYTES; default: the cgroup
    /// limit or MemTotal, less 512 MiB].
    #[arg(long)]
    pub memory_bytes: Option<u64>,
    /// JSON log lines [env RETEX_LOG_JSON=1].
    #[arg(long)]
    pub log_json: bool,
    /// PostgreSQL job store shared by replicas, postgres://USER:PASS@HOST:PORT/DB
    /// [env RETEX_DATABASE_URL; default: the SQLite file in the data dir].
    #[arg(long)]
    pub database_url: Option<String>,
    /// Object store for uploads and results shared by replicas: s3://BUCKET/PREFIX,
    /// gs://BUCKET/PREFIX, az://CONTAINER/PREFIX or file:///FOLDER; endpoint, region and
    /// credentials from AWS_* / GOOGLE_* / AZURE_* [env RETEX_BLOB_URL; default: files in the
    /// data dir].
    #[arg(long)]
    pub blob_url: Option<String>,
    /// api (routes only), worker (runs jobs; health endpoints only) or all [env RETEX_ROLE;
    /// default all].
    #[arg(long)]
    pub role: Option<retex::service::config::Role>,
    /// Seconds a claimed job's lease lasts without a heartbeat (PostgreSQL)
    /// [env RETEX_LEASE_SECS; default 30].
    #[arg(long)]
    pub lease_secs: Option<u64>,
    /// Seconds between an idle worker's looks for jobs when no notification wakes it
    /// [env RETEX_POLL_SECS; default 1].
    #[arg(long)]
    pub poll_secs: Option<u64>,
}

/// What [`config`] decided besides the settings: where `data_dir` came from (for the error when
/// it cannot be used), where the memory budget came from, and the lines saying what the budget
/// lowered (logged once tracing is up).
pub struct Origins {
    data_dir: String,
    memory: String,
    notes: Vec<String>,
}

/// Builds the configuration from file, environment and flags, and fits the jobs into the memory
/// budget (detected from the machine when no setting gives one).
pub fn config(args: &ServeArgs) -> Result<(ServeConfig, Origins), String> {
    let mut origin = "the default data_dir (./retex-data, relative to the current folder)".into();
    let mut c = match &args.config {
        Some(path) => {
            let c = ServeConfig::from_file(path).map_err(|e| e.to_string())?;
            if c.data_dir != ServeConfig::default().data_dir {
                origin = format!("data_dir in the config file {}", path.display());
            }
            c
        }
        None => ServeConfig::default(),
    };
    if std::env::var_os("RETEX_DATA_DIR").is_some() {
        origin = "the environment variable RETEX_DATA_DIR".into();
    }
    if args.data_dir.is_some() {
        origin = "the flag --data-dir".into();
    }
    c.apply_env(|k| std::env::var(k).ok())
        .map_err(|e| e.to_string())?;
    macro_rules! flag {
        ($($name:ident),*) => { $( if let Some(v) = args.$name.clone() { c.$name = v; } )* };
    }
    flag!(
        addr,
        data_dir,
        workers,
        queue_len,
        tokens,
        cors_origins,
        ttl_secs,
        prune_interval_secs
    );
    flag!(
        body_timeout_secs,
        header_timeout_secs,
        idle_timeout_secs,
        upload_timeout_secs,
        max_connections,
        max_connections_per_client,
        min_free_bytes,
        storage_retry_secs,
        shutdown_secs,
        max_body_bytes,
        max_part_bytes,
        max_texture_size,
        role,
        lease_secs,
        poll_secs
    );
    if let Some(url) = &args.blob_url {
        c.blob_url = Some(url.clone());
    }
    if let Some(url) = &args.database_url {
        c.database_url = Some(url.clone());
    }
    if let Some(v) = args.memory_bytes {
        c.memory_bytes = Some(v);
    }
    if let Some(v) = args.max_triangles {
        c.limits.max_triangles = v;
    }
    c.log_json |= args.log_json;
    c.validate().map_err(|e| e.to_string())?;
    let memory = match c.memory_bytes {
        Some(0) => "memory_bytes = 0 (no cap)".to_string(),
        Some(_) => "memory_bytes (config, RETEX_MEMORY_BYTES or --memory-bytes)".to_string(),
        None => match memory::detect_here() {
            Some(m) => {
                c.memory_bytes = Some(m.job_budget());
                format!(
                    "{} = {} bytes, less {} for the server",
                    m.source,
                    m.bytes,
                    memory::SERVER_RESERVE_BYTES
                )
            }
            None => "not detected (no cgroup limit or /proc/meminfo): no cap".to_string(),
        },
    };
    let notes = c
        .fit_workers()
        .map_err(|e| format!("{e} [budget from {memory}]"))?;
    c.validate().map_err(|e| e.to_string())?;
    Ok((
        c,
        Origins {
            data_dir: origin,
            memory,
            notes,
        },
    ))
}

/// Creates the data directory and checks that a file can be created in it, naming the setting
/// the path came from when it cannot (a config file written for a container, e.g.
/// `deploy/retex.example.toml` with `/var/lib/retex`, fails for a non-root user).
fn check_data_dir(dir: &Path, origin: &str) -> Result<(), String> {
    let fail = |e: std::io::Error| {
        format!(
            "data dir {}: {e} (set by {origin}; choose another with --data-dir or RETEX_DATA_DIR)",
            dir.display()
        )
    };
    std::fs::create_dir_all(dir).map_err(fail)?;
    let probe = dir.join(format!(".retex-write-check-{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(fail)?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

fn init_tracing(json: bool) {
    let filter = tracing_subscriber::EnvFilter::try_from_env("RETEX_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,tower_http=info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = if json {
        builder.json().try_init()
    } else {
        builder.try_init()
    };
}

/// Runs the server until SIGTERM/SIGINT.
pub fn run(args: &ServeArgs) -> Result<(), String> {
    let (config, origins) = config(args)?;
    check_data_dir(&config.data_dir, &origins.data_dir)?;
    init_tracing(config.log_json);
    for note in &origins.notes {
        tracing::warn!("{note}");
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("retex-http")
        .build()
        .map_err(|e| format!("tokio runtime: {e}"))?;
    runtime.block_on(async move {
        let server = http::start(config).await?;
        println!("retex listening on http://{}", server.addr);
        let _ = std::io::stdout().flush();
        tracing::info!(addr = %server.addr, data_dir = %server.state.config.data_dir.display(), "serving");
        let c = &server.state.config;
        tracing::info!(
            memory_bytes = c.memory_bytes.unwrap_or(0),
            budget_from = %origins.memory,
            job_worst_case_bytes = c.job_memory_bytes(),
            workers = c.workers,
            "memory: jobs need at most workers x job_worst_case_bytes (README \"Service\")"
        );
        http::shutdown_signal().await;
        tracing::info!("shutdown requested; draining");
        server.shutdown().await;
        tracing::info!("stopped");
        Ok(())
    })
}
