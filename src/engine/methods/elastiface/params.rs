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

/// The morphing of §5 ([`super::blend`]): template and fitted result blended by `weight`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BlendParams {
    /// Blend weight w: 0 gives the template back, 1 the fitted head with its re-laid texture.
    #[schemars(range(min = 0, max = 1))]
    pub weight: f64,
    /// The part of the template that is blended ([`super::region`]): `{"channel": "r"}` (a
    /// COLOR_0 channel of the source, per-vertex weight in [0, 1]) or a list of source face
    /// indices (the source's triangles numbered across its primitives in order). Absent: the
    /// whole head, blended linearly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region: Option<Region>,
    /// A face-list region's weight ramps up over this many vertex rings inside its border
    /// (border ring 1/(n+1), ..., 1 from ring n on). Default 2: with 0 every region vertex has
    /// weight 1 and the shape creases along the border (README "elastiface" has the sweep).
    #[serde(default = "default_feather_rings")]
    #[schemars(range(max = 20))]
    pub feather_rings: usize,
    /// At most this many texels of one texture in the region's gradient-domain solve (its
    /// sparse Cholesky factor grows faster than the texel count); a larger region is refused.
    /// Default 1,048,576 (README "elastiface" has the measured time and memory).
    #[serde(default = "default_max_region_texels")]
    #[schemars(range(min = 1, max = 16777216))]
    pub max_region_texels: usize,
}

fn default_feather_rings() -> usize {
    2
}

fn default_max_region_texels() -> usize {
    1 << 20
}

/// A COLOR_0 channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Red.
    R,
    /// Green.
    G,
    /// Blue.
    B,
    /// Alpha.
    A,
}

impl Channel {
    /// Index into an RGBA colour.
    pub fn index(self) -> usize {
        match self {
            Channel::R => 0,
            Channel::G => 1,
            Channel::B => 2,
            Channel::A => 3,
        }
    }
}

/// The region of a part-based blend (§5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Region {
    /// A COLOR_0 channel of the source: its value (clamped to [0, 1]) is the vertex weight.
    Channel {
        /// `r`, `g`, `b` or `a`.
        channel: Channel,
    },
    /// Source face indices: weight 1 on their vertices (feathered), 0 elsewhere.
    Faces(Vec<u32>),
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
    /// Closest-point solves per stiffness level of the registration of the originals, after its
    /// first solve on the carried points (`register`'s originals stage). Default 2.
    #[schemars(range(min = 1, max = 10))]
    pub original_iterations: usize,
    /// Stiffness levels of the registration of the originals: bending 3, 1, 0.3, 0.1 for the
    /// default 4, the last ones of that 1-3-10 series for fewer (1: the paper's 0.1 alone).
    /// Default 4 (README "elastiface" has the sweep).
    #[schemars(range(min = 1, max = 6))]
    pub original_stiffness_levels: usize,
    /// Weight of the backward fitting term of the registration of the originals (each target
    /// vertex pulls its closest point on the fitted source; not in the paper). Default 300, the
    /// forward fitting weight; 0 with `original_stiffness_levels = 1` and
    /// `original_iterations = 1` is the paper's stage.
    #[schemars(range(min = 0, max = 100000))]
    pub backward_weight: f64,
    /// A backward pair is dropped when its distance exceeds this fraction of the target's
    /// diagonal. Default 0.1.
    #[schemars(range(max = 1), extend("exclusiveMinimum" = 0))]
    pub backward_max_distance: f64,
    /// A backward pair is dropped when the cosine between the source triangle's normal and the
    /// target vertex's normal is below this. Default 0.5.
    #[schemars(range(min = -1, max = 1))]
    pub backward_min_cos: f64,
    /// In the registration of the originals, the vertices of a source boundary loop that
    /// correspondences pair with a target loop fit onto that target loop (its closest point on
    /// the loop) instead of onto the target surface (not in the paper; README "elastiface").
    /// Default true.
    pub boundary_to_boundary: bool,
    /// Template vertices whose ambient visibility (visible solid angle over 2π, 64 rays) is
    /// below this are free in the registration of the originals: not pulled to the target,
    /// they follow their fitted neighbours by bending (hidden cavities such as a mouth bag or
    /// eye sockets; Wrap's "free polygons"; not in the paper). Default 0 (off); 0.1 frees the
    /// mouth and eye cavities of the Lee Perry-Smith scan (README "elastiface").
    #[schemars(range(min = 0, max = 1))]
    pub free_visibility: f64,
    /// The target's bounding-box diagonal is scaled to this many units before solving (and the
    /// result scaled back), so that the weights mean what they mean in the paper whatever the
    /// model units. Default 50.
    #[schemars(range(min = 1, max = 10000))]
    pub reference_diagonal: f64,
    /// `positions` (default) or `morph_target`.
    pub output: OutputMode,
    /// Morphing (§5): `{"weight": w}` blends positions and base colour linearly between the
    /// template (w = 0) and the fitted result (w = 1). With `output = "morph_target"` the weight
    /// is the morph target's default weight. Absent: the fitted result (w = 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blend: Option<BlendParams>,
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
            original_stiffness_levels: 4,
            backward_weight: 300.0,
            backward_max_distance: 0.1,
            backward_min_cos: 0.5,
            boundary_to_boundary: true,
            free_visibility: 0.0,
            reference_diagonal: 50.0,
            output: OutputMode::Positions,
            blend: None,
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
        let params: Self = crate::engine::methods::params::parse(c)?;
        if let Some(blend) = &params.blend {
            if !blend.weight.is_finite() {
                return Err(ConstraintsError::new(
                    "params.blend.weight",
                    "must be a number in [0, 1]",
                ));
            }
            if matches!(&blend.region, Some(Region::Faces(f)) if f.is_empty()) {
                return Err(ConstraintsError::new(
                    "params.blend.region",
                    "the face list is empty: give at least one source face index",
                ));
            }
        }
        Ok(params)
    }

    /// The blend weight in effect: `None` for no blend or w = 1 (the fitted result as is), as
    /// long as no region is given (a region blend always runs).
    pub fn blend_weight(&self) -> Option<f64> {
        self.blend
            .as_ref()
            .filter(|b| b.region.is_none())
            .map(|b| b.weight)
            .filter(|&w| w != 1.0)
    }

    /// The blend parameters when a region is given.
    pub fn region_blend(&self) -> Option<(&BlendParams, &Region)> {
        let b = self.blend.as_ref()?;
        Some((b, b.region.as_ref()?))
    }
}
