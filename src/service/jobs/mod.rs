//! Jobs: the runner that claims jobs from the store and executes them on the engine's rayon
//! pool ([`runner`]), and the table from engine errors to problem objects ([`problem`]).

pub mod problem;
pub mod runner;
