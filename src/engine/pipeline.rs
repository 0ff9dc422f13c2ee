//! The whole transfer as one call: ingest both assets, run the method, export. This is exactly
//! what a service job runs and what `retex transfer` runs (DESIGN.md "Data flow").
//!
//! Stages reported through the [`Control`]: load, surface, align, bake, pad, export. The output
//! model bytes are deterministic (same inputs, constraints and seed give identical bytes with any
//! thread count); the report carries wall-clock timings and so is not.

use std::time::Instant;

use serde::Serialize;

use crate::engine::asset::constraints::{Constraints, ConstraintsError, MethodId, OutputFormat};
use crate::engine::asset::export::{export, ExportError};
use crate::engine::asset::{load, BlobSet, IngestError, IngestLimits};
use crate::engine::control::{Cancelled, Control};
use crate::engine::methods::meshmatch::{self, MeshMatchError, MeshMatchParams};
use crate::engine::methods::project::{self, ProjectError, ProjectParams};

/// The parsed parameters of the method that runs.
enum MethodParams {
    Project(ProjectParams),
    Meshmatch(Box<MeshMatchParams>),
}

/// One input model: the name of its main file inside its blob set.
#[derive(Clone, Copy, Debug)]
pub struct ModelInput<'a> {
    /// Name of the .glb or .gltf inside `blobs`.
    pub main: &'a str,
    /// The uploaded files.
    pub blobs: &'a BlobSet,
}

/// Everything a transfer needs.
#[derive(Clone, Debug)]
pub struct TransferInput<'a> {
    /// The textured source.
    pub source: ModelInput<'a>,
    /// The target that receives the appearance.
    pub target: ModelInput<'a>,
    /// The job description.
    pub constraints: Constraints,
    /// Ingest limits applied to both models.
    pub limits: IngestLimits,
}

/// A named by-product of a job (baked PNGs, the report).
#[derive(Clone, Debug)]
pub struct Artifact {
    /// File name, unique within the job.
    pub name: String,
    /// MIME type.
    pub media_type: &'static str,
    /// Content.
    pub bytes: Vec<u8>,
}

/// Wall-clock time of one stage.
#[derive(Clone, Debug, Serialize)]
pub struct StageTiming {
    /// Stage name.
    pub stage: String,
    /// Milliseconds.
    pub ms: f64,
}

/// The job report (also written as the `report.json` artifact).
#[derive(Clone, Debug, Serialize)]
pub struct TransferReport {
    /// The method that ran.
    pub method: MethodId,
    /// Warnings from ingest of the source.
    pub source_warnings: Vec<String>,
    /// Warnings from ingest of the target.
    pub target_warnings: Vec<String>,
    /// The method's own figures.
    pub method_report: serde_json::Value,
    /// Time per stage.
    pub timings: Vec<StageTiming>,
    /// Size of the output model in bytes.
    pub output_bytes: usize,
}

/// The result of a transfer.
#[derive(Clone, Debug)]
pub struct TransferOutput {
    /// The textured target, GLB or .gltf.
    pub model: Vec<u8>,
    /// Its format.
    pub format: OutputFormat,
    /// Figures and warnings.
    pub report: TransferReport,
    /// By-products, including `report.json`.
    pub artifacts: Vec<Artifact>,
}

/// Failures of a transfer; each names the side or field at fault.
#[derive(Debug, thiserror::Error)]
pub enum TransferError {
    /// One of the models could not be loaded.
    #[error("{side}: {source}")]
    Ingest {
        /// "source" or "target".
        side: &'static str,
        /// The cause.
        source: IngestError,
    },
    /// The constraints are invalid.
    #[error(transparent)]
    Constraints(#[from] ConstraintsError),
    /// The method is known but not implemented yet.
    #[error("method {0:?} is not implemented yet; available: project, meshmatch")]
    MethodNotImplemented(&'static str),
    /// The `project` method failed.
    #[error(transparent)]
    Project(ProjectError),
    /// The `meshmatch` method failed.
    #[error(transparent)]
    Meshmatch(MeshMatchError),
    /// Writing the output failed.
    #[error(transparent)]
    Export(#[from] ExportError),
    /// Cancelled through the Control.
    #[error("cancelled")]
    Cancelled,
}

impl From<Cancelled> for TransferError {
    fn from(_: Cancelled) -> Self {
        TransferError::Cancelled
    }
}

impl From<ProjectError> for TransferError {
    fn from(e: ProjectError) -> Self {
        match e {
            ProjectError::Cancelled(_) => TransferError::Cancelled,
            ProjectError::Constraints(c) => TransferError::Constraints(c),
            other => TransferError::Project(other),
        }
    }
}

impl From<MeshMatchError> for TransferError {
    fn from(e: MeshMatchError) -> Self {
        if e.is_cancelled() {
            return TransferError::Cancelled;
        }
        match e {
            MeshMatchError::Constraints(c) => TransferError::Constraints(c),
            other => TransferError::Meshmatch(other),
        }
    }
}

/// Runs a whole transfer under `control`.
pub fn transfer(
    input: &TransferInput<'_>,
    control: &Control,
) -> Result<TransferOutput, TransferError> {
    let c = &input.constraints;
    c.validate()?;
    let params = match c.method {
        MethodId::Project => MethodParams::Project(ProjectParams::from_constraints(c)?),
        MethodId::Meshmatch => {
            MethodParams::Meshmatch(Box::new(MeshMatchParams::from_constraints(c)?))
        }
        other => return Err(TransferError::MethodNotImplemented(other.as_str())),
    };
    control.plan(6);
    let mut timings = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &str, timings: &mut Vec<StageTiming>| {
        let now = Instant::now();
        timings.push(StageTiming {
            stage: name.to_string(),
            ms: (now - clock).as_secs_f64() * 1e3,
        });
        clock = now;
    };

    control.stage("load", 2)?;
    let source = load(input.source.main, input.source.blobs, &input.limits).map_err(|source| {
        TransferError::Ingest {
            side: "source",
            source,
        }
    })?;
    control.check()?;
    let target = load(input.target.main, input.target.blobs, &input.limits).map_err(|source| {
        TransferError::Ingest {
            side: "target",
            source,
        }
    })?;
    lap("load", &mut timings);

    let mut extra = Vec::new();
    let (edits, method_report) = match &params {
        MethodParams::Project(p) => {
            let (edits, report) = project::run(&source, &target, c, p, control)?;
            lap("project", &mut timings);
            (edits, serde_json::to_value(&report).unwrap_or_default())
        }
        MethodParams::Meshmatch(p) => {
            let (edits, report, nnf) = meshmatch::run(&source, &target, c, p, control)?;
            lap("meshmatch", &mut timings);
            if let Some(bytes) = nnf {
                extra.push(Artifact {
                    name: "nnf.bin".into(),
                    media_type: "application/octet-stream",
                    bytes,
                });
            }
            (edits, serde_json::to_value(&report).unwrap_or_default())
        }
    };

    control.stage("export", 1)?;
    let model = export(&target, &edits, c.output.format)?;
    lap("export", &mut timings);
    control.finish();

    let mut artifacts: Vec<Artifact> = edits
        .textures
        .iter()
        .map(|t| Artifact {
            name: format!("{}.png", t.name),
            media_type: "image/png",
            bytes: t.png.clone(),
        })
        .collect();
    let report = TransferReport {
        method: c.method,
        source_warnings: source.warnings.clone(),
        target_warnings: target.warnings.clone(),
        method_report,
        timings,
        output_bytes: model.len(),
    };
    artifacts.extend(extra);
    artifacts.push(Artifact {
        name: "report.json".into(),
        media_type: "application/json",
        bytes: serde_json::to_vec_pretty(&report).unwrap_or_default(),
    });
    Ok(TransferOutput {
        model,
        format: c.output.format,
        report,
        artifacts,
    })
}
