//! Parameters of the `correlation` method (Mertens, Kautz, Chen, Bekaert, Durand, *Texture
//! Transfer Using Geometry Correlation*, EGSR 2006): the `params` object of the constraints.
//!
//! Constants the paper does not publish are retex's choice and are stated on their field: the
//! four curvature radii, the ray counts, the number of nearest source clusters a target cluster
//! blends, the surface sample count (the paper's 512,000 is allowed; the default is a quarter of
//! it so that a transfer runs in well under a minute on two cores).
//!
//! The non-parametric variant (§5.1) takes `synthesis = "nonparametric"` and its
//! `nonparametric` options (neighbourhood, coherence κ, feature weight); its search passes per
//! level are `iterations`.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::methods::meshmatch::example::Channel;
use crate::engine::methods::shared_params::SharedParams;

/// Largest `samples`.
pub const MAX_SAMPLES: usize = 1_048_576;

/// Which synthesis runs on the guidance (§5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Synthesis {
    /// Per-cluster histograms and regressions (§5.2). Default.
    #[default]
    Parametric,
    /// Image analogies on the surface with Ashikhmin coherence (§5.1).
    Nonparametric,
}

/// How the target's guidance is matched to the source's (§4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum FeatureMatching {
    /// The target's guidance is used as it is.
    Off,
    /// n-D histogram matching of the guidance values (§4.1).
    Marginals,
    /// Matching of each Laplacian band of the guidance, then of the values (§4.2). Default.
    #[default]
    Multiscale,
}

/// How the 12-D features are reduced to the guidance (§3.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Reduction {
    /// Canonical correlation analysis with the source colour. Default.
    #[default]
    Cca,
    /// The top three principal components of the raw features (the paper's Fig. 5/6 baseline).
    Pca,
}

/// A mask that removes source regions from training: a COLOR_0 channel, or an image of the
/// source read through the base-colour UVs. A sample is removed where the value is above the
/// threshold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum SourceMask {
    /// A COLOR_0 channel of the source above a threshold.
    VertexColor {
        /// The channel.
        channel: Channel,
        /// Removed where the value is above this.
        #[schemars(range(min = 0, max = 1))]
        threshold: f32,
    },
    /// An image of the source (index into its glTF `images`) through the base-colour UVs;
    /// colour channels are compared in linear space, alpha as stored.
    Image {
        /// Index into the glTF `images`.
        index: usize,
        /// The channel.
        channel: Channel,
        /// Removed where the value is above this.
        #[schemars(range(min = 0, max = 1))]
        threshold: f32,
    },
}

/// Options of the non-parametric synthesis (§5.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct NonparametricParams {
    /// Neighbourhood size in samples across, odd (the paper's 5×5): geodesic fans of
    /// `(neighbourhood − 1)/2` rings of 8 spokes plus the centre. Default 5.
    #[schemars(range(min = 3, max = 15))]
    pub neighbourhood: usize,
    /// Ashikhmin coherence κ. Default 1 (paper).
    #[schemars(range(min = 0, max = 100))]
    pub coherence: f32,
    /// Weight `w` of the guidance against the colour in the neighbourhood distance, both
    /// normalised for dimension and variance: `(1 − w)·colour + w·guidance`, so 0.5 is the
    /// paper's equal weights (§5.1 text). Default 0.8 (the paper's Fig. 11), chosen from the
    /// README's sweep (two procedural cases × seeds 1-3 at 0.3, 0.5, 0.8, 1.0): 0.8 follows the
    /// geometry better than 0.5 in every run (correlation with the dirt term 0.917-0.969 of the
    /// source's own against 0.888-0.955), while 1.0 adds at most 0.014 and shrinks the coherent
    /// patches by a further 19-52 %.
    #[schemars(range(min = 0, max = 1))]
    pub feature_weight: f32,
}

impl Default for NonparametricParams {
    fn default() -> Self {
        Self {
            neighbourhood: 5,
            coherence: 1.0,
            feature_weight: 0.8,
        }
    }
}

/// Parameters of the `correlation` method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
#[schemars(transform = crate::engine::methods::shared_params::shared_fields)]
pub struct CorrelationParams {
    /// `parametric` (default, §5.2) or `nonparametric` (§5.1).
    pub synthesis: Synthesis,
    /// `off`, `marginals` or `multiscale` (default, §4).
    pub feature_matching: FeatureMatching,
    /// `cca` (default) or `pca` (§3.3).
    pub reduction: Reduction,
    /// Surface samples of each model (§3.1; the paper used 512,000). Default 131,072.
    #[schemars(range(min = 1024, max = MAX_SAMPLES))]
    pub samples: usize,
    /// k-means clusters on each model's guidance (§5.2). Default 50 (paper).
    #[schemars(range(min = 1, max = 1000))]
    pub clusters: usize,
    /// Source clusters a target cluster interpolates its statistics from, by reciprocal squared
    /// distance (§5.2; the paper does not give k). Default 4.
    #[schemars(range(min = 1, max = 64))]
    pub nearest_clusters: usize,
    /// Levels of the surface pyramid (§3.1, §5.2). Default 3 (paper).
    #[schemars(range(min = 1, max = 8))]
    pub pyramid_levels: usize,
    /// Heeger-Bergen iterations of the parametric synthesis (§5.2; default 3, the paper's), and
    /// the search passes per level of the non-parametric one (§5.1; at least 1 is used).
    #[schemars(range(min = 0, max = 20))]
    pub iterations: usize,
    /// Amplitude (standard deviation, in linear colour) of the white noise added to the
    /// regression's initialisation. Default: the regression's residual spread per cluster.
    #[schemars(range(min = 0, max = 1))]
    pub noise: Option<f32>,
    /// Up axis in object space for the height feature (glTF is y-up). Default `[0, 1, 0]`.
    pub up: [f32; 3],
    /// The four solid-angle curvature radii as fractions of the bounding-box diagonal (§3.2; the
    /// paper does not publish them). Default `[0.0125, 0.025, 0.05, 0.1]`: doubling from the
    /// scale of creases to that of whole limbs.
    pub curvature_radii: [f32; 4],
    /// Rays per vertex for the curvature and for the occlusion each (the paper computes the
    /// solid angle analytically and does not give an occlusion ray count). Default 128: the
    /// per-vertex quadrature error is about 1/128 of the range, below the spread the samples'
    /// interpolation leaves.
    #[schemars(range(min = 16, max = 1024))]
    pub feature_rays: usize,
    /// Source regions removed from training. Default none.
    pub mask: Option<SourceMask>,
    /// Options of the non-parametric synthesis.
    pub nonparametric: NonparametricParams,
    /// Also write the debug files `guidance.glb` (the target's guidance as colours, the paper's
    /// Fig. 8 bottom) and `segmentation.glb` (its k-means clusters, Fig. 9a), baked like the
    /// output. Default false.
    pub debug: bool,
    /// Shared: [`SharedParams::vertex_color_samples`].
    pub vertex_color_samples: usize,
    /// Shared: [`SharedParams::weld_tolerance`].
    pub weld_tolerance: f32,
}

impl Default for CorrelationParams {
    fn default() -> Self {
        let shared = SharedParams::default();
        Self {
            synthesis: Synthesis::Parametric,
            feature_matching: FeatureMatching::Multiscale,
            reduction: Reduction::Cca,
            samples: 131_072,
            clusters: 50,
            nearest_clusters: 4,
            pyramid_levels: 3,
            iterations: 3,
            noise: None,
            up: [0.0, 1.0, 0.0],
            curvature_radii: [0.0125, 0.025, 0.05, 0.1],
            feature_rays: 128,
            mask: None,
            nonparametric: NonparametricParams::default(),
            debug: false,
            vertex_color_samples: shared.vertex_color_samples,
            weld_tolerance: shared.weld_tolerance,
        }
    }
}

impl CorrelationParams {
    /// Reads and range-checks the parameters from the constraints' `params`, and what a schema
    /// cannot say: `up` is a finite non-zero vector, the radii lie in (0, 2], the
    /// neighbourhood is odd.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        let p: CorrelationParams = crate::engine::methods::params::parse(c)?;
        p.validate()?;
        Ok(p)
    }

    /// The checks a schema cannot express (see [`Self::from_constraints`]).
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<field>`.
    pub fn validate(&self) -> Result<(), ConstraintsError> {
        let up = self.up;
        if !(up.iter().all(|x| x.is_finite()) && up.iter().any(|x| *x != 0.0)) {
            return Err(ConstraintsError::new(
                "params.up",
                format!("up {up:?} is outside the range a finite non-zero vector"),
            ));
        }
        for (i, r) in self.curvature_radii.iter().enumerate() {
            if !(*r > 0.0 && *r <= 2.0) {
                return Err(ConstraintsError::new(
                    format!("params.curvature_radii[{i}]"),
                    format!("{r} is outside the range (0, 2]"),
                ));
            }
        }
        let n = self.nonparametric.neighbourhood;
        if n.is_multiple_of(2) {
            return Err(ConstraintsError::new(
                "params.nonparametric.neighbourhood",
                format!("{n} is outside the range odd numbers 3..=15"),
            ));
        }
        Ok(())
    }

    /// The unit up axis.
    pub fn up_unit(&self) -> [f32; 3] {
        let n = self.up.iter().map(|x| x * x).sum::<f32>().sqrt();
        self.up.map(|x| x / n)
    }
}
