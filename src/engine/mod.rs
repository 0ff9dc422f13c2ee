//! The transfer engine: ingest, Surface, spatial queries, texture sampling and baking, the
//! methods, and export. Pure and synchronous; long loops report to a [`control::Control`].

pub mod asset;
pub mod control;
pub mod geometry;
pub mod linalg;
pub mod math;
pub mod mesh;
pub mod methods;
pub mod multires;
pub mod pipeline;
pub mod rng;
pub mod spatial;
pub mod texture;
pub mod uv;
