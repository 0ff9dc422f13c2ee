//! MeshMatch (Chen et al. 2012).

pub mod features;
