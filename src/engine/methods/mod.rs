//! The transfer methods, one module per method id.

pub mod align;
pub mod color_output;
pub mod correspondence;
pub mod project;
