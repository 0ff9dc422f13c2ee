//! Spatial queries over triangles: a bounding volume hierarchy with exact closest-point and
//! ray-cast queries (refitted to moved vertices by [`refit`]), and the point–triangle /
//! ray–triangle primitives it uses.
//!
//! Distances are in the units of the positions given (world units for a Surface); barycentric
//! coordinates are weights of a face's corners in the order the face lists them.

pub mod bvh;
pub mod refit;
pub mod triangle;
pub use bvh::*;
pub use triangle::{closest_point_on_triangle, point_triangle_distance_squared, ray_triangle};
