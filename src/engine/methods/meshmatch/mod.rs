//! The `meshmatch` method: non-parametric texture transfer with PatchMatch on meshes (Chen,
//! Funkhouser, Goldman, Shechtman, *Non-parametric Texture Transfer Using MeshMatch*, 2012).
//!
//! The target's colour is synthesized so that every patch of it looks like some patch of the
//! source with similar shape features, instead of being mapped one to one: stretched regions get
//! more texture, repeated parts get repeated texture.
//!
//! - [`sampling`]: the synthesis meshes, both meshes resampled to the requested density; source
//!   colours on vertices.
//! - [`levels`]: hierarchies (§4) with frames, 1-rings, BVHs; fields moved between levels.
//! - [`features`]: shape features (§4.1): HKS + up, geodesic affinities to correspondences.
//! - [`matcher`]: patch dissimilarity (eq. 2), propagation and random search (§4.2 E-step).
//! - [`vote`]: Gaussian voting (§4.2 M-step, Figure 5) and nearest-neighbour reconstruction.
//! - [`fidelity`]: coherence, source self-match and completeness of a result.
//! - [`upsample`]: the field carried to the finer level (§4.2, Figure 6).
//! - [`em`]: [`em::synthesize`], the coarse-to-fine EM on two synthesis meshes: hierarchies,
//!   features, normalization.
//! - `coarse_to_fine`: its per-level loop (field initialization or upsampling, EM iterations,
//!   the final reconstruction).
//! - [`vote_schedule`]: the vote's σ per level and histogram strength; [`histogram`]: the
//!   histogram-matching bias; [`scale`]: the source's scale factor; `fine_histogram`: the
//!   E-step's cost on the source's finest colours (ours, default in plain transfers).
//! - [`example`]: the by-example mask (§5.3).
//! - [`update`]: texture update (§5.3, Figure 10): the copied region of an edited target.
//! - [`run`]: glTF in, glTF out (bake through [`super::color_output`]), the NNF artifact.

mod coarse_to_fine;
pub mod em;
pub mod example;
pub mod features;
pub mod fidelity;
mod fine_histogram;
pub mod histogram;
pub mod levels;
pub mod matcher;
pub mod nnf_file;
pub mod region_flip;
pub mod run;
pub mod sampling;
pub mod scale;
pub mod update;
pub mod upsample;
pub mod vote;
pub mod vote_schedule;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// `fine_histogram_cost` in a plain transfer (README "Finest-colour histogram cost").
pub const DEFAULT_FINE_HISTOGRAM_COST: f32 = 0.3;

/// `coarsest_restart_deviation`: ln 2.5 (README "Restarts on a deviation").
pub const DEFAULT_RESTART_DEVIATION: f32 = 0.916;

/// Starts of the coarsest level when its first start deviates (`coarsest_restart_deviation`):
/// the number the sweep of `coarsest_restarts` chose (README "Coarsest restarts").
pub const DEVIATION_RESTARTS: usize = 4;

use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::control::Cancelled;

use features::{AffinityParams, AutomaticFeatureParams};

pub use example::ExampleMask;
pub use run::run;
pub use update::UpdateParams;

use super::shared_params::SharedParams;
use super::{InputSpec, Method, MethodError, MethodInput, MethodOutput, ResultFile, WorkingSet};
use crate::engine::asset::constraints::MethodId;
use crate::engine::control::Control;

/// The `meshmatch` method (registry entry).
pub struct MeshMatch;

impl Method for MeshMatch {
    fn id(&self) -> MethodId {
        MethodId::Meshmatch
    }

    fn inputs(&self) -> InputSpec {
        InputSpec::SOURCE_AND_TARGET
    }

    fn params_schema(&self) -> serde_json::Value {
        super::params::schema_of::<MeshMatchParams>()
    }

    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError> {
        MeshMatchParams::from_constraints(constraints).map(drop)
    }

    fn extra_images(&self, constraints: &Constraints) -> Vec<(&'static str, usize)> {
        let Ok(p) = MeshMatchParams::from_constraints(constraints) else {
            return Vec::new();
        };
        let copy = p.update.and_then(|u| u.copy);
        match p.example.or(copy) {
            Some(ExampleMask::Image { index, .. }) => vec![("target", index)],
            _ => Vec::new(),
        }
    }

    fn working_set(&self, constraints: &Constraints, input_triangles: u64) -> Option<WorkingSet> {
        let params = MeshMatchParams::from_constraints(constraints).ok()?;
        let texture = super::texture_working_set(constraints);
        let synthesis = params.working_set_bytes();
        let inputs = input_triangles.saturating_mul(INPUT_TRIANGLE_BYTES);
        let atlas = super::atlas_working_set(constraints, input_triangles);
        let field = if atlas > inputs.max(synthesis).max(texture.bytes) {
            "output.uv"
        } else if inputs > synthesis.max(texture.bytes) {
            "inputs"
        } else if synthesis >= texture.bytes {
            "params.samples"
        } else {
            texture.field
        };
        Some(WorkingSet {
            bytes: synthesis
                .saturating_add(texture.bytes)
                .saturating_add(inputs)
                .saturating_add(atlas),
            field,
        })
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let params = MeshMatchParams::from_constraints(input.constraints)?;
        let (edits, report, nnf) = run(
            input.source()?,
            input.target,
            input.constraints,
            &params,
            control,
        )
        .map_err(MethodError::from)?;
        let mut out = MethodOutput::target(edits, &report);
        out.warnings = report.warnings;
        if let Some(bytes) = nnf {
            out.files.push(ResultFile {
                name: "nnf.bin".into(),
                media_type: "application/octet-stream".into(),
                bytes,
            });
        }
        Ok(out)
    }
}

impl From<MeshMatchError> for MethodError {
    fn from(e: MeshMatchError) -> Self {
        if e.is_cancelled() {
            return MethodError::Cancelled;
        }
        match e {
            MeshMatchError::Param { name, message } => {
                MethodError::Constraints(ConstraintsError::new(format!("params.{name}"), message))
            }
            MeshMatchError::Constraints(c) => MethodError::Constraints(c),
            MeshMatchError::Mesh { side, source } => MethodError::Mesh { side, source },
            e @ (MeshMatchError::Hierarchy(_)
            | MeshMatchError::Resample(_)
            | MeshMatchError::Features(_)) => MethodError::UnusableInput {
                field: None,
                kind: "unusable-mesh",
                message: format!("a mesh cannot be prepared for matching: {e}"),
            },
            other => MethodError::Internal(format!("meshmatch: {other}")),
        }
    }
}

/// Largest synthesis mesh (memory: about 3 KiB per vertex and mesh for fans, charts and levels
/// at the default fans; see [`MeshMatchParams::working_set_bytes`]).
pub const MAX_SAMPLES: usize = 262_144;

/// Bytes per synthesis vertex and mesh besides the fans (levels, frames, charts, BVH, features,
/// the field and its matches).
const VERTEX_BYTES: u64 = 1280;
/// Bytes per instanced triangle of the inputs while they are resampled to the synthesis meshes
/// (beyond the surfaces every method builds). Measured: `samples` 4096 on a 2,000,000-triangle
/// grid onto itself peaks 9.6 GB, 9.2 GB above the same job on 125,000 triangles (2.45 KB per
/// added triangle, of which about 400 bytes are the surfaces and BVHs of any method).
const INPUT_TRIANGLE_BYTES: u64 = 2048;
/// Bytes per fan sample (ring × spoke) of a synthesis vertex: its colour in the source and
/// target fans and its chart position.
const FAN_SAMPLE_BYTES: u64 = 32;
/// Filter weights kept per target fan sample, per squared `fan_radius` (the filter's reach is
/// half the fan radius, so the weights grow with its square): measured about 10 per sample at
/// the default radius 3 on Spot at 64K (peak 628 MiB against 357 MiB without them); 1.25 leaves
/// room for irregular meshes. Each weight is 8 bytes, plus a 4-byte offset per sample; at most
/// [`em::MAX_CHART_VERTICES`] weights per sample.
const FAN_WEIGHTS_PER_SQUARED_RADIUS: f64 = 1.25;

/// Which shape features describe a patch's place on the shape (§4.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ShapeFeatures {
    /// Geodesic affinities when correspondences are given, HKS + up otherwise. Default.
    #[default]
    Auto,
    /// HKS + up only.
    Automatic,
    /// Geodesic affinities only (needs correspondences).
    Affinity,
    /// Both, concatenated.
    Both,
    /// Colour fans only.
    None,
}

/// How the two meshes' sizes relate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ScaleMode {
    /// The smaller of `match_extents` and `match_area`: a stretch along one axis keeps the
    /// pattern's size, and a target slenderer than the source does not get oversized features.
    /// Default.
    #[default]
    Auto,
    /// Scale the source by the median, over the principal axes, of the target's extent over
    /// the source's (a stretch along one axis keeps the pattern's size; a uniformly larger
    /// model gets a larger pattern).
    MatchExtents,
    /// Scale the source so both surfaces have the same area (texture features keep their size
    /// relative to the whole model).
    MatchArea,
    /// Keep world units (texture features keep their absolute size).
    World,
}

/// Parameters of `meshmatch` (the `params` object of the constraints).
// Ranges are on the fields and checked through the derived schema (`super::params`), nested
// structs included; the shared options' doc, default and range come from `SharedParams`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
#[schemars(transform = super::shared_params::shared_fields)]
pub struct MeshMatchParams {
    /// Vertices of the target synthesis mesh. Default 65,536 (the paper's 64K); memory grows
    /// about 3 KiB per vertex and mesh.
    #[schemars(range(min = 256, max = MAX_SAMPLES))]
    pub samples: usize,
    /// Vertices of the source synthesis mesh. Default: the target's density (same vertices per
    /// unit area after scaling), at most 4 × `samples` and 262,144.
    #[schemars(range(min = 256, max = MAX_SAMPLES))]
    pub source_samples: Option<usize>,
    /// Relative size of the meshes. Default `auto`.
    pub scale: ScaleMode,
    /// Vertices of the coarsest level. Default 128 (paper).
    #[schemars(range(min = 16, max = 100_000))]
    pub min_vertices: usize,
    /// EM iterations per level. Default 5 (paper).
    #[schemars(range(min = 1, max = 100))]
    pub iterations: usize,
    /// A level stops early when fewer than this fraction of matches changed in an iteration.
    /// Default 0.01.
    #[schemars(range(min = 0, max = 1))]
    pub convergence: f32,
    /// Fan rings `R`. Default 3 (paper).
    #[schemars(range(min = 1, max = 8))]
    pub rings: usize,
    /// Fan spokes `A`. Default 18 (paper).
    #[schemars(range(min = 4, max = 64))]
    pub spokes: usize,
    /// Outer fan radius in mean edge lengths of the target level. Default 3 (the paper's fans
    /// span about three rings).
    #[schemars(range(max = 20), extend("exclusiveMinimum" = 0))]
    pub fan_radius: f32,
    /// Shape features. Default `auto`.
    pub shape_features: ShapeFeatures,
    /// HKS and up direction (the up direction also orients the fan frames).
    pub hks: AutomaticFeatureParams,
    /// Geodesic affinities.
    pub affinity: AffinityParams,
    /// Shape features are computed on the finest level with at most this many vertices and
    /// carried to the others. Default 8,000.
    #[schemars(range(min = 100, max = 1_000_000))]
    pub feature_vertices: usize,
    /// Weight of the shape block relative to colour on the coarsest level (1 = equal after
    /// normalizing for dimension and variance, the paper's §5.2 setting). Default 2: measured on
    /// the test suite, equal weights let colour win too often (Spot onto its remesh with 8
    /// correspondences: low-passed correlation with the ground truth 0.56 at 1, 0.66 at 2, 0.85
    /// at 4), while the stripe test keeps the source's stripe period up to 2 (×1.03–1.18) and
    /// starts stretching at 2.5 (×1.37).
    #[schemars(range(min = 0, max = 100))]
    pub shape_weight: f32,
    /// Shape weight on the finest level (geometric in between). Default: `shape_weight`.
    #[schemars(range(min = 0, max = 100))]
    pub finest_shape_weight: Option<f32>,
    /// Completeness weight: every match of a source vertex costs `completeness_weight × (fan
    /// dimension) × uses / expected uses` on top of its dissimilarity, so the field spreads over
    /// the source instead of piling onto its most common patches (see `em`). 0 turns it off.
    #[schemars(range(min = 0, max = 100))]
    pub completeness_weight: f32,
    /// Vote Gaussian σ as a fraction of the fan radius, on the coarsest level (on every level
    /// when `finest_vote_sigma` is not set). Default: by the shape features (module
    /// `vote_schedule`): 0.1 with HKS features alone, 0.5 with affinities or none.
    #[schemars(range(max = 10), extend("exclusiveMinimum" = 0))]
    pub vote_sigma: Option<f32>,
    /// Vote σ on the finest level (geometric in between). Default: 0.5 (with HKS features
    /// alone, when `vote_sigma` is not set), else `vote_sigma` on every level.
    #[schemars(range(max = 10), extend("exclusiveMinimum" = 0))]
    pub finest_vote_sigma: Option<f32>,
    /// Copy the matched colour at the finest level instead of voting (paper's last step).
    /// Default true.
    pub nearest_neighbor_final: bool,
    /// Search rotations around the propagated one instead of all `A` (Barnes et al. 2010).
    /// Default false (the paper's exhaustive search).
    pub randomized_rotations: bool,
    /// Region flips (module `region_flip`, ours) on every level of at most this many target
    /// vertices: each coherent region of the field smaller than half the level is re-grown from
    /// its largest neighbour and kept so when the field's energy after an EM round is lower, so
    /// that seams between equally good maps (a symmetric source's direct and mirrored copies)
    /// do not survive into the finer levels. Default 600, the two coarsest levels (256-272
    /// and 512-543 target vertices): deeper flips also remove the mirror seam on the stripe
    /// cases but shrink Spot → cat's black patches on 4 seeds of 5; 0 turns them off (README
    /// "meshmatch", region flips).
    #[schemars(range(max = 1_000_000))]
    pub region_flip_vertices: usize,
    /// Random starts of the coarsest level (module `coarse_to_fine::restarts`, ours): the
    /// coarsest level's EM runs from this many random fields and the one with the lowest final
    /// energy is kept, so that one unlucky start does not settle the whole synthesis in a poor
    /// basin. Default 1, the paper's single random start; 4 is the setting for organic pairs
    /// without correspondences, where it fixed the one miss of the real pairs' statistics, but it
    /// costs the symmetric stripe cases (README "meshmatch", coarsest restarts). A first start
    /// beyond `coarsest_restart_deviation` runs at least 4 starts whatever this is.
    #[schemars(range(min = 1, max = 64))]
    pub coarsest_restarts: usize,
    /// Restarts of the coarsest level on demand (module `coarse_to_fine::restarts`, ours): when
    /// the field of the coarsest level's first start implies, for some channel bin of the
    /// source's finest colours, a share whose log ratio to the source's own share is beyond
    /// this value (module `fine_histogram`, its deviation), the level runs `max(4,
    /// coarsest_restarts)` starts and keeps the lowest final energy. Default ln 2.5 = 0.916 (a
    /// colour at more than 2.5× or under 0.4× of its share): the first starts of the three
    /// stripe files reach at most 0.79, those of Blub's orange face 0.98-1.06 (README
    /// "Restarts on a deviation"). 0: never. Needs the finest-colour histograms (built for this
    /// alone when `fine_histogram_cost` is 0). Range: [0, 100].
    #[schemars(range(min = 0, max = 100))]
    pub coarsest_restart_deviation: f32,
    /// Weight each fan ring in the patch distance by the surface area its samples stand for
    /// (ring `i` of `R` at radius `(i + 1)·h` covers an annulus sector ∝ `i + 1`: weights
    /// `2(i + 1)/(R + 1)`, mean 1), so the distance is area-uniform over the fan's disc as the
    /// paper's surface sampling is. Default true (false: each sample counts once; see the
    /// README's sweep).
    pub fan_area_weights: bool,
    /// Histogram matching in the vote (Kopf et al. 2007 §3.3, module `histogram`): votes for
    /// colours over-represented in the target's current colours against the source's are
    /// down-weighted with this strength. Default: by the shape features (module
    /// `vote_schedule`): 4 with HKS features alone, 2 with affinities, 0 (off) without shape
    /// features and in the by-example and update modes. Range: [0, 100].
    #[schemars(range(min = 0, max = 100))]
    pub histogram_weight: Option<f32>,
    /// Histogram cost in the E-step (module `histogram`): a match of source vertex `s` costs
    /// `histogram_cost × (fan dimension) × Σ_ch max(0, H_t − H_s)·bins` at `s`'s colour on top
    /// of its dissimilarity, `H` the bin shares of the target's current colours and of the
    /// source's. Where the vote's histogram matching can only re-weight the colours that the
    /// matches offer, this makes the matches themselves move away from over-represented
    /// colours. Default 0 (off): 0.1 brings all three real pairs of the README's sweep closer to
    /// the source's statistics (Spot → cat TV 0.121 → 0.115) but makes the stripe cases' rings
    /// uneven (one capsule seed of five at ×2.06, the square bar's stretched part at ×1.35 on
    /// three). Range: [0, 100].
    #[schemars(range(min = 0, max = 100))]
    pub histogram_cost: f32,
    /// Histogram cost in the E-step on the source's finest colours (module `fine_histogram`,
    /// ours): a match of source vertex `s` costs `fine_histogram_cost × (fan dimension) ×
    /// Σ_ch Σ_b D_s · r`, `D_s` the 16-bin histogram of the finest colours under `s` and `r` the
    /// log ratio of the share the current matches imply for the target to the level's own,
    /// shrunk by ln 2 (no cost while every colour stays within 0.5-2× of the source's share).
    /// Unlike `histogram_cost` it sees on the coarse levels which source regions hold the
    /// colours that only the finest level tells apart (a cow's black patches against their grey
    /// rims). Default: 0.3 in a plain transfer, 0 (off) in the by-example and update modes,
    /// chosen by the README's sweep ("Finest-colour histogram cost"). Range: [0, 100].
    #[schemars(range(min = 0, max = 100))]
    pub fine_histogram_cost: Option<f32>,
    /// By-example mode (§5.3): which part of the target is painted. Default none.
    pub example: Option<ExampleMask>,
    /// Texture-update mode (§5.3, Figure 10): the target is an edited copy of the source; its
    /// unedited part keeps the source's texture (copied by projection) and the rest is
    /// synthesized. Default none.
    pub update: Option<UpdateParams>,
    /// Shared: [`SharedParams::vertex_color_samples`].
    pub vertex_color_samples: usize,
    /// Shared: [`SharedParams::snap_tolerance`].
    pub snap_tolerance: f32,
    /// Shared: [`SharedParams::weld_tolerance`].
    pub weld_tolerance: f32,
    /// Write the nearest-neighbour field artifact `nnf.bin`. Default true.
    pub write_nnf: bool,
    /// Measure coherence, the source self-match and completeness into the report
    /// ([`fidelity`]); costs about two more E-steps at the finest level. Default false.
    pub measure_fidelity: bool,
}

impl Default for MeshMatchParams {
    fn default() -> Self {
        let shared = SharedParams::default();
        Self {
            samples: 65_536,
            source_samples: None,
            scale: ScaleMode::Auto,
            min_vertices: 128,
            iterations: 5,
            convergence: 0.01,
            rings: 3,
            spokes: 18,
            fan_radius: 3.0,
            shape_features: ShapeFeatures::Auto,
            hks: AutomaticFeatureParams::default(),
            affinity: AffinityParams::default(),
            feature_vertices: 8_000,
            shape_weight: 2.0,
            finest_shape_weight: None,
            completeness_weight: 0.0,
            vote_sigma: None,
            finest_vote_sigma: None,
            nearest_neighbor_final: true,
            randomized_rotations: false,
            region_flip_vertices: 600,
            coarsest_restarts: 1,
            coarsest_restart_deviation: DEFAULT_RESTART_DEVIATION,
            fan_area_weights: true,
            histogram_weight: None,
            histogram_cost: 0.0,
            fine_histogram_cost: None,
            example: None,
            update: None,
            vertex_color_samples: shared.vertex_color_samples,
            snap_tolerance: shared.snap_tolerance,
            weld_tolerance: shared.weld_tolerance,
            write_nnf: true,
            measure_fidelity: false,
        }
    }
}

impl MeshMatchParams {
    /// `fine_histogram_cost` resolved: the given value, else 0.3 in a plain transfer and 0 in
    /// the by-example and update modes (whose fixed regions already hold the source's look).
    pub fn fine_histogram_strength(&self) -> f32 {
        self.fine_histogram_cost
            .unwrap_or(if self.example.is_none() && self.update.is_none() {
                DEFAULT_FINE_HISTOGRAM_COST
            } else {
                0.0
            })
    }

    /// Reads and range-checks the parameters from the constraints' `params`.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming `params.<path>` (`params.hks.eigenpairs`).
    pub fn from_constraints(c: &Constraints) -> Result<Self, ConstraintsError> {
        let p: MeshMatchParams = c.method_params()?;
        p.validate().map_err(|e| match e {
            MeshMatchError::Param { name, message } => {
                ConstraintsError::new(format!("params.{name}"), message)
            }
            MeshMatchError::Constraints(c) => c,
            other => ConstraintsError::new("params", other.to_string()),
        })?;
        Ok(p)
    }

    /// Estimated peak bytes of the synthesis: (target + source synthesis vertices) ×
    /// (1,280 + 32 × rings × spokes), plus the target's kept fan filter weights: target
    /// vertices × rings × spokes × (4 + 8 × ⌈1.25 × fan_radius²⌉). At the default fans that is
    /// about 3 KiB per vertex and mesh plus 5.4 KiB per target vertex (the 64K + 64K benchmark:
    /// 1.25 GiB estimated with the default `source_samples`, 628 MiB peak resident measured for
    /// the whole process). An unset `source_samples` counts as its largest default,
    /// 4 × `samples` up to 262,144.
    pub fn working_set_bytes(&self) -> u64 {
        let target = self.samples as u64;
        let source = self
            .source_samples
            .map_or((4 * target).min(MAX_SAMPLES as u64), |s| s as u64);
        let fan = (self.rings * self.spokes) as u64;
        let weights = (FAN_WEIGHTS_PER_SQUARED_RADIUS * (self.fan_radius as f64).powi(2))
            .ceil()
            .min(em::MAX_CHART_VERTICES as f64) as u64;
        (target + source) * (VERTEX_BYTES + FAN_SAMPLE_BYTES * fan)
            + target * fan * (4 + 8 * weights)
    }

    /// Checks every range (those of the derived schema, nested `hks`, `affinity` and `example`
    /// included) and what a schema cannot say: `hks.up` must be a finite non-zero vector.
    ///
    /// # Errors
    /// [`MeshMatchError::Constraints`] for a value out of range (path `params.<path>`),
    /// [`MeshMatchError::Param`] for `hks.up`.
    pub fn validate(&self) -> Result<(), MeshMatchError> {
        super::params::check_ranges(self).map_err(|e| MeshMatchError::Constraints(e.into()))?;
        if self.example.is_some() && self.update.is_some() {
            return Err(MeshMatchError::Param {
                name: "update",
                message: "texture update and by-example mode exclude each other: give one of `example` and `update`".into(),
            });
        }
        if let Some(up) = self.hks.up {
            if !(up.iter().all(|x| x.is_finite()) && up.iter().any(|x| *x != 0.0)) {
                return Err(MeshMatchError::Param {
                    name: "hks",
                    message: format!("up {up:?} is outside the range a finite non-zero vector"),
                });
            }
        }
        Ok(())
    }
}

/// Failures of `meshmatch`.
#[derive(Debug, thiserror::Error)]
pub enum MeshMatchError {
    /// A parameter is out of range or inconsistent.
    #[error("params.{name}: {message}")]
    Param {
        /// Field name.
        name: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The constraints are invalid (a parameter out of range, a correspondence, the example mask).
    #[error(transparent)]
    Constraints(#[from] ConstraintsError),
    /// A surface could not be built.
    #[error("{side}: {source}")]
    Mesh {
        /// "source" or "target".
        side: &'static str,
        /// The cause.
        source: crate::engine::mesh::MeshError,
    },
    /// Resampling failed.
    #[error(transparent)]
    Resample(#[from] crate::engine::multires::ResampleError),
    /// The hierarchy failed.
    #[error(transparent)]
    Hierarchy(#[from] crate::engine::multires::HierarchyError),
    /// Shape features failed.
    #[error(transparent)]
    Features(#[from] features::FeatureError),
    /// Fans failed.
    #[error(transparent)]
    Fans(#[from] crate::engine::geometry::fans::FanError),
    /// Charts failed.
    #[error(transparent)]
    Charts(#[from] crate::engine::geometry::expmap::ExpMapError),
    /// Cancelled through the Control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for MeshMatchError {
    fn from(_: Cancelled) -> Self {
        MeshMatchError::Cancelled
    }
}

impl MeshMatchError {
    /// Whether this is a cancellation (also when wrapped by a sub-step).
    pub fn is_cancelled(&self) -> bool {
        use crate::engine::geometry::expmap::ExpMapError;
        use crate::engine::geometry::fans::FanError;
        use crate::engine::multires::{HierarchyError, ResampleError};
        matches!(
            self,
            MeshMatchError::Cancelled
                | MeshMatchError::Hierarchy(HierarchyError::Cancelled)
                | MeshMatchError::Resample(ResampleError::Cancelled)
                | MeshMatchError::Fans(FanError::Cancelled)
                | MeshMatchError::Charts(ExpMapError::Cancelled)
        ) || matches!(
            self,
            MeshMatchError::Features(features::FeatureError::Cancelled(_))
        )
    }
}
