//! Jobs: the runner that claims jobs from the store and executes them on the engine's rayon
//! pool ([`runner`]), and the preview stage it runs after a method succeeded ([`preview`]).
//! Engine errors become problems through [`crate::service::problem_table`].

pub mod preview;
pub mod runner;
