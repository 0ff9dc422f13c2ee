//! The HTTP job service: axum routes, the durable embedded job store, the worker pool that runs
//! the engine, progress and cancellation, recovery after a crash, limits, and the OpenAPI spec.
//!
//! Only [`jobs::runner`] knows both worlds: it maps a job to an engine call on a dedicated rayon
//! pool and passes a [`crate::engine::control::Control`] whose progress the routes read.

pub mod config;
pub mod http;
pub mod jobs;
pub mod memory;
pub mod model;
pub mod problem_table;
pub mod store;
