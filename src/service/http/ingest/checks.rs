//! The checks of a submission that read the uploaded files: each model loads under the limits
//! without decoding pixels, the pattern's header is read, and the job's memory budget
//! ([`crate::engine::asset::budget`], the method's working set) holds over all of them, so an
//! upload that would need too much memory is refused before it is stored.

use std::path::Path;

use axum::http::StatusCode;

use super::{ApiError, UploadModel};
use crate::engine::asset::budget::{self, Demand};
use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::images::ImageHeader;
use crate::engine::asset::{load_with, BlobSet, Decode};
use crate::engine::methods::Method;
use crate::engine::pipeline::check_working_set;
use crate::service::config::ServeConfig;
use crate::service::problem_table::transfer_problem;

/// The job's budget over every input it reads (source, target, source base, pattern, in that
/// order), from the headers: what the job checks again before decoding.
pub(super) fn job_budget(
    demands: [Option<&Demand>; 4],
    method: &dyn Method,
    constraints: &Constraints,
    config: &ServeConfig,
) -> Result<(), ApiError> {
    let inputs: Vec<(&'static str, &Demand)> = ["source", "target", "source_base", "pattern"]
        .into_iter()
        .zip(demands)
        .filter_map(|(side, d)| d.map(|d| (side, d)))
        .collect();
    budget::check_job(&inputs, &config.limits).map_err(|(side, e)| ApiError::ingest(side, &e))?;
    let triangles = inputs.iter().map(|(_, d)| d.triangles).sum();
    check_working_set(method, constraints, triangles, &config.limits)
        .map_err(|e| ApiError::from_problem(transfer_problem(&e)))
}

/// Loads a model under the configured limits without decoding pixels and returns what it will
/// hold once loaded; the asset is dropped (the job loads it again on the engine pool).
pub(super) fn validate_model(
    side: &str,
    model: &UploadModel,
    config: &ServeConfig,
    extra: &[(&'static str, usize)],
) -> Result<Demand, ApiError> {
    let mut blobs = BlobSet::new();
    for f in &model.files {
        let bytes = std::fs::read(&f.path).map_err(ApiError::io)?;
        blobs.insert(f.name.clone(), bytes);
    }
    // Structure, ranges and image headers are checked here; pixels are decoded by the job.
    load_with(&model.main, &blobs, &config.limits, Decode::HeadersOnly)
        .map(|asset| {
            let extra: Vec<usize> = extra
                .iter()
                .filter(|(s, _)| *s == side)
                .map(|(_, i)| *i)
                .collect();
            Demand::of_asset(&asset, &extra)
        })
        .map_err(|e| ApiError::ingest(side, &e))
}

/// A pattern must be a PNG or JPEG within the image limits (only its header is read); returns
/// its decoded size for the job's budget.
pub(super) fn check_pattern(path: &Path, config: &ServeConfig) -> Result<Demand, ApiError> {
    let bad = |detail: String| {
        ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-pattern",
            "Invalid pattern image",
            detail,
        )
        .field("pattern")
    };
    let reader = image::ImageReader::open(path)
        .and_then(|r| r.with_guessed_format())
        .map_err(|e| bad(e.to_string()))?;
    if !matches!(
        reader.format(),
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg)
    ) {
        return Err(bad("not a png or jpeg image".into()));
    }
    let format = reader.format().unwrap_or(image::ImageFormat::Png);
    let decoder = reader.into_decoder().map_err(|e| bad(e.to_string()))?;
    let (w, h) = image::ImageDecoder::dimensions(&decoder);
    let bytes_per_pixel = image::ImageDecoder::color_type(&decoder).bytes_per_pixel();
    let side = config.limits.max_image_side;
    if w > side || h > side {
        return Err(
            bad(format!("{w}x{h} exceeds max_image_side = {side}")).limit("max_image_side", side)
        );
    }
    Ok(Demand::of_image(&ImageHeader {
        format,
        width: w,
        height: h,
        bytes_per_pixel,
    }))
}
