//! Foundations of the `detail` method (Berkiten, Halber, Solomon, Ma, Li, Rusinkiewicz,
//! *Learning Detail Transfer based on Geometric Features*, Eurographics 2017; issue 13).
//!
//! Not a registered method yet: only the building blocks exist, each tested on its own.
//! - [`metric`] (§3.2.3, eqs. 1-2): the learned Mahalanobis metric (two-block ADMM), its factor
//!   `M = AᵀA` and the equal-weights baseline.
//! - [`displacement`] (§3, Fig. 4): the base (given, or the source smoothed) and the signed
//!   displacement along its normal to the detailed surface.
//! - [`hierarchy`] (§3.1): four remeshed levels per shape, edge length halving per level, shared
//!   absolute lengths between source and target (remesher: [`crate::engine::mesh::remesh`]).
//! - [`steerable`] (§3.2.1): the 17 sub-band deviations of a steerable pyramid of a square grid
//!   of displacements.
//! - [`patches`] (§3.2.1): the exponential-map patch of every vertex sampled into that grid, and
//!   the 17-D detail feature per vertex.
//! - [`geometric_features`] (§3.2.2): the 60-D geometric feature vector per vertex, HKS / WKS
//!   at scales shared by a source and a target; [`segmentation`] the SDF segments it measures
//!   boundary distances to.
//! - [`synthesis`] (§3.3.1, Algorithms 1-2, eqs. 5-7): the displacement of every target level,
//!   coarse to fine, from the source levels' displacements and both shapes' transformed
//!   features; [`sweep`] the sweep order and source sampling, [`blend`] eqs. 5-7, and the
//!   private `patch_match` the patches, the two-step matching and SYNTHESIZE-LEVEL.
//!
//! Missing (see README "detail"): wiring the pieces into one pipeline (hierarchy → displacement
//! per level → features → metric → synthesis), the texture-space refinement (§3.3.2), the
//! outputs, and the method's registration.

pub mod blend;
pub mod displacement;
pub mod geometric_features;
pub mod hierarchy;
pub mod metric;
mod patch_match;
pub mod patches;
pub mod segmentation;
pub mod steerable;
pub mod sweep;
pub mod synthesis;
