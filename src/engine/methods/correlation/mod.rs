//! The `correlation` method (Mertens, Kautz, Chen, Bekaert, Durand, EGSR 2006; issue 11). This
//! placeholder only declares the pieces built so far; the method itself is in helper corr's
//! branch.

pub mod cluster_stats;
pub mod feather;
pub mod kmeans;
pub mod parametric;
pub mod pyramid;
pub mod quantiles;
