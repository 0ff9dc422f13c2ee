//! Assets: safe ingest of glTF 2.0 (.glb, or .gltf with its files as named blobs), the in-memory
//! model, constraints JSON v1, and export back to glTF.

pub mod accessor;
mod apply;
pub mod blobs;
pub mod budget;
pub mod constraints;
pub mod edits;
pub mod error;
pub mod export;
pub mod glb;
pub mod images;
pub mod load;
pub mod meshes;
pub mod model;
pub mod scene;
pub mod sniff;
pub mod uri;

pub use blobs::BlobSet;
pub use error::IngestError;
pub use load::{load, load_with, Decode, IngestLimits};
pub use model::*;
