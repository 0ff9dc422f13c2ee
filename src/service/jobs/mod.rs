//! Jobs: the runner that claims jobs from the store and executes them on the engine's rayon
//! pool ([`runner`]), the preview stage it runs after a method succeeded ([`preview`]) and the
//! heap trim after each job ([`heap`]).
//! Engine errors become problems through [`crate::service::problem_table`].

pub mod heap;
pub mod preview;
pub mod runner;
