//! The whole transfer as one call: check the constraints and the method's params, load the
//! inputs the method declares, run the method, apply its edits to the asset it names and export.
//! This is exactly what a service job runs and what `retex transfer` runs (DESIGN.md "Data
//! flow"). No method is named here: methods come from a [`Registry`].
//!
//! Progress: loading takes the first 5% of the job, the method 90%, export the rest; stage
//! timings come from the [`Control`]. The output model bytes are deterministic (same inputs,
//! constraints and seed give identical bytes with any thread count); the report carries
//! wall-clock timings and so is not.

use serde::Serialize;

use crate::engine::asset::budget::{self, Demand};
use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId, OutputFormat};
use crate::engine::asset::edits::{Edit, EditedAsset};
use crate::engine::asset::export::{export, ExportError};
use crate::engine::asset::images::read_header;
use crate::engine::asset::{load_with, Asset, BlobSet, Decode, IngestError, IngestLimits};
use crate::engine::control::{Cancelled, Control, StageTiming};
use crate::engine::methods::{InputUse, Method, MethodError, MethodInput, PatternImage, Registry};

/// One input model: the name of its main file inside its blob set.
#[derive(Clone, Copy, Debug)]
pub struct ModelInput<'a> {
    /// Name of the .glb or .gltf inside `blobs`.
    pub main: &'a str,
    /// The uploaded files.
    pub blobs: &'a BlobSet,
}

/// An input image file (a pattern).
#[derive(Clone, Copy, Debug)]
pub struct ImageInput<'a> {
    /// File name as uploaded.
    pub name: &'a str,
    /// Encoded bytes (PNG or JPEG).
    pub bytes: &'a [u8],
}

/// Everything a transfer needs. Build it with [`TransferInput::new`] and the `with_*` methods.
#[derive(Clone, Debug)]
pub struct TransferInput<'a> {
    pub(crate) source: Option<ModelInput<'a>>,
    pub(crate) target: ModelInput<'a>,
    pub(crate) source_base: Option<ModelInput<'a>>,
    pub(crate) pattern: Option<ImageInput<'a>>,
    pub(crate) constraints: Constraints,
    pub(crate) limits: IngestLimits,
}

impl<'a> TransferInput<'a> {
    /// A transfer onto `target` described by `constraints`, with default ingest limits.
    pub fn new(target: ModelInput<'a>, constraints: Constraints) -> Self {
        Self {
            source: None,
            target,
            source_base: None,
            pattern: None,
            constraints,
            limits: IngestLimits::default(),
        }
    }

    /// The common case: a source and a target.
    pub fn pair(source: ModelInput<'a>, target: ModelInput<'a>, constraints: Constraints) -> Self {
        Self::new(target, constraints).with_source(source)
    }

    /// Adds the source model.
    pub fn with_source(mut self, source: ModelInput<'a>) -> Self {
        self.source = Some(source);
        self
    }

    /// Adds the smooth base of the source.
    pub fn with_source_base(mut self, base: ModelInput<'a>) -> Self {
        self.source_base = Some(base);
        self
    }

    /// Adds a pattern image.
    pub fn with_pattern(mut self, pattern: ImageInput<'a>) -> Self {
        self.pattern = Some(pattern);
        self
    }

    /// Sets the ingest limits applied to every model and image.
    pub fn with_limits(mut self, limits: IngestLimits) -> Self {
        self.limits = limits;
        self
    }

    /// The job description.
    pub fn constraints(&self) -> &Constraints {
        &self.constraints
    }
}

/// A named by-product of a job (baked images, extra files, the report).
#[derive(Clone, Debug)]
pub struct Artifact {
    /// File name, unique within the job.
    pub name: String,
    /// MIME type.
    pub media_type: String,
    /// Content.
    pub bytes: Vec<u8>,
}

/// The job report (also written as the `report.json` artifact).
#[derive(Clone, Debug, Serialize)]
pub struct TransferReport {
    /// The method that ran.
    pub method: MethodId,
    /// The asset that was edited and exported.
    pub edited: EditedAsset,
    /// Warnings from ingest of the source.
    pub source_warnings: Vec<String>,
    /// Warnings from ingest of the target.
    pub target_warnings: Vec<String>,
    /// Warnings of the pipeline and the method.
    pub warnings: Vec<String>,
    /// The method's own figures.
    pub method_report: serde_json::Value,
    /// Time per stage, from the [`Control`].
    pub timings: Vec<StageTiming>,
    /// Size of the output model in bytes.
    pub output_bytes: usize,
}

/// The result of a transfer.
#[derive(Clone, Debug)]
pub struct TransferOutput {
    /// The edited asset, GLB or .gltf.
    pub model: Vec<u8>,
    /// Its format.
    pub format: OutputFormat,
    /// Figures and warnings.
    pub report: TransferReport,
    /// By-products, including `report.json`.
    pub artifacts: Vec<Artifact>,
}

/// Failures of a transfer; each names the input or field at fault.
#[derive(Debug, thiserror::Error)]
pub enum TransferError {
    /// An input could not be loaded.
    #[error("{side}: {source}")]
    Ingest {
        /// `source`, `target`, `source_base` or `pattern`.
        side: &'static str,
        /// The cause.
        source: IngestError,
    },
    /// The constraints are invalid.
    #[error(transparent)]
    Constraints(#[from] ConstraintsError),
    /// The method is known but not implemented.
    #[error("method {method:?} is not implemented yet; available: {available}")]
    MethodNotImplemented {
        /// The requested id.
        method: &'static str,
        /// The implemented ids.
        available: String,
    },
    /// The method needs an input that was not given.
    #[error("method {method:?} needs a {input} input")]
    MissingInput {
        /// The method.
        method: &'static str,
        /// `source`, `source_base` or `pattern`.
        input: &'static str,
    },
    /// The method failed.
    #[error(transparent)]
    Method(MethodError),
    /// Writing the output failed.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// The method's estimated working memory for these constraints exceeds `max_method_bytes`.
    #[error("{field}: the method would need about {bytes} bytes of working memory for these params and inputs, over max_method_bytes = {max}")]
    WorkingSet {
        /// The constraints path that drives it (`params.samples`, `output.texture_size`), or
        /// `inputs` when the input meshes' size does.
        field: String,
        /// The estimate.
        bytes: u64,
        /// The limit.
        max: u64,
    },
    /// Cancelled through the Control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for TransferError {
    fn from(_: Cancelled) -> Self {
        TransferError::Cancelled
    }
}

impl From<MethodError> for TransferError {
    fn from(e: MethodError) -> Self {
        match e {
            MethodError::Cancelled => TransferError::Cancelled,
            MethodError::Constraints(c) => TransferError::Constraints(c),
            other => TransferError::Method(other),
        }
    }
}

/// The method a constraints document asks for, checked: the id is implemented, the params
/// pass the method's own check and its working set ([`Method::working_set`]) is within
/// `limits.max_method_bytes`. This is what submission runs before accepting a job.
///
/// # Errors
/// [`TransferError::Constraints`], [`TransferError::MethodNotImplemented`] or
/// [`TransferError::WorkingSet`].
pub fn checked_method(
    registry: &Registry,
    constraints: &Constraints,
    limits: &IngestLimits,
) -> Result<&'static dyn Method, TransferError> {
    constraints.validate()?;
    let method =
        registry
            .get(constraints.method)
            .ok_or_else(|| TransferError::MethodNotImplemented {
                method: constraints.method.as_str(),
                available: registry.available(),
            })?;
    method.check(constraints)?;
    check_working_set(method, constraints, 0, limits)?;
    Ok(method)
}

/// Refuses a job whose method's working set ([`Method::working_set`]) with inputs of
/// `input_triangles` instanced triangles exceeds `limits.max_method_bytes`.
///
/// # Errors
/// [`TransferError::WorkingSet`].
pub fn check_working_set(
    method: &dyn Method,
    constraints: &Constraints,
    input_triangles: u64,
    limits: &IngestLimits,
) -> Result<(), TransferError> {
    match method.working_set(constraints, input_triangles) {
        Some(ws) if ws.bytes > limits.max_method_bytes => Err(TransferError::WorkingSet {
            field: ws.field.to_string(),
            bytes: ws.bytes,
            max: limits.max_method_bytes,
        }),
        _ => Ok(()),
    }
}

/// Runs a whole transfer with the built-in methods under `control`.
///
/// # Errors
/// [`TransferError`]; any error raised after cancellation was requested is
/// [`TransferError::Cancelled`].
pub fn transfer(
    input: &TransferInput<'_>,
    control: &Control,
) -> Result<TransferOutput, TransferError> {
    transfer_with(&Registry::builtin(), input, control)
}

/// Runs a whole transfer with the methods of `registry` under `control`.
///
/// # Errors
/// As [`transfer`].
pub fn transfer_with(
    registry: &Registry,
    input: &TransferInput<'_>,
    control: &Control,
) -> Result<TransferOutput, TransferError> {
    run(registry, input, control).map_err(|e| {
        if control.is_cancelled() {
            TransferError::Cancelled
        } else {
            e
        }
    })
}

/// The inputs as loaded.
struct Loaded {
    source: Option<Asset>,
    target: Asset,
    source_base: Option<Asset>,
    pattern: Option<PatternImage>,
    warnings: Vec<String>,
}

fn load_model(
    side: &'static str,
    m: ModelInput<'_>,
    limits: &IngestLimits,
    extra: &[(&'static str, usize)],
) -> Result<(Asset, Demand), TransferError> {
    let asset = load_with(m.main, m.blobs, limits, Decode::HeadersOnly)
        .map_err(|source| TransferError::Ingest { side, source })?;
    let extra: Vec<usize> = extra
        .iter()
        .filter(|(s, _)| *s == side)
        .map(|(_, i)| *i)
        .collect();
    let demand = Demand::of_asset(&asset, &extra);
    Ok((asset, demand))
}

/// Loads what `method` declares; refuses a missing required input, warns about unused ones.
/// Every input is read to its headers first, the job's budget ([`budget::check_job`]) is checked
/// over all of them, and only then are the sampled images and the pattern decoded.
fn load_inputs(
    method: &dyn Method,
    input: &TransferInput<'_>,
    control: &Control,
) -> Result<Loaded, TransferError> {
    let spec = method.inputs();
    let id = method.id().as_str();
    let mut warnings = Vec::new();
    let wanted = |name: &'static str, given: bool, used: InputUse| {
        used.reads(given).ok_or(TransferError::MissingInput {
            method: id,
            input: name,
        })
    };
    let use_source = wanted("source", input.source.is_some(), spec.source)?;
    let use_base = wanted("source_base", input.source_base.is_some(), spec.source_base)?;
    let use_pattern = wanted("pattern", input.pattern.is_some(), spec.pattern)?;
    for (name, given, used) in [
        ("source", input.source.is_some(), use_source),
        ("source_base", input.source_base.is_some(), use_base),
        ("pattern", input.pattern.is_some(), use_pattern),
    ] {
        if given && !used {
            warnings.push(format!(
                "method {id} does not read a {name}; it was ignored"
            ));
        }
    }
    let stage = control.stage("load", 4)?;
    let limits = &input.limits;
    let extra = method.extra_images(&input.constraints);
    let source = match input.source.filter(|_| use_source) {
        Some(m) => Some(load_model("source", m, limits, &extra)?),
        None => None,
    };
    control.check()?;
    let target = load_model("target", input.target, limits, &extra)?;
    let source_base = match input.source_base.filter(|_| use_base) {
        Some(m) => Some(load_model("source_base", m, limits, &extra)?),
        None => None,
    };
    let pattern = match input.pattern.filter(|_| use_pattern) {
        Some(p) => {
            let header =
                read_header(0, p.bytes, limits).map_err(|source| TransferError::Ingest {
                    side: "pattern",
                    source,
                })?;
            Some((p, Demand::of_image(&header)))
        }
        None => None,
    };
    let mut demands: Vec<(&'static str, &Demand)> = Vec::new();
    if let Some((_, d)) = &source {
        demands.push(("source", d));
    }
    demands.push(("target", &target.1));
    if let Some((_, d)) = &source_base {
        demands.push(("source_base", d));
    }
    if let Some((_, d)) = &pattern {
        demands.push(("pattern", d));
    }
    budget::check_job(&demands, limits)
        .map_err(|(side, source)| TransferError::Ingest { side, source })?;
    let triangles = demands.iter().map(|(_, d)| d.triangles).sum();
    check_working_set(method, &input.constraints, triangles, limits)?;
    stage.tick(1)?;

    let decode = |side: &'static str, (mut asset, demand): (Asset, Demand)| {
        control.check()?;
        budget::decode_images(&mut asset, &demand, limits)
            .map_err(|source| TransferError::Ingest { side, source })?;
        Ok::<_, TransferError>(asset)
    };
    let source = source.map(|m| decode("source", m)).transpose()?;
    stage.tick(1)?;
    let target = decode("target", target)?;
    let source_base = source_base.map(|m| decode("source_base", m)).transpose()?;
    stage.tick(1)?;
    let pattern = match pattern {
        Some((p, _)) => Some(
            PatternImage::decode(p.name, p.bytes.to_vec(), limits).map_err(|source| {
                TransferError::Ingest {
                    side: "pattern",
                    source,
                }
            })?,
        ),
        None => None,
    };
    stage.tick(1)?;
    Ok(Loaded {
        source,
        target,
        source_base,
        pattern,
        warnings,
    })
}

/// Artifacts of the images the edits add, in edit order.
fn image_artifacts(edits: &[Edit]) -> Vec<Artifact> {
    edits
        .iter()
        .filter_map(|e| match e {
            Edit::SetTexture { image, .. } => Some(Artifact {
                name: format!("{}.{}", image.name, image.extension()),
                media_type: image.mime_type.clone(),
                bytes: image.bytes.clone(),
            }),
            _ => None,
        })
        .collect()
}

fn run(
    registry: &Registry,
    input: &TransferInput<'_>,
    control: &Control,
) -> Result<TransferOutput, TransferError> {
    let c = &input.constraints;
    let method = checked_method(registry, c, &input.limits)?;
    let span = control.span(0.0, 0.05);
    let loaded = load_inputs(method, input, control)?;
    drop(span);

    let span = control.span(0.05, 0.95);
    let out = method.run(
        &MethodInput {
            source: loaded.source.as_ref(),
            target: &loaded.target,
            source_base: loaded.source_base.as_ref(),
            pattern: loaded.pattern.as_ref(),
            constraints: c,
        },
        control,
    )?;
    drop(span);

    let _span = control.span(0.95, 1.0);
    control.stage("export", 1)?;
    let edited = match out.asset {
        EditedAsset::Target => &loaded.target,
        EditedAsset::Source => loaded.source.as_ref().ok_or_else(|| {
            MethodError::Internal("the method edited a source it did not read".into())
        })?,
    };
    let model = export(edited, &out.edits, c.output.format)?;
    control.finish();

    let mut warnings = loaded.warnings;
    warnings.extend(out.warnings);
    let report = TransferReport {
        method: c.method,
        edited: out.asset,
        source_warnings: loaded
            .source
            .as_ref()
            .map(|s| s.warnings.clone())
            .unwrap_or_default(),
        target_warnings: loaded.target.warnings.clone(),
        warnings,
        method_report: out.report,
        timings: control.timings(),
        output_bytes: model.len(),
    };
    let mut artifacts = image_artifacts(&out.edits);
    artifacts.extend(out.files.into_iter().map(|f| Artifact {
        name: f.name,
        media_type: f.media_type,
        bytes: f.bytes,
    }));
    artifacts.push(Artifact {
        name: "report.json".into(),
        media_type: "application/json".into(),
        bytes: serde_json::to_vec_pretty(&report).unwrap_or_default(),
    });
    Ok(TransferOutput {
        model,
        format: c.output.format,
        report,
        artifacts,
    })
}
