//! `splat4d fit`: kernels fitted to a multi-view dataset with Adam. Every default comes from
//! [`splat4d::fit::plan::FitPlan`]; this file only maps flags onto it.

use std::path::PathBuf;

use splat4d::Blend;
use splat4d::Result;
use splat4d::fit::adam::LearningRates;
use splat4d::fit::adaptive::AdaptiveOptions;
use splat4d::fit::alpha::AlphaFitOptions;
use splat4d::fit::plan::{DEFAULT_ALPHA, FitPlan};
use splat4d::fit::train::FitMode;
use splat4d::tasks::fit::{FitRequest, fit_dataset};

use super::args::{RenderFlags, parse_list};

#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// Dataset folder: D-NeRF layout (transforms_train.json, and val/test for held-out
    /// views), one nerfstudio/instant-ngp transforms.json, or a COLMAP model (sparse/0 and
    /// images/).
    #[arg(long)]
    views: PathBuf,
    /// Refuse a dataset with frames whose image file is missing (by default they are
    /// skipped with one warning naming them).
    #[arg(long)]
    strict: bool,
    /// Initial scene: `auto` (one kernel at the centre of the box, then densify, prune and
    /// merge so the count follows the data), `random:N` for N kernels in the box (a fixed count unless
    /// --adaptive), or a scene file.
    #[arg(long, default_value = "auto")]
    init: String,
    /// Kernels `auto` starts from: 1 is one kernel at the centre of the box (space and
    /// time); more are spread at random in the box.
    /// (Default: 4 additive; 2000 kernels at random in the box for the alpha blend.)
    #[arg(long)]
    start_kernels: Option<usize>,
    /// Densify and prune during the fit (always on with `--init auto`).
    #[arg(long)]
    adaptive: bool,
    /// Budget of the adaptive fit: never more kernels than this.
    /// (Default: 100000 additive, 200000 alpha.)
    #[arg(long)]
    max_kernels: Option<usize>,
    /// Steps between densify/prune rounds.
    #[arg(long, default_value_t = FitPlan::default().rounds.every)]
    densify_every: usize,
    /// Fraction of the steps before the first densify/prune round.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.from)]
    densify_from: f64,
    /// Fraction of the steps after which the kernel count is frozen.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.until)]
    densify_until: f64,
    /// Mean positional gradient (loss per standard deviation of motion) at which a kernel
    /// is densified.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.gradient_threshold)]
    densify_threshold: f64,
    /// Kernels are densified only when the mean training loss fell by less than this
    /// fraction over the last --densify-every steps (the fit has stalled).
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.min_improvement)]
    min_improvement: f64,
    /// Kernels within this many standard deviations of each other (position, time,
    /// velocity, log-scale) are merged into one; 0 disables merging.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.merge_tolerance)]
    merge_tolerance: f64,
    /// Largest fraction of the kernels densified in one round.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.max_growth)]
    max_growth: f64,
    /// Peak |amplitude| below which a kernel is pruned (default: 2/255).
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rounds.prune_below)]
    prune_below: f64,
    /// Densified kernels whose mean spatial scale is above this are split (scales / 1.6),
    /// the others cloned (default: when the scales are not fitted, an eighth of the largest
    /// initial scale; otherwise never split: the fit sizes the kernels).
    #[arg(long, value_parser = super::args::finite)]
    min_scale: Option<f64>,
    /// Adam steps (default: 4000 additive, 6000 alpha).
    #[arg(long)]
    steps: Option<usize>,
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
    /// Amplitude of every channel of a `random:N` or `auto` start (default: the data's mean
    /// colour above the background, so the sign follows the data).
    #[arg(long, value_parser = super::args::finite, allow_negative_numbers = true)]
    init_amplitude: Option<f64>,
    /// Log file: one JSON object per step (step, seconds, train_loss, heldout_psnr).
    #[arg(long)]
    log: Option<PathBuf>,
    /// Watch the fit in a web browser: serve `splat4d view`'s page on this loopback port
    /// (8080 when given alone), with the current model every few seconds and the loss chart.
    #[arg(long, num_args = 0..=1, default_missing_value = "8080", value_name = "PORT")]
    view: Option<u16>,
    /// Learning rate of the spatial means.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rates.mean)]
    lr_mean: f64,
    /// Learning rate of the time means.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rates.time)]
    lr_time: f64,
    /// Learning rate of the amplitudes.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rates.amplitude)]
    lr_amplitude: f64,
    /// Learning rate of the velocities (with `--mode velocity` or --fit-velocity).
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rates.velocity)]
    lr_velocity: f64,
    /// Learning rates at the last step as a fraction of the first (exponential decay).
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().final_rate_factor)]
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
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rates.scale)]
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
    /// Keep the background fixed at its start (the given --background, or the median of the
    /// training images' border pixels).
    #[arg(long)]
    freeze_background: bool,
    /// Learning rate of the background colour.
    #[arg(long, value_parser = super::args::finite, default_value_t = FitPlan::default().rates.background)]
    lr_background: f64,
    /// Average N×N blocks of pixels of every image (a box filter, like nerfstudio's
    /// `images_N`); the intrinsics are divided by N.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=i64::from(splat4d::io::dataset::MAX_DOWNSCALE)))]
    downscale: u32,
    /// Read dataset images whose real path (symlinks followed) lies outside the dataset's
    /// folder (refused by default, naming the frame).
    #[arg(long)]
    allow_outside_images: bool,
    /// Views per step (default: 8 additive, 4 alpha).
    #[arg(long)]
    batch: Option<usize>,
    /// Held-out evaluation period, steps (0: only at the end).
    #[arg(long, default_value_t = FitPlan::default().eval_every)]
    eval_every: usize,
    /// Seed of the batch order and of `random:N`.
    #[arg(long, default_value_t = FitPlan::default().seed)]
    seed: u64,
    /// Background `r,g,b`: RGBA images are composited over it and the fit starts from it
    /// (default: RGBA images over black; the fit starts from the median of the images'
    /// border pixels). The background is fitted unless --freeze-background.
    #[arg(long, value_parser = parse_list::<3>)]
    background: Option<[f64; 3]>,
    /// The blend to fit (SPEC §5 or §8): `additive`, `alpha`, or `auto`: the start scene's
    /// blend, else the one a splat4d dataset records (`splat4d_blend`), else `alpha`
    /// (occlusion and view-dependent colour, what real captures need).
    #[arg(long, default_value = "auto")]
    blend: String,
    /// SH triplets per kernel of an alpha fit: 0, 3, 8 or 15 (degree 0–3).
    #[arg(long, default_value_t = DEFAULT_ALPHA.sh_count)]
    sh: usize,
    #[command(flatten)]
    render: RenderFlags,
}

pub fn run(args: &FitArgs) -> Result<()> {
    let defaults = FitPlan::default();
    let blend = match args.blend.as_str() {
        "auto" => None,
        other => Some(other.parse::<Blend>().map_err(splat4d::Error::Usage)?),
    };
    let alpha = AlphaFitOptions {
        steps: args.steps.unwrap_or(DEFAULT_ALPHA.steps),
        batch_size: args.batch.unwrap_or(DEFAULT_ALPHA.batch_size),
        start_kernels: args.start_kernels.unwrap_or(DEFAULT_ALPHA.start_kernels),
        max_kernels: args.max_kernels.unwrap_or(DEFAULT_ALPHA.max_kernels),
        sh_count: args.sh,
        eval_every: args.eval_every,
        seed: args.seed,
        render: args.render.options(),
        ..DEFAULT_ALPHA
    };
    let plan = FitPlan {
        steps: args.steps.unwrap_or(defaults.steps),
        start_kernels: args.start_kernels.unwrap_or(defaults.start_kernels),
        adaptive: args.adaptive,
        rounds: AdaptiveOptions {
            every: args.densify_every,
            from: args.densify_from,
            until: args.densify_until,
            gradient_threshold: args.densify_threshold,
            prune_below: args.prune_below,
            max_growth: args.max_growth,
            min_improvement: args.min_improvement,
            merge_tolerance: args.merge_tolerance,
            max_kernels: args.max_kernels.unwrap_or(defaults.rounds.max_kernels),
            ..defaults.rounds
        },
        min_scale: args.min_scale,
        bounds: args.r#box,
        time_range: args.time_range,
        init_scale: args.init_scale,
        init_amplitude: args.init_amplitude,
        rates: LearningRates {
            mean: args.lr_mean,
            time: args.lr_time,
            amplitude: args.lr_amplitude,
            velocity: args.lr_velocity,
            scale: args.lr_scale,
            background: args.lr_background,
        },
        final_rate_factor: args.lr_final,
        mode: args.mode,
        fit_velocity: args.fit_velocity,
        fit_scale: args.fit_scale,
        freeze_mean: args.freeze_mean,
        freeze_time: args.freeze_time,
        freeze_amplitude: args.freeze_amplitude,
        freeze_background: args.freeze_background,
        batch_size: args.batch.unwrap_or(defaults.batch_size),
        eval_every: args.eval_every,
        seed: args.seed,
        background: args.background,
        render: args.render.options(),
    };
    let request = FitRequest {
        views: args.views.clone(),
        downscale: args.downscale,
        strict: args.strict,
        allow_outside_images: args.allow_outside_images,
        init: args.init.clone(),
        plan,
        blend,
        alpha,
        out: args.out.clone(),
        log: args.log.clone(),
        threads: args.render.threads(),
        view: args.view,
    };
    super::with_progress(|bars| fit_dataset(&request, bars))
}
