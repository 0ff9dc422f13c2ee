//! retex: transfer of surface appearance (color texture, patterns, geometric detail, texture
//! layouts) between meshes.
//!
//! [`engine`] is pure and synchronous (rayon-parallel, no async runtime); it builds with
//! `--no-default-features`. See `DESIGN.md` in the shared folder for the data flow.

pub mod engine;

#[cfg(feature = "service")]
pub mod service;
