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
//! - Not done: the renderer draws the base colour only, so a normal map a method outputs is not
//!   lit in the preview (the 3D view of the dashboard shows it).

use crate::engine::asset::{load, BlobSet, IngestLimits};
use crate::engine::control::{Control, Progress};
use crate::engine::texture::preview::{render_turntable, PreviewParams};
use crate::service::model::JobProgress;

/// Views of the result turntable.
pub const RESULT_VIEWS: u32 = 4;
/// Pixels per result view (square).
pub const RESULT_SIZE: u32 = 256;
/// Views of an input preview.
pub const INPUT_VIEWS: u32 = 4;
/// Pixels per input view (square).
pub const INPUT_SIZE: u32 = 128;
/// Share of the job's progress bar given to the engine call; the previews take the rest. The
/// previews of the test assets take 2-5 % of a job's time (`project` at 1024 texels on Spot), so
/// the bar does not stall at the end.
pub const ENGINE_SHARE: f64 = 0.95;

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

/// Renders one model to a PNG.
fn render_one(input: &PreviewInput<'_>, limits: &IngestLimits) -> Result<Vec<u8>, String> {
    let asset = load(input.main, input.blobs, limits).map_err(|e| e.to_string())?;
    let params = PreviewParams {
        views: input.views,
        size: input.size,
        ..PreviewParams::default()
    };
    let image = render_turntable(&asset, &params).map_err(|e| e.to_string())?;
    let png = image.to_png();
    if png.is_empty() {
        return Err("PNG encoding failed".into());
    }
    Ok(png)
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
            Ok(png) => out.files.push((input.artifact.to_string(), png)),
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_model_that_does_not_load_is_a_warning_and_the_stage_still_finishes() {
        let mut blobs = BlobSet::new();
        blobs.insert("m.glb", b"not a glb at all".to_vec());
        let inputs = [PreviewInput {
            artifact: "preview.png",
            stage: "preview: result",
            main: "m.glb",
            blobs: &blobs,
            views: 2,
            size: 32,
        }];
        let control = Control::new();
        let out = render_previews(&inputs, &IngestLimits::default(), &control, || false).unwrap();
        assert!(out.files.is_empty());
        assert_eq!(out.warnings.len(), 1);
        assert!(
            out.warnings[0].starts_with("preview: preview.png"),
            "{:?}",
            out.warnings
        );
        let p = control.progress();
        assert_eq!((p.stages_done, p.stages_total), (1, 1));
        assert!((p.fraction - 1.0).abs() < 1e-12);
        let mut report = serde_json::json!({"timings": [], "warnings": ["w"]});
        amend_report(&mut report, &control, &out.warnings);
        assert_eq!(report["timings"][0]["stage"], "preview: result");
        assert_eq!(report["warnings"].as_array().unwrap().len(), 2);
    }

    #[test]
    fn a_cancelled_job_renders_nothing() {
        let blobs = BlobSet::new();
        let inputs = [PreviewInput {
            artifact: "preview.png",
            stage: "preview: result",
            main: "m.glb",
            blobs: &blobs,
            views: 2,
            size: 32,
        }];
        assert!(
            render_previews(&inputs, &IngestLimits::default(), &Control::new(), || true).is_none()
        );
    }

    #[test]
    fn progress_is_monotone_across_the_engine_and_the_previews() {
        let engine = Control::new();
        let preview = Control::new();
        engine.stage("load", 0).unwrap();
        let a = combined_progress(engine.progress(), preview.progress());
        engine.finish();
        let b = combined_progress(engine.progress(), preview.progress());
        assert!((b.fraction - ENGINE_SHARE).abs() < 1e-12);
        preview.stage("preview: result", 1).unwrap();
        let c = combined_progress(engine.progress(), preview.progress());
        assert_eq!(c.stage, "preview: result");
        preview.finish();
        let d = combined_progress(engine.progress(), preview.progress());
        assert!(a.fraction <= b.fraction && b.fraction <= c.fraction && c.fraction < d.fraction);
        assert!((d.fraction - 1.0).abs() < 1e-12);
        assert_eq!(d.stages_done, d.stages_total);
        assert_eq!(d.stages_total, 2);
    }
}
