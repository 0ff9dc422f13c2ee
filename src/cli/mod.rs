//! Subcommands of the `retex` binary.

pub mod bench;
pub mod inspect;
#[cfg(feature = "service")]
pub mod serve;
pub mod transfer;
