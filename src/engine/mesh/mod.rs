//! Surface: all triangles of an asset in world space, welded into one mesh with adjacency,
//! boundary loops and components, every corner linked back to its primitive and vertex.
//!
//! Units are the asset's world units; faces wind counter-clockwise around their outward normal
//! (see [`surface`] and [`mod@topology`] for the details).

pub mod csr;
pub mod halfedge;
pub mod primitives;
pub mod remesh;
pub mod surface;
pub mod topology;
pub use surface::*;
pub use topology::*;
