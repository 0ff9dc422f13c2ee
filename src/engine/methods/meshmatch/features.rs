//! Shape features of MeshMatch (Chen, Lai, Hsu & Funkhouser 2012, "Non-parametric texture
//! transfer using MeshMatch", section 4.1 "Patch Similarity", paragraph "Surface Features").
//!
//! Two kinds of per-vertex shape features, stored vertex-major as f32 ([`FeatureField`]):
//!
//! **Automatic** ([`automatic_features`]): the Heat Kernel Signature (Sun et al. 2009) at
//! [`AutomaticFeatureParams::hks_times`] times (paper: 8), plus one dimension `n·up`, the vertex
//! normal dotted with a prescribed up direction (paper: "positive Y"). To make the values of two
//! different meshes comparable:
//! - the spectrum is that of the surface **scaled to unit total area** (computed on the surface
//!   as given, then `λ ↦ λ·A`, `φ ↦ φ·√A`, `M ↦ M/A`, which is exactly the spectrum of the
//!   scaled surface, since the cotan Laplacian is scale-covariant and the solver's shift and mass
//!   floor are relative). The HKS of a unit-area surface is then invariant to the scale of the
//!   input. **The target is taken in the source's unit** ([`HksUnits::Common`], the default;
//!   ours, the paper does not say): MeshMatch has already scaled the source into the target's
//!   texture units, so the source is brought to unit area and the target by the *same* factor
//!   (it keeps its area relative to the source's). A part of the target that has the source's
//!   shape then has the source's signature. Each surface at its own unit area
//!   ([`HksUnits::PerShape`], the default before 2026-12-07) makes a target with more area look
//!   thinner everywhere: a capsule whose far half is stretched 2× has 1.4× the area, and at its
//!   unchanged end the largest |Δ ln HKS| to the source averages 0.214 (0.0001 in the source's
//!   unit; test `common_units_keep_the_signature_of_an_unchanged_part`); its unchanged half
//!   then matched a band near the source's far end, 1 unit of source for 1.6 of target, and its
//!   stripes came out ×1.14-1.22 wide (README "HKS units and time range"). A target
//!   with area `a > 1` in the unit needs `a·k` eigenpairs for the same truncation at `t_min`
//!   (`λ_k ≈ 4πk / a`), at most [`MAX_EIGENPAIR_FACTOR`]`·k` and [`MAX_SCALED_EIGENPAIRS`];
//! - the HKS is evaluated at a **fixed set of times** for unit area, the same on every mesh (not
//!   the per-mesh `4 ln 10 / λ` range of Sun et al., whose `λ₁` differs between shapes): `t`
//!   log-spaced in `[t_min, f·t_max]` with `t_min = 4 ln 10 / (4π k)` and `t_max = 4 ln 10 / (8π)`,
//!   `k` the number of eigenpairs ([`unit_area_hks_times`]). By Weyl's law `λ_k ≈ 4πk / A` on
//!   any surface, so `t_min` is where `e^{−λ_k t} ≈ 10⁻⁴`: the eigenpairs beyond `k` contribute
//!   about 10⁻⁴ of the heat there (the finest scale the truncated spectrum resolves); `8π` is `λ₁`
//!   of the unit-area round sphere (`l(l+1)/r²` with `4πr² = 1`), so at `t_max` heat has spread
//!   over the whole of a compact shape (global scale). `f` is
//!   [`AutomaticFeatureParams::max_time_fraction`], default 1/4 (ours): the times near `t_max`
//!   measure the distance to the shape's ends, which a stretched or differently proportioned
//!   target cannot share with the source, so they pull whole regions onto one band of the
//!   source (a stretched bar's middle all onto the source's centre) or one part onto an unrelated
//!   one (Spot's horn colour onto the cat's tail and paws). With the default `k = 100`:
//!   `t ∈ [7.33e-3, 0.0916]` (unit area), a factor 12.5;
//! - **the target's values are clamped to the source's range**, per time
//!   ([`clamp_hks_to_source`], `clamp_to_source`, default on; ours). Even a quarter of `t_max`
//!   sees the ends of a 4-unit bar: the middle of a target lengthened there lies farther from
//!   both ends than any source point, and a quadratic feature distance then pulls all of it onto
//!   the few source vertices nearest the source's centre (0.22 units wide for stripes of period
//!   0.5, measured on `nnf.bin`), which cannot hold a whole ring: the stripes swirl. Clamped, the
//!   source's extreme is an exact match and its neighbourhood a near one, so the middle copies
//!   a wider band;
//! - the raw (un-normalized) HKS of the unit-area surface is stored as its **natural logarithm**
//!   `ln HKS(x, t)`: the values of different times differ by decades (`≈ 1/(4πt)` at small `t`,
//!   `→ 1/A = 1` at large `t`), and differences of logs are relative differences, so every time
//!   contributes on the same footing. On a round sphere every column is constant.
//!
//! Feature layout: dimensions `0..hks_times` are `ln HKS` at increasing times; the last dimension
//! (when `up` is set) is `n·up/|up|` in `[−1, 1]` (0 for vertices without a normal).
//!
//! **Geodesic affinities** ([`geodesic_affinities`], the paper's equation 1) from `k` user
//! correspondences: `G_S(v)_i` is the heat-method geodesic distance ([`HeatGeodesics`]) from
//! source vertex `v` to the nearest source point of correspondence `i`, `G_T` likewise on the
//! target. An affine map `M = [A | b]` (`k × (k+1)`) takes target distance vectors to source ones
//! so that `A·G_T(t) + b = G_S(s)` at every correspondence (each (source point, target point)
//! combination of a pair is one set of `k` equations, so one-to-many pairs are allowed). The
//! system is usually under-determined (`k` pairs give `k²` equations for `k² + k` unknowns); we
//! take the solution nearest to the scale-matched identity:
//! - distances are first divided by each surface's largest distance
//!   `D = max_{i,v} G_i(v)` (`g = G / D`), which makes the problem unit free;
//! - in these units the solution minimizes `‖[A − I | b]‖_F` subject to the constraints (least
//!   squares when they cannot all hold), [`AffineRegularization::Identity`]. The paper's literal
//!   "minimum-norm" `‖[A | b]‖_F` ([`AffineRegularization::MinimumNorm`]) was tested against it
//!   (tests/engine/meshmatch_features.rs, 6 pairs on an ellipsoid, largest / mean affinity error at
//!   corresponding vertices). Identical surfaces: the literal map meets the constraints but is not
//!   the identity, so away from the correspondences the target features differ (0.075 / 0.015),
//!   where the identity variant gives exactly `[I | 0]` and identical features. ×2 scaled copy:
//!   identity exact (`A = I/2`), literal 0.075 / 0.015. ×2 copy with a coarser tessellation:
//!   0.038 / 0.010 against 0.099 / 0.023. Anisotropically stretched copy (no exact answer):
//!   0.080 / 0.035 against 0.079 / 0.038. Both satisfy the correspondences; they differ only away
//!   from them, where "leave the distances alone unless the constraints say
//!   otherwise" is the right prior.
//!
//! The affinity is `G'(v)_i = exp(−(M G(v))_i² / (2σ²))` with `σ = sigma_fraction · D_S`
//! (paper: `σ = max_{i,v} G_i(v) / 3`); on the source `M` is the identity. The paper prints
//! `exp(−M G(v) / 2σ²)`, which is not dimensionless (length over length²) and exceeds 1 for the
//! negative values an affine map can produce; we read it as the Gaussian of the distance, which
//! is 1 at the correspondence, `e^{−1/2}` at `σ` and independent of the unit of length.
//! Vertices that no correspondence reaches (another connected component) get affinity 0.
//!
//! Written by hand around the spectrum, signature and heat-geodesic operators of
//! [`crate::engine::geometry`].

use std::borrow::Cow;

use faer::Mat;

use crate::engine::control::{Cancelled, Control};
use crate::engine::geometry::heat::{HeatGeodesics, HeatParams, Source};
use crate::engine::geometry::laplacian::GeometryError;
use crate::engine::geometry::signatures::{heat_kernel_signature_at, HksNormalization};
use crate::engine::geometry::spectrum::{laplace_spectrum, SpectrumParams};
use crate::engine::linalg::lanczos::symmetric_eigen;
use crate::engine::mesh::Surface;
use crate::engine::methods::params::{check_ranges, OutOfRange};

/// Per-vertex shape features: `dim` f32 per vertex, vertex-major (`values[v · dim + j]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FeatureField {
    /// Features per vertex.
    pub dim: usize,
    /// Vertex-major values, `len() · dim` of them.
    pub values: Vec<f32>,
}

impl FeatureField {
    /// The feature vector of vertex `v`.
    ///
    /// # Panics
    /// If `v >= self.len()`.
    pub fn vertex(&self, v: usize) -> &[f32] {
        &self.values[v * self.dim..(v + 1) * self.dim]
    }

    /// Number of vertices (0 when `dim` is 0).
    pub fn len(&self) -> usize {
        self.values.len().checked_div(self.dim).unwrap_or(0)
    }

    /// Whether the field has no vertices.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Column `j` over all vertices.
    ///
    /// # Panics
    /// If `j >= self.dim`.
    pub fn column(&self, j: usize) -> Vec<f32> {
        assert!(j < self.dim, "column {j} of a {}-dim field", self.dim);
        self.values
            .iter()
            .skip(j)
            .step_by(self.dim)
            .copied()
            .collect()
    }
}

/// Errors of the feature computations.
#[derive(Debug, thiserror::Error)]
pub enum FeatureError {
    /// A parameter is outside its documented range.
    #[error("parameter {name} = {value} is out of range {range}")]
    InvalidParam {
        /// Parameter name.
        name: Cow<'static, str>,
        /// The offending value.
        value: f64,
        /// The valid range, as text.
        range: Cow<'static, str>,
    },
    /// [`geodesic_affinities`] was given no correspondence.
    #[error("no correspondences given")]
    NoCorrespondences,
    /// A correspondence is unusable (no point on one side, a point on another connected
    /// component than the other correspondences reach, ...).
    #[error("correspondence {pair}: {reason}")]
    InvalidPair {
        /// Index of the pair.
        pair: usize,
        /// What is wrong.
        reason: String,
    },
    /// The surface is too small or degenerate for the features.
    #[error("degenerate input: {0}")]
    Degenerate(String),
    /// An error of a geometry operator (spectrum, signature, heat geodesics).
    #[error(transparent)]
    Geometry(GeometryError),
    /// Cancelled through the Control.
    #[error(transparent)]
    Cancelled(#[from] Cancelled),
}

impl From<GeometryError> for FeatureError {
    fn from(e: GeometryError) -> Self {
        match e {
            GeometryError::Cancelled(c) => FeatureError::Cancelled(c),
            other => FeatureError::Geometry(other),
        }
    }
}

fn invalid(name: &'static str, value: f64, range: &'static str) -> FeatureError {
    FeatureError::InvalidParam {
        name: name.into(),
        value,
        range: range.into(),
    }
}

impl From<OutOfRange> for FeatureError {
    fn from(e: OutOfRange) -> Self {
        FeatureError::InvalidParam {
            name: e.field.into(),
            value: e.value,
            range: e.range.into(),
        }
    }
}

/// Parameters of [`automatic_features`] (`params.hks` of `meshmatch`).
// Ranges are on the fields and checked through the derived schema (`methods::params`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct AutomaticFeatureParams {
    /// Number of HKS times (log-spaced, see [`unit_area_hks_times`]). Default: 8 (the paper).
    #[schemars(range(min = 1, max = 64))]
    pub hks_times: usize,
    /// Number of lowest Laplace–Beltrami eigenpairs in the HKS sum. Default: 100. Meshes with
    /// fewer vertices use `vertices − 1`.
    #[schemars(range(min = 8, max = 500))]
    pub eigenpairs: usize,
    /// Up direction (any length > 0, world axes) for the extra `n·up` dimension; `None` (JSON
    /// `null`) leaves that dimension out. Default: `[0, 1, 0]` (the paper: "positive Y").
    pub up: Option<[f32; 3]>,
    /// The area unit of the target's HKS: [`HksUnits::Common`] (default) or
    /// [`HksUnits::PerShape`]. See the module docs.
    pub units: HksUnits,
    /// The largest HKS time as a fraction of `t_max`, the time at which heat has spread over the
    /// whole of a unit-area round sphere ([`unit_area_hks_times`]). Default: 0.25 (ours: the
    /// paper gives no time range; README "HKS units and time range" has the sweep).
    #[schemars(range(min = 0.01, max = 1))]
    pub max_time_fraction: f64,
    /// Clamp every HKS dimension of the target to the source's range of it
    /// ([`clamp_hks_to_source`]). Default: true (ours; see the module docs).
    pub clamp_to_source: bool,
}

/// The area unit in which the target's HKS is taken (`params.hks.units` of `meshmatch`).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum HksUnits {
    /// Both surfaces in the unit of the (scaled) source: the source at unit area and the target
    /// in the same unit, i.e. in the units the texture is transferred in, so a part of the
    /// target that is the source's shape keeps the source's signature.
    #[default]
    Common,
    /// Each surface at its own unit area (before 2026-12-07): a target with more area than the
    /// source looks thinner everywhere, also where it is unchanged.
    PerShape,
}

impl Default for AutomaticFeatureParams {
    fn default() -> Self {
        Self {
            hks_times: 8,
            eigenpairs: 100,
            up: Some([0.0, 1.0, 0.0]),
            units: HksUnits::Common,
            max_time_fraction: 0.25,
            clamp_to_source: true,
        }
    }
}

impl AutomaticFeatureParams {
    /// Feature dimensions produced: `hks_times` plus 1 when `up` is set.
    pub fn dim(&self) -> usize {
        self.hks_times + usize::from(self.up.is_some())
    }

    fn validate(&self) -> Result<Option<[f64; 3]>, FeatureError> {
        check_ranges(self)?;
        match self.up {
            None => Ok(None),
            Some(u) => {
                let u = u.map(f64::from);
                let len = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
                if !(len.is_finite() && len > 1e-12) {
                    return Err(invalid("up (length)", len, "finite, > 0"));
                }
                Ok(Some(u.map(|c| c / len)))
            }
        }
    }
}

/// Most eigenpairs [`automatic_features`] takes for a surface larger than its unit, as a
/// multiple of `eigenpairs` (a target 4× the source's area or more).
pub const MAX_EIGENPAIR_FACTOR: f64 = 4.0;

/// The scaled eigenpair count never exceeds this (the schema's largest `eigenpairs`), so a large
/// target costs no more than a user may already ask for.
pub const MAX_SCALED_EIGENPAIRS: usize = 500;

/// Fewest vertices [`automatic_features`] accepts (a tetrahedron).
pub const MIN_FEATURE_VERTICES: usize = 4;

/// The fixed HKS times of [`automatic_features`] for a unit-area surface and `eigenpairs`
/// eigenpairs: `count` times log-spaced from `t_min = 4 ln 10 / (4π · eigenpairs)` to
/// `max_time_fraction · 4 ln 10 / (8π)` (units: area; see the module docs), ascending; one time
/// gives their geometric mean. When `t_min` exceeds the largest time both ends are the largest.
pub fn unit_area_hks_times(eigenpairs: usize, count: usize, max_time_fraction: f64) -> Vec<f64> {
    let c = 4.0 * std::f64::consts::LN_10;
    let pi = std::f64::consts::PI;
    let t_max = c / (8.0 * pi) * max_time_fraction;
    let t_min = (c / (4.0 * pi * eigenpairs.max(1) as f64)).min(t_max);
    (0..count)
        .map(|j| {
            if count == 1 {
                (t_min * t_max).sqrt()
            } else {
                t_min * (t_max / t_min).powf(j as f64 / (count - 1) as f64)
            }
        })
        .collect()
}

/// The paper's automatic shape features: `ln HKS` of the surface at [`unit_area_hks_times`]
/// (dims `0..hks_times`, dimensionless log of 1/area units, comparable between meshes of any
/// scale and tessellation) plus `n·up` (last dim, in `[−1, 1]`, when `params.up` is set), with
/// the area `unit_area` taken as 1 (`None`: the surface's own area; MeshMatch passes the
/// source's for the target, [`HksUnits::Common`]). See the module docs. Stages: "features: spectrum" (plus the spectrum's
/// own), "features: signature".
///
/// # Errors
/// [`FeatureError::InvalidParam`] for out-of-range parameters; [`FeatureError::Degenerate`] for
/// fewer than [`MIN_FEATURE_VERTICES`] vertices, zero area or non-finite results;
/// [`FeatureError::Geometry`] for failures of the spectrum (empty surface, non-finite positions,
/// ...); [`FeatureError::Cancelled`].
pub fn automatic_features(
    surface: &Surface,
    params: &AutomaticFeatureParams,
    unit_area: Option<f64>,
    control: &Control,
) -> Result<FeatureField, FeatureError> {
    let up = params.validate()?;
    let n = surface.vertex_count();
    if surface.faces.is_empty() {
        return Err(GeometryError::EmptySurface.into());
    }
    if n < MIN_FEATURE_VERTICES {
        return Err(FeatureError::Degenerate(format!(
            "{n} vertices, at least {MIN_FEATURE_VERTICES} needed"
        )));
    }
    // The times are those of `eigenpairs` on a unit-area surface; a surface with area `a > 1`
    // in the unit (the target in the source's) has `λ_k ≈ 4πk / a`, so it needs `a·k`
    // eigenpairs for the same truncation at `t_min` (at most MAX_EIGENPAIR_FACTOR·k).
    let base = params.eigenpairs.min(n - 1);
    let own_area = surface.area();
    let ratio = match unit_area {
        Some(unit) if unit.is_finite() && unit > 0.0 => own_area / unit,
        Some(unit) => return Err(FeatureError::Degenerate(format!("unit area {unit}"))),
        None => 1.0,
    };
    let count = if ratio.is_finite() {
        let scaled = (params.eigenpairs as f64 * ratio.clamp(1.0, MAX_EIGENPAIR_FACTOR)).ceil();
        (scaled as usize)
            .min(MAX_SCALED_EIGENPAIRS.max(params.eigenpairs))
            .min(n - 1)
    } else {
        base
    };
    control.stage("features: spectrum", 0)?;
    let mut spectrum = laplace_spectrum(
        surface,
        &SpectrumParams {
            count,
            ..Default::default()
        },
        control,
    )?;
    control.stage("features: signature", 0)?;
    // Rescale to the unit-area surface (or the given unit).
    let area: f64 = spectrum.mass.iter().sum();
    if !(area.is_finite() && area > 0.0) {
        return Err(FeatureError::Degenerate(format!("total area {area}")));
    }
    let area = unit_area.unwrap_or(area);
    let root = area.sqrt();
    spectrum.values.iter_mut().for_each(|l| *l *= area);
    spectrum.vectors.iter_mut().for_each(|p| *p *= root);
    spectrum.mass.iter_mut().for_each(|m| *m /= area);
    let times = unit_area_hks_times(base, params.hks_times, params.max_time_fraction);
    let hks = heat_kernel_signature_at(&spectrum, &times, HksNormalization::None)?;

    let d_hks = params.hks_times;
    let dim = params.dim();
    let mut values = Vec::with_capacity(n * dim);
    let normals = up.map(|_| surface.vertex_normals());
    for v in 0..n {
        values.extend(
            hks.vertex(v)
                .iter()
                .map(|&h| h.max(f64::MIN_POSITIVE).ln() as f32),
        );
        if let (Some(u), Some(normals)) = (up, normals.as_ref()) {
            let nv = normals[v].map(f64::from);
            values.push((nv[0] * u[0] + nv[1] * u[1] + nv[2] * u[2]) as f32);
        }
    }
    if let Some(i) = values.iter().position(|x| !x.is_finite()) {
        return Err(FeatureError::Degenerate(format!(
            "non-finite feature at vertex {} (dimension {})",
            i / dim,
            i % dim
        )));
    }
    debug_assert_eq!(values.len(), n * (d_hks + usize::from(up.is_some())));
    Ok(FeatureField { dim, values })
}

/// Clamps the first `hks_dims` dimensions of every target vertex to the range of that
/// dimension over the source's vertices (`params.hks.clamp_to_source`). A target value beyond
/// every source value (the middle of a lengthened part lies farther from the shape's ends than
/// any point of the source) is then matched as the source's extreme itself, where the squared
/// distance to the extreme grows only with the fourth power of the distance from it, instead of
/// as a quadratic pull that shrinks the usable source to a band narrower than one stripe
/// (module docs).
pub fn clamp_hks_to_source(target: &mut FeatureField, source: &FeatureField, hks_dims: usize) {
    let dims = hks_dims.min(source.dim).min(target.dim);
    for j in 0..dims {
        let column = (0..source.len()).map(|v| source.values[v * source.dim + j]);
        let (lo, hi) = column.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| {
            (lo.min(x), hi.max(x))
        });
        if lo > hi {
            return;
        }
        for v in 0..target.len() {
            let x = &mut target.values[v * target.dim + j];
            *x = x.clamp(lo, hi);
        }
    }
}

/// Parameters of [`geodesic_affinities`] (`params.affinity` of `meshmatch`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct AffinityParams {
    /// `σ = sigma_fraction · max_{i,v} G_S,i(v)` (dimensionless). Default: 1/3 (the paper).
    #[schemars(range(max = 10), extend("exclusiveMinimum" = 0))]
    pub sigma_fraction: f32,
}

impl Default for AffinityParams {
    fn default() -> Self {
        Self {
            sigma_fraction: 1.0 / 3.0,
        }
    }
}

/// One correspondence on the two surfaces: source point(s) and target point(s) (one-to-many
/// allowed; distances are to the nearest point of each side). Every (source point, target point)
/// combination is one set of constraints of the affine map.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AffinityPair {
    /// Point(s) on the source surface (at least one).
    pub source: Vec<Source>,
    /// Point(s) on the target surface (at least one).
    pub target: Vec<Source>,
}

/// What [`geodesic_affinities`] computed besides the features.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AffinityReport {
    /// Number of correspondences `k` (the feature dimension).
    pub pairs: usize,
    /// `σ`, source world units.
    pub sigma: f32,
    /// `M_{T→S} = [A | b]`, `k` rows of `k + 1` (A dimensionless, b source world units), taking
    /// raw target distances (target units) to source distances (source units).
    pub transform: Vec<Vec<f64>>,
    /// Largest `|A·G_T(t) + b − G_S(s)|` over the constraints, source world units (0 up to
    /// rounding when the system is under-determined; the least-squares misfit otherwise).
    pub residual: f64,
}

/// Which minimum-norm solution of the affine constraints [`geodesic_affinities_with`] takes (in
/// max-distance-normalized units, see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AffineRegularization {
    /// Minimum `‖[A | b]‖_F` (the paper's literal wording).
    MinimumNorm,
    /// Minimum `‖[A − I | b]‖_F`: the identity when the shapes already agree (default, used by
    /// [`geodesic_affinities`]).
    #[default]
    Identity,
}

/// Most correspondences [`geodesic_affinities`] accepts (each costs one geodesic query per
/// surface and one feature dimension).
pub const MAX_AFFINITY_PAIRS: usize = 512;

/// Geodesic affinity features of the paper's equation 1 for a source and a target surface (see
/// the module docs), with [`AffineRegularization::Identity`]. Returns the source features, the
/// target features (both `dim = pairs.len()`, values in `[0, 1]`, 1 at the correspondence) and
/// a report. Stages: "features: geodesics" (plus the heat method's own), "features: affinities".
///
/// # Errors
/// [`FeatureError::NoCorrespondences`] for no pairs; [`FeatureError::InvalidParam`] for more than
/// [`MAX_AFFINITY_PAIRS`] pairs or a bad `sigma_fraction`; [`FeatureError::InvalidPair`] for a
/// pair with an empty side, a point outside the surface, or a point that another pair's points
/// do not reach; [`FeatureError::Geometry`] for surfaces the heat method refuses (empty,
/// non-finite, zero area); [`FeatureError::Degenerate`] when every distance is 0;
/// [`FeatureError::Cancelled`].
pub fn geodesic_affinities(
    source: &Surface,
    target: &Surface,
    pairs: &[AffinityPair],
    params: &AffinityParams,
    control: &Control,
) -> Result<(FeatureField, FeatureField, AffinityReport), FeatureError> {
    geodesic_affinities_with(
        source,
        target,
        pairs,
        params,
        AffineRegularization::Identity,
        control,
    )
}

/// [`geodesic_affinities`] with a choice of the minimum-norm solution (for comparisons).
///
/// # Errors
/// As [`geodesic_affinities`].
pub fn geodesic_affinities_with(
    source: &Surface,
    target: &Surface,
    pairs: &[AffinityPair],
    params: &AffinityParams,
    regularization: AffineRegularization,
    control: &Control,
) -> Result<(FeatureField, FeatureField, AffinityReport), FeatureError> {
    check_ranges(params)?;
    let f = params.sigma_fraction;
    if pairs.is_empty() {
        return Err(FeatureError::NoCorrespondences);
    }
    let k = pairs.len();
    if k > MAX_AFFINITY_PAIRS {
        return Err(invalid("pairs (count)", k as f64, "[1, 512]"));
    }
    for (i, p) in pairs.iter().enumerate() {
        if p.source.is_empty() || p.target.is_empty() {
            return Err(FeatureError::InvalidPair {
                pair: i,
                reason: format!(
                    "{} source and {} target points (at least one each needed)",
                    p.source.len(),
                    p.target.len()
                ),
            });
        }
    }
    control.stage("features: geodesics", 0)?;
    let g_s = pair_distances(source, pairs, |p| &p.source, control)?;
    let g_t = pair_distances(target, pairs, |p| &p.target, control)?;
    control.stage("features: affinities", 0)?;
    let d_s = max_finite(&g_s);
    let d_t = max_finite(&g_t);
    if !(d_s > 0.0 && d_t > 0.0) {
        return Err(FeatureError::Degenerate(
            "every geodesic distance is 0".into(),
        ));
    }

    // Constraint rows in normalized units.
    let mut rows_t = Vec::new();
    let mut rows_s = Vec::new();
    for (i, p) in pairs.iter().enumerate() {
        for s in &p.source {
            let gs = point_distances(source, &g_s, *s, i).map_err(|reason| {
                FeatureError::InvalidPair {
                    pair: i,
                    reason: format!("source: {reason}"),
                }
            })?;
            for t in &p.target {
                let gt = point_distances(target, &g_t, *t, i).map_err(|reason| {
                    FeatureError::InvalidPair {
                        pair: i,
                        reason: format!("target: {reason}"),
                    }
                })?;
                rows_s.push(gs.iter().map(|x| x / d_s).collect::<Vec<_>>());
                rows_t.push(gt.iter().map(|x| x / d_t).collect::<Vec<_>>());
            }
        }
    }
    let map = fit_affine_map(&rows_t, &rows_s, regularization)?;
    let apply = |g: &[f64]| -> Vec<f64> {
        map.iter()
            .map(|row| row[k] + row[..k].iter().zip(g).map(|(a, x)| a * x).sum::<f64>())
            .collect()
    };
    let residual = rows_t
        .iter()
        .zip(&rows_s)
        .flat_map(|(t, s)| {
            apply(t)
                .into_iter()
                .zip(s.iter())
                .map(|(y, x)| (y - x).abs())
                .collect::<Vec<_>>()
        })
        .fold(0.0f64, f64::max)
        * d_s;

    let inv_two_f2 = 1.0 / (2.0 * f64::from(f) * f64::from(f));
    let affinity = |y: f64| -> f32 {
        let a = (-(y * y) * inv_two_f2).exp();
        if a.is_finite() {
            a as f32
        } else {
            0.0
        }
    };
    let n_s = source.vertex_count();
    let mut source_values = Vec::with_capacity(n_s * k);
    for v in 0..n_s {
        source_values.extend((0..k).map(|i| affinity(g_s[i][v] / d_s)));
    }
    let n_t = target.vertex_count();
    let mut target_values = Vec::with_capacity(n_t * k);
    let mut g = vec![0.0; k];
    for v in 0..n_t {
        for i in 0..k {
            g[i] = g_t[i][v] / d_t;
        }
        if g.iter().all(|x| x.is_finite()) {
            target_values.extend(apply(&g).into_iter().map(affinity));
        } else {
            target_values.extend(std::iter::repeat_n(0.0f32, k));
        }
    }
    let transform = map
        .iter()
        .map(|row| {
            let mut r: Vec<f64> = row[..k].iter().map(|a| a * d_s / d_t).collect();
            r.push(row[k] * d_s);
            r
        })
        .collect();
    let report = AffinityReport {
        pairs: k,
        sigma: (f64::from(f) * d_s) as f32,
        transform,
        residual,
    };
    Ok((
        FeatureField {
            dim: k,
            values: source_values,
        },
        FeatureField {
            dim: k,
            values: target_values,
        },
        report,
    ))
}

/// Per pair, the heat-method distance field to its points on `surface`.
fn pair_distances(
    surface: &Surface,
    pairs: &[AffinityPair],
    side: impl Fn(&AffinityPair) -> &Vec<Source>,
    control: &Control,
) -> Result<Vec<Vec<f64>>, FeatureError> {
    let heat = HeatGeodesics::new(surface, &HeatParams::default(), control)?;
    let queries: Vec<Vec<Source>> = pairs.iter().map(|p| side(p).clone()).collect();
    Ok(heat.distance_many(&queries, control)?)
}

fn max_finite(fields: &[Vec<f64>]) -> f64 {
    fields
        .iter()
        .flatten()
        .copied()
        .filter(|x| x.is_finite())
        .fold(0.0, f64::max)
}

/// Distances from `point` to every pair's points (`own` pair: exactly 0), interpolated over the
/// face for points inside faces. Errors (as text) for points outside the surface or unreachable.
fn point_distances(
    surface: &Surface,
    fields: &[Vec<f64>],
    point: Source,
    own: usize,
) -> Result<Vec<f64>, String> {
    let (corners, weights) = match point {
        Source::Vertex(v) => {
            if v as usize >= surface.vertex_count() {
                return Err(format!("vertex {v} out of range"));
            }
            ([v; 3], [1.0, 0.0, 0.0])
        }
        Source::Point { face, bary } => {
            let f = surface
                .faces
                .get(face as usize)
                .ok_or_else(|| format!("face {face} out of range"))?;
            let sum: f64 = bary.iter().sum();
            if !(bary.iter().all(|b| b.is_finite() && *b >= 0.0) && sum > 0.0) {
                return Err(format!("bad barycentric weights {bary:?}"));
            }
            (*f, bary.map(|b| b / sum))
        }
    };
    let mut out = Vec::with_capacity(fields.len());
    for (i, field) in fields.iter().enumerate() {
        if i == own {
            out.push(0.0);
            continue;
        }
        let mut d = 0.0;
        for c in 0..3 {
            if weights[c] > 0.0 {
                d += weights[c] * field[corners[c] as usize];
            }
        }
        if !d.is_finite() {
            return Err(format!("not reached by the points of pair {i}"));
        }
        out.push(d);
    }
    Ok(out)
}

/// The affine map `X = [A | b]` (`k` rows of `k + 1`) with `A·t_j + b = s_j` for every row pair
/// (`target_rows[j]`, `source_rows[j]`, each of length `k`), in the least-squares sense when the
/// constraints conflict, of minimum `‖X − X₀‖_F` with `X₀ = 0` ([`AffineRegularization::MinimumNorm`])
/// or `[I | 0]` ([`AffineRegularization::Identity`]): `X = X₀ + (S − X₀P) P⁺` with `P` the columns
/// `[t_j; 1]` and `S` the columns `s_j`. The pseudo-inverse comes from the eigendecomposition of
/// the smaller Gram matrix (`PᵀP` or `PPᵀ`), eigenvalues below `1e-12 ×` the largest dropped.
///
/// # Errors
/// [`FeatureError::NoCorrespondences`] for no rows; [`FeatureError::Degenerate`] for rows of
/// unequal length, non-finite values, or a failed eigendecomposition.
pub fn fit_affine_map(
    target_rows: &[Vec<f64>],
    source_rows: &[Vec<f64>],
    regularization: AffineRegularization,
) -> Result<Vec<Vec<f64>>, FeatureError> {
    let m = target_rows.len();
    if m == 0 || source_rows.is_empty() {
        return Err(FeatureError::NoCorrespondences);
    }
    let k = target_rows[0].len();
    if source_rows.len() != m
        || target_rows
            .iter()
            .chain(source_rows)
            .any(|r| r.len() != k || r.iter().any(|x| !x.is_finite()))
    {
        return Err(FeatureError::Degenerate(
            "affine constraints of unequal length or non-finite".into(),
        ));
    }
    let p = Mat::<f64>::from_fn(k + 1, m, |r, j| if r < k { target_rows[j][r] } else { 1.0 });
    let identity = regularization == AffineRegularization::Identity;
    // R = S − X₀P (k × m).
    let rhs = Mat::<f64>::from_fn(k, m, |r, j| {
        source_rows[j][r] - if identity { target_rows[j][r] } else { 0.0 }
    });
    let delta = if m <= k + 1 {
        // Δ = R (PᵀP)⁺ Pᵀ.
        let gram = p.transpose() * &p;
        let pinv = pseudo_inverse(&gram)?;
        &rhs * &pinv * p.transpose()
    } else {
        // Δ = R Pᵀ (PPᵀ)⁺.
        let gram = &p * p.transpose();
        let pinv = pseudo_inverse(&gram)?;
        &rhs * p.transpose() * &pinv
    };
    Ok((0..k)
        .map(|r| {
            (0..=k)
                .map(|c| delta[(r, c)] + if identity && r == c { 1.0 } else { 0.0 })
                .collect()
        })
        .collect())
}

/// Moore–Penrose pseudo-inverse of a symmetric positive semi-definite matrix.
fn pseudo_inverse(a: &Mat<f64>) -> Result<Mat<f64>, FeatureError> {
    let (values, vectors) = symmetric_eigen(a.as_ref())
        .map_err(|e| FeatureError::Degenerate(format!("affine fit: {e}")))?;
    let top = values.iter().copied().fold(0.0, f64::max);
    let n = a.nrows();
    let inv: Vec<f64> = values
        .iter()
        .map(|&l| if l > 1e-12 * top { 1.0 / l } else { 0.0 })
        .collect();
    Ok(Mat::from_fn(n, n, |r, c| {
        (0..n)
            .map(|i| vectors[(r, i)] * inv[i] * vectors[(c, i)])
            .sum()
    }))
}
