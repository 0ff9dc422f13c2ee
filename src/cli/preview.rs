//! `retex preview`: renders a model's base color from several azimuths into one PNG strip
//! (see [`retex::engine::texture::preview`]), e.g. to look at a transfer's output.

use std::path::PathBuf;

use retex::engine::asset::{load, BlobSet, IngestLimits};
use retex::engine::texture::preview::{render_turntable, PreviewParams};

/// Arguments of `retex preview`.
pub struct Args {
    pub file: PathBuf,
    pub out: PathBuf,
    pub params: PreviewParams,
    pub quiet: bool,
}

/// Runs the command.
pub fn run(args: &Args) -> Result<(), String> {
    // Check the parameters before reading a possibly large model.
    args.params.validate().map_err(|e| e.to_string())?;
    super::check_output(&args.out, &["png"])?;
    let path = &args.file;
    let (main, blobs) = BlobSet::from_path(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let asset = load(&main, &blobs, &IngestLimits::default())
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let image =
        render_turntable(&asset, &args.params).map_err(|e| format!("{}: {e}", path.display()))?;
    let png = image.to_png();
    if png.is_empty() {
        return Err("png encoding failed".into());
    }
    std::fs::write(&args.out, &png).map_err(|e| format!("{}: {e}", args.out.display()))?;
    if !args.quiet {
        eprintln!(
            "wrote {} ({}x{}, {} views)",
            args.out.display(),
            image.width,
            image.height,
            args.params.views
        );
    }
    Ok(())
}
