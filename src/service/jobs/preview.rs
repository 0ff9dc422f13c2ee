//! The preview stage of a job (issue 16, part 1): after the method succeeded, the runner renders
//! a turntable PNG of the result (`preview.png`) and small ones of the inputs
//! (`source_preview.png`, `target_preview.png`) with the engine's software renderer
//! ([`crate::engine::texture::preview::render_turntable`]) and stores them as job artifacts, so
//! they are served, with ETags, by `GET /v1/jobs/{id}/artifacts/{name}` like every other file.
//!
//! - Runs on the job's engine thread (the worker pool), after the method and before the outputs
//!   are stored, under its own [`Control`] whose stages (`preview: result`, `preview: source`,
//!   `preview: target`) the runner counts in the job's progress ([`combined_progress`]) and whose
//!   timings are appended to the report's `timings`.
//! - Never fails a job: a model that does not load or render becomes a line in the report's
//!   `warnings` (`preview: ...`) and that file is left out.
//! - Views: [`RESULT_VIEWS`] azimuths of [`RESULT_SIZE`] px for the result and [`INPUT_VIEWS`] of
//!   [`INPUT_SIZE`] px for the inputs, base colour with Lambert shading. Chosen for a dashboard
//!   tile (a 1024 × 256 strip shows front, side, back, side); not from a paper.
//! - A normal map the model carries is lit ([`crate::engine::texture::preview_normals`]); one
//!   left out of the lighting (too large, or not decodable) becomes a warning.

use crate::engine::asset::{load, BlobSet, IngestLimits};
use crate::engine::control::{Control, Progress};
use crate::engine::texture::preview::{render_turntable_noted, PreviewParams};
use crate::service::model::JobProgress;

/// Views of the result turntable.
pub const RESULT_VIEWS: u32 = 4;
/// Pixels per result view (square).
pub const RESULT_SIZE: u32 = 256;
/// Views of an input preview.
pub const INPUT_VIEWS: u32 = 4;
/// Pixels per input view (square).
pub const INPUT_SIZE: u32 = 128;
/// Share of the job's progress bar given to the engine call; the previews take the rest. Not
/// proportional to time for every job: the previews cost about the same for any method (Spot onto
/// its remesh, `project` at 512 texels, in the browser test: 254 ms of a 1287 ms job, 20 %), which
/// is under 1 % of a minute-long meshmatch job; 0.9 keeps the bar moving in both (the stage name
/// says what runs).
pub const ENGINE_SHARE: f64 = 0.9;

/// A model to preview: artifact name, stage name, main file name and its files.
pub struct PreviewInput<'a> {
    /// Artifact name (`preview.png`, ...).
    pub artifact: &'static str,
    /// Stage name shown in progress (`preview: result`).
    pub stage: &'static str,
    /// The main .glb/.gltf file's name in `blobs`.
    pub main: &'a str,
    /// The model's files.
    pub blobs: &'a BlobSet,
    /// Views and their size.
    pub views: u32,
    /// Pixels per view.
    pub size: u32,
}

/// What the stage produced.
#[derive(Debug, Default)]
pub struct Previews {
    /// (artifact name, PNG bytes) of each preview that rendered.
    pub files: Vec<(String, Vec<u8>)>,
    /// One line per preview that did not.
    pub warnings: Vec<String>,
}

/// Renders one model to a PNG; returns it and the renderer's notes.
fn render_one(
    input: &PreviewInput<'_>,
    limits: &IngestLimits,
) -> Result<(Vec<u8>, Vec<String>), String> {
    let asset = load(input.main, input.blobs, limits).map_err(|e| e.to_string())?;
    let params = PreviewParams {
        views: input.views,
        size: input.size,
        ..PreviewParams::default()
    };
    let (image, notes) = render_turntable_noted(&asset, &params).map_err(|e| e.to_string())?;
    let png = image.to_png();
    if png.is_empty() {
        return Err("PNG encoding failed".into());
    }
    Ok((png, notes))
}

/// Renders every input in order, one stage each, then finishes `control`. Returns `None` when
/// the job was cancelled meanwhile (`cancelled` is polled between models).
pub fn render_previews(
    inputs: &[PreviewInput<'_>],
    limits: &IngestLimits,
    control: &Control,
    cancelled: impl Fn() -> bool,
) -> Option<Previews> {
    let mut out = Previews::default();
    for input in inputs {
        if cancelled() {
            return None;
        }
        // The preview control is never cancelled itself: the job's is checked above.
        let _stage = control.stage(input.stage, 1).ok()?;
        match render_one(input, limits) {
            Ok((png, notes)) => {
                out.files.push((input.artifact.to_string(), png));
                out.warnings.extend(
                    notes
                        .into_iter()
                        .map(|n| format!("preview: {}: {n}", input.artifact)),
                );
            }
            Err(e) => out
                .warnings
                .push(format!("preview: {} not rendered: {e}", input.artifact)),
        }
    }
    control.finish();
    Some(out)
}

/// The job's progress: the engine's, scaled into [0, [`ENGINE_SHARE`]], then the previews' in
/// the rest; stage counts add up.
pub fn combined_progress(engine: Progress, preview: Progress) -> JobProgress {
    if preview.stages_total == 0 {
        return JobProgress {
            stage: engine.stage,
            fraction: engine.fraction * ENGINE_SHARE,
            stages_done: engine.stages_done,
            stages_total: engine.stages_total,
        };
    }
    JobProgress {
        stage: preview.stage,
        fraction: ENGINE_SHARE + (1.0 - ENGINE_SHARE) * preview.fraction,
        stages_done: engine.stages_done + preview.stages_done,
        stages_total: engine.stages_total + preview.stages_total,
    }
}

/// Adds the preview stage's timings and warnings to a job report (the JSON of
/// [`crate::engine::pipeline::TransferReport`]).
pub fn amend_report(report: &mut serde_json::Value, control: &Control, warnings: &[String]) {
    if let Some(t) = report
        .get_mut("timings")
        .and_then(serde_json::Value::as_array_mut)
    {
        for timing in control.timings() {
            t.push(serde_json::json!({"stage": timing.stage, "ms": timing.ms}));
        }
    }
    if let Some(w) = report
        .get_mut("warnings")
        .and_then(serde_json::Value::as_array_mut)
    {
        w.extend(warnings.iter().cloned().map(serde_json::Value::from));
    }
}
