//! The method seam: the [`Method`] trait and the types that cross it (DESIGN.md "Data flow":
//! `run(&MethodInput, &Control) -> MethodOutput`).

use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use crate::engine::asset::edits::{Edit, EditedAsset};
use crate::engine::asset::images::{checked_dimensions, decode_rgba8, mime_of};
use crate::engine::asset::{Asset, DecodedImage, IngestError, IngestLimits};
use crate::engine::control::{Cancelled, Control};
use crate::engine::mesh::MeshError;

/// Whether a method reads an input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum InputUse {
    /// The job fails without it (at submission: a 400 naming the part).
    Required,
    /// Read when given.
    Optional,
    /// Never read; an upload is accepted and ignored, with a warning.
    Unused,
}

impl InputUse {
    /// Whether an input that was (or was not) `given` is read: `Some(false)` for an unused one
    /// (ignored, with a warning by the caller), `None` for a required one that is missing.
    pub fn reads(self, given: bool) -> Option<bool> {
        match (self, given) {
            (InputUse::Required, false) => None,
            (InputUse::Unused, _) => Some(false),
            (_, given) => Some(given),
        }
    }
}

/// The inputs a method reads besides the target (always required) and the constraints.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct InputSpec {
    /// The source model (multipart part `source`, CLI `--source`).
    pub source: InputUse,
    /// A smooth base of the source (part `source_base`, CLI `--source-base`).
    pub source_base: InputUse,
    /// A pattern image, PNG or JPEG (part `pattern`, CLI `--pattern`).
    pub pattern: InputUse,
}

impl InputSpec {
    /// A method that reads a required source and nothing else.
    pub const SOURCE_AND_TARGET: InputSpec = InputSpec {
        source: InputUse::Required,
        source_base: InputUse::Unused,
        pattern: InputUse::Unused,
    };
}

/// An uploaded pattern image: its bytes as uploaded (for pass-through) and its decoded texels.
#[derive(Clone, Debug)]
pub struct PatternImage {
    /// File name as uploaded.
    pub name: String,
    /// Encoded bytes, unmodified.
    pub bytes: Vec<u8>,
    /// `image/png` or `image/jpeg`.
    pub mime_type: &'static str,
    /// Decoded sRGB RGBA8 texels.
    pub image: DecodedImage,
}

impl PatternImage {
    /// Checks the header against the image limits and decodes (PNG or JPEG only).
    ///
    /// # Errors
    /// [`IngestError::UnrecognizedImage`], [`IngestError::ImageTooLarge`] or
    /// [`IngestError::ImageDecode`] (image index 0).
    pub fn decode(name: &str, bytes: Vec<u8>, limits: &IngestLimits) -> Result<Self, IngestError> {
        let (format, _, _) = checked_dimensions(0, &bytes, limits)?;
        let image = decode_rgba8(0, &bytes, format, limits)?;
        Ok(Self {
            name: name.to_string(),
            mime_type: mime_of(format),
            bytes,
            image,
        })
    }
}

/// What a method reads. Inputs the method declared [`InputUse::Required`] are present.
#[derive(Clone, Copy, Debug)]
pub struct MethodInput<'a> {
    /// The source model.
    pub source: Option<&'a Asset>,
    /// The target model.
    pub target: &'a Asset,
    /// The smooth base of the source.
    pub source_base: Option<&'a Asset>,
    /// The pattern image.
    pub pattern: Option<&'a PatternImage>,
    /// The job description (already checked by [`Method::check`]).
    pub constraints: &'a Constraints,
}

impl<'a> MethodInput<'a> {
    /// The source, for methods that require it.
    ///
    /// # Errors
    /// [`MethodError::Internal`] if the pipeline did not load it (a method that reads the source
    /// must declare it).
    pub fn source(&self) -> Result<&'a Asset, MethodError> {
        self.source.ok_or_else(|| {
            MethodError::Internal("the method read a source it did not declare".into())
        })
    }
}

/// A file a job produces besides the output model and the report (e.g. `nnf.bin`).
#[derive(Clone, Debug, PartialEq)]
pub struct ResultFile {
    /// File name, unique within the job.
    pub name: String,
    /// MIME type.
    pub media_type: String,
    /// Content.
    pub bytes: Vec<u8>,
}

/// What a method returns.
#[derive(Clone, Debug)]
pub struct MethodOutput {
    /// The asset the edits apply to (and that is exported).
    pub asset: EditedAsset,
    /// The edits, applied in order.
    pub edits: Vec<Edit>,
    /// Extra result files.
    pub files: Vec<ResultFile>,
    /// Things the user should know (lowercase sentences).
    pub warnings: Vec<String>,
    /// The method's own figures (a serialized typed report).
    pub report: serde_json::Value,
}

impl MethodOutput {
    /// Edits of the target with a typed report.
    pub fn target<R: serde::Serialize>(edits: Vec<Edit>, report: &R) -> Self {
        Self {
            asset: EditedAsset::Target,
            edits,
            files: Vec::new(),
            warnings: Vec::new(),
            report: serde_json::to_value(report).unwrap_or_default(),
        }
    }
}

/// Failures of a method, by category; the service maps each category to a problem type in one
/// table (`service::problem`).
#[derive(Debug, thiserror::Error)]
pub enum MethodError {
    /// Cancelled through the Control (also any error raised once cancellation was requested).
    #[error("cancelled")]
    Cancelled,
    /// A constraint or parameter cannot be used; the path names it (`params.samples`).
    #[error(transparent)]
    Constraints(#[from] ConstraintsError),
    /// A surface cannot be built from an input model.
    #[error("{side} surface: {source}")]
    Mesh {
        /// `source`, `target` or `source_base`.
        side: &'static str,
        /// The cause.
        source: MeshError,
    },
    /// An input is valid glTF but the method cannot work with it (e.g. a mesh too broken for a
    /// hierarchy); `kind` is the stable problem type.
    #[error("{message}")]
    UnusableInput {
        /// The input at fault (`source`, `target`, `pattern`), when known.
        field: Option<String>,
        /// Stable kebab-case kind (`unusable-mesh`).
        kind: &'static str,
        /// What is wrong, lowercase.
        message: String,
    },
    /// A bug or an environment failure.
    #[error("{0}")]
    Internal(String),
}

impl From<Cancelled> for MethodError {
    fn from(_: Cancelled) -> Self {
        MethodError::Cancelled
    }
}

/// One transfer method.
pub trait Method: Sync + Send {
    /// The wire id.
    fn id(&self) -> MethodId;

    /// The inputs it reads.
    fn inputs(&self) -> InputSpec;

    /// JSON Schema of its `params` object.
    fn params_schema(&self) -> serde_json::Value;

    /// Parses and range-checks its params (and anything else in the constraints it can check
    /// without the models). Runs at submission and again inside the job.
    ///
    /// # Errors
    /// A [`ConstraintsError`] naming the JSON path (`params.hks.eigenpairs`).
    fn check(&self, constraints: &Constraints) -> Result<(), ConstraintsError>;

    /// The method's own working memory for these constraints (beyond the loaded inputs and
    /// their surfaces) when its inputs hold `input_triangles` instanced triangles, and the
    /// constraints path that drives it; the pipeline and the service refuse a job whose estimate
    /// exceeds `max_method_bytes` before running it: from the params alone (0 triangles) when
    /// the constraints are checked, and again once the inputs' headers are read. `None` (the
    /// default) for a method that does not say.
    fn working_set(&self, constraints: &Constraints, input_triangles: u64) -> Option<WorkingSet> {
        let _ = (constraints, input_triangles);
        None
    }

    /// Images of an input (`source`, `target`, `source_base`) the method decodes besides the
    /// base-colour images its primitives sample (e.g. a mask), so that they count against the
    /// job's decoded-image budget and are decoded with the rest. Default: none.
    fn extra_images(&self, constraints: &Constraints) -> Vec<(&'static str, usize)> {
        let _ = constraints;
        Vec::new()
    }

    /// Runs the method.
    ///
    /// # Errors
    /// [`MethodError`].
    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError>;
}

/// A method's estimated working memory ([`Method::working_set`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WorkingSet {
    /// Estimated peak bytes.
    pub bytes: u64,
    /// The constraints path of the value that drives it (`params.samples`,
    /// `output.texture_size`), or `inputs` when the input meshes' size does.
    pub field: &'static str,
}

/// Bytes per texel of a texture output (bake hits, linear colour, coverage, padding pyramid,
/// the sRGB image and its PNG). Measured: `project` Fox → Fox at 8192² peaks 1.78 GB above the
/// same job at 2048² (28 bytes per added texel).
pub const TEXEL_BYTES: u64 = 32;

/// The working set of baking one `output.texture_size` texture. A target whose primitives use
/// several materials gets one texture each; each further one holds about 17 bytes per texel
/// more (its linear colour and coverage) until all are padded, which this does not count.
pub fn texture_working_set(constraints: &Constraints) -> WorkingSet {
    let size = u64::from(constraints.output.texture_size);
    WorkingSet {
        bytes: size * size * TEXEL_BYTES,
        field: "output.texture_size",
    }
}

/// The working set of a UV atlas generated for the output (`output.uv = "auto"`, the default):
/// [`crate::engine::uv::working_set_bytes`] for every input triangle, since which inputs lack
/// UVs is not known before they are read; 0 for `keep` and `vertex_colors`. Every method that
/// writes a colour texture through the shared writer (project, meshmatch, correlation) adds it.
pub fn atlas_working_set(constraints: &Constraints, input_triangles: u64) -> u64 {
    match constraints.output.uv {
        crate::engine::asset::constraints::UvMode::Auto => {
            crate::engine::uv::working_set_bytes(input_triangles)
        }
        _ => 0,
    }
}
