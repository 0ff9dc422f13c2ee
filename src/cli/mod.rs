//! Subcommands of the `retex` binary.

pub mod bench;
pub mod bench_meshmatch;
pub mod inspect;
pub mod preview;
#[cfg(feature = "service")]
pub mod serve;
pub mod transfer;
