//! Spatial queries over triangles: a bounding volume hierarchy with exact closest-point and
//! ray-cast queries.

pub mod bvh;
pub use bvh::*;
