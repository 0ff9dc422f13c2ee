//! Multiresolution: the decimation hierarchy with its vertex tree (MeshMatch, Chen et al. 2012,
//! §4 and Figures 4 and 6) and refinement by edge splitting (DESIGN.md: methods that work per
//! vertex run on "a dense resampling of the surface"), both keeping the links needed to move
//! per-vertex fields between resolutions.
//!
//! - [`build_hierarchy`] → [`Hierarchy`]: levels by shortest-edge-first midpoint collapse
//!   ([`collapse`](self::collapse) has the rules), parents, children, projections onto the
//!   coarser level, uniformly random descendants, prolongation.
//! - [`refine`] (uniform passes) and [`resample`] (longest edge first, to an exact sample count):
//!   split edges without moving the geometry; every vertex knows its (face, barycentric) on the
//!   input so fields computed on the refined mesh can be baked back.

mod collapse;
pub mod hierarchy;
pub mod refine;
pub mod resample;
pub mod vertex_tree;
pub use hierarchy::*;
pub use refine::*;
pub use resample::*;

/// A point on a face: face index and barycentric weights of its corners (in the order the face
/// lists them; they sum to 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FacePoint {
    /// Face index.
    pub face: u32,
    /// Weights of the face's corners 0, 1, 2.
    pub bary: [f32; 3],
}

impl FacePoint {
    /// Marks a vertex that lies on no input face (an input vertex used by no triangle).
    pub const NONE: FacePoint = FacePoint {
        face: u32::MAX,
        bary: [0.0; 3],
    };
}
