//! UV atlas generation for targets without texture coordinates: segmentation into disc charts
//! ([`charts`]), least-squares conformal maps per chart ([`param`], Lévy et al. 2002), a stretch
//! bound (Sander et al. 2001) that splits charts above it, an optional as-rigid-as-possible
//! refinement of each chart ([`arap`], Liu et al. 2008), merging of neighbouring charts within
//! that bound ([`merge`]), packing with quarter turns and a gutter ([`pack`]: skyline packing of
//! boxes or [`bitmap_pack`]ing of outlines, whichever is tighter), and a quality report
//! ([`report`]); [`atlas::generate`] runs them in order.
//! Pure Rust (faer for the sparse solves), deterministic, independent of the thread count.

pub mod arap;
pub mod atlas;
pub mod bitmap_pack;
pub mod charts;
pub mod merge;
pub mod pack;
pub mod param;
pub mod report;

pub use arap::Parameterization;
pub use atlas::{generate, working_set_bytes, Atlas, AtlasError, AtlasParams, Chart};
pub use report::{AtlasReport, ChartReport};
