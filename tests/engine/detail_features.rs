//! The `detail` method's per-vertex features (Berkiten et al. 2017, §3.2.1-3.2.2) and the metric
//! learning on them, and the synthesis (§3.3.1) fed by them: one module of the engine tests
//! holding the four test files.

#[path = "detail_geometric.rs"]
mod geometric;
#[path = "detail_metric_features.rs"]
pub(crate) mod metric_features;
#[path = "detail_patches.rs"]
mod patches;
#[path = "detail_synthesis.rs"]
pub(crate) mod synthesis;
