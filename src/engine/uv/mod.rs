//! UV atlas generation for targets without texture coordinates: segmentation into disc charts
//! ([`charts`]), least-squares conformal maps per chart ([`param`], Lévy et al. 2002), a stretch
//! bound (Sander et al. 2001) that splits charts above it, merging of neighbouring charts within
//! that bound ([`merge`]), skyline packing with rotation and a gutter ([`pack`]), and a quality report ([`report`]); [`atlas::generate`] runs them in order.
//! Pure Rust (faer for the sparse solves), deterministic, independent of the thread count.

pub mod atlas;
pub mod charts;
pub mod merge;
pub mod pack;
pub mod param;
pub mod report;

pub use atlas::{generate, working_set_bytes, Atlas, AtlasError, AtlasParams, Chart};
pub use report::{AtlasReport, ChartReport};
