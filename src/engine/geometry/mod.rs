//! Differential geometry on Surfaces: Laplacian and mass, geodesics (heat method, bounded
//! walks), curvature, and ray-cast shape features (solid angle, occlusion, shape diameter).
//! Each operator is a plain function with a `Params` struct.
pub mod expmap;
pub mod fans;
