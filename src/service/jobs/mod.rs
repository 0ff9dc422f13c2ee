//! Jobs: the worker pool and the runner that executes jobs on the engine.

pub mod runner;
