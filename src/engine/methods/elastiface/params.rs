//! Parameters of the `elastiface` method (the `params` object of the constraints).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::methods::shared_params::SharedParams;

/// What the output asset holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum OutputMode {
    /// POSITION holds the fitted shape (in the target's world placement).
    #[default]
    Positions,
    /// POSITION is kept; a morph target `elastiface` holds the displacement in the source's frame.
    MorphTarget,
}

/// Parameters of the `elastiface` method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
#[schemars(transform = crate::engine::methods::shared_params::shared_fields)]
pub struct ElastifaceParams {
    /// Joint fairing smoothness weight λ1 (§3.2). Default 0.1; 10 for extreme shapes that do not
    /// unfold.
    #[schemars(range(max = 1000), extend("exclusiveMinimum" = 0))]
    pub lambda_smooth: f64,
    /// Joint fairing weight λ2 making corresponding reference points coincide. Default 100.
    #[schemars(range(max = 100000), extend("exclusiveMinimum" = 0))]
    pub lambda_coincide: f64,
    /// Joint fairing weight λ3 keeping reference points near their mean start position.
    /// Default 1.
    #[schemars(range(max = 100000), extend("exclusiveMinimum" = 0))]
    pub lambda_position: f64,
    /// Joint fairing iterations (Voronoi area updates). Default 5.
    #[schemars(range(min = 1, max = 50))]
    pub fairing_iterations: usize,
    /// Closest-point updates per stiffness level of the base-mesh registration (3 levels).
    /// Default 3.
    #[schemars(range(min = 1, max = 20))]
    pub registration_iterations: usize,
    /// Solves of the registration of the originals. Default 2.
    #[schemars(range(min = 1, max = 10))]
    pub original_iterations: usize,
    /// The target's bounding-box diagonal is scaled to this many units before solving (and the
    /// result scaled back), so that the weights mean what they mean in the paper whatever the
    /// model units. Default 50.
    #[schemars(range(min = 1, max = 10000))]
    pub reference_diagonal: f64,
    /// `positions` (default) or `morph_target`.
    pub output: OutputMode,
    /// Shared: [`SharedParams::vertex_color_samples`] (unused: colour is written on the
    /// source's own vertices).
    pub vertex_color_samples: usize,
    /// Shared: [`SharedParams::snap_tolerance`].
    pub snap_tolerance: f32,
    /// Shared: [`SharedParams::weld_tolerance`].
    pub weld_tolerance: f32,
}

impl Default for ElastifaceParams {
    fn default() -> Self {
        let shared = SharedParams::default();
        Self {
            lambda_smooth: 0.1,
            lambda_coincide: 100.0,
            lambda_position: 1.0,
            fairing_iterations: 5,
            registration_iterations: 3,
            original_iterations: 2,
            reference_diagonal: 50.0,
            output: OutputMode::Positions,
            vertex_color_samples: shared.vertex_color_samples,
            snap_tolerance: shared.snap_tolerance,
            weld_tolerance: shared.weld_tolerance,
        }
    }
}

impl ElastifaceParams {
    /// Reads and range-checks the parameters from the constraints' `params`.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        crate::engine::methods::params::parse(c)
    }
}
