//! Command-line flags (clap) and what each subcommand calls in the library.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

use indicatif::{ProgressBar, ProgressStyle};
use splat4d::fit::adam::LearningRates;
use splat4d::fit::adaptive::AdaptiveOptions;
use splat4d::fit::dataset::{DatasetSpec, frame_count, render_dataset};
use splat4d::fit::init::{SpaceTimeBox, box_from_cameras, centre_scene, random_scene};
use splat4d::fit::loss::{psnr, view_loss_and_gradients};
use splat4d::fit::train::{DEFAULT_RATES, FitMode, FitOptions, evaluate, fit};
use splat4d::io::dataset::{SPLITS, load_dataset, write_split};
use splat4d::io::image_file::{BitDepth, ImageKind, load_image, save_image};
use splat4d::io::write_bytes_atomically;
use splat4d::raster::ExpMode;
use splat4d::render::{DEFAULT_CUTOFF, DEFAULT_DILATION};
use splat4d::{Camera, Gradients, RenderContext, RenderOptions, Scene};

/// Prints a line of the report to stdout. A closed stdout (`splat4d … | head`) is not an
/// error: the work is done and written, only the report has no reader.
macro_rules! report {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout().lock(), $($arg)*);
    }};
}

/// splat4d: render and fit dynamic scenes of 4D Gaussian kernels on the CPU.
///
/// Without a subcommand, runs the seed paper's experiment and writes `out/report.md`.
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
    /// The MSE of a render against a target image, and its gradient per kernel, as JSON.
    Grad(GradArgs),
    /// Render a multi-view dataset (D-NeRF / Blender layout) of a scene.
    Dataset(DatasetArgs),
    /// Fit kernels to a multi-view dataset with Adam.
    Fit(Box<FitArgs>),
    /// Write the seed paper's toy scene: its point data, or the continuous blob.
    Toy(ToyArgs),
    /// Evaluate the Eq. 1 sum on a 3D grid; write slices through its peak and print max/min per time.
    Volume(VolumeArgs),
    /// Sample a glTF 2.0 model (.gltf or .glb) and its node animation into 4D kernels.
    ImportGltf(ImportGltfArgs),
    /// Write the 3D Gaussian Splatting PLY of a scene's slice at one time, for splat viewers.
    ExportPly(ExportPlyArgs),
    /// Render videos along camera paths: orbits at fixed times, a spiral, or a path file.
    Video(VideoArgs),
    /// Measure forward-render speed, with the error against the f64 reference.
    Bench(BenchArgs),
    /// Run the seed paper's experiment (toy data → dataset → fits → baselines → ablation →
    /// volumes) and write `report.md` with its charts.
    Report(ReportArgs),
}

/// An orbit or spiral: explicit `cx,cy,cz,radius,elevation,frames`, or `auto` (from the
/// scene's bounds: 20° elevation, 60 frames).
#[derive(Clone, Debug)]
struct CircleSpec(Option<[f64; 6]>);

fn parse_circle(text: &str) -> Result<CircleSpec, String> {
    if text == "auto" {
        return Ok(CircleSpec(None));
    }
    let values = parse_list::<6>(text)?;
    if values[5] < 1.0 || values[5].fract() != 0.0 {
        return Err(format!("frames = {} must be a whole number ≥ 1", values[5]));
    }
    Ok(CircleSpec(Some(values)))
}

#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("path_kind").required(true).multiple(true).args(["orbit", "spiral", "path"])))]
struct VideoArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Orbit at each of --times: `cx,cy,cz,radius,elevation_degrees,frames`, or alone for
    /// one framing the scene (a value starting with `-` needs `--orbit=-1,...`).
    #[arg(long, num_args = 0..=1, default_missing_value = "auto", value_parser = parse_circle)]
    orbit: Option<CircleSpec>,
    /// Times of the orbits, comma-separated.
    #[arg(long, default_value = "0.5", value_parser = parse_times, allow_hyphen_values = true)]
    times: TimeList,
    /// One turn while time runs over --time-range and the elevation rises from -e to +e:
    /// `cx,cy,cz,radius,elevation_degrees,frames`, or alone for one framing the scene.
    #[arg(long, num_args = 0..=1, default_missing_value = "auto", value_parser = parse_circle)]
    spiral: Option<CircleSpec>,
    /// Time range of the spiral, `t0,t1`.
    #[arg(long, value_parser = parse_list::<2>, default_value = "0,1", allow_hyphen_values = true)]
    time_range: [f64; 2],
    /// A path file: `[{"camera": {camera JSON}, "time": t}, ...]`.
    #[arg(long)]
    path: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Frame size of orbits and spirals, `WxH`.
    #[arg(long, value_parser = parse_size, default_value = "256x256")]
    size: (u32, u32),
    /// Vertical field of view of orbits and spirals, degrees.
    #[arg(long, default_value_t = 40.0)]
    fov: f64,
    /// Frames per second of the GIF and MP4.
    #[arg(long, default_value_t = 25, value_parser = clap::value_parser!(u32).range(1..=100))]
    fps: u32,
    /// Do not write GIFs.
    #[arg(long)]
    no_gif: bool,
    /// Do not try ffmpeg for MP4s.
    #[arg(long)]
    no_mp4: bool,
    #[command(flatten)]
    render: RenderFlags,
}

#[derive(Debug, clap::Args)]
struct ImportGltfArgs {
    /// The model.
    model: PathBuf,
    /// Surface points to sample (each becomes one kernel per time sample).
    #[arg(long, default_value_t = 2000)]
    kernels: usize,
    /// Time samples over the animation's range (1: static).
    #[arg(long, default_value_t = 16)]
    times: usize,
    /// Output scene (.json or .ply).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the surface samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(Debug, clap::Args)]
struct ExportPlyArgs {
    /// Scene file (JSON or 4D PLY).
    #[arg(long)]
    scene: PathBuf,
    /// Scene time τ of the slice.
    #[arg(long, allow_negative_numbers = true)]
    time: f64,
    /// Output `.ply`.
    #[arg(long)]
    out: PathBuf,
    /// Kernels whose value at τ stays below this cut-off are left out (SPEC §5).
    #[arg(long, default_value_t = DEFAULT_CUTOFF)]
    cutoff: f64,
    /// Add 45 zero `f_rest_*` properties (degree-3 spherical harmonics) for loaders that
    /// require them, such as the reference 3DGS training code.
    #[arg(long)]
    sh_rest: bool,
}

#[derive(Debug, clap::Args)]
struct BenchArgs {
    /// Scene: a built-in seeded bench scene by kernel count (`10k`, `100k`, `1m`, `2500`)
    /// or a scene file; repeat for several (default: `10k` and `100k`).
    #[arg(long)]
    scene: Vec<String>,
    /// Camera file for scene files (default: a look-at camera framing the scene).
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Frame size `WxH` (ignored with --camera).
    #[arg(long, value_parser = parse_size, default_value = "512x512")]
    size: (u32, u32),
    /// Worker threads (default: 1, and one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    threads: Option<u16>,
    /// Timed frames per configuration (the median is reported).
    #[arg(long, default_value_t = 10)]
    frames: usize,
    /// Pixels sampled for the error against the f64 reference.
    #[arg(long, default_value_t = 400)]
    samples: usize,
    /// Scene time τ.
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    time: f64,
    /// Variance added to each screen covariance, px².
    #[arg(long, default_value_t = DEFAULT_DILATION)]
    dilation: f64,
    /// Cut-off ε.
    #[arg(long, default_value_t = DEFAULT_CUTOFF)]
    cutoff: f64,
    /// How exp(-q/2) is evaluated: `poly` (inlined polynomial, batched and vectorised) or
    /// `std` (libm).
    #[arg(long, default_value = "poly")]
    exp: ExpMode,
    /// Time the seed-style dense baseline (every kernel at every pixel) for every scene. By
    /// default it runs when kernels × pixels ≤ 3·10⁹ (a few seconds a frame).
    #[arg(long, conflicts_with = "no_dense")]
    dense: bool,
    /// Never time the dense baseline.
    #[arg(long)]
    no_dense: bool,
    /// Measure speed against error over the cut-off, dilation and exp evaluation on the
    /// first scene (with --threads, or one thread per core); writes sweep.md and sweep.png
    /// to --out.
    #[arg(long)]
    sweep: bool,
    /// Output folder of --sweep.
    #[arg(long, default_value = "out/bench")]
    out: PathBuf,
}

#[derive(Debug, clap::Args)]
struct ReportArgs {
    /// Output folder for report.md and its charts.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// A small, fast configuration (for smoke tests): fewer views, steps and kernels.
    #[arg(long)]
    quick: bool,
    /// Kernels of the 4D model (overrides the default or --quick).
    #[arg(long)]
    kernels: Option<usize>,
    /// Adam steps of the 4D model and of each ablation fit.
    #[arg(long)]
    steps: Option<usize>,
    /// Image size `WxH` of the dataset.
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum ToyKind {
    /// 30 frames × 1000 noisy points along (0,0,0) → (1,1,1), one small kernel each.
    Points,
    /// The single velocity kernel behind the points (SPEC §7).
    Blob,
}

#[derive(Debug, clap::Args)]
struct ToyArgs {
    /// Which scene.
    #[arg(long, value_enum)]
    kind: ToyKind,
    /// Seed of the points.
    #[arg(long, default_value_t = splat4d::toy::DEFAULT_SEED)]
    seed: u64,
    /// Output scene JSON.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Debug, clap::Args)]
struct VolumeArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Grid cells per axis.
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u16).range(2..=1024))]
    res: u16,
    /// Times, comma-separated.
    #[arg(long, default_value = "0,0.5,1", value_parser = parse_times, allow_hyphen_values = true)]
    times: TimeList,
    /// Output folder for the slice images.
    #[arg(long)]
    out: PathBuf,
    /// Cut-off ε per kernel (SPEC §5 applied in 3D); 0 sums every kernel everywhere.
    #[arg(long, default_value_t = 1e-6)]
    cutoff: f64,
    /// Worker threads (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    threads: Option<u16>,
}

#[derive(Debug, clap::Args)]
struct GradArgs {
    #[command(flatten)]
    view: ViewFlags,
    /// Target image (`.exr` or `.png`), the camera's size.
    #[arg(long)]
    target: PathBuf,
    /// Output JSON: `{"loss": L, "kernels": [{"mean": [4], "amplitude": [3], "velocity": [3]}]}`.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    render: RenderFlags,
}

#[derive(Debug, clap::Args)]
struct DatasetArgs {
    /// Scene JSON file.
    #[arg(long)]
    scene: PathBuf,
    /// Training cameras, seeded on a sphere around the scene.
    #[arg(long)]
    views: usize,
    /// Training times, evenly spread over the time range.
    #[arg(long)]
    times: usize,
    /// Image size, `WxH`.
    #[arg(long, value_parser = parse_size)]
    size: (u32, u32),
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the cameras.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Also write float32 EXR images beside the 16-bit PNGs.
    #[arg(long)]
    exr: bool,
    /// Time range `t0,t1`.
    #[arg(long, value_parser = parse_list::<2>, default_value = "0,1", allow_hyphen_values = true)]
    time_range: [f64; 2],
    /// Vertical field of view of the cameras, degrees.
    #[arg(long, default_value_t = 40.0)]
    fov: f64,
    #[command(flatten)]
    render: RenderFlags,
}

#[derive(Debug, clap::Args)]
struct FitArgs {
    /// Dataset folder (D-NeRF layout: transforms_train.json, and val/test for held-out views).
    #[arg(long)]
    views: PathBuf,
    /// Initial scene: `auto` (one kernel at the centre of the box, then densify, prune and
    /// merge so the count follows the data), `random:N` for N kernels in the box (a fixed count unless
    /// --adaptive), or a scene file.
    #[arg(long, default_value = "auto")]
    init: String,
    /// Kernels `auto` starts from: 1 is one kernel at the centre of the box (space and
    /// time); more are spread at random in the box.
    #[arg(long, default_value_t = 1)]
    start_kernels: usize,
    /// Densify and prune during the fit (always on with `--init auto`).
    #[arg(long)]
    adaptive: bool,
    /// Budget of the adaptive fit: never more kernels than this.
    #[arg(long, default_value_t = 100_000)]
    max_kernels: usize,
    /// Steps between densify/prune rounds.
    #[arg(long, default_value_t = 50)]
    densify_every: usize,
    /// Fraction of the steps before the first densify/prune round.
    #[arg(long, default_value_t = AdaptiveOptions::default().from)]
    densify_from: f64,
    /// Fraction of the steps after which the kernel count is frozen.
    #[arg(long, default_value_t = AdaptiveOptions::default().until)]
    densify_until: f64,
    /// Mean positional gradient (loss per standard deviation of motion) at which a kernel
    /// is densified.
    #[arg(long, default_value_t = AdaptiveOptions::default().gradient_threshold)]
    densify_threshold: f64,
    /// Kernels are densified only when the mean training loss fell by less than this
    /// fraction over the last --densify-every steps (the fit has stalled).
    #[arg(long, default_value_t = AdaptiveOptions::default().min_improvement)]
    min_improvement: f64,
    /// Kernels within this many standard deviations of each other (position, time,
    /// velocity, log-scale) are merged into one; 0 disables merging.
    #[arg(long, default_value_t = AdaptiveOptions::default().merge_tolerance)]
    merge_tolerance: f64,
    /// Largest fraction of the kernels densified in one round.
    #[arg(long, default_value_t = 0.5)]
    max_growth: f64,
    /// Peak |amplitude| below which a kernel is pruned (default: 2/255).
    #[arg(long, default_value_t = AdaptiveOptions::default().prune_below)]
    prune_below: f64,
    /// Densified kernels whose mean spatial scale is above this are split (scales / 1.6),
    /// the others cloned (default: when the scales are not fitted, an eighth of the largest
    /// initial scale; otherwise never split: the fit sizes the kernels).
    #[arg(long)]
    min_scale: Option<f64>,
    /// Adam steps.
    #[arg(long)]
    steps: usize,
    /// Output scene JSON.
    #[arg(long)]
    out: PathBuf,
    /// Box for `random:N`: `x0,y0,z0,x1,y1,z1` (default: from the cameras).
    #[arg(long, value_parser = parse_list::<6>, allow_hyphen_values = true)]
    r#box: Option<[f64; 6]>,
    /// Time range for `random:N`: `t0,t1` (default: the training times' range).
    #[arg(long, value_parser = parse_list::<2>, allow_hyphen_values = true)]
    time_range: Option<[f64; 2]>,
    /// Scales for `random:N`: `sx,sy,sz,st` (default: from the box and N).
    #[arg(long, value_parser = parse_list::<4>)]
    init_scale: Option<[f64; 4]>,
    /// Amplitude of every channel for `random:N`.
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
    init_amplitude: f64,
    /// Log file: one JSON object per step (step, seconds, train_loss, heldout_psnr).
    #[arg(long)]
    log: Option<PathBuf>,
    /// Learning rate of the spatial means.
    #[arg(long, default_value_t = DEFAULT_RATES.mean)]
    lr_mean: f64,
    /// Learning rate of the time means.
    #[arg(long, default_value_t = DEFAULT_RATES.time)]
    lr_time: f64,
    /// Learning rate of the amplitudes.
    #[arg(long, default_value_t = DEFAULT_RATES.amplitude)]
    lr_amplitude: f64,
    /// Learning rate of the velocities (with `--mode velocity` or --fit-velocity).
    #[arg(long, default_value_t = DEFAULT_RATES.velocity)]
    lr_velocity: f64,
    /// Learning rates at the last step as a fraction of the first (exponential decay).
    #[arg(long, default_value_t = 0.05)]
    lr_final: f64,
    /// What the fit moves: `paper` (means and amplitudes; kernels static in space, scales
    /// fixed, as in the seed paper), `static` (also the scales), `velocity` (also the
    /// velocities and the scales). Default: `velocity` with `--init auto` (the most compact
    /// models in the report), `paper` otherwise.
    #[arg(long)]
    mode: Option<FitMode>,
    /// Fit the velocities too, whatever the mode.
    #[arg(long)]
    fit_velocity: bool,
    /// Fit the scales (sx, sy, sz, st) too, in log space, whatever the mode.
    #[arg(long)]
    fit_scale: bool,
    /// Learning rate of the scales, a relative change per step (modes `static` and
    /// `velocity`, or --fit-scale).
    #[arg(long, default_value_t = DEFAULT_RATES.scale)]
    lr_scale: f64,
    /// Keep the spatial means fixed.
    #[arg(long)]
    freeze_mean: bool,
    /// Keep the time means fixed.
    #[arg(long)]
    freeze_time: bool,
    /// Keep the amplitudes fixed.
    #[arg(long)]
    freeze_amplitude: bool,
    /// Views per step.
    #[arg(long, default_value_t = 8)]
    batch: usize,
    /// Held-out evaluation period, steps (0: only at the end).
    #[arg(long, default_value_t = 50)]
    eval_every: usize,
    /// Seed of the batch order and of `random:N`.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Background `r,g,b`: RGBA images are composited over it and the fitted scene uses it
    /// (default: white when the images have alpha, as D-NeRF does; otherwise the initial
    /// scene's, black for `random:N`).
    #[arg(long, value_parser = parse_list::<3>)]
    background: Option<[f64; 3]>,
    #[command(flatten)]
    render: RenderFlags,
}

#[derive(Debug, clap::Args)]
struct RenderArgs {
    #[command(flatten)]
    view: ViewFlags,
    /// Output image: `.png` (8 or 16 bits) or `.exr` (float32 linear RGB).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    render: RenderFlags,
    /// Bits per channel of a PNG output: 8 or 16.
    #[arg(long, default_value_t = 8, value_parser = parse_bit_depth)]
    bit_depth: u8,
    /// Draw a debug overlay over the render (PNG only): per-tile load as a red heat map, the
    /// tile grid, and each kernel's ellipse at its cut-off.
    #[arg(long)]
    overlay: bool,
}

/// What to look at: a scene through a camera at a time.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("camera_source").required(true).args(["camera", "camera_from"])))]
struct ViewFlags {
    /// Scene file: JSON or 4D PLY.
    #[arg(long)]
    scene: PathBuf,
    /// Camera JSON file.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// A glTF model's camera instead: `MODEL.gltf[#index]` (the index-th camera node).
    #[arg(long)]
    camera_from: Option<String>,
    /// Image size `WxH` for --camera-from (default: 512 high, the camera's aspect ratio).
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Scene time τ.
    #[arg(long, allow_negative_numbers = true)]
    time: f64,
}

impl ViewFlags {
    fn load(&self) -> Result<(Scene, Camera)> {
        let camera = match (&self.camera, &self.camera_from) {
            (Some(path), _) => Camera::load(path)?,
            (None, Some(spec)) => {
                let (path, index) = splat4d::io::gltf_import::split_camera_spec(spec)?;
                splat4d::io::gltf_import::load_camera(path, index, self.size)?
            }
            (None, None) => unreachable!("clap requires one camera source"),
        };
        Ok((Scene::load(&self.scene)?, camera))
    }

    /// Where the camera came from, for messages.
    fn camera_name(&self) -> String {
        self.camera.as_ref().map_or_else(
            || self.camera_from.clone().unwrap_or_default(),
            |p| p.display().to_string(),
        )
    }
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
    /// How exp(-q/2) is evaluated per pixel: `poly` (inlined polynomial, relative error
    /// ≤ 4e-7, batched and vectorised) or `std` (libm).
    #[arg(long, default_value = "poly")]
    exp: ExpMode,
    /// Worker threads (default: one per core). The output does not depend on it.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    threads: Option<u16>,
}

impl RenderFlags {
    fn options(&self) -> Result<RenderOptions> {
        let options = RenderOptions {
            dilation: self.dilation,
            cutoff: self.cutoff,
            exp: self.exp,
        };
        options.validate()?;
        Ok(options)
    }
}

fn parse_list<const N: usize>(text: &str) -> Result<[f64; N], String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().map_err(|e| format!("`{v}`: {e}")))
        .collect::<Result<_, _>>()?;
    let array: [f64; N] = values
        .try_into()
        .map_err(|v: Vec<f64>| format!("expected {N} comma-separated numbers, got {}", v.len()))?;
    match array.iter().find(|v| !v.is_finite()) {
        Some(v) => Err(format!("{v} is not finite")),
        None => Ok(array),
    }
}

/// A comma-separated list of times.
#[derive(Clone, Debug)]
struct TimeList(Vec<f64>);

fn parse_times(text: &str) -> Result<TimeList, String> {
    text.split(',')
        .map(|v| match v.trim().parse::<f64>() {
            Ok(t) if t.is_finite() => Ok(t),
            _ => Err(format!("`{v}` is not a finite time")),
        })
        .collect::<Result<_, _>>()
        .map(TimeList)
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{text}` is not WxH"))?;
    let parse = |v: &str| v.trim().parse::<u32>().ok().filter(|&n| n > 0);
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("`{text}` is not WxH with W, H ≥ 1")),
    }
}

fn progress_bar(len: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix} [{elapsed_precise}] {wide_bar} {pos}/{len} ({per_sec}) {msg}",
        )
        .expect("a valid template"),
    );
    bar.set_prefix(what.to_owned());
    bar
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
        None => report_command(&ReportArgs {
            out: PathBuf::from("out"),
            quick: false,
            kernels: None,
            steps: None,
            size: None,
        }),
        Some(Command::Render(args)) => render_command(&args),
        Some(Command::Grad(args)) => grad_command(&args),
        Some(Command::Dataset(args)) => dataset_command(&args),
        Some(Command::Fit(args)) => fit_command(&args),
        Some(Command::Toy(args)) => toy_command(&args),
        Some(Command::Volume(args)) => volume_command(&args),
        Some(Command::Report(args)) => report_command(&args),
        Some(Command::Video(args)) => video_command(&args),
        Some(Command::Bench(args)) => bench_command(&args),
        Some(Command::ExportPly(args)) => export_ply_command(&args),
        Some(Command::ImportGltf(args)) => import_gltf_command(&args),
    }
}

fn render_command(args: &RenderArgs) -> Result<()> {
    let options = args.render.options()?;
    // Check the output's extension before any work, so a typo costs nothing.
    let kind = ImageKind::from_path(&args.out)?;
    if args.overlay && kind != ImageKind::Png {
        anyhow::bail!(
            "{}: --overlay draws an 8-bit PNG; use a .png output",
            args.out.display()
        );
    }
    let (scene, camera) = args.view.load()?;
    let depth = if args.bit_depth == 16 {
        BitDepth::Sixteen
    } else {
        BitDepth::Eight
    };
    let mut context = RenderContext::new();
    let stats = with_threads(args.render.threads, || {
        context.render(&scene, &camera, args.view.time, &options)
    })??;
    if args.overlay {
        splat4d::overlay::write_overlay(&context, &args.out)?;
    } else {
        save_image(context.image(), &args.out, depth)?;
    }
    report!(
        "{}: {}×{} at t = {}, {} of {} kernels on screen, {} pairs",
        args.out.display(),
        camera.width,
        camera.height,
        args.view.time,
        stats.projected,
        scene.len(),
        stats.pairs
    );
    Ok(())
}

fn grad_command(args: &GradArgs) -> Result<()> {
    let options = args.render.options()?;
    let (scene, camera) = args.view.load()?;
    let background = scene.background.map(|b| b as f32);
    let target = load_image(&args.target, background)?;
    if (target.width, target.height) != (camera.width, camera.height) {
        anyhow::bail!(
            "{}: the target is {}×{} but {} is {}×{}",
            args.target.display(),
            target.width,
            target.height,
            args.view.camera_name(),
            camera.width,
            camera.height
        );
    }
    let mut context = RenderContext::new();
    let mut grads = Gradients::zeros(scene.len());
    let loss = with_threads(args.render.threads, || {
        view_loss_and_gradients(
            &mut context,
            &scene,
            &camera,
            args.view.time,
            &options,
            &target,
            &mut grads,
        )
    })??;
    write_bytes_atomically(&args.out, grads.to_json_string(loss).as_bytes())?;
    report!(
        "{}: loss {loss:e} (PSNR {:.2} dB), gradients of {} kernels",
        args.out.display(),
        psnr(loss),
        scene.len()
    );
    Ok(())
}

fn dataset_command(args: &DatasetArgs) -> Result<()> {
    let options = args.render.options()?;
    let scene = Scene::load(&args.scene)?;
    let spec = DatasetSpec {
        views: args.views,
        times: args.times,
        width: args.size.0,
        height: args.size.1,
        time_range: args.time_range,
        fov_y_degrees: args.fov,
        seed: args.seed,
    };
    let bar = progress_bar(frame_count(&spec), "render");
    let dataset = with_threads(args.render.threads, || {
        render_dataset(&scene, &spec, &options, || bar.inc(1))
    })??;
    bar.finish_and_clear();
    for (split, views) in SPLITS
        .iter()
        .zip([&dataset.train, &dataset.val, &dataset.test])
    {
        write_split(&args.out, split, views, args.exr)?;
    }
    report!(
        "{}: {} train, {} val, {} test frames ({}×{})",
        args.out.display(),
        dataset.train.len(),
        dataset.val.len(),
        dataset.test.len(),
        spec.width,
        spec.height
    );
    Ok(())
}

fn fit_command(args: &FitArgs) -> Result<()> {
    let render = args.render.options()?;
    let composite_on = args.background.unwrap_or([1.0; 3]).map(|b| b as f32);
    let dataset = load_dataset(&args.views, composite_on)?;
    let train_times = dataset.train.iter().map(|v| v.time);
    let time_range = args.time_range.unwrap_or_else(|| {
        let (lo, hi) = train_times.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), t| {
            (lo.min(t), hi.max(t))
        });
        [lo, hi]
    });
    let auto = args.init == "auto";
    let random_count =
        if auto {
            Some(args.start_kernels.max(1))
        } else {
            match args.init.strip_prefix("random:") {
                Some(count) => Some(count.parse().ok().filter(|&n| n > 0).with_context(|| {
                    format!("--init {}: N must be a whole number ≥ 1", args.init)
                })?),
                None => None,
            }
        };
    let mut scene = match random_count {
        Some(n) => {
            let bounds = match args.r#box {
                Some([x0, y0, z0, x1, y1, z1]) => {
                    if !(x0 < x1 && y0 < y1 && z0 < z1) {
                        anyhow::bail!("--box: need x0 < x1, y0 < y1, z0 < z1");
                    }
                    SpaceTimeBox {
                        min: [x0, y0, z0],
                        max: [x1, y1, z1],
                        time: time_range,
                    }
                }
                None => {
                    let cameras: Vec<Camera> = dataset.train.iter().map(|v| v.camera).collect();
                    box_from_cameras(&cameras, time_range)?
                }
            };
            if let Some(scale) = args.init_scale
                && scale.iter().any(|&s| s <= 0.0)
            {
                anyhow::bail!("--init-scale: every scale must be > 0");
            }
            if auto && n == 1 && args.init_scale.is_none() {
                centre_scene(&bounds, args.init_amplitude)?
            } else {
                random_scene(n, &bounds, args.init_scale, args.init_amplitude, args.seed)?
            }
        }
        None => Scene::load(Path::new(&args.init))?,
    };
    let mode = args.mode.unwrap_or(if auto {
        FitMode::Velocity
    } else {
        FitMode::Paper
    });
    let fits_scales = args.fit_scale || mode != FitMode::Paper;
    let adaptive = (auto || args.adaptive).then(|| {
        // With fixed scales, splitting is the only way to finer kernels.
        let initial_scale = scene
            .scales
            .iter()
            .map(|s| (s[0] * s[1] * s[2]).cbrt())
            .fold(0.0_f64, f64::max);
        let split_above = if fits_scales {
            f64::INFINITY
        } else {
            initial_scale / 8.0
        };
        AdaptiveOptions {
            every: args.densify_every,
            from: args.densify_from,
            until: args.densify_until,
            gradient_threshold: args.densify_threshold,
            prune_below: args.prune_below,
            max_growth: args.max_growth,
            min_improvement: args.min_improvement,
            merge_tolerance: args.merge_tolerance,
            max_kernels: args.max_kernels.max(1),
            min_scale: args.min_scale.unwrap_or(split_above),
        }
    });
    if let Some(background) = args.background {
        scene.background = background;
    } else if dataset.had_alpha {
        scene.background = [1.0; 3];
    }
    let rate = |frozen: bool, lr: f64| if frozen { 0.0 } else { lr };
    let options = FitOptions {
        steps: args.steps,
        batch_size: args.batch,
        learning_rates: LearningRates {
            mean: rate(args.freeze_mean, args.lr_mean),
            time: rate(args.freeze_time, args.lr_time),
            amplitude: rate(args.freeze_amplitude, args.lr_amplitude),
            velocity: rate(
                !(args.fit_velocity || mode == FitMode::Velocity),
                args.lr_velocity,
            ),
            scale: rate(!fits_scales, args.lr_scale),
        },
        final_rate_factor: args.lr_final,
        eval_every: args.eval_every,
        seed: args.seed,
        render,
        adaptive,
        ..FitOptions::default()
    };
    let heldout = if dataset.val.is_empty() {
        &dataset.test
    } else {
        &dataset.val
    };
    let bar = progress_bar(args.steps, "fit");
    let mut last_heldout = None;
    let records = with_threads(args.render.threads, || {
        fit(&mut scene, &dataset.train, heldout, &options, |record| {
            if record.heldout_psnr.is_some() {
                last_heldout = record.heldout_psnr;
            }
            let heldout = last_heldout.map_or(String::new(), |p| format!(", held-out {p:.2} dB"));
            bar.set_message(format!(
                "{} kernels, loss {:.3e}, PSNR {:.2} dB{heldout}",
                record.kernels,
                record.train_loss,
                psnr(record.train_loss)
            ));
            bar.inc(1);
        })
    })??;
    bar.finish_and_clear();
    scene.save(&args.out)?;
    if let Some(log) = &args.log {
        let mut lines = String::new();
        for record in &records {
            lines.push_str(&serde_json::to_string(record)?);
            lines.push('\n');
        }
        write_bytes_atomically(log, lines.as_bytes())?;
    }
    let seconds = records.last().map_or(0.0, |r| r.seconds);
    report!(
        "{}: {} kernels fitted in {} steps, {seconds:.1} s",
        args.out.display(),
        scene.len(),
        args.steps
    );
    let mut context = RenderContext::new();
    for (split, views) in [
        ("train", &dataset.train),
        ("val", &dataset.val),
        ("test", &dataset.test),
    ] {
        if !views.is_empty() {
            let mse = with_threads(args.render.threads, || {
                evaluate(&scene, views, &render, &mut context)
            })??;
            report!(
                "  {split}: {} views, MSE {mse:.3e}, PSNR {:.2} dB",
                views.len(),
                psnr(mse)
            );
        }
    }
    Ok(())
}

fn toy_command(args: &ToyArgs) -> Result<()> {
    let scene = match args.kind {
        ToyKind::Points => splat4d::toy::points_scene(args.seed),
        ToyKind::Blob => splat4d::toy::blob_scene(),
    };
    scene.save(&args.out)?;
    report!("{}: {} kernels", args.out.display(), scene.len());
    Ok(())
}

fn volume_command(args: &VolumeArgs) -> Result<()> {
    use splat4d::volume::{Grid, evaluate_volume, scene_bounds};
    if !(args.cutoff.is_finite() && args.cutoff >= 0.0) {
        anyhow::bail!("--cutoff {} must be finite and ≥ 0", args.cutoff);
    }
    let scene = Scene::load(&args.scene)?;
    let (min, max) = scene_bounds(&scene, &args.times.0, args.cutoff).with_context(|| {
        format!(
            "{}: no kernel is alive at the requested times",
            args.scene.display()
        )
    })?;
    let grid = Grid {
        min,
        max,
        res: usize::from(args.res),
    };
    let name = args
        .scene
        .file_stem()
        .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
    let mut volumes = Vec::new();
    for &tau in &args.times.0 {
        let start = std::time::Instant::now();
        let volume = with_threads(args.threads, || {
            evaluate_volume(&scene, tau, &grid, args.cutoff)
        })?;
        volumes.push((tau, volume, start.elapsed().as_secs_f64()));
    }
    let vmax = volumes
        .iter()
        .map(|(_, v, _)| v.range().0)
        .fold(0.0, f32::max);
    report!(
        "{}: {}³ grid over [{:.3}, {:.3}] × [{:.3}, {:.3}] × [{:.3}, {:.3}]",
        name,
        grid.res,
        min[0],
        max[0],
        min[1],
        max[1],
        min[2],
        max[2]
    );
    report!("{:>8} {:>10} {:>10} {:>10}", "t", "max", "min", "ms");
    for (tau, volume, seconds) in &volumes {
        let path = args.out.join(format!("{name}_volume_t{tau:.2}.png"));
        splat4d::report::charts::volume_slices_figure(&path, &name, *tau, volume, vmax)?;
        let (hi, lo) = volume.range();
        report!("{tau:>8} {hi:>10.4} {lo:>10.4} {:>10.1}", 1e3 * seconds);
    }
    Ok(())
}

fn import_gltf_command(args: &ImportGltfArgs) -> Result<()> {
    let imported =
        splat4d::io::gltf_import::import_scene(&args.model, args.kernels, args.times, args.seed)?;
    imported.scene.save(&args.out)?;
    let [t0, t1] = imported.time_range;
    report!(
        "{}: {} kernels ({} surface points × {} times over [{t0}, {t1}])",
        args.out.display(),
        imported.scene.len(),
        imported.points,
        imported.times
    );
    Ok(())
}

fn export_ply_command(args: &ExportPlyArgs) -> Result<()> {
    if !(args.cutoff.is_finite() && args.cutoff >= 0.0) {
        anyhow::bail!("--cutoff {} must be finite and ≥ 0", args.cutoff);
    }
    if !args.time.is_finite() {
        anyhow::bail!("--time must be finite");
    }
    if !args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
    {
        anyhow::bail!(
            "{}: the output of export-ply must end in .ply",
            args.out.display()
        );
    }
    let scene = Scene::load(&args.scene)?;
    let n =
        splat4d::io::ply::write_slice_ply(&scene, args.time, args.cutoff, args.sh_rest, &args.out)?;
    report!(
        "{}: {n} splats of {} kernels at t = {}",
        args.out.display(),
        scene.len(),
        args.time
    );
    Ok(())
}

/// A bench scene named by its kernel count (`10k`, `1m`, `2500`), if `text` is one.
fn builtin_scene_size(text: &str) -> Option<usize> {
    let lower = text.to_ascii_lowercase();
    let (digits, unit) = match lower.strip_suffix('k') {
        Some(d) => (d, 1_000),
        None => match lower.strip_suffix('m') {
            Some(d) => (d, 1_000_000),
            None => (lower.as_str(), 1),
        },
    };
    digits
        .parse::<usize>()
        .ok()
        .and_then(|n| n.checked_mul(unit))
        .filter(|&n| n > 0)
}

/// The scenes `bench` measures: built-in ones by size, or files with their cameras.
fn bench_scenes(args: &BenchArgs) -> Result<Vec<(String, Scene, Camera)>> {
    let (w, h) = args.size;
    let names = if args.scene.is_empty() {
        vec!["10k".to_owned(), "100k".to_owned()]
    } else {
        args.scene.clone()
    };
    let mut scenes = Vec::new();
    for name in &names {
        let path = Path::new(name);
        if let (false, Some(n)) = (path.exists(), builtin_scene_size(name)) {
            scenes.push((
                format!("bench-{}", name.to_ascii_lowercase()),
                splat4d::synthetic::bench_scene(n, 42),
                splat4d::synthetic::bench_camera(w, h),
            ));
            continue;
        }
        let scene = Scene::load(path)?;
        let camera = match &args.camera {
            Some(c) => Camera::load(c)?,
            None => {
                let (centre, r) = splat4d::volume::scene_sphere(&scene, &[args.time], args.cutoff)
                    .with_context(|| {
                        format!(
                            "{}: no kernel is alive at t = {}",
                            path.display(),
                            args.time
                        )
                    })?;
                let distance = 1.05 * r / 20f64.to_radians().sin();
                let eye = [
                    centre[0] + 0.6 * distance,
                    centre[1] + 0.35 * distance,
                    centre[2] + 0.72 * distance,
                ];
                Camera::look_at(eye, centre, [0.0, 1.0, 0.0], 40.0, w, h)?
            }
        };
        let file_name = path
            .file_name()
            .map_or("scene".into(), |n| n.to_string_lossy().into_owned());
        scenes.push((file_name, scene, camera));
    }
    Ok(scenes)
}

fn bench_command(args: &BenchArgs) -> Result<()> {
    use splat4d::report::bench::{
        BenchSettings, Method, SweepGrid, bench_render, fill_speedups, format_table, sweep,
    };
    let options = RenderOptions {
        dilation: args.dilation,
        cutoff: args.cutoff,
        exp: args.exp,
    };
    options.validate()?;
    let scenes = bench_scenes(args)?;
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let threads: Vec<usize> = match args.threads {
        Some(n) => vec![usize::from(n)],
        None if cores > 1 => vec![1, cores],
        None => vec![1],
    };
    if args.sweep {
        let (name, scene, camera) = &scenes[0];
        let grid = SweepGrid::default();
        let count = grid.cutoffs.len()
            * grid.dilations.len()
            * grid.exps.len()
            * splat4d::report::bench::SWEEP_ROUNDS;
        let settings = BenchSettings {
            tau: args.time,
            options,
            threads: *threads.last().unwrap_or(&1),
            frames: args.frames,
            samples: args.samples,
        };
        let bar = progress_bar(count, "sweep");
        let points = sweep(scene, camera, &settings, &grid, || bar.inc(1))?;
        bar.finish_and_clear();
        write_sweep(args, name, camera, settings.threads, &grid, &points)?;
        return Ok(());
    }
    let dense_for = |scene: &Scene, camera: &Camera| {
        !args.no_dense
            && (args.dense
                || scene.len() as f64 * f64::from(camera.width) * f64::from(camera.height) <= 3e9)
    };
    let jobs: usize = scenes
        .iter()
        .map(|(_, s, c)| threads.len() * if dense_for(s, c) { 2 } else { 1 })
        .sum();
    let bar = progress_bar(jobs, "bench");
    let mut rows = Vec::new();
    for (name, scene, camera) in &scenes {
        for &t in &threads {
            let settings = BenchSettings {
                tau: args.time,
                options,
                threads: t,
                frames: args.frames,
                samples: args.samples,
            };
            rows.push(bench_render(name, scene, camera, &settings, Method::Tiles)?);
            bar.inc(1);
            if dense_for(scene, camera) {
                rows.push(bench_render(name, scene, camera, &settings, Method::Dense)?);
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    fill_speedups(&mut rows);
    report!("{}", format_table(&rows).trim_end());
    report!(
        "error: |render - f64 reference| at {} seeded pixels per row; /bound = largest ratio to 1e-6 + 2e-6·Σ|a|; speed-up = dense ms / tiles ms",
        args.samples
    );
    Ok(())
}

/// Writes the sweep's table (sweep.md) and chart (sweep.png) to `args.out`.
fn write_sweep(
    args: &BenchArgs,
    name: &str,
    camera: &Camera,
    threads: usize,
    grid: &splat4d::report::bench::SweepGrid,
    points: &[splat4d::report::bench::SweepPoint],
) -> Result<()> {
    use splat4d::report::bench::sweep_table;
    use splat4d::report::charts::{TradeOffPoint, pareto_chart};
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let table = sweep_table(points);
    let heading = format!(
        "# Speed against error: {name}, {}x{}, {threads} threads, τ = {}\n\n\
         Error: |render - exact| at {} seeded pixels, exact = f64 reference without truncation \
         (ε = 0) at the default dilation {DEFAULT_DILATION}. /bound: the implementation's error \
         against the f64 reference with the point's own options, as a ratio to \
         1e-6 + 2e-6·Σ|a|. ★: on the Pareto front of (ms/frame, max error).\n\n",
        camera.width, camera.height, args.time, args.samples
    );
    write_bytes_atomically(
        &args.out.join("sweep.md"),
        format!("{heading}{table}").as_bytes(),
    )?;
    let series: Vec<String> = grid
        .dilations
        .iter()
        .flat_map(|d| {
            grid.exps
                .iter()
                .map(move |e| format!("dilation {d}, exp {e}"))
        })
        .collect();
    let chart_points: Vec<TradeOffPoint> = points
        .iter()
        .map(|p| {
            let d = grid
                .dilations
                .iter()
                .position(|&d| d == p.options.dilation)
                .unwrap_or(0);
            let e = grid
                .exps
                .iter()
                .position(|&e| e == p.options.exp)
                .unwrap_or(0);
            TradeOffPoint {
                label: format!(
                    "ε {}, s {}, {}",
                    if p.options.cutoff == DEFAULT_CUTOFF {
                        "1/255".to_owned()
                    } else {
                        format!("{:.0e}", p.options.cutoff)
                    },
                    p.options.dilation,
                    p.options.exp
                ),
                cost: p.ms_per_frame,
                error: p.model_error,
                series: d * grid.exps.len() + e,
                front: p.pareto,
            }
        })
        .collect();
    let chart = args.out.join("sweep.png");
    pareto_chart(
        &chart,
        &format!(
            "Speed against error: {name}, {}x{}, {threads} threads",
            camera.width, camera.height
        ),
        ("ms per frame", "log10 max |render - exact|"),
        &series,
        &chart_points,
    )?;
    report!("{}", table.trim_end());
    report!(
        "wrote {} and {}",
        args.out.join("sweep.md").display(),
        chart.display()
    );
    Ok(())
}

fn video_command(args: &VideoArgs) -> Result<()> {
    use splat4d::camera_path::{Circle, Lens, load_path, orbit, spiral};
    use splat4d::io::video::{VideoOptions, write_video};
    let render = args.render.options()?;
    let scene = Scene::load(&args.scene)?;
    let lens = Lens {
        width: args.size.0,
        height: args.size.1,
        fov_y_degrees: args.fov,
    };
    if !(args.fov > 0.0 && args.fov < 180.0) {
        anyhow::bail!("--fov {} must be in (0, 180) degrees", args.fov);
    }
    // A circle that frames every kernel alive at `times`.
    let circle = |spec: &CircleSpec, times: &[f64]| -> Circle {
        match spec.0 {
            Some([cx, cy, cz, radius, elevation, frames]) => Circle {
                centre: [cx, cy, cz],
                radius,
                elevation_degrees: elevation,
                frames: frames as usize,
            },
            None => {
                // The sphere around the kernels alive at `times` (slice centres ± 3σ).
                let (centre, r) = splat4d::volume::scene_sphere(&scene, times, render.cutoff)
                    .unwrap_or(([0.0; 3], 3f64.sqrt()));
                let half = 0.5
                    * args
                        .fov
                        .to_radians()
                        .min(2.0 * (f64::from(lens.width) / f64::from(lens.height)).atan());
                Circle {
                    centre,
                    radius: 1.05 * r / half.sin(),
                    elevation_degrees: 20.0,
                    frames: 60,
                }
            }
        }
    };
    let mut videos: Vec<(String, Vec<splat4d::camera_path::PathFrame>)> = Vec::new();
    if let Some(spec) = &args.orbit {
        for &tau in &args.times.0 {
            videos.push((
                format!("orbit_t{tau:.2}"),
                orbit(&circle(spec, &[tau]), &lens, tau)?,
            ));
        }
    }
    if let Some(spec) = &args.spiral {
        let [t0, t1] = args.time_range;
        let sweep: Vec<f64> = (0..=10)
            .map(|k| t0 + (t1 - t0) * f64::from(k) / 10.0)
            .collect();
        videos.push((
            "spiral".into(),
            spiral(&circle(spec, &sweep), &lens, args.time_range)?,
        ));
    }
    if let Some(path) = &args.path {
        let name = path
            .file_stem()
            .map_or("path".into(), |s| s.to_string_lossy().into_owned());
        videos.push((name, load_path(path)?));
    }
    let total = videos.iter().map(|(_, f)| f.len()).sum();
    let bar = progress_bar(total, "frames");
    let options = VideoOptions {
        fps: args.fps,
        gif: !args.no_gif,
        mp4: !args.no_mp4,
    };
    let mut written = Vec::new();
    for (name, frames) in &videos {
        let files = with_threads(args.render.threads, || {
            write_video(&scene, frames, &render, &args.out, name, &options, || {
                bar.inc(1)
            })
        })??;
        written.push(files);
    }
    bar.finish_and_clear();
    for files in &written {
        let mut line = format!("{}: {} frames", files.frames_dir.display(), files.frames);
        if let Some(gif) = &files.gif {
            line.push_str(&format!(", {}", gif.display()));
        }
        if let Some(mp4) = &files.mp4 {
            line.push_str(&format!(", {}", mp4.display()));
        }
        report!("{line}");
    }
    if let Some(note) = written.iter().find_map(|f| f.mp4_note.clone()) {
        report!("note: {note}");
    }
    Ok(())
}

/// Progress of the experiment's phases, one bar each.
struct PhaseBars(Option<ProgressBar>);

impl splat4d::report::experiment::Progress for PhaseBars {
    fn start(&mut self, phase: &str, total: usize) {
        if let Some(bar) = self.0.take() {
            bar.finish();
        }
        self.0 = Some(progress_bar(total, &format!("{phase:>10}")));
    }

    fn tick(&mut self) {
        if let Some(bar) = &self.0 {
            bar.inc(1);
        }
    }
}

fn report_command(args: &ReportArgs) -> Result<()> {
    use splat4d::report::experiment::{ExperimentConfig, run_experiment};
    let mut config = ExperimentConfig::default();
    let mut command = format!("splat4d report --out {}", args.out.display());
    if args.quick {
        config.dataset.views = 4;
        config.dataset.times = 4;
        config.dataset.width = 32;
        config.dataset.height = 32;
        config.model_kernels = 20;
        config.model_steps = 60;
        config.frame_kernels = 5;
        config.frame_steps = 20;
        config.ablation_sigma_t = vec![0.05, 0.2];
        config.sweep_times = 9;
        config.volume_res = 16;
        config.adaptive_steps = 60;
        config.blob_dataset.views = 4;
        config.blob_dataset.times = 3;
        config.blob_dataset.width = 24;
        config.blob_dataset.height = 24;
        command.push_str(" --quick");
    }
    if let Some(n) = args.kernels {
        config.model_kernels = n;
        command.push_str(&format!(" --kernels {n}"));
    }
    if let Some(n) = args.steps {
        config.model_steps = n;
        command.push_str(&format!(" --steps {n}"));
    }
    if let Some((w, h)) = args.size {
        (config.dataset.width, config.dataset.height) = (w, h);
        command.push_str(&format!(" --size {w}x{h}"));
    }
    let mut bars = PhaseBars(None);
    let results = run_experiment(&config, &mut bars)?;
    if let Some(bar) = bars.0.take() {
        bar.finish();
    }
    let path = splat4d::report::markdown::write_report(&results, &args.out, &command)?;
    report!(
        "{:<16} {:>8} {:>8} {:>12} {:>12} {:>12} {:>11}",
        "method",
        "params",
        "fit s",
        "train",
        "held-out t",
        "held-out v+t",
        "roughness"
    );
    for m in &results.methods {
        let [a, b, t] = m.psnr_splits;
        report!(
            "{:<16} {:>8} {:>8.1} {a:>9.2} dB {b:>9.2} dB {t:>9.2} dB {:>11.2e}",
            m.name,
            m.parameters,
            m.fit_seconds,
            m.roughness
        );
    }
    report!(
        "{:<16} {:>8} {:>8} {:>12} {:>12} {:>12} {:>11.2e}",
        "ground truth",
        "",
        "",
        "",
        "",
        "",
        results.ground_truth_roughness
    );
    report!("report: {} ({:.0} s)", path.display(), results.seconds);
    Ok(())
}
