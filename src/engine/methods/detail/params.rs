//! Parameters of the `detail` method (Berkiten et al. 2017): the `params` object of the
//! constraints, and their mapping onto the pipeline's settings ([`super::pipeline`]).
//!
//! The paper's published constants are the defaults: four levels (§3.1), λ = 0.1 (§3.2.3), the
//! (1, 0, 0) frame direction (§3.1). The values it leaves open are retex's and are stated on
//! their field and in [`super::synthesis`] (patch size, candidates, samples, threshold, seeds).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::displacement::{BaseParams, DisplacementParams};
use super::hierarchy::HierarchyParams;
use super::metric::{MetricKind, MetricParams};
use super::patches::PatchParams;
use super::pipeline::PipelineParams;
use super::refine::RefineParams;
use super::synthesis::SynthesisParams;
use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::methods::shared_params::SharedParams;

/// Which metric compares geometric features.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum MetricChoice {
    /// Learned from the source (§3.2.3).
    #[default]
    Learned,
    /// Equal weights on the z-scored features (the paper's baseline, Fig. 16a).
    Identity,
}

/// Parameters of the `detail` method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
#[schemars(transform = crate::engine::methods::shared_params::shared_fields)]
pub struct DetailParams {
    /// Hierarchy levels, each halving the edge length (§3.1). Default 4 (paper).
    #[schemars(range(min = 1, max = 6))]
    pub levels: usize,
    /// Edge length of the finest level as a fraction of the target's bounding-box diagonal.
    /// Default: the detailed source's mean edge length, raised so that no level of either shape
    /// exceeds `max_faces`.
    #[schemars(range(max = 0.5), extend("exclusiveMinimum" = 0))]
    pub finest_edge_length: Option<f32>,
    /// Face limit of any level of either shape. Default 200,000.
    #[schemars(range(min = 100, max = 2_000_000))]
    pub max_faces: usize,
    /// Width of the smoothing that derives the base when no `source_base` is given, as a
    /// fraction of the source's bounding-box diagonal. Default 0.02.
    #[schemars(range(max = 0.5), extend("exclusiveMinimum" = 0))]
    pub base_smoothing: f32,
    /// Largest displacement searched from the base, fraction of the base's diagonal.
    /// Default 0.05.
    #[schemars(range(max = 0.5), extend("exclusiveMinimum" = 0))]
    pub max_displacement: f32,
    /// `learned` (default) or `identity` (equal weights).
    pub metric: MetricChoice,
    /// The metric's ℓ1 weight λ (§3.2.3). Default 0.1 (paper).
    #[schemars(range(min = 0, max = 100))]
    pub lambda: f64,
    /// λ relative to the strongest covariance between a geometric feature and the detail
    /// (`B̂`'s largest diagonal entry; λ ≥ 2 then gives `M = 0` whatever the units). Default
    /// true. False: λ is in the squared units of the detail features (world-unit displacements),
    /// where the paper's 0.1 leaves `M` zero for detail below a few tenths of a unit (README
    /// "An absolute λ leaves the learned metric zero").
    pub lambda_relative: bool,
    /// Finest-level source vertices the metric is learned on (farthest-point samples).
    /// Default 4,000.
    #[schemars(range(min = 16, max = 100_000))]
    pub metric_samples: usize,
    /// Vertex limit of the level the geometric features are computed on (they are interpolated
    /// to the others). Default 20,000.
    #[schemars(range(min = 100, max = 500_000))]
    pub feature_vertices: usize,
    /// Patch side on the coarsest level, in edges (§3.3.1, `n`; doubled plus one per level).
    /// Default 3.
    #[schemars(range(min = 1, max = 63))]
    pub patch_size: usize,
    /// Candidates of the first matching step (§3.3.1). Default 16 (README sweep).
    #[schemars(range(min = 1, max = 64))]
    pub candidates: usize,
    /// Source patches sampled per level. Default 1024.
    #[schemars(range(min = 16, max = 65_536))]
    pub source_samples: usize,
    /// Largest reach of the candidates' wider refinement (not in the paper), in edges: step 1's
    /// candidates are re-aligned by feature distance over every shift up to the source samples'
    /// covering radius, at most this. 0 turns it off. Default 0: it reproduces a scan's own
    /// detail better (README "detail", "The candidates' reach") but drifts the stretch case's
    /// rings.
    #[schemars(range(min = 0, max = 16))]
    pub max_reach: usize,
    /// Scale the source (and its base) about its bounding-box centre so that its bounding-box
    /// diagonal equals the target's before anything else: the hierarchy shares absolute edge
    /// lengths and the detail keeps its world size, which only means something when both models
    /// are in the same units (a scan in mm onto a head in m would not). Default true; false
    /// keeps the source's detail at its own world size.
    pub match_scale: bool,
    /// Texture-space high-frequency refinement (§3.3.2, [`super::refine`]) of targets with UVs.
    /// Default true (the paper's step); skipped by itself when the textures have fewer than 2
    /// texels per finest edge.
    pub refine: bool,
    /// Largest translation of a vertex's source point in the refinement, in finest edges.
    /// Default 0.25 (README sweep).
    #[schemars(range(min = 0.0, max = 2.0))]
    pub refine_max_translation: f64,
    /// Shared: [`SharedParams::weld_tolerance`].
    pub weld_tolerance: f32,
}

impl Default for DetailParams {
    fn default() -> Self {
        let synthesis = SynthesisParams::default();
        let pipeline = PipelineParams::default();
        Self {
            levels: 4,
            finest_edge_length: None,
            max_faces: 200_000,
            base_smoothing: 0.02,
            max_displacement: 0.05,
            metric: MetricChoice::Learned,
            lambda: super::metric::DEFAULT_LAMBDA,
            lambda_relative: true,
            metric_samples: pipeline.metric_samples,
            feature_vertices: pipeline.feature_vertices,
            patch_size: synthesis.initial_patch_size,
            candidates: synthesis.candidates,
            source_samples: synthesis.source_samples,
            max_reach: synthesis.max_reach,
            match_scale: true,
            refine: true,
            refine_max_translation: RefineParams::default().max_translation,
            weld_tolerance: SharedParams::default().weld_tolerance,
        }
    }
}

impl DetailParams {
    /// Reads and range-checks the parameters from the constraints' `params`.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        crate::engine::methods::params::parse(c)
    }

    /// The refinement's settings.
    pub fn refine_params(&self) -> RefineParams {
        RefineParams {
            enabled: self.refine,
            max_translation: self.refine_max_translation,
            ..RefineParams::default()
        }
    }

    /// The pipeline's settings for a source of diagonal `source_diagonal` and a target of
    /// diagonal `target_diagonal` (world units).
    pub fn pipeline(&self, source_diagonal: f64, target_diagonal: f64) -> PipelineParams {
        let d = PipelineParams::default();
        PipelineParams {
            base: BaseParams {
                sigma: Some(self.base_smoothing as f64 * source_diagonal),
                ..BaseParams::default()
            },
            hierarchy: HierarchyParams {
                levels: self.levels,
                finest_edge_length: self.finest_edge_length.map(|f| f as f64 * target_diagonal),
                max_faces: self.max_faces,
                ..HierarchyParams::default()
            },
            displacement: DisplacementParams {
                max_distance: Some(self.max_displacement as f64 * source_diagonal),
            },
            patches: PatchParams::default(),
            metric_kind: match self.metric {
                MetricChoice::Learned => MetricKind::Learned,
                MetricChoice::Identity => MetricKind::Identity,
            },
            metric: MetricParams {
                lambda: self.lambda,
                ..MetricParams::default()
            },
            metric_samples: self.metric_samples,
            feature_vertices: self.feature_vertices,
            lambda_relative: self.lambda_relative,
            synthesis: SynthesisParams {
                initial_patch_size: self.patch_size,
                candidates: self.candidates,
                source_samples: self.source_samples,
                max_reach: self.max_reach,
                ..SynthesisParams::default()
            },
            ..d
        }
    }
}
