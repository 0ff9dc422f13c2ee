//! Parameters of the `pattern` method (Soler, Cani, Angelidis, *Hierarchical Pattern Mapping*,
//! SIGGRAPH 2002): the `params` object of the constraints.
//!
//! Constants the paper does not publish are retex's choice and are stated on their field: the
//! default `scale` (a quarter of the target's bounding-box diagonal per image width, so a pattern
//! repeats about four times across the model), the children per split (4, the paper's figures show
//! about that many), the flatness and fitting thresholds (the paper gives none; chosen on the
//! sphere / folded-sheet / real-mesh sweep written in the README).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::methods::shared_params::SharedParams;

/// Default `scale` as a fraction of the target's bounding-box diagonal.
pub const DEFAULT_SCALE_FRACTION: f32 = 0.25;

/// A triangle of the target: index into the asset's primitives (in the order of the glTF meshes
/// and their primitives) and the triangle within that primitive.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct FaceRef {
    /// Index into the target's primitives (glTF meshes in order, then their primitives).
    /// Default 0.
    pub primitive: usize,
    /// Triangle of that primitive (after strip/fan conversion). Default 0.
    pub triangle: usize,
}

/// Parameters of the `pattern` method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
#[schemars(transform = crate::engine::methods::shared_params::shared_fields)]
pub struct PatternParams {
    /// World units covered by one image width. Default: a quarter of the target's bounding-box
    /// diagonal.
    #[schemars(extend("exclusiveMinimum" = 0))]
    pub scale: Option<f32>,
    /// Whether the pattern tiles (REPEAT sampler; otherwise every UV stays inside the image and
    /// the sampler is CLAMP_TO_EDGE). Default true.
    pub toroidal: bool,
    /// Rotation of the pattern on the first patch, degrees counter-clockwise from the target's
    /// up axis (+y) projected onto the surface pointing to the image's top (§2.2). Default 0.
    #[schemars(range(min = -360, max = 360))]
    pub orientation_deg: f32,
    /// The face whose cluster is textured first (§2.2: the first patch sets the global
    /// orientation). Default: the face nearest the centre of the largest flat-enough cluster.
    pub first_face: Option<FaceRef>,
    /// A cluster whose best fit (mean squared colour error per mask pixel, divided by that of
    /// two random pattern pixels) is above this is split (§2.2). Default 0.35.
    #[schemars(range(min = 0, max = 10))]
    pub fit_threshold: f32,
    /// A cluster whose flattening error E_flat (area-weighted mean of |surface/texture area
    /// ratio − 1| per face) is above this is split (§3.2). Default 0.1.
    #[schemars(range(min = 0, max = 10))]
    pub flatness_threshold: f32,
    /// Width of a textured neighbour's band used as the mask, as a fraction of the neighbour's
    /// largest distance from the shared border (§4.1). Default 0.2 (paper).
    #[schemars(range(min = 0.01, max = 1))]
    pub band: f32,
    /// Pattern orientations tried by the FFT fit, over 360° (§4.2). Default 19 (paper).
    #[schemars(range(min = 1, max = 72))]
    pub orientations: usize,
    /// Sub-clusters per split (§3.1; the paper gives no number). Default 4.
    #[schemars(range(min = 2, max = 16))]
    pub children: usize,
    /// Shared: [`SharedParams::weld_tolerance`].
    pub weld_tolerance: f32,
}

impl Default for PatternParams {
    fn default() -> Self {
        Self {
            scale: None,
            toroidal: true,
            orientation_deg: 0.0,
            first_face: None,
            fit_threshold: 0.35,
            flatness_threshold: 0.1,
            band: 0.2,
            orientations: 19,
            children: 4,
            weld_tolerance: SharedParams::default().weld_tolerance,
        }
    }
}

impl PatternParams {
    /// Reads and range-checks the parameters from the constraints' `params`, and what a schema
    /// cannot say: `scale` is finite and positive.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        let p: PatternParams = crate::engine::methods::params::parse(c)?;
        p.validate()?;
        Ok(p)
    }

    /// The checks a schema cannot express (see [`Self::from_constraints`]).
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn validate(&self) -> Result<(), ConstraintsError> {
        if let Some(s) = self.scale {
            if !(s.is_finite() && s > 0.0) {
                return Err(ConstraintsError::new(
                    "params.scale",
                    format!("{s} is outside the range a finite number > 0"),
                ));
            }
        }
        for (name, v) in [
            ("orientation_deg", self.orientation_deg),
            ("fit_threshold", self.fit_threshold),
            ("flatness_threshold", self.flatness_threshold),
            ("band", self.band),
        ] {
            if !v.is_finite() {
                return Err(ConstraintsError::new(
                    format!("params.{name}"),
                    format!("{v} is not a finite number"),
                ));
            }
        }
        Ok(())
    }

    /// The scale in world units per image width for a target of bounding-box diagonal
    /// `diagonal`.
    pub fn scale_for(&self, diagonal: f32) -> f32 {
        self.scale
            .unwrap_or(DEFAULT_SCALE_FRACTION * diagonal)
            .max(f32::MIN_POSITIVE)
    }
}
