//! Command-line flags (clap) and what each subcommand calls in the library.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

use splat4d::io::image_file::{BitDepth, ImageKind, save_image};
use splat4d::render::{DEFAULT_CUTOFF, DEFAULT_DILATION};
use splat4d::{Camera, RenderContext, RenderOptions, Scene};

/// The shipped seed blob (SPEC §7) and a camera that frames its path, for the default job.
const BLOB_SCENE: &str = include_str!("../data/blob.json");
const BLOB_CAMERA: &str = include_str!("../data/blob_camera.json");

/// splat4d: render and fit dynamic scenes of 4D Gaussian kernels on the CPU.
///
/// Without a subcommand, renders the shipped seed blob at t = 0, 0.5 and 1 into `out/`.
#[derive(Debug, Parser)]
#[command(name = "splat4d", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Render a scene through a camera at one time into a PNG or EXR image.
    Render(RenderArgs),
}

#[derive(Debug, clap::Args)]
struct RenderArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Camera JSON file.
    #[arg(long)]
    camera: PathBuf,
    /// Scene time τ.
    #[arg(long, allow_negative_numbers = true)]
    time: f64,
    /// Output image: `.png` (8 or 16 bits) or `.exr` (float32 linear RGB).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    render: RenderFlags,
    /// Bits per channel of a PNG output: 8 or 16.
    #[arg(long, default_value_t = 8, value_parser = parse_bit_depth)]
    bit_depth: u8,
}

/// Flags shared by every command that renders.
#[derive(Debug, clap::Args)]
struct RenderFlags {
    /// Variance added to each screen-space covariance, px² (SPEC §4).
    #[arg(long, default_value_t = DEFAULT_DILATION, allow_negative_numbers = true)]
    dilation: f64,
    /// Cut-off ε on a kernel's value; 0 disables truncation (SPEC §5).
    #[arg(long, default_value_t = DEFAULT_CUTOFF, allow_negative_numbers = true)]
    cutoff: f64,
    /// Worker threads (default: one per core). The output does not depend on it.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    threads: Option<u16>,
}

impl RenderFlags {
    fn options(&self) -> Result<RenderOptions> {
        let options = RenderOptions {
            dilation: self.dilation,
            cutoff: self.cutoff,
        };
        options.validate()?;
        Ok(options)
    }
}

fn parse_bit_depth(text: &str) -> Result<u8, String> {
    match text {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("`{text}` is not a bit depth: use 8 or 16")),
    }
}

/// Runs `work` on a pool of `threads` threads, or on rayon's global pool.
fn with_threads<T: Send>(threads: Option<u16>, work: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(work()),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(usize::from(n))
                .build()
                .context("cannot start the worker threads")?;
            Ok(pool.install(work))
        }
    }
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        None => default_job(),
        Some(Command::Render(args)) => render_command(&args),
    }
}

fn render_command(args: &RenderArgs) -> Result<()> {
    let options = args.render.options()?;
    // Check the output's extension before any work, so a typo costs nothing.
    ImageKind::from_path(&args.out)?;
    let scene = Scene::load(&args.scene)?;
    let camera = Camera::load(&args.camera)?;
    let depth = if args.bit_depth == 16 {
        BitDepth::Sixteen
    } else {
        BitDepth::Eight
    };
    let mut context = RenderContext::new();
    let stats = with_threads(args.render.threads, || {
        context.render(&scene, &camera, args.time, &options)
    })??;
    save_image(context.image(), &args.out, depth)?;
    println!(
        "{}: {}×{} at t = {}, {} of {} kernels on screen, {} pairs",
        args.out.display(),
        camera.width,
        camera.height,
        args.time,
        stats.projected,
        scene.len(),
        stats.pairs
    );
    Ok(())
}

/// The default job: the shipped blob at t = 0, 0.5, 1 into `out/`.
fn default_job() -> Result<()> {
    let scene = Scene::from_json_str(BLOB_SCENE, "data/blob.json")?;
    let camera = Camera::from_json_str(BLOB_CAMERA, "data/blob_camera.json")?;
    let options = RenderOptions::default();
    let mut context = RenderContext::new();
    let out = Path::new("out");
    for tau in [0.0, 0.5, 1.0] {
        context.render(&scene, &camera, tau, &options)?;
        let path = out.join(format!("blob_t{tau:.2}.png"));
        save_image(context.image(), &path, BitDepth::Eight)?;
        println!("wrote {} (the seed blob at t = {tau})", path.display());
    }
    Ok(())
}
