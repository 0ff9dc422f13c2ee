//! Subcommands of the `retex` binary.

pub mod bench;
pub mod inspect;
pub mod transfer;
