//! `retex` command line: `serve` runs the HTTP job service, `transfer` runs exactly what a service job runs, `inspect` describes a
//! model and the problems found in it, `preview` renders a model's base color from several sides, `bench` measures the pipeline on the shared assets.

use clap::{Parser, Subcommand};
use retex::cli;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "retex",
    version,
    about = "Transfer surface appearance between meshes"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Transfer appearance from SOURCE onto TARGET and write the textured target.
    Transfer {
        /// Textured source model (.glb, or .gltf with its files beside it); required by every
        /// method that reads a source.
        #[arg(long)]
        source: Option<PathBuf>,
        /// Target model.
        #[arg(long)]
        target: PathBuf,
        /// Smooth base of the source, for methods that read one.
        #[arg(long)]
        source_base: Option<PathBuf>,
        /// Pattern image (PNG or JPEG), for methods that read one.
        #[arg(long)]
        pattern: Option<PathBuf>,
        /// Constraints JSON v1 (method, correspondences, output options, params).
        #[arg(long)]
        constraints: Option<PathBuf>,
        /// Method id; overrides the constraints' method (default project).
        #[arg(long)]
        method: Option<String>,
        /// Output file (.glb or .gltf; the constraints' output.format wins when given).
        #[arg(long)]
        out: PathBuf,
        /// Also write the report and the baked textures into this folder.
        #[arg(long)]
        artifacts: Option<PathBuf>,
        /// Hide the progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Print meshes, primitives, counts, UV sets, materials, textures, bounds and problems.
    Inspect {
        /// The model.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Render the model's base color from several azimuths around +Y into one PNG strip.
    Preview {
        /// The model.
        file: PathBuf,
        /// Output PNG (views side by side).
        #[arg(long)]
        out: PathBuf,
        /// Number of views (1..=64).
        #[arg(long, default_value_t = 8)]
        views: u32,
        /// Pixels per view, width = height (16..=2048).
        #[arg(long, default_value_t = 256)]
        size: u32,
        /// Camera elevation in degrees ([-89, 89]).
        #[arg(long, default_value_t = 20.0, allow_hyphen_values = true)]
        elevation: f32,
        /// Plain base color, without Lambert + ambient shading.
        #[arg(long)]
        no_shading: bool,
        /// Print nothing on success.
        #[arg(long)]
        quiet: bool,
    },
    /// Run the HTTP job service (see README "Service").
    #[cfg(feature = "service")]
    Serve(Box<cli::serve::ServeArgs>),
    /// Measure ingest and whole transfers on the shared assets; prints a Markdown table.
    Bench {
        /// The shared asset folder.
        #[arg(long, default_value = "../shared/assets")]
        assets: PathBuf,
        /// Runs per case (the median is reported).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Which table: `project` (default), `atlas` (issue 15: atlas and whole transfer onto UV-less targets), `meshmatch`, `elastiface`, `correlation`, `pattern`, or `geometry` (the geometry core on a
        /// 64K-vertex sphere; needs no assets).
        #[arg(long, default_value = "project")]
        method: String,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Transfer {
            source,
            target,
            source_base,
            pattern,
            constraints,
            method,
            out,
            artifacts,
            quiet,
        } => cli::transfer::run(&cli::transfer::Args {
            source,
            target,
            source_base,
            pattern,
            constraints,
            method,
            out,
            artifacts,
            quiet,
        }),
        Command::Inspect { file, json } => cli::inspect::run(&file, json),
        Command::Preview {
            file,
            out,
            views,
            size,
            elevation,
            no_shading,
            quiet,
        } => cli::preview::run(&cli::preview::Args {
            file,
            out,
            params: retex::engine::texture::preview::PreviewParams {
                views,
                size,
                elevation_degrees: elevation,
                shading: !no_shading,
            },
            quiet,
        }),
        Command::Bench {
            assets,
            runs,
            method,
        } => match method.as_str() {
            "project" => cli::bench::run(&assets, runs),
            "atlas" => cli::bench_atlas::run(&assets, runs),
            "meshmatch" => cli::bench_meshmatch::run(&assets, runs),
            "elastiface" => cli::bench_elastiface::run(&assets, runs),
            "correlation" => cli::bench_correlation::run(&assets, runs),
            "pattern" => cli::bench_pattern::run(&assets, runs),
            "detail" => cli::bench_detail::run(&assets, runs),
            "geometry" => cli::bench_geometry::run(runs),
            other => Err(format!(
                "no benchmark for method {other:?}: expected project, atlas, meshmatch, elastiface, correlation, pattern, detail or geometry"
            )),
        },
        #[cfg(feature = "service")]
        Command::Serve(args) => cli::serve::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}
