//! Differential geometry on Surfaces: Laplacian and mass, geodesics (heat method, bounded
//! walks), exponential map and geodesic fans, curvature, and ray-cast shape features (solid
//! angle, occlusion, shape diameter), the Laplace–Beltrami spectrum and spectral signatures
//! (HKS, WKS). Each operator is a plain function with a `Params` struct.

pub mod curvature;
pub mod expmap;
pub mod fan_filter;
pub mod fans;
pub mod heat;
pub mod laplacian;
pub mod occlusion;
pub mod ray_sets;
pub mod sdf;
pub mod signatures;
pub mod solid_angle;
pub mod spectrum;
pub mod walk;
