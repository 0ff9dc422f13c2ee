//! The HTTP job service's integration tests, one test binary (`cargo test --release --test
//! service`): the job store, the runner, the HTTP API end to end (including malformed uploads),
//! the OpenAPI document, robustness (issue 9), and crash recovery of the real `retex serve` process. Filter by module,
//! e.g. `cargo test --release --test service http::`. Needs the default features (the service,
//! and the CLI binary that the recovery test runs).
#![cfg(all(feature = "service", feature = "cli"))]

#[path = "../common/mod.rs"]
mod common;
mod service_common;

mod blob_store;
mod connections;
mod contract;
mod correlation;
mod dashboard_previews;
mod dashboard_routes;
mod deploy_scale;
mod elastiface_inputs;
mod fuzz_multipart;
mod http;
mod http_errors;
mod job_stream;
mod memory_budget;
mod meshmatch_update;
mod method_seam;
mod openapi;
mod pg_bench;
mod pg_feed;
mod pg_kill;
mod pg_replicas;
mod pg_server;
mod pg_stale;
mod preview_normals;
mod recovery;
mod robustness;
mod runner;
mod s3_server;
mod scopes;
mod soak;
mod storage_faults;
mod storage_live;
mod store;
