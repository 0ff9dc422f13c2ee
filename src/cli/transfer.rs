//! `retex transfer`: reads the files, runs [`retex::engine::pipeline::transfer`] on a worker
//! thread while a progress bar shows the Control's stage and fraction, writes the output.

use std::path::{Path, PathBuf};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use retex::engine::asset::constraints::{Constraints, MethodId, OutputFormat};
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ImageInput, ModelInput, TransferInput};

/// Arguments of `retex transfer`.
pub struct Args {
    pub source: Option<PathBuf>,
    pub target: PathBuf,
    pub source_base: Option<PathBuf>,
    pub pattern: Option<PathBuf>,
    pub constraints: Option<PathBuf>,
    pub method: Option<String>,
    pub out: PathBuf,
    pub artifacts: Option<PathBuf>,
    pub quiet: bool,
}

fn read_model(path: &Path) -> Result<(String, BlobSet), String> {
    BlobSet::from_path(path).map_err(|e| format!("{}: {e}", path.display()))
}

/// Runs the command.
pub fn run(args: &Args) -> Result<(), String> {
    // Fail on an unwritable output before the (possibly long) transfer, not after it.
    super::check_output(&args.out, &["glb", "gltf"])?;
    if let Some(dir) = &args.artifacts {
        std::fs::create_dir_all(dir).map_err(|e| format!("--artifacts {}: {e}", dir.display()))?;
    }
    let source = args.source.as_deref().map(read_model).transpose()?;
    let (tgt_main, tgt_blobs) = read_model(&args.target)?;
    let base = args.source_base.as_deref().map(read_model).transpose()?;
    let pattern = match &args.pattern {
        Some(p) => {
            let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
            let name = p
                .file_name()
                .map_or_else(|| "pattern".into(), |n| n.to_string_lossy().into_owned());
            Some((name, bytes))
        }
        None => None,
    };
    let mut constraints = match &args.constraints {
        Some(p) => {
            let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
            Constraints::from_json(&bytes).map_err(|e| format!("{}: {e}", p.display()))?
        }
        None => {
            let mut c = Constraints::default();
            if args
                .out
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("gltf"))
            {
                c.output.format = OutputFormat::Gltf;
            }
            c
        }
    };
    if let Some(m) = &args.method {
        constraints.method = MethodId::parse(m).map_err(|e| e.to_string())?;
    }
    let control = Control::new();
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(1000)
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} {elapsed_precise} [{bar:40}] {percent:>3}% {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let mut input = TransferInput::new(
        ModelInput {
            main: &tgt_main,
            blobs: &tgt_blobs,
        },
        constraints,
    );
    if let Some((main, blobs)) = &source {
        input = input.with_source(ModelInput { main, blobs });
    }
    if let Some((main, blobs)) = &base {
        input = input.with_source_base(ModelInput { main, blobs });
    }
    if let Some((name, bytes)) = &pattern {
        input = input.with_pattern(ImageInput { name, bytes });
    }
    let result = std::thread::scope(|scope| {
        let worker = scope.spawn(|| transfer(&input, &control));
        while !worker.is_finished() {
            let p = control.progress();
            bar.set_position((p.fraction * 1000.0) as u64);
            bar.set_message(p.stage);
            std::thread::sleep(Duration::from_millis(50));
        }
        match worker.join() {
            Ok(r) => r.map_err(|e| e.to_string()),
            Err(panic) => {
                let msg = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                Err(format!("internal error: {msg}"))
            }
        }
    });
    bar.finish_and_clear();
    let output = result?;
    std::fs::write(&args.out, &output.model).map_err(|e| format!("{}: {e}", args.out.display()))?;
    if let Some(dir) = &args.artifacts {
        for a in &output.artifacts {
            let p = dir.join(&a.name);
            std::fs::write(&p, &a.bytes).map_err(|e| format!("{}: {e}", p.display()))?;
        }
    }
    if !args.quiet {
        let total: f64 = output.report.timings.iter().map(|t| t.ms).sum();

        eprintln!(
            "wrote {} ({} bytes) in {:.0} ms",
            args.out.display(),
            output.model.len(),
            total
        );
        for w in output
            .report
            .source_warnings
            .iter()
            .chain(&output.report.target_warnings)
            .chain(&output.report.warnings)
        {
            eprintln!("warning: {w}");
        }
    }
    Ok(())
}
