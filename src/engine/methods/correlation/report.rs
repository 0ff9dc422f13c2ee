//! The report of the `correlation` method (issue 11: canonical correlations, CCA weights per
//! feature as in the paper's Fig. 4, cluster count and sizes; timings per stage come from the
//! job's `Control`).

use serde::Serialize;

use super::cca::GuidanceModel;
use super::histmatch::FeatureMatchReport;
use super::nonparametric::NonparametricReport;
use super::parametric::ParametricReport;
use super::params::{FeatureMatching, Reduction};
use crate::engine::methods::color_output::ColorOutputReport;

/// Sample counts of one model.
#[derive(Clone, Debug, Serialize)]
pub struct SideReport {
    /// Welded vertices of the input surface (where the features are computed).
    pub vertices: usize,
    /// Level-0 surface samples.
    pub samples: usize,
    /// Samples per pyramid level.
    pub level_samples: Vec<usize>,
}

/// What `correlation` reports.
#[derive(Clone, Debug, Serialize)]
pub struct CorrelationReport {
    /// The source model.
    pub source: SideReport,
    /// The target model.
    pub target: SideReport,
    /// Source samples the mask removed from training.
    pub masked_samples: usize,
    /// `cca` or `pca`.
    pub reduction: Reduction,
    /// The guidance model: its dimension, canonical correlations and weights per feature.
    pub guidance: GuidanceModel,
    /// `off`, `marginals` or `multiscale`.
    pub feature_matching: FeatureMatching,
    /// What the feature matching did.
    pub matching: FeatureMatchReport,
    /// Clusters requested.
    pub clusters: usize,
    /// The parametric synthesis (cluster sizes on source and target, …); absent with
    /// `synthesis = "nonparametric"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub synthesis: Option<ParametricReport>,
    /// The non-parametric synthesis (per level: coherent choices, distances; coherent patch
    /// sizes); absent with `synthesis = "parametric"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nonparametric: Option<NonparametricReport>,
    /// What was written into the target.
    pub output: ColorOutputReport,
    /// With `params.debug`: per guidance axis, the source's 1st and 99th percentiles that map to
    /// 0 and 1 in `guidance.glb`'s R, G, B.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub debug_guidance_range: Option<[[f32; 2]; 3]>,
    /// Things the user should know.
    pub warnings: Vec<String>,
}
