//! Surface: all triangles of an asset in world space, welded into one mesh with adjacency,
//! boundary loops and components, every corner linked back to its primitive and vertex.

pub mod surface;
pub mod topology;
pub use surface::*;
