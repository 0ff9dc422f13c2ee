//! The transfer methods, one module per method id.

pub mod align;
pub mod correspondence;
pub mod meshmatch;
pub mod project;
