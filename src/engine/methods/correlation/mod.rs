//! The `correlation` method (Mertens, Kautz, Chen, Bekaert, Durand, *Texture Transfer Using
//! Geometry Correlation*, EGSR 2006).

pub mod cca;
pub mod features;
pub mod histmatch;
pub mod mask;
pub mod params;
pub mod pyramid;
pub mod quantiles;
