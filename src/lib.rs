//! retex: transfer of surface appearance (color texture, patterns, geometric detail, texture
//! layouts) between meshes.
//!
//! [`engine`] is pure and synchronous (rayon-parallel, no async runtime); it builds with
//! `--no-default-features`. See `DESIGN.md` in the shared folder for the data flow.

// The front ends name the crate `retex::` whether they are compiled into the library (here) or
// used from the binary.
extern crate self as retex;

pub mod engine;

/// The `retex` command's subcommands (in the library so tests can run them with their own
/// method registry).
#[cfg(feature = "cli")]
pub mod cli;

#[cfg(feature = "service")]
pub mod service;
