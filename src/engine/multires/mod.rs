//! Multiresolution: refinement of meshes (edge splitting) so per-vertex fields have enough
//! samples. The decimation hierarchy (MeshMatch section 4) will live here too.

pub mod refine;
pub use refine::*;
